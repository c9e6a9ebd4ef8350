#!/usr/bin/env bash
# Every pass on the Country Kitchen at 1280 x 720 (issue 33): per pass, the time of a frame by
# phase (the last of FRAMES frames, so the stateful passes run with their history) and the
# process's peak resident memory (GNU time's "Maximum resident set size": scene, BVH, buffers,
# the cache), as a Markdown table; then `nrc train` at 1280 x 720 (its frame by phase). The
# passes that read a radiance cache read a snapshot trained here first (64 frames at 160 x 90).
# 'Country Kitchen' by Jay-Artist, CC-BY 3.0; pbrt version by Benedikt Bitterli.
#
#   scripts/kitchen-720p.sh [FRAMES]     # default 2; needs ../shared/scenes/kitchen, /usr/bin/time
set -euo pipefail
cd "$(dirname "$0")/.."
nrc=${NRC:-${CARGO_TARGET_DIR:-$HOME/.cache/nrc-target}/release/nrc}
frames=${1:-2}
kitchen=../shared/scenes/kitchen
[[ -f $kitchen/kitchen.gltf ]] || { echo "error: $kitchen/kitchen.gltf is missing" >&2; exit 1; }
[[ -x /usr/bin/time ]] || { echo "error: GNU time (/usr/bin/time) is not installed" >&2; exit 1; }
read -ra camera < "$kitchen/camera.txt"
scene=(--scene "$kitchen/kitchen.gltf" "${camera[@]}")
out=out/kitchen-720p
mkdir -p "$out"
"$nrc" train "${scene[@]}" --width 160 --height 90 --frames 64 --snapshot "$out/cache.nrc" >"$out/train-snapshot.log" 2>&1
echo "| pass | frame (s) | phases | peak memory (MiB) |"
echo "|---|---:|---|---:|"
for pass in pt restir-di restir-gi wsrestir-gi ddgi-spread ddgi-restir ir smc-ir \
    cache cache-first restir-gi-nrc wsrestir-gi-nrc nrc-restir ddgi-nrc-restir smc-ir-nrc; do
  extra=()
  case $pass in cache*|*-nrc|nrc-*|*-nrc-*) extra=(--cache "$out/cache.nrc") ;; esac
  log="$out/$pass.log"
  /usr/bin/time -v "$nrc" render "${scene[@]}" --width 1280 --height 720 --spp 1 --pass "$pass" \
    --frames "$frames" "${extra[@]}" --out "$out/$pass.exr" >"$log" 2>&1
  line=$(grep '^rendered' "$log")
  secs=$(sed -E 's/.* in ([0-9.]+) s.*/\1/' <<<"$line")
  phases=$(sed -nE 's/.*phases: (.*)/\1/p' <<<"$line")
  rss=$(awk '/Maximum resident set size/ {printf "%.0f", $NF / 1024}' "$log")
  echo "| \`$pass\` | $secs | ${phases:-–} | $rss |"
done
log="$out/train.log"
/usr/bin/time -v "$nrc" train "${scene[@]}" --width 1280 --height 720 --frames 4 >"$log" 2>&1
rss=$(awk '/Maximum resident set size/ {printf "%.0f", $NF / 1024}' "$log")
echo
echo "nrc train at 1280 x 720, 4 frames: peak memory $rss MiB; its closing lines:"
grep -v '^\s' "$log" | grep -iE 'frame|phase|ms' | tail -4
