"""nst3d: neural style transfer for smoke volumes and hair grooms, on the CPU.

The same jobs as the ``nst3d`` command line, with the same settings and
defaults, run by the same Rust library (no subprocess, no network):

- :func:`stylize_volume` — a dense density array (numpy) in, a stylized one out;
- :func:`stylize_vdb` — an OpenVDB file or a ``####`` sequence to files;
- :func:`stylize_groom` — strand points (numpy) in, stylized points out;
- :func:`stylize_groom_file` — a groom file or animated groom to files;
- :func:`train` and :class:`Model` — the feed-forward network.

Keyword arguments are the command line's flags with ``_`` for ``-``
(``nst3d volume --help``, ``nst3d strands --help``); ``None`` keeps the
command line's default. Long jobs report through ``progress(done, total,
message)`` and log their notes to the ``"nst3d"`` :mod:`logging` logger.
The GIL is released while a job computes; Ctrl-C (or an exception raised
by ``progress``) stops it after the iteration in progress and is raised
again. A failed job raises :class:`Nst3dError` with the command line's
one-line message.

Arrays are indexed like OpenVDB's ``copyToArray``: ``density[i, j, k]`` is
the voxel at index (x=i, y=j, z=k), so an array from ``pyopenvdb`` goes in
as it is and the result goes back with ``copyFromArray``. Grids are z-up
by default (Blender); pass ``up="y"`` for Houdini and Maya.
"""

from __future__ import annotations

import logging
import os
from typing import TYPE_CHECKING, Any, Callable, Dict, List, Literal, Optional, Sequence, Tuple, Union

import numpy as np

if TYPE_CHECKING:
    from numpy.typing import NDArray

from . import _nst3d
from ._nst3d import Nst3dError, __version__, precision, set_precision, set_threads, threads

__all__ = [
    "Nst3dError",
    "Model",
    "__version__",
    "bench_volume_iter",
    "precision",
    "print_progress",
    "read_groom",
    "read_mesh",
    "set_precision",
    "set_threads",
    "stylize_groom",
    "stylize_groom_file",
    "stylize_vdb",
    "stylize_volume",
    "threads",
    "train",
]

PathLike = Union[str, "os.PathLike[str]"]
Progress = Callable[[int, int, str], Any]
# The command line's choices, as the type checker sees them.
Mode = Literal["velocity", "density"]
Up = Literal["y", "z"]
Camera = Literal["perspective", "orthographic"]
Strength = Union[Literal["subtle", "default", "strong"], float]
Upsample = Union[Literal["auto"], int]
Preset = Literal["short-hair", "short-hair-360", "long-hair", "cat", "fur-ball", "grass"]
Temporal = Literal["ema-one-euro", "ema", "one-euro", "off"]
EmaClock = Literal["scale", "frame"]
Layer = Literal["relu1_1", "relu1_2", "relu2_1", "relu2_2", "relu3_1", "relu3_2", "relu3_3", "relu3_4",
                "relu4_1", "relu4_2", "relu4_3", "relu4_4", "relu5_1"]

_log = logging.getLogger("nst3d")
_LEVELS = {"note": logging.INFO, "status": logging.INFO, "result": logging.INFO, "warning": logging.WARNING}


def _to_log(level: str, message: str) -> None:
    _log.log(_LEVELS.get(level, logging.INFO), message)


def print_progress(done: int, total: int, message: str) -> None:
    """A ready-made ``progress`` callback: one line per step on stderr."""
    import sys

    if total and done:
        print(f"[{done}/{total}] {message}", file=sys.stderr, flush=True)


def _options(**kw: Any) -> Any:
    """The options the caller gave, paths as strings, sequences as lists."""
    out: Dict[str, Any] = {}
    for k, v in kw.items():
        if v is None:
            continue
        if isinstance(v, os.PathLike):
            v = os.fspath(v)
        elif isinstance(v, tuple):
            v = list(v)
        out[k] = v
    return out


def _camera(camera: Optional[Camera], projection: Optional[Camera]) -> Optional[Camera]:
    """``camera`` (the command line's ``--camera``), or its old name ``projection``."""
    if projection is not None:
        import warnings

        warnings.warn("'projection' is now 'camera' (as nst3d volume --camera)", DeprecationWarning, stacklevel=3)
        if camera is None:
            return projection
    return camera


