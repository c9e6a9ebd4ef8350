"""Scenes and renders: what a scene holds, and renders with the same bits as `nrc render`."""

import numpy as np
import pytest

import nrc
from conftest import SCENES


def test_scene_holds_what_nrc_info_says(cornell):
    assert cornell.triangle_count == 32
    assert cornell.light_count >= 1
    lo, hi = cornell.bounds
    assert all(h > l for l, h in zip(lo, hi))
    tris = cornell.triangles()
    assert tris.shape == (32, 3, 3) and tris.dtype == np.float32
    # Every vertex lies in the bounds.
    assert (tris >= np.array(lo) - 1e-6).all() and (tris <= np.array(hi) + 1e-6).all()
    assert "triangles" in cornell.summary()
    lights = cornell.lights()
    emissive = lights["emissive_triangles"]
    assert len(emissive) + len(lights["punctual"]) + lights["environment"] == cornell.light_count
    # The emissive triangles are the ceiling light's: the highest in the box.
    assert len(emissive) > 0 and (tris[emissive][:, :, 1] > 0.5).all()
    assert abs(cornell.camera["fov_y"] - 39.3077) < 1e-3


def test_camera_override_moves_the_camera():
    s = nrc.Scene.load(SCENES / "cornell-box.gltf", camera_pos=(0.3, 0.3, -0.5), fov_y=50)
    assert np.allclose(s.camera["position"], (0.3, 0.3, -0.5))
    assert abs(s.camera["fov_y"] - 50) < 1e-4


def test_animated_scene_moves_with_time():
    s = nrc.Scene.load(SCENES / "cornell-box-moving.gltf")
    assert s.is_animated and s.duration > 0

    def triangle_set(scene):
        # The acceleration structure orders triangles as it likes: compare them as a set.
        t = scene.triangles().reshape(-1, 9)
        return t[np.lexsort(t.T[::-1])]

    a, b = triangle_set(s.at(0.0)), triangle_set(s.at(0.7))
    assert a.shape == b.shape
    assert not np.array_equal(a, b)
    # Posing is a function of time.
    assert np.array_equal(triangle_set(s.at(0.7)), b)


def test_render_has_the_same_bits_as_the_program(cornell, tmp_path):
    out = tmp_path / "pt.exr"
    nrc.cli([
        "render", "--scene", str(SCENES / "cornell-box.gltf"), "--spp", "4",
        "--width", "40", "--height", "24", "--seed", "7", "--out", str(out),
    ])
    program = nrc.read_exr(out)
    image = nrc.render(cornell, spp=4, width=40, height=24, seed=7)
    assert image.shape == (24, 40, 3) and image.dtype == np.float32
    assert np.array_equal(image, program)
    # Another seed is another image (the comparison above could not pass by accident).
    assert not np.array_equal(nrc.render(cornell, spp=4, width=40, height=24, seed=8), program)


def test_cache_render_has_the_same_bits_as_the_program(cornell, trained, tmp_path):
    snapshot = tmp_path / "c.nrc"
    trained.save(snapshot)
    out = tmp_path / "cache.exr"
    nrc.cli([
        "render", "--scene", str(SCENES / "cornell-box.gltf"), "--spp", "2",
        "--width", "32", "--height", "32", "--cache", str(snapshot),
        "--termination", "first", "--out", str(out),
    ])
    image = nrc.render(cornell, spp=2, width=32, height=32, cache=trained, termination="first")
    assert np.array_equal(image, nrc.read_exr(out))
    assert image.mean() > 0


def test_passes_by_name(cornell, trained):
    for pass_ in ["pt", "pt-nonee", "restir-di"]:
        img = nrc.render(cornell, pass_=pass_, spp=1, width=16, height=16)
        assert img.shape == (16, 16, 3) and np.isfinite(img).all()
    img = nrc.render(cornell, pass_="cache-first", width=16, height=16, cache=trained)
    assert np.isfinite(img).all() and img.mean() > 0


