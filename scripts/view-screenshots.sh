#!/usr/bin/env bash
# The README's pictures of the viewer, taken by its headless mode (no display needed, only a
# Vulkan driver; Mesa's software one will do): the Cornell box after 120 frames of the online
# loop, and the Country Kitchen ('Country Kitchen' by Jay-Artist, CC-BY 3.0; pbrt version by
# Benedikt Bitterli; read from ../shared/scenes/kitchen, not shipped) after 40.
set -euo pipefail
cd "$(dirname "$0")/.."
nrc=${NRC:-${CARGO_TARGET_DIR:-$HOME/.cache/nrc-target}/release/nrc}
"$nrc" view --headless --scene scenes/cornell-box.gltf --frames 120 --width 320 --height 320 \
  --screenshot docs/images/view-cornell.png
kitchen=../shared/scenes/kitchen
if [[ -f $kitchen/kitchen.gltf ]]; then
  # shellcheck disable=SC2046 # the camera file holds flags
  "$nrc" view --headless --scene $kitchen/kitchen.gltf $(cat $kitchen/camera.txt) --frames 40 \
    --width 480 --height 270 --screenshot docs/images/view-kitchen.png
else
  echo "skipped the kitchen: $kitchen is absent" >&2
fi
