"""Volumes through the package: numpy arrays in and out, OpenVDB files
read back by OpenVDB's own Python binding, and the same bytes as the
command line for the same settings."""

import threading
import time

import numpy as np
import pyopenvdb as vdb
import pytest

import nst3d
from conftest import run_cli

FAST = dict(iters=3, octaves=1)


def read_density(path):
    grid = vdb.read(str(path), "density")
    (lo, hi) = grid.evalActiveVoxelBoundingBox()
    shape = tuple(h - l + 1 for l, h in zip(lo, hi))
    a = np.zeros(shape, dtype=np.float32)
    grid.copyToArray(a, ijk=lo)
    return grid, lo, a


def test_array_in_array_out_on_a_real_frame(data, style):
    _, _, a = read_density(data / "volumes" / "smoke_000003.vdb")
    rep = {}
    out = nst3d.stylize_volume(a, style, mode="density", upsample=1, report=rep, **FAST)
    assert out.shape == a.shape and out.dtype == np.float32
    assert np.isfinite(out).all()
    assert rep["loss_after"] < rep["loss_before"]
    # The density field scales smoke; it never creates any where there was none.
    assert (out[a == 0] == 0).all()
    assert not np.allclose(out, a)


def test_the_file_job_matches_the_command_line_byte_for_byte(tmp_path, data, style, nst3d_bin):
    src = data / "volumes" / "smoke_000003.vdb"
    ours = tmp_path / "py.vdb"
    rep = nst3d.stylize_vdb(src, ours, style, preview=tmp_path / "py.png", **FAST)
    assert rep["kind"] == "frame" and rep["loss_after"] < rep["loss_before"]
    cli = tmp_path / "cli.vdb"
    run_cli(nst3d_bin, "volume", "--input", src, "--style", style, "--out", cli, "--iters", 3, "--octaves", 1)
    assert ours.read_bytes() == cli.read_bytes()
    assert (tmp_path / "py.png").stat().st_size > 0


def test_two_paintings_by_a_style_map_match_the_command_line(tmp_path, data, style, nst3d_bin):
    src = data / "volumes" / "smoke_000003.vdb"
    other = data / "styles" / "shipwreck.jpg"
    ours = tmp_path / "py.vdb"
    rep = nst3d.stylize_vdb(src, ours, [style, other], style_map="@height", mode="density", **FAST)
    assert rep["kind"] == "frame"
    cli = tmp_path / "cli.vdb"
    run_cli(nst3d_bin, "volume", "--input", src, "--style", style, "--style", other, "--style-map", "@height",
            "--mode", "density", "--out", cli, "--iters", 3, "--octaves", 1)
    assert ours.read_bytes() == cli.read_bytes()
    # One painting and a map is one error line, as on the command line.
    with pytest.raises(nst3d.Nst3dError, match="style-map"):
        nst3d.stylize_vdb(src, tmp_path / "one.vdb", style, style_map="@height", **FAST)


def test_a_numpy_style_map_is_the_map_it_draws(tmp_path, data, style):
    """A numpy map over the density's active box, [x, y, z]: integer labels
    cut at mid-height are @height-split, byte for byte (booleans too); a
    float ramp along z is @height; a wrong shape, dtype or rank is one line."""
    src = data / "volumes" / "smoke_000003.vdb"
    other = data / "styles" / "shipwreck.jpg"
    _, _, a = read_density(src)
    nz = a.shape[2]
    ramp = np.broadcast_to((np.arange(nz, dtype=np.float32) / (nz - 1))[None, None, :], a.shape)
    split = (ramp >= 0.5).astype(np.int32)
    run = dict(mode="density", upsample=1, **FAST)
    for name, array, spec in [("split", split, "@height-split"), ("ramp", ramp, "@height")]:
        ours, want = tmp_path / f"{name}_array.vdb", tmp_path / f"{name}_spec.vdb"
        nst3d.stylize_vdb(src, ours, [style, other], style_map=array, **run)
        nst3d.stylize_vdb(src, want, [style, other], style_map=spec, **run)
        if name == "split":
            assert ours.read_bytes() == want.read_bytes()
            nst3d.stylize_vdb(src, tmp_path / "bool.vdb", [style, other], style_map=array.astype(bool), **run)
            assert (tmp_path / "bool.vdb").read_bytes() == want.read_bytes()
        else:
            _, lo, x = read_density(ours)
            _, _, y = read_density(want)
            np.testing.assert_allclose(x, y, rtol=0, atol=1e-5)
    with pytest.raises(nst3d.Nst3dError) as e:
        nst3d.stylize_vdb(src, tmp_path / "o.vdb", [style, other], style_map=ramp[:-1], **run)
    assert "style_map array has shape (50, 49, 96)" in str(e.value) and "(51, 49, 96)" in str(e.value)
    assert "\n" not in str(e.value)
    with pytest.raises(TypeError, match="floats .* or integers"):
        nst3d.stylize_vdb(src, tmp_path / "o.vdb", [style, other], style_map=split.astype(np.complex64), **run)
    with pytest.raises(ValueError, match="must be 3D"):
        nst3d.stylize_vdb(src, tmp_path / "o.vdb", [style, other], style_map=ramp[:, :, 0], **run)
    with pytest.raises(ValueError, match="integer array holds labels"):
        nst3d.stylize_vdb(src, tmp_path / "o.vdb", [style, other], style_map=split, style_map_labels=False, **run)
    with pytest.raises(nst3d.Nst3dError, match="one frame"):
        nst3d.stylize_vdb(src, tmp_path / "o_####.vdb", [style, other], style_map=ramp, frames="3", **run)
    assert not (tmp_path / "o.vdb").exists()


