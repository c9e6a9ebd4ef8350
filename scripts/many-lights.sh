#!/usr/bin/env bash
# The light tree against choosing lights by power, and ReSTIR DI against path tracing, on the
# many-light hall (scenes/many-lights.gltf; issue 33), 128 x 128, 4 runs, the pixels that see
# a lamp directly left out of the errors (--exclude-emitters: their error is anti-aliasing,
# which no light sampler touches; the full-image runs keep them):
#  - direct light only (--max-depth 2), 16 samples a pixel: next-event estimation's error with
#    each light sampler at equal samples (MSE x samples is the variance of one sample);
#  - full paths at equal time (200 ms a frame): path tracing and ReSTIR DI with 32 light
#    candidates and with 4 (the default with the tree), with each sampler; then the same on the
#    full image.
# Every run shares one reference (either sampler is unbiased).
#
#   scripts/many-lights.sh            # out/many-lights/{direct,time,full}-{power,tree}
set -euo pipefail
cd "$(dirname "$0")/.."
nrc=${NRC:-${CARGO_TARGET_DIR:-$HOME/.cache/nrc-target}/release/nrc}
common=(--scene scenes/many-lights.gltf --width 128 --height 128 --runs 4 --reference-spp 1024)
methods=pt-1spp,restir-di:light=32,tree-light=32,restir-di:light=4,tree-light=4
for sampler in tree power; do
  "$nrc" compare "${common[@]}" --light-sampler "$sampler" --max-depth 2 --methods pt-1spp \
    --equal-spp 16 --exclude-emitters --out "out/many-lights/direct-$sampler"
done
for sampler in tree power; do
  "$nrc" compare "${common[@]}" --light-sampler "$sampler" --methods "$methods" \
    --equal-time 200 --exclude-emitters --out "out/many-lights/time-$sampler"
done
for sampler in tree power; do
  "$nrc" compare "${common[@]}" --light-sampler "$sampler" --methods "$methods" \
    --equal-time 200 --out "out/many-lights/full-$sampler"
done