def _grid_bytes(density: "NDArray[Any]") -> Tuple[bytes, Tuple[int, int, int]]:
    a = np.asarray(density)
    if a.ndim != 3:
        raise ValueError(f"density must be a 3D array, got shape {a.shape}")
    if not np.issubdtype(a.dtype, np.floating):
        raise TypeError(f"density must hold floats, got {a.dtype}")
    # [i, j, k] = (x, y, z) → x fastest, as the library's grids are.
    raw = np.ascontiguousarray(a.transpose(2, 1, 0), dtype="<f4").tobytes()
    return raw, (int(a.shape[0]), int(a.shape[1]), int(a.shape[2]))


def _grid_array(raw: bytes, dims: Sequence[int]) -> "NDArray[Any]":
    nx, ny, nz = (int(d) for d in dims)
    return np.ascontiguousarray(np.frombuffer(raw, dtype="<f4").reshape(nz, ny, nx).transpose(2, 1, 0))


def stylize_volume(
    density: "NDArray[Any]",
    style: PathLike,
    *,
    mode: Optional[Mode] = None,
    octaves: Optional[int] = None,
    iters: Optional[int] = None,
    lr: Optional[float] = None,
    vmax: Optional[float] = None,
    smin: Optional[float] = None,
    smax: Optional[float] = None,
    style_scale: Optional[float] = None,
    strength: Optional[Strength] = None,
    style_color: Optional[bool] = None,
    layers: Optional[Sequence[Layer]] = None,
    absorption: Optional[float] = None,
    equalize: Optional[bool] = None,
    camera: Optional[Camera] = None,
    fov: Optional[float] = None,
    up: Optional[Up] = None,
    weights: Optional[PathLike] = None,
    cameras: Optional[str] = None,
    camera_seed: Optional[int] = None,
    eval_cameras: Optional[str] = None,
    upsample: Optional[Upsample] = None,
    preview: Optional[PathLike] = None,
    progress: Optional[Progress] = None,
    report: Optional[Dict[str, Any]] = None,
    projection: Optional[Camera] = None,
) -> "NDArray[Any]":
    """Stylizes one density grid with a painting (volumetric paper, Sec. 3).

    ``density`` is a 3D float array indexed ``[x, y, z]`` (see the module
    docstring); the result has the same shape, or ``upsample`` times it when
    a small grid is refined (``upsample="auto"``, the default, refines a
    grid whose largest side is under 32 voxels; ``upsample=1`` never does).
    Smoke a velocity carries outside the array's box is not kept: leave a
    margin of empty voxels around the smoke if it matters.

    ``mode`` is ``"velocity"`` (default: the smoke is moved by an optimised
    velocity field) or ``"density"`` (scaled by an optimised field); the
    other options are ``nst3d volume``'s (``cameras="omniview:16"`` for
    views all around, ``strength="subtle"`` or ``"strong"``...). When
    ``report`` is a dict it receives the losses before and after.
    """
    raw, dims = _grid_bytes(density)
    opts = _options(
        mode=mode, octaves=octaves, iters=iters, lr=lr, vmax=vmax, smin=smin, smax=smax,
        style_scale=style_scale, strength=strength, style_color=style_color, layers=layers,
        absorption=absorption, equalize=equalize, camera=_camera(camera, projection), fov=fov, up=up,
        weights=weights, cameras=cameras, camera_seed=camera_seed, eval_cameras=eval_cameras,
        upsample=upsample, preview=preview,
    )
    out, rep = _nst3d.stylize_volume(raw, dims, os.fspath(style), opts, progress, _to_log)
    if report is not None:
        report.update(rep)
    return _grid_array(out, rep["dims"])


