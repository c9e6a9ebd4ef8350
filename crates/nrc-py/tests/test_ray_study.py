"""The Ray driver of a study (scripts/ray_study.py) on a local Ray cluster of 2 CPUs: the same
errors per method as `nrc compare` in one process (timings excepted)."""

import json
import os
import subprocess
import sys
import time

import pytest

import nrc
from conftest import ROOT

FLAGS = ["--scene", "scenes/cornell-box.gltf", "--methods", "pt-1spp,nrc-pt-sl-first,restir-di",
         "--equal-spp", "2", "--width", "32", "--height", "32", "--runs", "2",
         "--reference-spp", "48", "--train-frames", "4", "--records", "1024"]


def rows(out):
    with open(os.path.join(out, "report.json")) as f:
        return json.load(f)["rows"]


# Timings differ between processes; the rays a pass traced do not.
TIMINGS = {"time_per_frame_ms", "ms_per_pass", "phases"}


def same(a, b, path=""):
    if isinstance(a, dict):
        return all(k in TIMINGS or same(v, b[k], f"{path}.{k}") for k, v in a.items())
    if isinstance(a, float) or isinstance(b, float):
        return abs(a - b) <= 1e-4 * max(abs(a), abs(b)) + 1e-12
    return a == b


def test_ray_driver_matches_one_process(tmp_path):
    try:
        import ray  # noqa: F401
    except ImportError as e:
        log = os.environ.get("NRC_SKIP_LOG")
        if log:
            with open(log, "a") as f:
                f.write(f"python test_ray_driver_matches_one_process: no ray: {e}\n")
        pytest.skip(f"ray is not installed: {e}")
    program = os.environ.get("NRC_BIN")
    assert program and os.path.exists(program), "tests/python.rs sets NRC_BIN"
    cwd = os.getcwd()
    os.chdir(ROOT)
    try:
        t = time.perf_counter()
        nrc.cli(["compare", *FLAGS, "--out", str(tmp_path / "one"), "--cache-dir", str(tmp_path / "refs-one")])
        one_process = time.perf_counter() - t
        study = tmp_path / "study"
        nrc.cli(["compare", *FLAGS, "--out", str(tmp_path / "ray"), "--cache-dir", str(tmp_path / "refs-ray"),
                 "--plan", str(study), "--chunks", "2"])
    finally:
        os.chdir(cwd)
    t = time.perf_counter()
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "ray_study.py"), str(study),
                           "--nrc", program, "--num-cpus", "2"], capture_output=True, text=True, cwd=ROOT)
    on_ray = time.perf_counter() - t
    assert done.returncode == 0, done.stderr[-3000:]
    assert "ray: job 9 done" not in done.stdout and done.stdout.count("done in") == 8
    print(f"one process {one_process:.1f} s, Ray with 2 CPUs {on_ray:.1f} s (Ray's start included)")
    a, b = rows(tmp_path / "one"), rows(tmp_path / "ray")
    assert [r["method"] for r in a] == [r["method"] for r in b] == ["pt-1spp", "nrc-pt-sl-first", "restir-di"]
    for x, y in zip(a, b):
        assert same(x, y), (x, y)
    # Resuming a finished study submits nothing.
    again = subprocess.run([sys.executable, str(ROOT / "scripts" / "ray_study.py"), str(study),
                            "--nrc", program, "--num-cpus", "2", "--no-merge"], capture_output=True, text=True, cwd=ROOT)
    assert again.returncode == 0 and "ray: 0 of 8 jobs to run" in again.stdout
