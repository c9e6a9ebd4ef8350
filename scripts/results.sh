#!/usr/bin/env bash
# Reproduces the tables of RESULTS.md: on each shipped scene, path tracing at 1 spp and each
# producer's cache (trained online for $FRAMES frames, then measured at 1 spp, training
# included in the frame time; training records per frame: the default), at equal samples; then path tracing at the caches' mean time per
# frame (equal time). Usage: scripts/results.sh [OUT_DIR]   (env: FRAMES, W, H, RUNS)
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-out/results}
FRAMES=${FRAMES:-200}
W=${W:-128}
H=${H:-128}
RUNS=${RUNS:-4}
# NRC: a prebuilt binary to measure (else the release build of this checkout).
if [[ -z "${NRC:-}" ]]; then
  cargo build --release --quiet
fi
nrc=${NRC:-${CARGO_TARGET_DIR:-target}/release/nrc}
mkdir -p "$out"
for scene in cornell-box caustics ajar; do
  case $scene in
    cornell-box) res=128; refspp=1024; extra=(nrc-pt-sl-first); masks=("" "--exclude-emitters") ;;
    caustics) res=256; refspp=4096; extra=(nrc-pt-sl-first); masks=("") ;;
    *) res=256; refspp=1024; extra=(nrc-pt-sl-first); masks=("") ;;
  esac
  methods=$(IFS=,; echo "pt-1spp,nrc-pt,nrc-pt-sl,nrc-bt,nrc-lt,nrc-sppc${extra:+,${extra[*]}}")
  for mask in "${masks[@]}"; do
    dir="$out/$scene${mask:+-noemit}"
    "$nrc" compare --scene "scenes/$scene.gltf" --methods "$methods" --equal-spp 1 \
      --width "$W" --height "$H" --runs "$RUNS" --train-frames "$FRAMES" \
      --resolution "$res" --reference-spp "$refspp" $mask --out "$dir/equal-spp"
    # Path tracing at equal time: at each cache's time per frame.
    python3 -c "import json; [print(x['method'], round(x['time_per_frame_ms'])) for x in json.load(open('$dir/equal-spp/report.json'))['rows'] if x['method'].startswith('nrc-')]" |
    while read -r m t; do
      "$nrc" compare --scene "scenes/$scene.gltf" --methods pt-1spp --equal-time "$t" \
        --width "$W" --height "$H" --runs "$RUNS" --reference-spp "$refspp" $mask --out "$dir/equal-time-$m"
    done
  done
done
# Caustics, termination study: at the first vertex or the first diffuse vertex the cache's own
# caustic (what SPPC's photons carry) shows; the spread heuristic never ends at the primary hit.
"$nrc" compare --scene scenes/caustics.gltf \
  --methods nrc-pt-first,nrc-sppc-first,nrc-bt-first,nrc-lt-first,nrc-pt-diffuse,nrc-sppc-diffuse \
  --equal-spp 1 --width "$W" --height "$H" --runs "$RUNS" --train-frames "$FRAMES" \
  --resolution 256 --reference-spp 4096 --out "$out-extra/caustics-first/equal-spp"
