#!/usr/bin/env python3
"""Where each method's error is, from `nrc compare --diagnostics`.

    python3 scripts/error_regions.py OUT [--box NAME=x0,y0,x1,y1]... [--top 1]

OUT is the comparison's folder. For every `METHOD-errors.exr` in it (red: a pixel's expected
squared error of one run against the true image, the reference's noise removed; green: bias²;
blue: variance; the channels averaged) prints the method's MSE, the share
of it that is bias², and for each box (pixels x0 <= x < x1, y0 <= y < y1) the box's share of the
MSE and of the bias². Where the method has `METHOD-view-reservoir-contribution.exr` (a
resampling pass's mean W·p̂ after its last frame), also the share of the MSE in the pixels whose
contribution is in the top `--top` percent: how much of the error sits where the reservoirs
carry the largest weights. With `--footprint REF`, a reference folder (`nrc reference`: mean.exr
and variance.exr) of the same view at k times the resolution, also each box's footprint variance:
the variance of the radiance over a pixel's area, from its k × k sub-pixels' means (their own
noise removed: a lower bound, finer detail adds to it), against the method's variance per sample
(blue × the samples per pixel of report.json): the part of a camera sample's noise that only
more camera rays through the pixel remove. Needs numpy and OpenEXR (`pip install numpy
OpenEXR`).
"""

import json

import argparse
import glob
import os
import sys

import numpy as np

try:
    import OpenEXR
    import Imath
except ImportError:
    sys.exit("error: this script needs the OpenEXR module (pip install OpenEXR)")


def read_rgb(path):
    f = OpenEXR.InputFile(path)
    dw = f.header()["dataWindow"]
    w, h = dw.max.x - dw.min.x + 1, dw.max.y - dw.min.y + 1
    float_type = Imath.PixelType(Imath.PixelType.FLOAT)
    return np.stack(
        [np.frombuffer(f.channel(c, float_type), dtype=np.float32).reshape(h, w) for c in "RGB"],
        -1,
    ).astype(np.float64)


def parse_box(text):
    try:
        name, coords = text.split("=", 1)
        x0, y0, x1, y1 = (int(v) for v in coords.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"a box is NAME=x0,y0,x1,y1, not {text!r}")
    if x1 <= x0 or y1 <= y0:
        raise argparse.ArgumentTypeError(f"box {name} is empty")
    return name, (x0, y0, x1, y1)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out")
    ap.add_argument("--box", type=parse_box, action="append", default=[])
    ap.add_argument("--top", type=float, default=1.0)
    ap.add_argument("--footprint", metavar="REF")
    a = ap.parse_args()
    footprint = None
    spp = {}
    if a.footprint:
        hi = read_rgb(os.path.join(a.footprint, "mean.exr"))
        hv = read_rgb(os.path.join(a.footprint, "variance.exr"))
        report = json.load(open(os.path.join(a.out, "report.json")))
        spp = {r["method"]: r["samples_per_pixel"] for r in report["rows"]}
    files = sorted(glob.glob(os.path.join(a.out, "*-errors.exr")))
    if not files:
        sys.exit(f"error: no METHOD-errors.exr in {a.out} (run nrc compare with --diagnostics)")
    for path in files:
        method = os.path.basename(path)[: -len("-errors.exr")]
        e = read_rgb(path)
        mse, bias, total = e[..., 0], e[..., 1], e[..., 0].sum()
        if a.footprint and footprint is None:
            h, w = mse.shape
            k = hi.shape[0] // h
            if hi.shape[:2] != (h * k, w * k) or k < 2:
                sys.exit(f"error: the footprint reference is {hi.shape[1]}x{hi.shape[0]}, not a multiple of {w}x{h}")
            blocks = hi.reshape(h, k, w, k, 3)
            noise = hv.reshape(h, k, w, k, 3).mean(axis=(1, 3))
            footprint = (blocks.var(axis=(1, 3), ddof=1) - noise).mean(-1)
        line = (
            f"{method}: bias² + variance {mse.mean():.4g}, bias² {bias.mean():.4g}"
            f" ({bias.sum() / total:.0%})"
        )
        for name, (x0, y0, x1, y1) in a.box:
            inside = mse[y0:y1, x0:x1]
            line += (
                f"; {name} ({inside.size} px) {inside.sum() / total:.0%} of the error,"
                f" bias² {bias[y0:y1, x0:x1].sum() / total:.0%}"
            )
            if footprint is not None and method in spp:
                per_sample = e[y0:y1, x0:x1, 2].mean() * spp[method]
                fp = footprint[y0:y1, x0:x1].mean()
                line += (
                    f", variance per sample {per_sample:.4g} against the footprint's {fp:.4g}"
                    f" ({fp / per_sample:.0%})"
                )
        if a.box:
            rest = np.ones(mse.shape, bool)
            for _, (x0, y0, x1, y1) in a.box:
                rest[y0:y1, x0:x1] = False
            line += f"; the rest ({rest.sum()} px) {mse[rest].sum() / total:.0%} of the error"
        view = os.path.join(a.out, f"{method}-view-reservoir-contribution.exr")
        if os.path.exists(view):
            c = read_rgb(view)[..., 0].ravel()
            # The top `--top` percent by rank (ties broken by position), at least one pixel.
            k = max(1, int(round(c.size * a.top / 100.0)))
            top = np.zeros(c.size, bool)
            top[np.argsort(c, kind="stable")[-k:]] = True
            top = top.reshape(mse.shape)
            line += f"; top {a.top:g} % reservoir contributions {mse[top].sum() / total:.0%} of the error"
        print(line)


if __name__ == "__main__":
    main()