def test_light_tree_renders_as_the_program(tmp_path):
    """`light_sampler="tree"` loads the scene with the light tree: the same bits as
    `nrc render --light-sampler tree`, another image than the power sampler's; a wrong name is
    refused."""
    hall = SCENES / "many-lights.gltf"
    out = tmp_path / "tree.exr"
    nrc.cli([
        "render", "--scene", str(hall), "--light-sampler", "tree", "--spp", "2",
        "--width", "24", "--height", "16", "--seed", "3", "--out", str(out),
    ])
    tree = nrc.Scene.load(hall, light_sampler="tree")
    image = nrc.render(tree, spp=2, width=24, height=16, seed=3)
    assert np.array_equal(image, nrc.read_exr(out))
    power = nrc.render(nrc.Scene.load(hall), spp=2, width=24, height=16, seed=3)
    assert not np.array_equal(image, power)
    with pytest.raises(ValueError, match="light sampler `bvh`"):
        nrc.Scene.load(hall, light_sampler="bvh")


def program_render(tmp_path, flags, spp, size, seed=5):
    """`nrc render` of the Cornell box with `flags` at `spp` and `size` (width, height), read
    back: what the module's `render` with the same options must equal bit for bit."""
    out = tmp_path / "program.exr"
    nrc.cli([
        "render", "--scene", str(SCENES / "cornell-box.gltf"), *flags, "--spp", str(spp),
        "--width", str(size[0]), "--height", str(size[1]), "--seed", str(seed), "--out", str(out),
    ])
    return nrc.read_exr(out)


def test_direct_samples_render_as_the_program(cornell, tmp_path):
    """`direct_samples=4` takes four stratified light samples at each first vertex as
    `nrc render --direct-samples 4` does (the same bits); the image differs from one light
    sample's; a count out of its range (1 to 64) is refused."""
    program = program_render(tmp_path, ["--direct-samples", "4"], 1, (24, 24))
    four = nrc.render(cornell, spp=1, width=24, height=24, seed=5, direct_samples=4)
    assert np.array_equal(four, program)
    one = nrc.render(cornell, spp=1, width=24, height=24, seed=5)
    assert np.any(four != one)
    for bad in (0, 1000):
        with pytest.raises(ValueError, match="direct-samples"):
            nrc.render(cornell, spp=1, width=8, height=8, direct_samples=bad)


def test_sobol_camera_offsets_render_as_the_program(cornell, tmp_path):
    """`camera_offsets="sobol"` stratifies a pixel's samples by one scrambled Sobol sequence as
    `nrc render --camera-offsets sobol` does (the same bits); the image differs from the
    independent offsets'; an unknown kind of offsets is refused."""
    program = program_render(tmp_path, ["--camera-offsets", "sobol"], 4, (24, 24))
    sobol = nrc.render(cornell, spp=4, width=24, height=24, seed=5, camera_offsets="sobol")
    assert np.array_equal(sobol, program)
    independent = nrc.render(cornell, spp=4, width=24, height=24, seed=5)
    assert np.any(sobol != independent)
    with pytest.raises(ValueError, match="camera-offsets"):
        nrc.render(cornell, spp=1, width=8, height=8, camera_offsets="halton")


def test_emitter_samples_render_as_the_program(cornell, tmp_path):
    """`emitter_samples=8` takes the extra camera rays at the outline of the Cornell box's
    light as `nrc render --emitter-samples 8` does (the same bits); the image differs from the
    one without them only near the light; an out-of-range count is refused."""
    program = program_render(tmp_path, ["--emitter-samples", "8"], 1, (32, 32))
    aa = nrc.render(cornell, spp=1, width=32, height=32, seed=5, emitter_samples=8)
    assert np.array_equal(aa, program)
    plain = nrc.render(cornell, spp=1, width=32, height=32, seed=5)
    changed = np.any(aa != plain, axis=2)
    assert 0 < changed.sum() < 0.25 * changed.size
    with pytest.raises(ValueError, match="emitter-samples"):
        nrc.render(cornell, spp=1, width=8, height=8, emitter_samples=1000)
