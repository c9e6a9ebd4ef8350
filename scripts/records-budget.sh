#!/usr/bin/env bash
# The training budget per frame, measured: on the shipped scenes, each cache method at each
# number of training records per frame, rendered at 1 spp (one full online frame per displayed
# frame: produce, train, render, all timed), against path tracing given the same time per frame
# (equal time). The best records-per-frame gives the largest error ratio (path tracing's over
# the cache's) on the emitter-excluded image.
# Usage: scripts/records-budget.sh [OUT_DIR]   (env: NRC, W, H, RUNS, FRAMES, RECORDS)
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-out/records-budget}
W=${W:-128}
H=${H:-128}
RUNS=${RUNS:-3}
FRAMES=${FRAMES:-100}
RECORDS=${RECORDS:-"4096 16384 65536"}
# NRC: a prebuilt binary to measure (else the release build of this checkout).
if [[ -z "${NRC:-}" ]]; then
  cargo build --release --quiet
fi
nrc=${NRC:-${CARGO_TARGET_DIR:-target}/release/nrc}
mkdir -p "$out"
for scene in cornell-box ajar; do
  case $scene in
    cornell-box) res=128 ;;
    *) res=256 ;;
  esac
  for r in $RECORDS; do
    dir="$out/$scene-$r"
    [[ -f "$dir/report.json" ]] || "$nrc" compare --scene "scenes/$scene.gltf" \
      --methods nrc-pt-sl,nrc-pt-sl-first --equal-spp 1 --width "$W" --height "$H" --runs "$RUNS" \
      --train-frames "$FRAMES" --records "$r" --resolution "$res" --reference-spp 1024 \
      --exclude-emitters --no-flip --out "$dir" > /dev/null 2>&1
    python3 -c "import json; [print(x['method'], round(x['time_per_frame_ms'])) for x in json.load(open('$dir/report.json'))['rows']]" |
    while read -r m t; do
      [[ -f "$dir-pt-$m/report.json" ]] || "$nrc" compare --scene "scenes/$scene.gltf" --methods pt-1spp \
        --equal-time "$t" --width "$W" --height "$H" --runs "$RUNS" --reference-spp 1024 \
        --exclude-emitters --no-flip --out "$dir-pt-$m" > /dev/null 2>&1
      python3 - "$dir/report.json" "$dir-pt-$m/report.json" "$scene" "$r" "$m" <<'PY'
import json, sys
c = next(x for x in json.load(open(sys.argv[1]))["rows"] if x["method"] == sys.argv[5])
p = json.load(open(sys.argv[2]))["rows"][0]
print(f"{sys.argv[3]:12s} records {sys.argv[4]:>6s} {c['method']:16s} {c['time_per_frame_ms']:6.1f} ms/frame  "
      f"MSE {c['mse']:.3g} (pt at equal time {p['mse']:.3g}, {p['samples_per_pixel']:.2f} spp: x{p['mse']/c['mse']:.2f})  "
      f"relMSE {c['rel_mse']:.3g} (x{p['rel_mse']/c['rel_mse']:.2f})  MAPE {c['mape']:.3g} (x{p['mape']/c['mape']:.2f})")
PY
    done
  done
done
