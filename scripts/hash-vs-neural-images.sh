#!/usr/bin/env bash
# Side-by-side images of the neural against the spatial-hash cache (issue 34), from the renders
# that scripts/hash-vs-neural.sh leaves in out/hash-vs-neural-all/SCENE (run 0 of each method,
# tone-mapped as `nrc compare --png` writes them): per scene (a row), the reference, path
# tracing, the network and the hash cache ending paths by the spread heuristic and at the first
# vertex, and screen-space ReSTIR GI reading each; every image from the same 150 ms budget.
# Needs ImageMagick's `montage` and the DejaVu fonts.
#
#   scripts/hash-vs-neural-images.sh [OUT.png]     # default docs/images/hash-vs-neural.png
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-docs/images/hash-vs-neural.png}
dir=out/hash-vs-neural-all
command -v montage >/dev/null || { echo "error: ImageMagick's montage is not installed" >&2; exit 1; }
columns=(reference pt-1spp nrc-pt-sl hash-pt-sl nrc-pt-sl-first hash-pt-sl-first restir-gi-nrc "restir-gi-nrc@1spp+hash:pt-sl")
labels=("reference" "path tracing" "neural, spread" "hash, spread" "neural, 1st vertex" "hash, 1st vertex" "ReSTIR GI + neural" "ReSTIR GI + hash")
args=()
for scene in cornell-box ajar glossy caustics sun-spot-env; do
  for k in "${!columns[@]}"; do
    png="$dir/$scene/${columns[$k]}.png"
    [[ -f $png ]] || { echo "error: $png is missing: run scripts/hash-vs-neural.sh first" >&2; exit 1; }
    label=${labels[$k]}
    ((k == 0)) && label="$scene: $label"
    args+=(-label "$label" "$png")
  done
done
tmp="$out.tmp.$$.png"
montage -font DejaVu-Sans -pointsize 11 "${args[@]}" -tile "${#columns[@]}x" -filter point \
  -geometry 144x144+3+3 -background white "$tmp"
mv "$tmp" "$out"
echo "wrote $out"
