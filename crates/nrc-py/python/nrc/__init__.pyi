from typing import Any, Dict, Optional, Sequence, Union
from os import PathLike

from ._nrc import (
    QUERY_DIMS as QUERY_DIMS,
    Cache as Cache,
    NrcError as NrcError,
    OnlineTrainer as OnlineTrainer,
    Producer as Producer,
    Scene as Scene,
    cli as cli,
    read_exr as read_exr,
    render as render,
    run_command as run_command,
)

def compare(
    scene: Scene,
    methods: Union[str, Sequence[str]],
    out: Optional[Union[str, PathLike]] = None,
    **options: Any,
) -> Dict[str, Any]: ...