def stylize_vdb(
    input: PathLike,
    out: PathLike,
    style: Union[PathLike, Sequence[PathLike], None] = None,
    *,
    style_map: Union[str, "NDArray[Any]", None] = None,
    style_map_labels: Optional[bool] = None,
    grid: Optional[str] = None,
    frames: Optional[str] = None,
    ema: Optional[float] = None,
    ema_settle: Optional[bool] = None,
    velocity_grid: Optional[str] = None,
    velocity_scale: Optional[float] = None,
    chunk: Optional[str] = None,
    warmup: Optional[int] = None,
    force: Optional[bool] = None,
    work_dir: Optional[PathLike] = None,
    model: Optional[PathLike] = None,
    tile: Optional[int] = None,
    tile_margin: Optional[int] = None,
    mode: Optional[Mode] = None,
    octaves: Optional[int] = None,
    iters: Optional[int] = None,
    lr: Optional[float] = None,
    vmax: Optional[float] = None,
    smin: Optional[float] = None,
    smax: Optional[float] = None,
    style_scale: Optional[float] = None,
    strength: Optional[Strength] = None,
    style_color: Optional[bool] = None,
    color: Optional[bool] = None,
    color_grid: Optional[str] = None,
    layers: Optional[Sequence[Layer]] = None,
    absorption: Optional[float] = None,
    equalize: Optional[bool] = None,
    camera: Optional[Camera] = None,
    fov: Optional[float] = None,
    up: Optional[Up] = None,
    weights: Optional[PathLike] = None,
    cameras: Optional[str] = None,
    camera_file: Optional[PathLike] = None,
    camera_seed: Optional[int] = None,
    eval_cameras: Optional[str] = None,
    upsample: Optional[Upsample] = None,
    preview: Optional[PathLike] = None,
    progress: Optional[Progress] = None,
    projection: Optional[Camera] = None,
) -> Dict[str, Any]:
    """Stylizes an OpenVDB file into ``out``, exactly as ``nst3d volume``.

    With ``frames`` (e.g. ``"1-120"``) ``input`` and ``out`` are patterns
    with ``####`` and the whole simulation is stylized with the EMA of
    Algorithm 1 (``ema``), resumable (``force`` starts over) and in farm
    chunks (``chunk="41-80"``, ``warmup``). With ``model`` a trained network
    stylizes each frame instead (``style`` is then not needed). Every other
    grid of the file is kept; outputs are written atomically. Returns the
    report as a dict (``kind`` is ``"frame"``, ``"sequence"`` or ``"model"``).

    Several paintings (``style=[a, b]``) go where ``style_map`` puts them,
    as ``nst3d volume --style a --style b --style-map``: a grid of the file
    (``"temperature"``), of another file (``"map.vdb:mask"``) or
    ``"@height"``; a float map blends two paintings, a label map
    (``style_map_labels=True``) picks one of several.

    ``style_map`` may also be a numpy array over the active bounding box of
    the input's density grid (``grid``), indexed ``[x, y, z]`` like
    ``pyopenvdb``'s ``copyToArray`` from the box's first corner: floats
    blend two paintings (0 the first, 1 the second), integers or booleans
    are labels (0 the first painting, 1 the second, ...). It is sampled as a grid of
    the file lying over that box, so it follows the density through
    ``upsample``. One frame only (not with ``frames``).
    """
    map_array = None
    if style_map is not None and not isinstance(style_map, str):
        map_array, style_map_labels = _style_map_array(style_map, style_map_labels)
        style_map = None
    opts = _options(
        style_map=style_map, style_map_labels=style_map_labels,
        grid=grid, frames=frames, ema=ema, ema_settle=ema_settle, velocity_grid=velocity_grid,
        velocity_scale=velocity_scale, chunk=chunk, warmup=warmup, force=force, work_dir=work_dir,
        model=model, tile=tile, tile_margin=tile_margin, mode=mode, octaves=octaves, iters=iters,
        lr=lr, vmax=vmax, smin=smin, smax=smax, style_scale=style_scale, strength=strength,
        style_color=style_color, color=color, color_grid=color_grid, layers=layers, absorption=absorption, equalize=equalize,
        camera=_camera(camera, projection), fov=fov, up=up, weights=weights, cameras=cameras,
        camera_file=camera_file, camera_seed=camera_seed, eval_cameras=eval_cameras,
        upsample=upsample, preview=preview,
    )
    if style is None and model is None:
        raise ValueError("stylize_vdb needs a style painting (or a trained model)")
    if style is None:
        styles = [""]
    elif isinstance(style, (str, os.PathLike)):
        styles = [os.fspath(style)]
    else:
        styles = [os.fspath(s) for s in style]
    return _nst3d.stylize_vdb(os.fspath(input), os.fspath(out), styles, opts, progress, _to_log, map_array)


