#!/usr/bin/env bash
# Issue 31: the per-frame training budget. For each scene and producer, `nrc train` online with
# `--train-budget-ms`, and from its per-frame statistics: the records the loop chose, and how many
# frames after the warm-up (nrc_train::schedule::BUDGET_WARM_UP_FRAMES) spent more than 1.2 × what
# they planned (the whole budget while the cache warms up or recovers, half once it has settled),
# and more than 1.2 × the budget.
# Usage: scripts/budget-study.sh [BUDGET_MS...]    (from the repository root; default 10)
# Environment: SCENES (caustics ajar photon-nrc-ajar-caustic), PRODUCERS (pt pt-sl bt lt sppc),
# FRAMES (500), SIZE (128: the render's width and height), NRC (the program; default the release
# build in $CARGO_TARGET_DIR or target/).
set -euo pipefail
[ $# -eq 0 ] && set -- 10
nrc=${NRC:-${CARGO_TARGET_DIR:-target}/release/nrc}
[ -x "$nrc" ] || { echo "error: $nrc not found: build with cargo build --release first" >&2; exit 1; }
scene_path() {
  case $1 in
    photon-nrc-ajar-caustic) echo ../shared/scenes/photon-nrc-ajar-caustic/ajar_caustic.glb ;;
    *) echo "scenes/$1.gltf" ;;
  esac
}
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
echo "| budget (ms) | scene | producer | records/frame (min · mean · max) | produce + train ms (mean) | frames over 1.2 × plan | worst frame / plan | frames over 1.2 × budget | worst frame / budget |"
echo "|---:|---|---|---|---:|---:|---:|---:|---:|"
for budget in "$@"; do
  for scene in ${SCENES:-caustics ajar photon-nrc-ajar-caustic}; do
    path=$(scene_path "$scene")
    if [ ! -f "$path" ]; then echo "skipped: $path not found" >&2; continue; fi
    for producer in ${PRODUCERS:-pt pt-sl bt lt sppc}; do
      "$nrc" train --scene "$path" --producer "$producer" --frames "${FRAMES:-500}" \
        --width "${SIZE:-128}" --height "${SIZE:-128}" --resolution 128 \
        --train-budget-ms "$budget" --stats "$out/stats.csv" > /dev/null 2>&1
      python3 - "$out/stats.csv" "$budget" "$scene" "$producer" <<'PY'
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))[10:]
records = [int(r["records"]) for r in rows]
cost = [float(r["produce_ms"]) + float(r["train_ms"]) for r in rows]
plan = [float(r["spend_ms"]) for r in rows]
budget = float(sys.argv[2])
over = sum(c > 1.2 * p for c, p in zip(cost, plan))
worst = max(c / p for c, p in zip(cost, plan))
over_budget = sum(c > 1.2 * budget for c in cost)
print(f"| {sys.argv[2]} | {sys.argv[3]} | `{sys.argv[4]}` | {min(records)} · {sum(records)/len(records):.0f} · {max(records)} "
      f"| {sum(cost)/len(cost):.1f} | {over} of {len(rows)} | {worst:.2f} | {over_budget} of {len(rows)} | {max(cost) / budget:.2f} |")
PY
    done
  done
done
