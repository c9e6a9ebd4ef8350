#!/usr/bin/env python3
"""Prints the RESULTS.md tables from the reports scripts/results.sh wrote.

Usage: scripts/results_tables.py [OUT_DIR]  (default out/results)"""
import json
import os
import sys

out = sys.argv[1] if len(sys.argv) > 1 else "out/results"


def fmt(x):
    if x is None:
        return "–"
    if x == 0:
        return "0"
    a = abs(x)
    return f"{x:.3e}" if a < 1e-3 or a >= 1e4 else f"{x:.4g}"


for scene in sorted(os.listdir(out)):
    base = os.path.join(out, scene)
    if not os.path.exists(os.path.join(base, "equal-spp", "report.json")):
        continue
    spp = json.load(open(os.path.join(base, "equal-spp", "report.json")))
    print(f"### {scene}\n")
    print(spp["reference"] + "\n")
    for n in spp.get("notes", []):
        if "emitter" in n:
            print(n + "\n")
    print("| method | budget | ms/frame | spp | MSE | relMSE | MAPE | FLIP | bias² | variance |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")

    def row(r, budget):
        bv = r.get("bias_variance") or {}
        print(
            f"| {r['method']} | {budget} | {r['time_per_frame_ms']:.1f} | {r['samples_per_pixel']:.2f} | "
            f"{fmt(r['mse'])} | {fmt(r['rel_mse'])} | {fmt(r['mape'])} | {fmt(r['flip'])} | {fmt(bv.get('bias_sq'))} | {fmt(bv.get('variance'))} |"
        )

    for r in spp["rows"]:
        row(r, "1 pass")
    for r in spp["rows"]:
        if not r["method"].startswith("nrc-"):
            continue
        path = os.path.join(base, f"equal-time-{r['method']}", "report.json")
        if os.path.exists(path):
            for t in json.load(open(path))["rows"]:
                row(t, f"time of {r['method']}")
    print()
