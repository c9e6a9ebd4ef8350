#!/usr/bin/env python3
"""Generate the FLIP test fixtures of crates/nrc-eval from NVIDIA's published FLIP tool.

The fixtures are small, deterministic image pairs (gradients, an edge, noise, a bright
highlight, colour shifts) written as PFM files (Portable Float Map: a three-line text header,
then little-endian f32 pixels, bottom row first), and the FLIP values that the authors' tool
computes for them, written to `expected.json`. crates/nrc-eval/tests/flip_fixtures.rs checks
our HDR-FLIP and LDR-FLIP against these values.

The tool is the PyPI package `flip-evaluator` (NVIDIA's official FLIP, C++ core behind a
Python binding). To regenerate:

    python3 -m venv /tmp/flip-venv
    /tmp/flip-venv/bin/pip install flip-evaluator==1.7 numpy
    /tmp/flip-venv/bin/python scripts/flip_fixtures.py

HDR pairs are linear RGB (any non-negative value); LDR pairs are sRGB-encoded in [0, 1], the
convention of the tool's LDR mode.
"""

import json
import os
import sys

import numpy as np

try:
    import flip_evaluator as flip
    from importlib.metadata import version as package_version
except ImportError:
    sys.exit("needs the PyPI package flip-evaluator (pip install flip-evaluator numpy)")

OUT_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "crates", "nrc-eval",
                       "tests", "fixtures", "flip")


def write_pfm(path, image):
    """Write an HxWx3 (colour, 'PF') or HxW (grey, 'Pf') float image as little-endian PFM."""
    image = np.asarray(image, dtype="<f4")
    if image.ndim == 3:
        magic, (h, w, _) = b"PF", image.shape
    else:
        magic, (h, w) = b"Pf", image.shape
    with open(path, "wb") as f:
        f.write(magic + b"\n" + f"{w} {h}\n".encode() + b"-1.0\n")
        f.write(np.ascontiguousarray(image[::-1]).tobytes())  # PFM stores the bottom row first


def coords(w, h):
    y, x = np.meshgrid(np.arange(h, dtype=np.float64), np.arange(w, dtype=np.float64),
                       indexing="ij")
    return x / (w - 1), y / (h - 1)


def hdr_cases():
    """Deterministic HDR (linear RGB) reference/test pairs."""
    rng = np.random.default_rng(20210501)
    cases = []

    # 1. Exponential horizontal gradient over four decades, test 10 % brighter plus an offset.
    u, v = coords(32, 32)
    lum = 10.0 ** (4.0 * u - 2.0)
    ref = np.stack([lum, lum * (0.6 + 0.4 * v), lum * 0.5], axis=-1)
    test = ref * 1.1 + 0.002
    cases.append(("gradient", ref, test, {}))

    # 2. A vertical step edge, dark to bright; the test's edge sits one pixel to the right.
    ref = np.full((32, 32, 3), 0.05)
    ref[:, 16:, :] = [4.0, 3.5, 3.0]
    test = np.full((32, 32, 3), 0.05)
    test[:, 17:, :] = [4.0, 3.5, 3.0]
    cases.append(("edge", ref, test, {}))

    # 3. A smooth colour field; the test adds Gaussian noise (clipped at zero), as a 1-spp render.
    u, v = coords(32, 32)
    ref = np.stack([0.2 + 0.8 * u, 0.3 + 0.5 * v, 0.4 + 0.3 * u * v], axis=-1)
    test = np.maximum(ref + rng.normal(0.0, 0.15, ref.shape), 0.0)
    cases.append(("noise", ref, test, {}))

    # 4. A dim room with a 3x3 highlight of radiance 50; the test's highlight is dimmer and wider.
    ref = np.full((32, 32, 3), 0.2)
    ref[14:17, 14:17, :] = 50.0
    test = np.full((32, 32, 3), 0.2)
    test[13:18, 13:18, :] = 8.0
    test[14:17, 14:17, :] = 20.0
    cases.append(("highlight", ref, test, {}))

    # 5. Coloured checker squares; the test rotates the colour channels in one quadrant.
    u, v = coords(32, 32)
    checker = ((np.floor(u * 3.999) + np.floor(v * 3.999)) % 2)[..., None]
    ref = checker * np.array([1.5, 0.3, 0.1]) + (1 - checker) * np.array([0.1, 0.4, 1.2])
    test = ref.copy()
    test[:16, :16, :] = ref[:16, :16, [1, 2, 0]]
    cases.append(("colour", ref, test, {}))

    # 6. A non-square image (40 wide, 24 high) with noise and a bias, to catch swapped axes,
    #    evaluated at 30 pixels per degree (other filter radii than the default 67 ppd).
    u, v = coords(40, 24)
    ref = np.stack([0.5 + 2.0 * u, 0.5 + 1.0 * v * v, 0.2 + u * (1 - v)], axis=-1)
    test = np.maximum(ref * 0.9 + rng.normal(0.0, 0.1, ref.shape), 0.0)
    cases.append(("wide_ppd30", ref, test, {"ppd": 30.0}))

    # 7-9. The other tone curves of the tool, and exposures given by hand instead of derived.
    by_name = {name: (r, t) for name, r, t, _ in cases}
    cases.append(("noise_hable", *by_name["noise"], {"tonemapper": "hable"}))
    cases.append(("highlight_reinhard", *by_name["highlight"], {"tonemapper": "reinhard"}))
    cases.append(("gradient_fixed", *by_name["gradient"],
                  {"startExposure": -3.0, "stopExposure": 2.0, "numExposures": 4}))
    return cases


