#!/usr/bin/env bash
# The viewer's frame rates in a real window: starts Xvfb, opens `nrc view` on a scene, lets it
# run idle, then flies the camera (keys held with xdotool) and prints the UI's and the loop's
# frame rates the viewer reports (--print-rates, every 5 s). Needs Xvfb, xdotool and a Vulkan
# driver (Mesa's software one will do); the binary is the release build.
#
#   scripts/view-rates.sh [SCENE] [extra nrc view flags...]
#   scripts/view-rates.sh ../shared/scenes/kitchen/kitchen.gltf --width 320 --height 180 ...
set -euo pipefail
cd "$(dirname "$0")/.."
scene=${1:-scenes/cornell-box.gltf}
shift || true
nrc=${NRC:-${CARGO_TARGET_DIR:-$HOME/.cache/nrc-target}/release/nrc}
idle=${IDLE:-12}
fly=${FLY:-12}

display=""
for n in $(seq 150 199); do
  if [[ ! -e /tmp/.X$n-lock ]]; then display=":$n"; break; fi
done
[[ -n $display ]] || { echo "error: no free X display number" >&2; exit 1; }
Xvfb "$display" -screen 0 1600x1000x24 -nolisten tcp >/dev/null 2>&1 &
xvfb=$!
log=$(mktemp)
cleanup() { kill "${viewer:-}" "$xvfb" 2>/dev/null || true; rm -f "$log"; }
trap cleanup EXIT
for _ in $(seq 50); do [[ -e /tmp/.X11-unix/X${display#:} ]] && break; sleep 0.1; done

DISPLAY=$display "$nrc" view --scene "$scene" --print-rates "$@" >"$log" 2>&1 &
viewer=$!
window=""
for _ in $(seq 300); do
  window=$(DISPLAY=$display xdotool search --name "nrc view" 2>/dev/null | head -1 || true)
  [[ -n $window ]] && break
  sleep 0.2
done
[[ -n $window ]] || { cat "$log" >&2; echo "error: the viewer's window did not appear" >&2; exit 1; }
DISPLAY=$display xdotool windowfocus --sync "$window"

sleep "$idle"
echo "idle (the UI draws when the loop has a new frame):"
grep "frames/s" "$log" | tail -2
: >"$log.mark"
lines=$(wc -l <"$log")
# Up and down in turns, a second each, so that the camera stays in the scene.
end=$((SECONDS + fly))
while ((SECONDS < end)); do
  for key in e q; do
    DISPLAY=$display xdotool keydown $key
    sleep 1
    DISPLAY=$display xdotool keyup $key
  done
done
echo "flying (E and Q held in turns: the camera moves every UI frame):"
tail -n +"$((lines + 1))" "$log" | grep "frames/s" | tail -2
DISPLAY=$display xdotool key Escape
wait "$viewer"
rm -f "$log.mark"
