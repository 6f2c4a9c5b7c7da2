"""Grooms through the package: numpy points in and out, the command line's
file job byte for byte."""

import numpy as np
import pytest

import nst3d
from conftest import run_cli

FAST = dict(iters=6, render_size=96, proxies=100, views_per_scale=2, eval_views=1)


def strand_lengths(points, counts):
    out, at = [], 0
    for n in counts:
        p = points[at : at + n]
        out.append(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())
        at += n
    return np.array(out)


def test_points_in_points_out_on_the_real_groom(data, style):
    points, counts = nst3d.read_groom(data / "grooms" / "Bangs_100.hair")
    assert points.shape == (1165, 3) and counts.sum() == 1165 and len(counts) == 100
    verts, tris = nst3d.read_mesh(data / "grooms" / "Bangs_head.ply")
    rep = {}
    out = nst3d.stylize_groom(points, counts, style, mesh=(verts, tris), report=rep, **FAST)
    assert out.shape == points.shape and np.isfinite(out).all()
    assert not np.allclose(out, points), "the groom did not change"
    # Roots stay where they grow (a root under the skin is pushed out onto
    # it by the collision constraint: 3 of the 100, by < 1 % of the groom's
    # size); lengths are kept (the length constraint).
    roots = np.concatenate([[0], np.cumsum(counts)[:-1]])
    moved = np.linalg.norm(out[roots] - points[roots], axis=1)
    extent = np.linalg.norm(points.max(0) - points.min(0))
    assert (moved > 1e-4).sum() <= 5 and moved.max() < 0.01 * extent
    np.testing.assert_allclose(strand_lengths(out, counts), strand_lengths(points, counts), rtol=0.01)
    assert rep["inside"] == 0 and rep["strands"] == 100
    # A mesh file gives the same result as the same mesh as arrays.
    again = nst3d.stylize_groom(points, counts, style, mesh=data / "grooms" / "Bangs_head.ply", **FAST)
    np.testing.assert_array_equal(out, again)
    # The same groom and head turned z-up (as Blender holds them), with
    # up="z": the cameras circle z, and the result is the y-up one turned
    # the same way, to the bit.
    def to_z(p):
        return np.ascontiguousarray(np.stack([p[:, 0], -p[:, 2], p[:, 1]], axis=1), dtype=np.float32)

    z = nst3d.stylize_groom(to_z(points), counts, style, mesh=(to_z(verts), tris), up="z", **FAST)
    np.testing.assert_array_equal(z, to_z(out))


def test_the_file_job_matches_the_command_line_byte_for_byte(tmp_path, data, style, nst3d_bin):
    groom, mesh = data / "grooms" / "Bangs_100.hair", data / "grooms" / "Bangs_head.ply"
    ours = tmp_path / "py.usda"
    rep = nst3d.stylize_groom_file(groom, ours, style, mesh=mesh, **FAST)
    assert rep["kind"] == "groom" and rep["inside"] == 0
    cli = tmp_path / "cli.usda"
    run_cli(nst3d_bin, "strands", "--groom", groom, "--mesh", mesh, "--style", style, "--out", cli,
            "--iters", 6, "--render-size", 96, "--proxies", 100, "--views-per-scale", 2, "--eval-views", 1)
    assert ours.read_bytes() == cli.read_bytes()


def test_bad_grooms_are_refused_with_a_message(style):
    with pytest.raises(ValueError, match="counts"):
        nst3d.stylize_groom(np.zeros((5, 3), np.float32), [2, 2], style)
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        nst3d.stylize_groom(np.zeros((5, 2), np.float32), [5], style)
    with pytest.raises(ValueError, match="poodle"):
        nst3d.stylize_groom(np.random.rand(4, 3).astype(np.float32), [2, 2], style, preset="poodle")
    with pytest.raises(ValueError, match="up"):
        nst3d.stylize_groom(np.random.rand(4, 3).astype(np.float32), [2, 2], style, up="x")
    with pytest.raises(nst3d.Nst3dError):
        nst3d.read_groom("/nonexistent.hair")


def test_color_returns_stylized_colours_from_the_given_ones(data, style):
    # With color=True the result is (points, colours); the colours
    # start from the ones given and move, stay in [0, 1], and the points are
    # stylized as well.
    points, counts = nst3d.read_groom(data / "grooms" / "Bangs_100.hair")
    start = np.tile(np.array([[0.8, 0.6, 0.4]], np.float32), (len(points), 1))
    out, colors = nst3d.stylize_groom(points, counts, style, mesh=data / "grooms" / "Bangs_head.ply",
                                      color=True, colors=start, **FAST)
    assert out.shape == points.shape and colors.shape == points.shape
    assert not np.allclose(out, points)
    assert colors.min() >= 0.0 and colors.max() <= 1.0
    assert np.abs(colors - start).max() > 0.02, "the colours did not move"
    with pytest.raises(ValueError, match="colors"):
        nst3d.stylize_groom(points, counts, style, color=True, colors=start[:5], **FAST)


def test_a_style_map_array_is_the_command_lines_map_file(tmp_path, data, style):
    """Two paintings shared by an array of one value per strand (integers:
    labels) give the groom the command line's `--style-map FILE.txt
    --style-map-labels` gives; a wrong length or rank is one error."""
    points, counts = nst3d.read_groom(data / "grooms" / "Bangs_100.hair")
    mesh = data / "grooms" / "Bangs_head.ply"
    ship = data / "styles" / "shipwreck.jpg"
    side = (np.arange(len(counts)) >= 50).astype(np.int32)
    arr = nst3d.stylize_groom(points, counts, [style, ship], style_map=side, mesh=mesh, **FAST)
    (tmp_path / "side.txt").write_text("".join(f"{v}\n" for v in side))
    txt = nst3d.stylize_groom(points, counts, [style, ship], style_map=str(tmp_path / "side.txt"),
                              style_map_labels=True, mesh=mesh, **FAST)
    np.testing.assert_array_equal(arr, txt)
    single = nst3d.stylize_groom(points, counts, style, mesh=mesh, **FAST)
    assert not np.array_equal(arr, single), "the map's second painting changed nothing"
    with pytest.raises(nst3d.Nst3dError, match="99 values for 100 strands"):
        nst3d.stylize_groom(points, counts, [style, ship], style_map=side[:99], mesh=mesh, **FAST)
    with pytest.raises(ValueError, match="one value per strand"):
        nst3d.stylize_groom(points, counts, [style, ship], style_map=side.reshape(10, 10), mesh=mesh, **FAST)
