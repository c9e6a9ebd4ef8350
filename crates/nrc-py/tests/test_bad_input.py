"""Bad input: a Python exception with a clear message, never a crash of the interpreter."""

import numpy as np
import pytest

import nrc
from conftest import SCENES, random_queries


def test_wrong_dtype(trained):
    with pytest.raises(TypeError, match="float32"):
        trained.infer(random_queries(8).astype(np.float64))


def test_not_an_array(trained):
    with pytest.raises(TypeError, match="NumPy array"):
        trained.infer([[0.0] * 16])


def test_wrong_shape(trained):
    with pytest.raises(ValueError, match=r"shape \(N, 16\)"):
        trained.infer(np.zeros((8, 15), np.float32))
    with pytest.raises(ValueError, match=r"shape \(N, 16\)"):
        trained.infer(np.zeros(16, np.float32))


def test_non_contiguous(trained):
    q = np.asfortranarray(random_queries(8))
    with pytest.raises(ValueError, match="C-contiguous"):
        trained.infer(q)
    # A strided view too.
    with pytest.raises(ValueError, match="C-contiguous"):
        trained.infer(random_queries(16)[::2])


def test_nan_in_queries_and_targets(trained, cornell):
    q = random_queries(8)
    q[3, 5] = np.nan
    with pytest.raises(ValueError, match="row 3, column 5"):
        trained.infer(q)
    batch = nrc.Producer(cornell, "pt").produce(64)
    batch["targets"][0, 0] = np.inf
    with pytest.raises(ValueError, match="targets holds a NaN or infinite"):
        trained.train(batch)


def test_mismatched_batch(trained, cornell):
    batch = nrc.Producer(cornell, "pt").produce(64)
    batch["targets"] = batch["targets"][:10]
    with pytest.raises(ValueError, match="rows for"):
        trained.train(batch)
    with pytest.raises(ValueError, match="queries"):
        trained.train({"targets": batch["targets"]})


def test_snapshot_of_another_scene(trained, glossy, tmp_path):
    """A cache over another scene box is refused for a render, and allowed when asked."""
    with pytest.raises(nrc.NrcError, match="another scene box.*allow_other_scene=True"):
        nrc.render(glossy, cache=trained, width=8, height=8)
    img = nrc.render(glossy, cache=trained, width=8, height=8, allow_other_scene=True)
    assert img.shape == (8, 8, 3)


def test_unknown_names(cornell):
    with pytest.raises(nrc.NrcError, match="unknown producer `nope`"):
        nrc.Producer(cornell, "nope")
    with pytest.raises(nrc.NrcError, match="invalid pass `nope`"):
        nrc.render(cornell, pass_="nope")
    with pytest.raises(nrc.NrcError, match="ends paths in a cache"):
        nrc.render(cornell, pass_="cache-first")
    with pytest.raises(ValueError, match="unknown field `colour`"):
        nrc.render(cornell, colour=3)
    with pytest.raises(ValueError, match="unknown device"):
        nrc.Cache.load("x.nrc", device="tpu")
    with pytest.raises(ValueError, match="nrc.Cache"):
        nrc.Cache(scene=cornell, kind="neurral")
    with pytest.raises(nrc.NrcError, match="no-such-preset.json: No such file"):
        nrc.Cache(config="no-such-preset.json", scene=cornell)
    with pytest.raises(nrc.NrcError, match="n_levels"):
        nrc.Cache(config={"encoding": {"otype": "Composite", "nested": [{"otype": "HashGrid", "n_dims_to_encode": 3, "n_levels": "many"}]}})


def test_missing_and_corrupt_files(tmp_path):
    with pytest.raises(nrc.NrcError, match="no-such.gltf"):
        nrc.Scene.load(tmp_path / "no-such.gltf")
    bad = tmp_path / "bad.nrc"
    bad.write_bytes(b"not a snapshot at all")
    with pytest.raises(nrc.NrcError, match="cannot load the cache snapshot"):
        nrc.Cache.load(bad)
    with pytest.raises(nrc.NrcError, match="error|unrecognized|unexpected"):
        nrc.cli(["render", "--no-such-flag"])


def test_closed_objects_refuse_use(cornell):
    cache = nrc.Cache(scene=cornell, kind="hash")
    cache.close()
    with pytest.raises(ValueError, match="closed"):
        cache.infer(random_queries(4))
    with nrc.Cache(scene=cornell, kind="hash") as c:
        c.infer(random_queries(4))
    with pytest.raises(ValueError, match="closed"):
        c.describe()
    p = nrc.Producer(cornell, "pt")
    p.close()
    with pytest.raises(ValueError, match="closed"):
        p.produce(16)
    t = nrc.OnlineTrainer(cornell, producer="pt", records=64, width=8, height=8)
    t.close()
    with pytest.raises(ValueError, match="closed"):
        t.step()


def test_bad_numbers(cornell):
    with pytest.raises(nrc.NrcError, match="empty"):
        nrc.render(cornell, width=0)
    with pytest.raises(ValueError, match="scene_box"):
        nrc.Cache(scene_box=((0, 0, 0), (1, float("nan"), 1)))
    with pytest.raises(ValueError, match="n must be in 1"):
        nrc.Producer(cornell, "pt").produce(0)
    with pytest.raises(ValueError, match="finite"):
        cornell.at(float("inf"))
    with pytest.raises(OverflowError):
        nrc.render(cornell, spp=-1)


def test_sizes_beyond_the_limits(cornell):
    """Requests whose allocation could fail (which would abort the interpreter) are refused."""
    with pytest.raises(ValueError, match="limit"):
        nrc.render(cornell, width=1 << 16, height=1 << 16)
    with pytest.raises(ValueError, match="n must be in"):
        nrc.Producer(cornell, "pt").produce(10**12)
    with pytest.raises(nrc.NrcError, match="--fps must be positive"):
        nrc.OnlineTrainer(nrc.Scene.load(SCENES / "cornell-box-moving.gltf"), fps=0)


def test_empty_and_odd_arrays(trained):
    assert trained.infer(np.zeros((0, 16), np.float32)).shape == (0, 3)
    # A misaligned float32 view (offset by one byte) is refused, not read.
    raw = np.zeros(16 * 4 * 4 + 1, np.uint8)[1:].view(np.float32).reshape(4, 16)
    with pytest.raises((ValueError, TypeError)):
        trained.infer(raw)


def test_cli_help_prints(capfd):
    nrc.cli(["--version"])
    assert "nrc" in capfd.readouterr().out