def _style_map_array(
    style_map: Any, labels: Optional[bool]
) -> Tuple[Tuple[bytes, Tuple[int, int, int]], Optional[bool]]:
    """A numpy style map as float32 bytes (x fastest) and its shape, and
    whether it holds labels (an integer or boolean array does)."""
    a = np.asarray(style_map)
    if np.issubdtype(a.dtype, np.integer) or a.dtype == np.bool_:
        if labels is False:
            raise ValueError("style_map: an integer array holds labels; pass floats to blend two paintings")
        labels = True
    elif not np.issubdtype(a.dtype, np.floating):
        raise TypeError(f"style_map: an array must hold floats (a blend) or integers (labels), got {a.dtype}")
    if a.ndim != 3:
        raise ValueError(
            f"style_map: an array must be 3D, indexed [x, y, z] over the density grid's active box; got shape {a.shape}"
        )
    raw = np.ascontiguousarray(a.transpose(2, 1, 0), dtype="<f4").tobytes()
    return (raw, (int(a.shape[0]), int(a.shape[1]), int(a.shape[2]))), labels


def stylize_groom(
    points: "NDArray[Any]",
    counts: Union[Sequence[int], "NDArray[Any]"],
    style: Union[PathLike, Sequence[PathLike]],
    *,
    style_map: Union[str, "NDArray[Any]", None] = None,
    style_map_labels: Optional[bool] = None,
    mesh: Union[PathLike, Tuple["NDArray[Any]", "NDArray[Any]"], None] = None,
    preset: Optional[Preset] = None,
    iters: Optional[int] = None,
    scale_iters: Optional[Sequence[int]] = None,
    render_size: Optional[int] = None,
    proxies: Optional[int] = None,
    up: Optional[Up] = None,
    seed: Optional[int] = None,
    lr_scale: Optional[float] = None,
    style_scale: Optional[float] = None,
    views_per_scale: Optional[int] = None,
    eval_views: Optional[int] = None,
    strand_width: Optional[float] = None,
    rematch: Optional[bool] = None,
    field_neighbors: Optional[int] = None,
    orientation: Optional[float] = None,
    weights: Optional[PathLike] = None,
    preview: Optional[PathLike] = None,
    color: Optional[bool] = None,
    colors: Optional["NDArray[Any]"] = None,
    progress: Optional[Progress] = None,
    report: Optional[Dict[str, Any]] = None,
) -> Union["NDArray[Any]", Tuple["NDArray[Any]", "NDArray[Any]"]]:
    """Stylizes a groom (strand paper, Alg. 1) and returns its new points.

    ``points`` is an ``(N, 3)`` float array of every control point, strand
    after strand, root first; ``counts`` the points of each strand (at least
    2 each, summing to N). ``mesh`` is the scalp or body mesh the strands
    grow from — a ``.ply``/``.obj`` path or ``(vertices (V, 3), triangles
    (T, 3))`` — kept out of by the collision constraint; without it there
    is no collision handling. The result has the same shape and order, with
    every strand's length kept. ``preset`` is a Table 1 example
    (``"short-hair"`` default, ``"short-hair-360"``, ``"long-hair"``,
    ``"cat"``, ``"fur-ball"``, ``"grass"``). ``up`` is the axis the
    points and mesh stand on (``"y"`` default, ``"z"`` for Blender): the
    cameras circle it and the result is in the same axes. With
    ``color=True`` the strands' colour is stylized too, starting from
    ``colors`` (an ``(N, 3)`` array in ``[0, 1]``; white without), and the
    result is ``(points, colors)``. Several paintings (``style=[a, b]``)
    go where ``style_map`` puts them: one value per strand, as a numpy
    array (floats blend two paintings, 0 the first and 1 the second;
    integers are labels, 0 the first painting, 1 the second, ...) or as
    ``nst3d strands --style-map`` takes it (``"@height"``, a ``.txt``
    file). The other options are ``nst3d strands``'s.
    """
    p = np.ascontiguousarray(points, dtype="<f4")
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must be an (N, 3) array, got shape {p.shape}")
    c = [int(n) for n in np.asarray(counts).ravel()]
    style_map, style_map_labels, map_values = _strand_map(style_map, style_map_labels)
    opts = _options(
        style_map=style_map, style_map_labels=style_map_labels,
        preset=preset, iters=iters, scale_iters=scale_iters, render_size=render_size, proxies=proxies,
        up=up, seed=seed, lr_scale=lr_scale, style_scale=style_scale, views_per_scale=views_per_scale, eval_views=eval_views,
        strand_width=strand_width, rematch=rematch, field_neighbors=field_neighbors, orientation=orientation, weights=weights, preview=preview, color=color,
    )
    col = None
    if colors is not None:
        cc = np.ascontiguousarray(colors, dtype="<f4")
        if cc.shape != p.shape:
            raise ValueError(f"colors must be an (N, 3) array like points, got shape {cc.shape}")
        col = cc.tobytes()
    mesh_file = None
    mesh_arrays = None
    if isinstance(mesh, (str, os.PathLike)):
        mesh_file = os.fspath(mesh)
    elif mesh is not None:
        verts, tris = mesh
        v = np.ascontiguousarray(verts, dtype="<f4")
        t = np.ascontiguousarray(tris, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3 or t.ndim != 2 or t.shape[1] != 3:
            raise ValueError("mesh must be (vertices (V, 3), triangles (T, 3))")
        if t.size and (t.min() < 0 or t.max() >= len(v)):
            raise ValueError("mesh: a triangle index is outside the vertices")
        mesh_arrays = (v.tobytes(), [int(i) for i in t.ravel()])
    out, rep = _nst3d.stylize_groom(
        p.tobytes(), c, _paths(style), opts, mesh_file, mesh_arrays, progress, _to_log, col, map_values
    )
    stylized = rep.pop("colors", None)
    if report is not None:
        report.update(rep)
    new_points = np.frombuffer(out, dtype="<f4").reshape(-1, 3).copy()
    if color:
        return new_points, np.frombuffer(stylized, dtype="<f4").reshape(-1, 3).copy()
    return new_points


def stylize_groom_file(
    groom: PathLike,
    out: PathLike,
    style: Union[PathLike, Sequence[PathLike]],
    *,
    style_map: Union[str, "NDArray[Any]", None] = None,
    style_map_labels: Optional[bool] = None,
    mesh: Optional[PathLike] = None,
    preset: Optional[Preset] = None,
    frames: Optional[str] = None,
    force: Optional[bool] = None,
    work_dir: Optional[PathLike] = None,
    temporal: Optional[Temporal] = None,
    ema_sigma: Optional[float] = None,
    ema_nu: Optional[float] = None,
    ema_clock: Optional[EmaClock] = None,
    one_euro_alpha: Optional[float] = None,
    one_euro_beta: Optional[float] = None,
    one_euro_fmin: Optional[float] = None,
    fps: Optional[float] = None,
    style_flow: Optional[Sequence[float]] = None,
    iters: Optional[int] = None,
    scale_iters: Optional[Sequence[int]] = None,
    render_size: Optional[int] = None,
    proxies: Optional[int] = None,
    up: Optional[Up] = None,
    seed: Optional[int] = None,
    lr_scale: Optional[float] = None,
    style_scale: Optional[float] = None,
    views_per_scale: Optional[int] = None,
    eval_views: Optional[int] = None,
    strand_width: Optional[float] = None,
    rematch: Optional[bool] = None,
    field_neighbors: Optional[int] = None,
    orientation: Optional[float] = None,
    weights: Optional[PathLike] = None,
    preview: Optional[PathLike] = None,
    color: Optional[bool] = None,
    progress: Optional[Progress] = None,
) -> Dict[str, Any]:
    """Stylizes a groom file (``.hair .data .ply .abc``, USD ``.usda .usdc
    .usd .usdz``) into ``out`` (``.usda .usdc .usdz`` or ``.ply``, same
    topology, colours, widths and USD primvars), exactly as ``nst3d
    strands``. ``up`` (``"y"`` or ``"z"``) defaults to a USD groom's
    ``upAxis``, else ``"y"``; Blender's grooms are z-up.

    With ``frames`` (e.g. ``"1-24"``) ``groom``, ``out`` (and ``mesh``,
    ``preview``) are ``####`` patterns of an animated groom, stylized with
    the EMA and 1€ filter of Sec. 3.3 (``temporal``), resumable after a kill.
    Several paintings go where ``style_map`` puts them (as
    :func:`stylize_groom`; a strand or vertex property's name of a ``.ply``
    groom, or a primvar's of a USD groom, too). Returns the report as a dict.
    """
    style_map, style_map_labels, map_values = _strand_map(style_map, style_map_labels)
    opts = _options(
        style_map=style_map, style_map_labels=style_map_labels,
        preset=preset, frames=frames, force=force, work_dir=work_dir, temporal=temporal,
        ema_sigma=ema_sigma, ema_nu=ema_nu, ema_clock=ema_clock, one_euro_alpha=one_euro_alpha,
        one_euro_beta=one_euro_beta, one_euro_fmin=one_euro_fmin, fps=fps, style_flow=style_flow,
        iters=iters, scale_iters=scale_iters, render_size=render_size, proxies=proxies, up=up,
        seed=seed, lr_scale=lr_scale, style_scale=style_scale, views_per_scale=views_per_scale, eval_views=eval_views,
        strand_width=strand_width, rematch=rematch, field_neighbors=field_neighbors, orientation=orientation, weights=weights, preview=preview, color=color,
    )
    return _nst3d.stylize_groom_file(
        os.fspath(groom), os.fspath(out), _paths(style), opts,
        os.fspath(mesh) if mesh is not None else None, progress, _to_log, map_values,
    )


def _paths(style: Union[PathLike, Sequence[PathLike]]) -> List[str]:
    """One painting or several, as a list of paths."""
    if isinstance(style, (str, os.PathLike)):
        return [os.fspath(style)]
    return [os.fspath(s) for s in style]


def _strand_map(
    style_map: Any, labels: Optional[bool]
) -> Tuple[Optional[str], Optional[bool], Optional[bytes]]:
    """A groom's style map: a string passes through; an array of one value
    per strand becomes float32 bytes (integers or booleans are labels)."""
    if style_map is None or isinstance(style_map, str):
        return style_map, labels, None
    a = np.asarray(style_map)
    if a.dtype.kind in "iub":
        if labels is False:
            raise ValueError("style_map: an integer array holds labels; pass floats to blend two paintings")
        labels = True
    elif a.dtype.kind != "f":
        raise TypeError(f"style_map: an array must hold floats (a blend) or integers (labels), got {a.dtype}")
    if a.ndim != 1:
        raise ValueError(f"style_map: an array must hold one value per strand, got shape {a.shape}")
    return None, labels, np.ascontiguousarray(a, dtype="<f4").tobytes()


def train(
    input: Union[PathLike, Sequence[PathLike]],
    style: PathLike,
    out: PathLike,
    *,
    frames: Union[str, Sequence[str], None] = None,
    mode: Optional[Mode] = None,
    grid: Optional[str] = None,
    channels: Optional[int] = None,
    patch: Optional[int] = None,
    steps: Optional[int] = None,
    minutes: Optional[float] = None,
    theta: Optional[float] = None,
    phi: Optional[float] = None,
    view_axes: Optional[str] = None,
    absorption: Optional[str] = None,
    texture: Optional[int] = None,
    style_scale: Optional[float] = None,
    octaves: Optional[int] = None,
    seed: Optional[int] = None,
    checkpoint_every: Optional[int] = None,
    batch: Optional[int] = None,
    weights: Optional[PathLike] = None,
    progress: Optional[Progress] = None,
) -> Dict[str, Any]:
    """Trains the feed-forward network (volumetric paper Sec. 4) for one
    painting into ``out`` (``.safetensors``), exactly as ``nst3d train``.

    ``input`` is a VDB file, a list of files, or a ``####`` pattern with
    ``frames`` (``"1-40"``; a list gives one per input). A checkpoint is
    written beside ``out``; calling again with the same arguments resumes.
    ``minutes`` alone sizes the schedule to fill that time; with ``steps``
    it bounds one call.
    """
    inputs = [os.fspath(input)] if isinstance(input, (str, os.PathLike)) else [os.fspath(p) for p in input]
    # The command line's frame lists, one per input, parsed by the library.
    frame_lists = [] if frames is None else [frames] if isinstance(frames, str) else list(frames)
    opts = _options(
        mode=mode, grid=grid, channels=channels, patch=patch, steps=steps, minutes=minutes,
        theta=theta, phi=phi, view_axes=view_axes, absorption=absorption, texture=texture, style_scale=style_scale, octaves=octaves,
        seed=seed, checkpoint_every=checkpoint_every, batch=batch, weights=weights,
    )
    return _nst3d.train(inputs, frame_lists, os.fspath(style), os.fspath(out), opts, progress, _to_log)


class Model:
    """A trained feed-forward network (from :func:`train` or ``nst3d train``),
    loaded once and applied to any number of grids."""

    def __init__(self, native: Any) -> None:
        self._m = native

    @classmethod
    def load(
        cls,
        path: PathLike,
        *,
        tile: Optional[int] = None,
        tile_margin: Optional[int] = None,
        mode: Optional[Mode] = None,
        strength: Optional[Strength] = None,
    ) -> "Model":
        """Reads and checks ``path``; ``tile`` and ``tile_margin`` (voxels)
        bound the memory of one pass as ``nst3d volume --model`` does;
        ``mode`` refuses a model of the other mode; ``strength`` takes the
        network's stylization further or less far (``--strength``)."""
        opts = _options(tile=tile, tile_margin=tile_margin, mode=mode, strength=strength)
        return cls(_nst3d.Model.load(os.fspath(path), opts))

    @property
    def mode(self) -> str:
        """``"density"`` or ``"velocity"``."""
        return str(self._m.mode)

    @property
    def info(self) -> Dict[str, str]:
        """The model's metadata (style, patch, steps, ...)."""
        return dict(self._m.info)

    def stylize(
        self,
        density: "NDArray[Any]",
        *,
        origin: Sequence[int] = (0, 0, 0),
        progress: Optional[Progress] = None,
    ) -> "NDArray[Any]":
        """Stylizes a density array (indexed ``[x, y, z]``) in one pass, tile
        by tile; returns an array of the same shape. ``origin`` is the
        OpenVDB index of ``density[0, 0, 0]``: the network's tiles are fixed
        in index space, so the array's index origin gives exactly the
        result ``stylize_vdb(model=...)`` writes for that file."""
        raw, dims = _grid_bytes(density)
        o = [int(v) for v in origin]
        return _grid_array(self._m.stylize(raw, dims, o, progress, _to_log), dims)


def read_groom(path: PathLike) -> Tuple["NDArray[Any]", "NDArray[Any]"]:
    """Reads a groom file (``.hair .data .ply .abc``, USD ``.usda .usdc .usd
    .usdz``): ``(points (N, 3) float32, counts (S,) int64)``, the arrays
    :func:`stylize_groom` takes."""
    raw, counts = _nst3d.read_groom(os.fspath(path))
    return np.frombuffer(raw, dtype="<f4").reshape(-1, 3).copy(), np.asarray(counts, dtype=np.int64)


def read_mesh(path: PathLike) -> Tuple["NDArray[Any]", "NDArray[Any]"]:
    """Reads a triangle mesh (``.ply`` or ``.obj``): ``(vertices (V, 3)
    float32, triangles (T, 3) int64)``."""
    raw, tris = _nst3d.read_mesh(os.fspath(path))
    return np.frombuffer(raw, dtype="<f4").reshape(-1, 3).copy(), np.asarray(tris, dtype=np.int64).reshape(-1, 3)


def bench_volume_iter(n: int = 128, mode: Mode = "velocity", iters: int = 6) -> Tuple[List[float], float]:
    """``nst3d bench volume-iter``'s work: milliseconds of each iteration and their median."""
    return _nst3d.bench_volume_iter(n, mode, iters)
