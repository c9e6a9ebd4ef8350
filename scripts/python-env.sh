#!/usr/bin/env bash
# Runs a command with the Python module `nrc` importable, from the workspace's release build
# (built here if needed, in the same selection as CI's build so that nothing is rebuilt with
# other features): `libnrc_py.so` is copied beside the package's Python files, not built a
# second time. Example: bash scripts/python-env.sh python3 -m pytest -s crates/nrc-py/tests/test_overhead.py
set -euo pipefail
cd "$(dirname "$0")/.."
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-${XDG_CACHE_HOME:-$HOME/.cache}/nrc-target}"
cargo build --release --locked --workspace --all-targets
pkg="$CARGO_TARGET_DIR/python-module/nrc"
rm -rf "$pkg"
mkdir -p "$pkg"
cp crates/nrc-py/python/nrc/* "$pkg/"
cp "$CARGO_TARGET_DIR/release/libnrc_py.so" "$pkg/_nrc.abi3.so"
# The program too, for the tests of the study drivers (scripts/ray_study.py).
export NRC_BIN="$CARGO_TARGET_DIR/release/nrc"
PYTHONPATH="$(dirname "$pkg")${PYTHONPATH:+:$PYTHONPATH}" exec "$@"
