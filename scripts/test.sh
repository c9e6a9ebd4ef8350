#!/usr/bin/env bash
# The README's test command: every test, Rust and Python, in the release profile, from one build
# (the Python module is the workspace build's, see scripts/python-env.sh). Arguments go to
# `cargo test`.
set -euo pipefail
cd "$(dirname "$0")/.."
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-${XDG_CACHE_HOME:-$HOME/.cache}/nrc-target}"
python="${PYTHON:-python3}"
if ! "$python" -c "import numpy, pytest" 2>/dev/null; then
  echo "error: the Python tests need numpy and pytest: $python -m pip install numpy pytest" >&2
  exit 1
fi

# The same selection as CI's build, so that nothing is rebuilt with other features.
cargo build --release --locked --workspace --all-targets
cargo test --release --locked --workspace "$@"
# No bytecode or pytest cache left in the clone.
PYTHONDONTWRITEBYTECODE=1 bash scripts/python-env.sh "$python" -m pytest -q -p no:cacheprovider crates/nrc-py/tests
