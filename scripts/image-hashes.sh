#!/usr/bin/env bash
# Hashes of a fixed set of images for fixed seeds, to show that a refactor leaves the arithmetic
# unchanged: renders (Cornell box, ajar), online-training frames, renders from the trained
# snapshot (first vertex, spread), and `nrc compare`'s images and reference; then the caustics
# scene (delta vertices) with a producer mix. Run it with the builds before and after a change
# and compare the two hash lists (`diff <(sort -k2 A/hashes.txt) <(sort -k2 B/hashes.txt)`).
# Usage: scripts/image-hashes.sh NRC_BINARY OUT_DIR   (from the repository root)
set -euo pipefail
B=$1
O=$2
mkdir -p "$O/train" "$O/cmp" "$O/caustics/train" "$O/reuse"
S=scenes/cornell-box.gltf
log="$O/log.txt"
"$B" render --scene $S --spp 8 --width 64 --height 64 --out "$O/render.exr" --seed 5 > "$log" 2>&1
"$B" render --scene scenes/ajar.gltf --spp 4 --width 48 --height 48 --out "$O/render-ajar.exr" --seed 5 >> "$log" 2>&1
"$B" train --scene $S --frames 6 --resolution 64 --records 4096 --width 48 --height 48 \
  --frames-out "$O/train" --every 2 --snapshot "$O/c.nrc" --seed 3 >> "$log" 2>&1
"$B" render --scene $S --cache "$O/c.nrc" --spp 4 --width 48 --height 48 --termination first --out "$O/cache-first.exr" >> "$log" 2>&1
"$B" render --scene $S --cache "$O/c.nrc" --spp 4 --width 48 --height 48 --out "$O/cache-spread.exr" >> "$log" 2>&1
"$B" compare --scene $S --methods pt-2spp,pt-1spp-nonee,nrc-pt-sl --equal-spp 1 --width 32 --height 32 \
  --train-frames 3 --records 4096 --out "$O/cmp" --reference-spp 16 --no-flip --cache-dir "$O/refs" >> "$log" 2>&1
C=scenes/caustics.gltf
"$B" render --scene $C --spp 8 --width 48 --height 48 --out "$O/caustics/render.exr" --seed 5 >> "$log" 2>&1
"$B" train --scene $C --frames 4 --resolution 64 --records 4096 --width 32 --height 32 --frames-out "$O/caustics/train" \
  --every 1 --snapshot "$O/caustics/c.nrc" --seed 3 --producer mix:pt-sl=0.5,bt=0.2,lt=0.1,sppc=0.2 >> "$log" 2>&1
"$B" render --scene $C --cache "$O/caustics/c.nrc" --spp 4 --width 32 --height 32 --termination bth --out "$O/caustics/cache-bth.exr" >> "$log" 2>&1
# The resampling passes: three frames each (history reused), two runs, warm-up included.
"$B" compare --scene scenes/ajar.gltf --equal-spp 3 --runs 2 --width 32 --height 32 --no-flip \
  --methods restir-di,restir-di-biased,restir-gi,restir-gi-biased,wsrestir-gi,ddgi-restir,nrc-restir,ddgi-nrc-restir,restir-gi-nrc,wsrestir-gi-nrc \
  --train-frames 3 --records 4096 --reference-spp 16 --out "$O/reuse" --cache-dir "$O/refs" >> "$log" 2>&1
cd "$O" && sha256sum render.exr render-ajar.exr train/*.exr cache-*.exr cmp/*.exr refs/*/mean.exr caustics/*.exr caustics/train/*.exr reuse/*.exr \
  | sed 's#  # #' > hashes.txt
echo "wrote $O/hashes.txt"