def test_openvdb_reads_what_the_package_writes(tmp_path, data, style):
    src = data / "volumes" / "smoke_000003.vdb"
    out = tmp_path / "styled.vdb"
    nst3d.stylize_vdb(src, out, style, mode="density", upsample=1, **FAST)
    names_in = {g.name for g in vdb.readAllGridMetadata(str(src))}
    names_out = {g.name for g in vdb.readAllGridMetadata(str(out))}
    assert names_in <= names_out | {"flags"}, (names_in, names_out)
    grid_in, lo, a = read_density(src)
    grid_out = vdb.read(str(out), "density")
    assert grid_out.transform.voxelSize() == grid_in.transform.voxelSize()
    b = np.zeros_like(a)
    grid_out.copyToArray(b, ijk=lo)
    # The same stylization through the array path gives the same voxels.
    c = nst3d.stylize_volume(a, style, mode="density", upsample=1, **FAST)
    np.testing.assert_allclose(b, c, rtol=0, atol=1e-6)


def test_errors_are_the_command_lines_one_line(tmp_path, style, nst3d_bin):
    missing = tmp_path / "missing.vdb"
    with pytest.raises(nst3d.Nst3dError) as e:
        nst3d.stylize_vdb(missing, tmp_path / "o.vdb", style)
    r = run_cli(nst3d_bin, "volume", "--input", missing, "--style", style, "--out", tmp_path / "o.vdb", check=False)
    assert r.returncode == 1
    assert r.stderr.strip() == f"nst3d: error: {e.value}"
    assert "\n" not in str(e.value)
    with pytest.raises(TypeError, match="itres"):
        nst3d.stylize_volume(np.ones((4, 4, 4), np.float32), style, itres=3)
    with pytest.raises(ValueError, match="3D"):
        nst3d.stylize_volume(np.ones((4, 4), np.float32), style)
    with pytest.raises(nst3d.Nst3dError, match="empty"):
        nst3d.stylize_volume(np.zeros((8, 8, 8), np.float32), style)
    bad = np.ones((8, 8, 8), np.float32)
    bad[1, 2, 3] = np.nan
    with pytest.raises(nst3d.Nst3dError, match="non-finite"):
        nst3d.stylize_volume(bad, style)
    with pytest.raises(ValueError, match="mode"):
        nst3d.stylize_volume(np.ones((8, 8, 8), np.float32), style, mode="swirl")


