"""Type stubs of the native module (crates/python); users call ``nst3d``'s functions."""

from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple

__version__: str

class Nst3dError(RuntimeError):
    """A job failed; the message is the command line's one-line error."""

_Progress = Optional[Callable[[int, int, str], Any]]
_Log = Optional[Callable[[str, str], Any]]

def stylize_volume(
    density: bytes, dims: Tuple[int, int, int], style: str, options: Dict[str, Any],
    progress: _Progress = None, log: _Log = None,
) -> Tuple[bytes, Dict[str, Any]]: ...
def stylize_vdb(
    input: str, out: str, style: str, options: Dict[str, Any], progress: _Progress = None, log: _Log = None
) -> Dict[str, Any]: ...
def stylize_groom(
    points: bytes, counts: Sequence[int], style: str, options: Dict[str, Any],
    mesh_file: Optional[str] = None, mesh: Optional[Tuple[bytes, Sequence[int]]] = None,
    progress: _Progress = None, log: _Log = None, colors: Optional[bytes] = None,
) -> Tuple[bytes, Dict[str, Any]]: ...
def stylize_groom_file(
    groom: str, out: str, style: str, options: Dict[str, Any], mesh: Optional[str] = None,
    progress: _Progress = None, log: _Log = None,
) -> Dict[str, Any]: ...
def train(
    inputs: List[str],
    frame_lists: List[str],
    style: str,
    out: str,
    options: Dict[str, Any],
    progress: _Progress = None,
    log: _Log = None,
) -> Dict[str, Any]: ...
def read_groom(path: str) -> Tuple[bytes, List[int]]: ...
def read_mesh(path: str) -> Tuple[bytes, List[int]]: ...
def bench_volume_iter(n: int = 128, mode: str = "velocity", iters: int = 6) -> Tuple[List[float], float]: ...
def set_threads(n: int) -> None: ...
def set_precision(name: str) -> str: ...
def precision() -> str: ...
def threads() -> int: ...

class Model:
    @staticmethod
    def load(path: str, options: Dict[str, Any]) -> "Model": ...
    @property
    def mode(self) -> str: ...
    @property
    def info(self) -> Dict[str, str]: ...
    def stylize(
        self, density: bytes, dims: Tuple[int, int, int], origin: Sequence[int] = ..., progress: _Progress = None,
        log: _Log = None,
    ) -> bytes: ...