def ldr_cases():
    """Deterministic LDR (sRGB-encoded, [0, 1]) reference/test pairs."""
    rng = np.random.default_rng(20200701)
    cases = []

    u, v = coords(32, 32)
    ref = np.stack([u, v, 0.5 * (u + v)], axis=-1)
    test = np.clip(ref + rng.normal(0.0, 0.05, ref.shape), 0.0, 1.0)
    cases.append(("ldr_noise", ref, test, {}))

    ref = np.full((32, 32, 3), 0.1)
    ref[8:24, 8:24, :] = [0.9, 0.8, 0.2]
    test = np.full((32, 32, 3), 0.1)
    test[9:25, 8:24, :] = [0.85, 0.8, 0.3]
    cases.append(("ldr_square", ref, test, {}))
    return cases


def evaluate(name, ref, test, mode, params):
    ref = np.ascontiguousarray(ref, dtype=np.float32)
    test = np.ascontiguousarray(test, dtype=np.float32)
    error_map, mean, used = flip.evaluate(ref, test, mode, applyMagma=False,
                                         computeMeanError=True, parameters=dict(params))
    write_pfm(os.path.join(OUT_DIR, f"{name}_ref.pfm"), ref)
    write_pfm(os.path.join(OUT_DIR, f"{name}_test.pfm"), test)
    write_pfm(os.path.join(OUT_DIR, f"{name}_flip.pfm"), np.asarray(error_map)[..., 0])
    case = {
        "name": name,
        "mode": mode,
        "reference": f"{name}_ref.pfm",
        "test": f"{name}_test.pfm",
        "error_map": f"{name}_flip.pfm",
        "width": int(ref.shape[1]),
        "height": int(ref.shape[0]),
        "ppd": float(used["ppd"]),
        "mean_flip": float(mean),
    }
    if mode == "HDR":
        case["start_exposure"] = float(used["startExposure"])
        case["stop_exposure"] = float(used["stopExposure"])
        case["num_exposures"] = int(used["numExposures"])
        case["tone_mapper"] = str(used["tonemapper"]).lower()
        case["given"] = {k: v for k, v in params.items() if k != "ppd"}
    return case


def main():
    os.makedirs(OUT_DIR, exist_ok=True)
    cases = [evaluate(n, r, t, "HDR", p) for n, r, t, p in hdr_cases()]
    cases += [evaluate(n, r, t, "LDR", p) for n, r, t, p in ldr_cases()]
    expected = {
        "tool": f"flip-evaluator {package_version('flip-evaluator')} (PyPI, NVIDIA FLIP)",
        "generator": "scripts/flip_fixtures.py",
        "cases": cases,
    }
    with open(os.path.join(OUT_DIR, "expected.json"), "w") as f:
        json.dump(expected, f, indent=2)
        f.write("\n")
    for c in cases:
        print(f"{c['name']:>12} {c['mode']}: mean FLIP {c['mean_flip']:.6f}")


if __name__ == "__main__":
    main()
