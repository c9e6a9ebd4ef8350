#!/usr/bin/env bash
# The neural cache against the spatial-hash cache with every pass that takes a radiance
# source (issue 34): cache-terminated paths (spread and first vertex), screen- and world-space
# ReSTIR GI with the cache, DDGI resampling with the cache as the light, DDGI probes fed by the
# cache, and SMC instant radiosity with the cache; each trained online by pt-sl records, at
# equal time, on the scenes given (default: the five shipped static scenes).
#
#   scripts/hash-vs-neural.sh [SCENE...]      # names of scenes/NAME.gltf
set -euo pipefail
cd "$(dirname "$0")/.."
nrc=${NRC:-${CARGO_TARGET_DIR:-$HOME/.cache/nrc-target}/release/nrc}
scenes=("$@")
((${#scenes[@]})) || scenes=(cornell-box ajar glossy caustics sun-spot-env)
hash="@1spp+hash:pt-sl"
methods="pt-1spp,nrc-pt-sl,hash-pt-sl,nrc-pt-sl-first,hash-pt-sl-first"
for pass in restir-gi-nrc wsrestir-gi-nrc nrc-restir ddgi-nrc-restir smc-ir-nrc; do
  methods+=",$pass,$pass$hash"
done
for scene in "${scenes[@]}"; do
  "$nrc" compare --scene "scenes/$scene.gltf" --methods "$methods" --equal-time 150 --runs 2 \
    --width 96 --height 96 --train-frames 100 --reference-spp 2048 \
    --out "out/hash-vs-neural-all/$scene"
done