def smoke(n=24):
    a = np.zeros((n, n, n), np.float32)
    a[n // 4 : 3 * n // 4, n // 4 : 3 * n // 4, n // 4 : 3 * n // 4] = 1.0
    return a


def test_progress_reaches_the_end(style):
    seen = []
    nst3d.stylize_volume(smoke(), style, upsample=1, progress=lambda d, t, m: seen.append((d, t, m)), **FAST)
    assert seen[0][:2] == (0, 3) and seen[-1][:2] == (3, 3)
    assert "iteration 3/3" in seen[-1][2]


def test_a_raising_callback_stops_the_job_and_is_raised(style):
    calls = []

    def stop_at_two(done, total, message):
        calls.append(done)
        if done == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        nst3d.stylize_volume(smoke(), style, upsample=1, iters=50, octaves=1, progress=stop_at_two)
    assert max(calls) == 2, "the job went on after the interrupt"
    # The next job runs: the stop request does not stick.
    out = nst3d.stylize_volume(smoke(), style, upsample=1, **FAST)
    assert out.shape == (24, 24, 24)

    def broken(done, total, message):
        raise ValueError("callback bug")

    with pytest.raises(ValueError, match="callback bug"):
        nst3d.stylize_volume(smoke(), style, upsample=1, **FAST, progress=broken)


def test_the_gil_is_released_while_computing(style):
    ticks = []
    done = threading.Event()

    def job():
        nst3d.stylize_volume(smoke(32), style, upsample=1, iters=6, octaves=1)
        done.set()

    t = threading.Thread(target=job)
    t.start()
    while not done.is_set():
        ticks.append(time.perf_counter())
        time.sleep(0.01)
    t.join()
    # Python kept running beside the job: many ticks, none stalled for long.
    assert len(ticks) > 20
    assert max(np.diff(ticks)) < 0.5


def test_model_trains_and_stylizes_like_the_command_line(tmp_path, data, style, nst3d_bin):
    frames = [data / "volumes" / f"smoke_00000{i}.vdb" for i in (1, 2)]
    model = tmp_path / "m.safetensors"
    rep = nst3d.train(frames, style, model, steps=3, patch=16, channels=4, checkpoint_every=3)
    assert rep["steps"] == 3 and model.exists()
    m = nst3d.Model.load(model)
    assert m.mode == "density"
    src = data / "volumes" / "smoke_000003.vdb"
    _, lo, a = read_density(src)
    out = m.stylize(a, origin=lo)
    assert out.shape == a.shape and np.isfinite(out).all()
    cli = tmp_path / "cli.vdb"
    run_cli(nst3d_bin, "volume", "--model", model, "--input", src, "--out", cli)
    b = np.zeros_like(a)
    vdb.read(str(cli), "density").copyToArray(b, ijk=lo)
    np.testing.assert_allclose(out, b, rtol=0, atol=1e-6)
    py = tmp_path / "py.vdb"
    nst3d.stylize_vdb(src, py, model=model)
    assert py.read_bytes() == cli.read_bytes()
    # --strength reaches the network from both front ends: strong moves the
    # smoke further than the trained network, subtle less far.
    strong = nst3d.Model.load(model, strength="strong").stylize(a, origin=lo)
    cli2 = tmp_path / "cli2.vdb"
    run_cli(nst3d_bin, "volume", "--model", model, "--strength", "strong", "--input", src, "--out", cli2)
    b = np.zeros_like(a)
    vdb.read(str(cli2), "density").copyToArray(b, ijk=lo)
    np.testing.assert_allclose(strong, b, rtol=0, atol=1e-6)
    assert np.abs(strong - a).sum() > np.abs(out - a).sum()
    weak = nst3d.Model.load(model, strength="subtle").stylize(a, origin=lo)
    assert np.abs(weak - a).sum() < np.abs(out - a).sum()


def test_the_benchmark_work_runs():
    times, median = nst3d.bench_volume_iter(16, "density", 1)
    assert len(times) == 1 and median > 0


def test_ctrl_c_stops_a_running_job(tmp_path, style):
    """A real SIGINT (what Ctrl-C sends) while the job runs with the GIL
    released: KeyboardInterrupt comes out after the iteration in progress.
    The job is long (tens of seconds) so that a parent delayed by a loaded
    machine still signals it mid-run."""
    import signal
    import subprocess
    import sys

    script = tmp_path / "job.py"
    script.write_text(
        "import signal, sys, time, numpy as np, nst3d\n"
        # A process started in the background by a non-interactive shell (as
        # some CI runners start the tests) inherits SIGINT ignored, and
        # Python then installs no handler; an interactive session has one.
        "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
        "a = np.zeros((32, 32, 32), np.float32); a[8:24, 8:24, 8:24] = 1\n"
        "def progress(done, total, message):\n"
        "    if done == 1:\n"
        "        print('started', flush=True)\n"
        "try:\n"
        f"    nst3d.stylize_volume(a, {str(style)!r}, upsample=1, iters=4000, octaves=1, progress=progress)\n"
        "    print('finished', flush=True)\n"
        "except KeyboardInterrupt:\n"
        "    print('interrupted', flush=True)\n"
    )
    p = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "started"
    t0 = time.perf_counter()
    p.send_signal(signal.SIGINT)
    out, _ = p.communicate(timeout=120)
    assert out.strip() == "interrupted"
    assert time.perf_counter() - t0 < 10, "the job did not stop at its next iteration"


def test_a_model_run_checks_the_mode_as_the_command_line_does(tmp_path, data, nst3d_bin):
    """``mode`` with ``model`` is checked against the model's, as ``--mode``
    is (it used to be dropped: a velocity model ran as asked for density)."""
    model = need_model("starry_velocity")
    src = data / "volumes" / "smoke_000003.vdb"
    with pytest.raises(nst3d.Nst3dError) as e:
        nst3d.stylize_vdb(src, tmp_path / "py.vdb", model=model, mode="density")
    r = run_cli(nst3d_bin, "volume", "--model", model, "--mode", "density", "--input", src,
                "--out", tmp_path / "cli.vdb", check=False)
    assert r.returncode == 1
    assert r.stderr.strip().endswith(f"nst3d: error: {e.value}")
    assert not (tmp_path / "py.vdb").exists()


def test_a_textured_model_stylizes_like_the_command_line(tmp_path, data, style, nst3d_bin):
    """``train(texture=P)`` learns a solid texture beside the network; the
    package applies it in the file's index space (through ``origin``) as
    ``nst3d volume --model`` does, and a frame shifted by whole periods of
    the texture and of the network's leaves gets the same result."""
    frames = [data / "volumes" / f"smoke_00000{i}.vdb" for i in (1, 2)]
    model = tmp_path / "t.safetensors"
    nst3d.train(frames, style, model, steps=3, patch=16, channels=2, texture=12, checkpoint_every=3)
    m = nst3d.Model.load(model)
    src = data / "volumes" / "smoke_000003.vdb"
    _, lo, a = read_density(src)
    out = m.stylize(a, origin=lo)
    cli = tmp_path / "cli.vdb"
    run_cli(nst3d_bin, "volume", "--model", model, "--input", src, "--out", cli)
    b = np.zeros_like(a)
    vdb.read(str(cli), "density").copyToArray(b, ijk=lo)
    np.testing.assert_allclose(out, b, rtol=0, atol=1e-6)
    # 8 keeps the network's lattice (leaves of 8) and moves the texture's
    # phase; 24 keeps both.
    assert np.abs(out - m.stylize(a, origin=[v + 8 for v in lo])).max() > 1e-4
    np.testing.assert_allclose(out, m.stylize(a, origin=[v + 24 for v in lo]), rtol=0, atol=1e-6)

@pytest.mark.parametrize("frames", ["1-10:0", "5-1", "1-x", ""])
def test_train_frame_lists_are_the_command_lines(tmp_path, data, style, nst3d_bin, frames):
    """``train(frames=...)`` goes through the library's frame-list parser:
    the same errors as ``nst3d train --frames`` (the package once had its own
    parser, with Python's errors and without sorting or de-duplication)."""
    pattern = str(data / "volumes" / "smoke_######.vdb")
    with pytest.raises(nst3d.Nst3dError) as e:
        nst3d.train(pattern, style, tmp_path / "m.safetensors", frames=frames, steps=1)
    r = run_cli(nst3d_bin, "train", "--input", pattern, "--frames", frames, "--style", style,
                "--out", tmp_path / "m.safetensors", "--steps", "1", check=False)
    assert r.returncode == 1
    assert r.stderr.strip().endswith(f"nst3d: error: {e.value}")


def test_train_frame_lists_are_sorted_and_deduplicated(tmp_path, data, style):
    """``"3,1-2,2"`` trains on frames 1, 2, 3 once each: the checkpoint of
    that run is the one of ``"1-3"`` (its fingerprint lists the files)."""
    pattern = str(data / "volumes" / "smoke_######.vdb")
    out = tmp_path / "m.safetensors"
    small = dict(steps=2, patch=16, channels=2, checkpoint_every=1, minutes=0)
    nst3d.train(pattern, style, out, frames="3,1-2,2", **small)
    # Resuming with the plain list accepts the checkpoint (a different file
    # list would be "a checkpoint of a different training run").
    rep = nst3d.train(pattern, style, out, frames="1-3", **{**small, "minutes": None})
    assert rep["resumed_at"] == 1 and rep["steps"] == 2


def need_model(name):
    import pathlib

    path = pathlib.Path(__file__).resolve().parents[2] / "models" / f"{name}.safetensors"
    if not path.exists():
        raise FileNotFoundError(f"committed model missing: {path}")
    return path
