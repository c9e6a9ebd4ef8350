"""Type stubs of the native part of `nrc` (see the package docstring)."""

from os import PathLike
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

_Path = Union[str, PathLike]
_Vec3 = Tuple[float, float, float]
_F32 = npt.NDArray[np.float32]

QUERY_DIMS: int

class NrcError(Exception):
    """An error of nrc: the message is the command line's `error:` line."""

class Scene:
    @staticmethod
    def load(path: _Path, **options: Any) -> "Scene":
        """Loads a glTF scene; options are `nrc info`'s flags (camera_pos=(x, y, z), env=...)."""
    def at(self, t: float) -> "Scene":
        """The scene posed at `t` seconds of its animation."""
    @property
    def path(self) -> str: ...
    @property
    def triangle_count(self) -> int: ...
    @property
    def light_count(self) -> int: ...
    @property
    def is_animated(self) -> bool: ...
    @property
    def duration(self) -> float: ...
    @property
    def time(self) -> float: ...
    @property
    def bounds(self) -> Tuple[List[float], List[float]]: ...
    @property
    def scene_box(self) -> Tuple[List[float], List[float]]:
        """The box query positions are normalised to."""
    @property
    def camera(self) -> Dict[str, Any]: ...
    def lights(self) -> Dict[str, Any]:
        """emissive_triangles (indices), punctual (list of dicts), environment (bool)."""
    def triangles(self) -> _F32:
        """Vertices, float32 of shape (T, 3, 3)."""
    def summary(self) -> str: ...
    def _options(self) -> Dict[str, Any]: ...

class Cache:
    def __init__(
        self,
        config: Union[None, str, _Path, Dict[str, Any]] = None,
        scene: Optional[Scene] = None,
        scene_box: Optional[Tuple[_Vec3, _Vec3]] = None,
        device: str = "cpu",
        kind: str = "neural",
        **options: Any,
    ) -> None: ...
    @staticmethod
    def load(path: _Path, device: str = "cpu") -> "Cache": ...
    def train(self, batch: Dict[str, _F32], steps: int = 1) -> float:
        """`steps` optimiser steps on a batch (queries (N, 16), targets (N, 3), weights (N,)); the last loss."""
    def infer(self, queries: _F32) -> _F32:
        """Radiance (N, 3) at queries (N, 16), float32."""
    def save(self, path: _Path) -> None: ...
    def export(self, path: _Path) -> Dict[str, Any]:
        """Portable export (docs/export.md) into the folder `path`."""
    def parameters(self, inference: bool = True) -> Dict[str, _F32]: ...
    @property
    def kind(self) -> str: ...
    @property
    def scene_box(self) -> Tuple[List[float], List[float]]: ...
    @property
    def memory_bytes(self) -> int: ...
    def describe(self) -> str: ...
    def close(self) -> None: ...
    def __enter__(self) -> "Cache": ...
    def __exit__(self, *args: Any) -> bool: ...
    def _time_infer(self, queries: _F32, reps: int) -> float: ...

class Producer:
    def __init__(
        self,
        scene: Scene,
        kind: str = "pt-sl",
        seed: int = 1,
        width: int = 128,
        height: int = 128,
        **options: Any,
    ) -> None: ...
    def produce(self, n: int = 4096, cache: Optional[Cache] = None) -> Dict[str, _F32]:
        """The next frame's training records: queries (N, 16), targets (N, 3), weights (N,)."""
    @property
    def frame(self) -> int: ...
    def close(self) -> None: ...

class OnlineTrainer:
    def __init__(
        self,
        scene: Scene,
        producer: str = "pt-sl",
        pass_: Optional[str] = None,
        width: int = 128,
        height: int = 128,
        **options: Any,
    ) -> None: ...
    def step(self, render: bool = True) -> Tuple[Optional[_F32], Dict[str, Any]]:
        """One frame of the online loop: (image (H, W, 3) or None, statistics)."""
    @property
    def frames(self) -> int: ...
    def save(self, path: _Path) -> None: ...
    def cache(self) -> Cache: ...
    def close(self) -> None: ...

def render(
    scene: Scene,
    pass_: Optional[str] = None,
    spp: int = 1,
    width: int = 128,
    height: int = 128,
    cache: Optional[Cache] = None,
    seed: int = 1,
    **options: Any,
) -> _F32:
    """An (H, W, 3) float32 image: the same bits as `nrc render` for the same settings."""

def _time_render(scene: Scene, reps: int, pass_: Optional[str] = None, spp: int = 1, width: int = 128, height: int = 128, cache: Optional[Cache] = None, seed: int = 1, **options: Any) -> float: ...
def cli(args: Sequence[str]) -> None:
    """Runs a command of the `nrc` program (its words after `nrc`)."""
def run_command(sub: str, **options: Any) -> None: ...
def read_exr(path: _Path) -> _F32: ...
