"""Type stubs of the native module (crates/python); users call ``nst3d``'s functions.

The options each job takes are typed dicts with the command line's flags as
keys (``_`` for ``-``); every key is optional (the command line's default),
and an unknown key or a value of the wrong type is refused by the library
with ``TypeError``/``ValueError`` as well as by a type checker here.
"""

from typing import Any, Callable, Dict, List, Literal, Optional, Sequence, Tuple, TypedDict, Union

__version__: str

class Nst3dError(RuntimeError):
    """A job failed; the message is the command line's one-line error."""

_Progress = Optional[Callable[[int, int, str], Any]]
_Log = Optional[Callable[[str, str], Any]]
_Mode = Literal["velocity", "density"]
_Up = Literal["y", "z"]
_Strength = Union[Literal["subtle", "default", "strong"], float]

class VolumeOptions(TypedDict, total=False):
    """``nst3d volume``'s flags (one frame, a sequence or a trained model)."""

    preview: str
    grid: str
    mode: _Mode
    octaves: int
    iters: int
    lr: float
    vmax: float
    smin: float
    smax: float
    style_scale: float
    strength: _Strength
    style_color: bool
    color: bool
    color_grid: str
    layers: List[str]
    absorption: float
    equalize: bool
    camera: Literal["perspective", "orthographic"]
    fov: float
    up: _Up
    weights: str
    cameras: str
    camera_file: str
    camera_seed: int
    eval_cameras: str
    style_map: str
    style_map_labels: bool
    upsample: Union[Literal["auto"], int]
    frames: str
    ema: float
    ema_settle: bool
    velocity_grid: str
    velocity_scale: float
    chunk: str
    warmup: int
    force: bool
    work_dir: str
    model: str
    tile: int
    tile_margin: int

class ModelOptions(TypedDict, total=False):
    """How a trained model is applied (``nst3d volume --model``'s flags)."""

    tile: int
    tile_margin: int
    mode: _Mode
    strength: _Strength

class GroomOptions(TypedDict, total=False):
    """``nst3d strands``'s flags."""

    preview: str
    style_map: str
    style_map_labels: bool
    preset: Literal["short-hair", "short-hair-360", "long-hair", "cat", "fur-ball", "grass"]
    frames: str
    force: bool
    work_dir: str
    temporal: Literal["ema-one-euro", "ema", "one-euro", "off"]
    ema_sigma: float
    ema_nu: float
    ema_clock: Literal["scale", "frame"]
    one_euro_alpha: float
    one_euro_beta: float
    one_euro_fmin: float
    fps: float
    style_flow: List[float]
    iters: int
    scale_iters: List[int]
    render_size: int
    proxies: int
    up: _Up
    seed: int
    lr_scale: float
    style_scale: float
    views_per_scale: int
    eval_views: int
    strand_width: float
    rematch: bool
    field_neighbors: int
    orientation: float
    color: bool
    weights: str

class TrainOptions(TypedDict, total=False):
    """``nst3d train``'s flags."""

    mode: _Mode
    grid: str
    channels: int
    patch: int
    steps: int
    minutes: float
    theta: float
    phi: float
    view_axes: str
    absorption: str
    texture: int
    style_scale: float
    octaves: int
    seed: int
    checkpoint_every: int
    batch: int
    weights: str

def stylize_volume(
    density: bytes, dims: Tuple[int, int, int], style: str, options: VolumeOptions,
    progress: _Progress = None, log: _Log = None,
) -> Tuple[bytes, Dict[str, Any]]: ...
def stylize_vdb(
    input: str, out: str, styles: List[str], options: VolumeOptions, progress: _Progress = None, log: _Log = None,
    style_map_array: Optional[Tuple[bytes, Tuple[int, int, int]]] = None,
) -> Dict[str, Any]: ...
def stylize_groom(
    points: bytes, counts: Sequence[int], styles: List[str], options: GroomOptions,
    mesh_file: Optional[str] = None, mesh: Optional[Tuple[bytes, Sequence[int]]] = None,
    progress: _Progress = None, log: _Log = None, colors: Optional[bytes] = None,
    style_map_values: Optional[bytes] = None,
) -> Tuple[bytes, Dict[str, Any]]: ...
def stylize_groom_file(
    groom: str, out: str, styles: List[str], options: GroomOptions, mesh: Optional[str] = None,
    progress: _Progress = None, log: _Log = None, style_map_values: Optional[bytes] = None,
) -> Dict[str, Any]: ...
def train(
    inputs: List[str],
    frame_lists: List[str],
    style: str,
    out: str,
    options: TrainOptions,
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
    def load(path: str, options: ModelOptions) -> "Model": ...
    @property
    def mode(self) -> str: ...
    @property
    def info(self) -> Dict[str, str]: ...
    def stylize(
        self, density: bytes, dims: Tuple[int, int, int], origin: Sequence[int] = ..., progress: _Progress = None,
        log: _Log = None,
    ) -> bytes: ...
