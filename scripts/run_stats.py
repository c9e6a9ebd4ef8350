#!/usr/bin/env python3
"""Per-run MSE of an `nrc compare` output folder, grouped by method: each run's figure, the mean
and the median (the report gives means only; one firefly run moves a mean of four)."""
import json
import statistics
import sys

if len(sys.argv) != 2:
    sys.exit("usage: run_stats.py OUT  (the folder `nrc compare --out OUT` wrote)")
try:
    runs = json.load(open(f"{sys.argv[1]}/runs.json"))["runs"]
except (OSError, KeyError, ValueError) as e:
    sys.exit(f"error: cannot read {sys.argv[1]}/runs.json: {e}")
by_method = {}
for r in runs:
    by_method.setdefault(r["method"], []).append(r["metrics"]["mse"])
for method, mse in by_method.items():
    each = ", ".join(f"{x:.4f}" for x in mse)
    print(f"{method}: {each}; mean {statistics.mean(mse):.4f}, median {statistics.median(mse):.4f}")
