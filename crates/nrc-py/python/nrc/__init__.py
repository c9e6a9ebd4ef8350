"""nrc: the neural radiance cache trainer from Python.

Thin bindings of the Rust workspace (every function calls its crates):

- ``Scene.load(path, **options)``: a glTF scene (``options``: ``nrc info``'s flags);
  ``scene.at(t)`` poses an animated one.
- ``render(scene, pass_=..., spp=..., width=..., height=..., cache=None, seed=...)``: an
  ``(H, W, 3)`` float32 image, the same bits as ``nrc render``.
- ``Producer(scene, kind="pt-sl", ...)``: ``.produce(n)`` gives the training records the
  online loop would use, as arrays (``queries`` ``(N, 16)``, ``targets`` ``(N, 3)``,
  ``weights`` ``(N,)``).
- ``Cache(config=..., scene=..., device=...)``: ``.train(batch)``, ``.infer(queries)``,
  ``.save(path)``, ``Cache.load(path)``, ``.export(dir)``, ``.parameters()``.
- ``OnlineTrainer(scene, producer=..., ...)``: ``.step()`` runs one frame of ``nrc train``.
- ``compare(scene, methods=[...], ...)``: ``nrc compare``'s report as a dict.
- ``cli([...])``: any command of the ``nrc`` program.

A query row holds 16 float32: position (3, normalised to the scene box's [0,1]^3), outgoing
direction (3), surface normal (3), roughness (1), diffuse reflectance (3), specular
reflectance (3). Errors of the library raise ``NrcError`` with the command line's ``error:``
message; malformed arrays raise ``TypeError`` or ``ValueError``.
"""

import json
import os
import tempfile

from ._nrc import (
    QUERY_DIMS,
    Cache,
    NrcError,
    OnlineTrainer,
    Producer,
    Scene,
    cli,
    read_exr,
    render,
    run_command,
)

__all__ = [
    "QUERY_DIMS",
    "Cache",
    "NrcError",
    "OnlineTrainer",
    "Producer",
    "Scene",
    "cli",
    "compare",
    "read_exr",
    "render",
]


def compare(scene, methods, out=None, **options):
    """Runs ``nrc compare`` on ``scene`` (a ``Scene``: its file and load options) for
    ``methods`` (a list of method names) and returns its ``report.json`` as a dict.

    ``options`` are ``nrc compare``'s flags (``equal_time=400``, ``equal_spp=4``,
    ``width=64``, ``runs=2``, ``reference_spp=256``, ...). ``out``: the folder for the report,
    images and plots (default: a temporary folder, removed afterwards).
    """
    if isinstance(methods, str):
        methods = [methods]
    fields = dict(scene._options())
    fields.update(options)
    fields["methods"] = list(methods)
    if out is not None:
        run_command("compare", out=os.fspath(out), **fields)
        with open(os.path.join(out, "report.json")) as f:
            return json.load(f)
    with tempfile.TemporaryDirectory(prefix="nrc-compare-") as tmp:
        run_command("compare", out=tmp, **fields)
        with open(os.path.join(tmp, "report.json")) as f:
            return json.load(f)
