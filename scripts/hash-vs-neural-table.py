#!/usr/bin/env python3
"""The neural-against-hash-cache table of RESULTS.md (issue 34) from the reports that
scripts/hash-vs-neural.sh writes: one row per scene and consumer pass, each cache's MSE, relMSE,
MAPE, HDR-FLIP and bias² with the frames it rendered in the budget, and which cache has the
lower MSE and the lower FLIP.

    scripts/hash-vs-neural-table.py [DIR...]     # default: out/hash-vs-neural-all/*
"""

import json
import sys
from pathlib import Path

PAIRS = [
    ("cache (spread)", "nrc-pt-sl", "hash-pt-sl"),
    ("cache (first vertex)", "nrc-pt-sl-first", "hash-pt-sl-first"),
] + [
    (f"`{p}`", p, p + "@1spp+hash:pt-sl")
    for p in ["restir-gi-nrc", "wsrestir-gi-nrc", "nrc-restir", "ddgi-nrc-restir", "smc-ir-nrc"]
]


def g(x):
    return f"{x:.3g}"


def cell(r):
    return (
        f"{g(r['mse'])} · {g(r['rel_mse'])} · {g(r['mape'])} · {g(r['flip'])} · "
        f"{g(r['bias_variance']['bias_sq'])} ({g(r['samples_per_pixel'])})"
    )


def main():
    dirs = [Path(d) for d in sys.argv[1:]] or sorted(Path("out/hash-vs-neural-all").iterdir())
    order = ["cornell-box", "ajar", "glossy", "caustics", "sun-spot-env", "hwrt-cornell-box",
             "photon-nrc-ajar-caustic", "kajiya-roughness-scale", "kitchen"]
    dirs.sort(key=lambda d: order.index(d.name) if d.name in order else len(order))
    print(
        "| scene | pass | path tracing MSE · FLIP | neural: MSE · relMSE · MAPE · FLIP · bias² (frames) "
        "| hash: MSE · relMSE · MAPE · FLIP · bias² (frames) | lower MSE | lower FLIP |"
    )
    print("|---|---|---:|---:|---:|---|---|")
    for d in dirs:
        path = d / "report.json"
        if not path.exists():
            sys.exit(f"error: {path} does not exist: run scripts/hash-vs-neural.sh first")
        rows = {r["method"]: r for r in json.loads(path.read_text())["rows"]}
        if rows.get("pt-1spp", {}).get("flip") is None:
            sys.exit(f"error: {path} has no FLIP (made with --no-flip?)")
        pt = rows["pt-1spp"]
        for name, neural, hashed in PAIRS:
            if neural not in rows or hashed not in rows:
                continue
            a, b = rows[neural], rows[hashed]
            both = lambda k: a[k] < pt[k] and b[k] < pt[k]
            mse = ("neural" if a["mse"] < b["mse"] else "hash") + (" (both below PT)" if both("mse") else "")
            flip = ("neural" if a["flip"] < b["flip"] else "hash") + (" (both below PT)" if both("flip") else "")
            print(f"| {d.name} | {name} | {g(pt['mse'])} · {g(pt['flip'])} | {cell(a)} | {cell(b)} | {mse} | {flip} |")


if __name__ == "__main__":
    main()
