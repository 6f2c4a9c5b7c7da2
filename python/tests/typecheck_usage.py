"""Checked by mypy --strict in CI (tools/test_python.sh), never run: calls as
a user writes them type-check, and each wrong one is flagged — its
`type: ignore` would otherwise be unused, which --strict reports."""

import pathlib

import numpy as np

import nst3d


def right() -> None:
    d = np.zeros((8, 8, 8), np.float32)
    out = nst3d.stylize_volume(d, "p.jpg", mode="density", iters=4, upsample=1, strength="subtle", up="y",
                               layers=["relu1_1", "relu3_1"], camera="orthographic")
    out.sum()
    nst3d.stylize_vdb(pathlib.Path("in.vdb"), "out.vdb", "p.jpg", frames="1-40", chunk="1-10", warmup=8,
                      color=True, upsample="auto", strength=1.5)
    nst3d.stylize_vdb("in.vdb", "out.vdb", ["a.jpg", "b.jpg"], style_map=np.zeros((8, 8, 8), np.int32), color=True)
    points, counts = nst3d.read_groom("g.usda")
    nst3d.stylize_groom(points, counts, "p.jpg", preset="fur-ball", render_size=48, scale_iters=[0, 0, 3])
    nst3d.stylize_groom_file("g.usda", "o.usda", "p.jpg", temporal="ema", ema_clock="frame", style_flow=(0, 1, 0))
    nst3d.stylize_groom(points, counts, ["a.jpg", "b.jpg"], style_map=np.zeros(len(counts)), preset="fur-ball")
    nst3d.stylize_groom_file("g.ply", "o.usda", ["a.jpg", "b.jpg"], style_map="side", style_map_labels=True)
    nst3d.train("f_####.vdb", "p.jpg", "m.safetensors", frames="1-40", steps=4, mode="velocity")
    nst3d.Model.load("m.safetensors", tile=64, strength="strong").stylize(d, origin=(0, 0, 0))


def wrong() -> None:
    d = np.zeros((8, 8, 8), np.float32)
    nst3d.stylize_volume(d, "p.jpg", mode="sideways")  # type: ignore[arg-type]
    nst3d.stylize_volume(d, "p.jpg", iters="4")  # type: ignore[arg-type]
    nst3d.stylize_volume(d, "p.jpg", up="x")  # type: ignore[arg-type]
    nst3d.stylize_vdb("in.vdb", "out.vdb", "p.jpg", upsample="twice")  # type: ignore[arg-type]
    nst3d.stylize_vdb("in.vdb", "out.vdb", "p.jpg", colour=True)  # type: ignore[call-arg]
    nst3d.stylize_groom_file("g.usda", "o.usda", "p.jpg", preset="long")  # type: ignore[arg-type]
    nst3d.train("f.vdb", "p.jpg", "m.safetensors", steps=2.5)  # type: ignore[arg-type]
    nst3d.Model.load("m.safetensors", strength="huge")  # type: ignore[arg-type]
