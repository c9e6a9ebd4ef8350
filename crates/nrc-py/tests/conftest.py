"""Shared fixtures of the Python module's tests: the shipped scenes and a trained cache."""

import pathlib

import numpy as np
import pytest

import nrc

ROOT = pathlib.Path(__file__).resolve().parents[3]
SCENES = ROOT / "scenes"


@pytest.fixture(scope="session")
def cornell():
    return nrc.Scene.load(SCENES / "cornell-box.gltf")


@pytest.fixture(scope="session")
def glossy():
    return nrc.Scene.load(SCENES / "glossy.gltf")


@pytest.fixture(scope="session")
def trained(cornell):
    """A small neural cache trained on 20 frames of path-traced records of the Cornell box."""
    cache = nrc.Cache(scene=cornell, resolution=64)
    producer = nrc.Producer(cornell, "pt", seed=3)
    for _ in range(20):
        cache.train(producer.produce(2048), steps=2)
    return cache


def random_queries(n, seed=0):
    """Queries spread over the scene box and every direction, with random materials."""
    rng = np.random.default_rng(seed)
    q = np.empty((n, nrc.QUERY_DIMS), np.float32)
    q[:, 0:3] = rng.random((n, 3))
    q[:, 3:6] = rng.normal(size=(n, 3))
    q[:, 6:9] = rng.normal(size=(n, 3))
    q[:, 9] = rng.exponential(0.5, n)
    q[:, 10:13] = rng.random((n, 3))
    q[:, 13:16] = rng.random((n, 3)) * 0.3
    return q


def relative_error(a, b):
    """Per-element |a - b| / max(|b|, 1e-6)."""
    return np.abs(a - b) / np.maximum(np.abs(b), 1e-6)

