#!/usr/bin/env bash
# Issue 31: what makes the cache drift in long online runs. One training setting changed at a
# time from the hash-grid preset (models/nrc-hashgrid.json); for each, a long online run, and the
# cache's relMSE at every tenth of it for paths ending at the first vertex (where the camera's
# records land) and by the spread heuristic (where later vertices query the cache): the
# `drift_study` test of crates/nrc-harness/tests/online.rs, which prints a Markdown table.
# Usage: scripts/drift-study.sh [VARIANT...]    (from the repository root; a variant is a
# comma-separated list of path=value edits of the preset's JSON, or `base`)
# Environment: SCENE (photon-nrc-ajar-caustic, ajar or caustics), PRODUCERS (pt), FRAMES (2000),
# RECORDS (4096), RESOLUTION (128: the finest grid resolution along the scene's longest axis),
# SPP (256: the renders' samples; at 4 the spread render's relMSE is mostly its own variance,
# which a darker cache lowers, and the study prints that control).
set -euo pipefail
if [ $# -eq 0 ]; then
  set -- base \
    optimizer.nested.nested.learning_rate=2e-3 \
    optimizer.nested.nested.epsilon=1e-8 \
    optimizer.nested.nested.beta2=0.999 \
    optimizer.nested.nested.l2_reg=1e-6 \
    optimizer.decay=0.999 \
    optimizer.decay=0.9995 \
    encoding.nested.0.log2_hashmap_size=15 \
    encoding.nested.0.n_levels=8 \
    loss.epsilon=1.0 \
    loss.max_relative_error=4
fi
variants=$(IFS=';'; echo "$*")
NRC_DRIFT_SCENE=${SCENE:-photon-nrc-ajar-caustic} NRC_DRIFT_PRODUCERS=${PRODUCERS:-pt} \
  NRC_DRIFT_FRAMES=${FRAMES:-2000} NRC_DRIFT_RECORDS=${RECORDS:-4096} \
  NRC_DRIFT_RESOLUTION=${RESOLUTION:-128} NRC_DRIFT_SPP=${SPP:-256} NRC_DRIFT_VARIANTS="$variants" \
  cargo test --release --locked --workspace --test online drift_study -- --ignored --nocapture \
  | grep -E '^(\||  )'
