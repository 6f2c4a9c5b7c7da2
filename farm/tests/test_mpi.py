"""Data-parallel training over MPI (docs/guide/farm.md), with the MPI-enabled
binary tools/build_mpi.sh builds: `mpirun -n 2` trains the same model as
one rank with the same global batch; a run started on 2 ranks resumes on 1;
the multi-node Slurm script runs with 2 tasks, and the time limit's warning
signal mid-run stops every rank cleanly (rank 0 checkpoints) and the
requeued job resumes. Tiny patches and
networks: seconds of training. Missing tools or data fail loudly."""

import json
import os
import pathlib
import re
import struct
import subprocess
import time

import numpy as np

from test_farm import NST3D, PLUME, REPO, STYLE, need, requeue_now, tool, wait_for

NST3D_MPI = pathlib.Path(os.environ.get("NST3D_MPI_BIN", NST3D.parent / "nst3d-mpi"))
# Ranks and the one-rank run alike use 1 thread (the patch gradients are the
# same on any thread count here, but the checkpoint's fingerprint holds it).
TRAIN = ["train", "--input", str(PLUME), "--frames", "20-22", "--style", str(STYLE), "--patch", "16",
         "--channels", "2", "--style-scale", "0.25", "--seed", "3", "--batch", "2"]
# Largest difference allowed between a model trained on 2 ranks and on one
# rank with the same global batch, relative to the largest weight. The
# batch's gradients are summed in 64-bit fixed point, which no order of
# summation changes, so the measured difference is 0 (the same bytes).
TOLERANCE = 0.0
# Open MPI refuses to start as root (CI runs as root) without these.
MPI_ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")


def tensors(path):
    """A .safetensors file's f32 tensors by name, and its metadata."""
    data = pathlib.Path(path).read_bytes()
    (n,) = struct.unpack("<Q", data[:8])
    header = json.loads(data[8:8 + n])
    meta = header.pop("__metadata__", {})
    out = {}
    for name, t in header.items():
        a, b = t["data_offsets"]
        out[name] = np.frombuffer(data[8 + n + a:8 + n + b], np.float32)
    return out, meta


def difference(a, b):
    ta, ma = tensors(a)
    tb, mb = tensors(b)
    assert ta.keys() == tb.keys() and ma == mb, (ma, mb)
    largest = max(float(np.abs(t).max()) for t in ta.values())
    return max(float(np.abs(ta[k] - tb[k]).max()) for k in ta) / largest


def train(binary, out, *extra, ranks=1):
    need(binary), need(STYLE)
    launch = [tool("mpirun"), "-n", str(ranks), "--oversubscribe"] if ranks > 1 else []
    r = subprocess.run([*launch, str(binary), "--threads", "1", *TRAIN, "--out", str(out), *extra],
                       capture_output=True, text=True, env=MPI_ENV)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-3000:]
    return r.stdout + r.stderr


def one_rank(tmp_path_factory, steps):
    out = tmp_path_factory.mktemp("one") / "one.safetensors"
    train(NST3D, out, "--steps", str(steps))
    return out


def test_two_ranks_train_the_model_one_rank_trains_with_the_same_batch(tmp_path_factory):
    one = one_rank(tmp_path_factory, 4)
    two = tmp_path_factory.mktemp("two") / "two.safetensors"
    log = train(NST3D_MPI, two, "--steps", "4", ranks=2)
    assert "training on 2 MPI ranks" in log and "batch 2" in log, log[-2000:]
    # One report (rank 0's), one loss log.
    assert log.count("trained 4 of 4 steps") == 1, log[-2000:]
    rel = difference(one, two)
    print(f"2 ranks vs 1 rank, global batch 2: largest weight difference {rel:.3g} of the largest weight")
    assert rel <= TOLERANCE
    assert one.with_suffix(".csv").read_text() == two.with_suffix(".csv").read_text()


def test_a_run_started_on_two_ranks_resumes_on_one(tmp_path_factory):
    whole = one_rank(tmp_path_factory, 4)
    parts = tmp_path_factory.mktemp("parts") / "m.safetensors"
    # Two ranks through the OpenJD template (Ranks=2: mpirun on the one
    # worker); a zero-minute budget stops after the first step, checkpointed
    # by rank 0.
    settings = " ".join([*TRAIN[7:], "--steps", "4", "--minutes", "0"])
    r = subprocess.run([tool("openjd"), "run", str(REPO / "farm" / "openjd" / "train.yaml"),
                        *[a for k, v in {"InputDir": PLUME.parent, "InputFrames": PLUME.name, "TrainFrames": "20-22",
                                         "Style": STYLE, "Model": parts, "TrainSettings": f"--threads 1 {settings}",
                                         "Nst3d": NST3D_MPI, "Ranks": 2}.items() for a in ("-p", f"{k}={v}")]],
                       capture_output=True, text=True, env=MPI_ENV, cwd=parts.parent)
    assert r.returncode == 0 and "training on 2 MPI ranks" in r.stdout, r.stdout[-3000:] + r.stderr[-2000:]
    assert "trained 1 of 4 steps" in r.stdout, r.stdout[-2000:]
    log = train(NST3D, parts, "--steps", "4")
    assert "resumed at step 2" in log, log[-2000:]
    assert difference(whole, parts) <= TOLERANCE


def sbatch_train(tmp_path, out, steps, *extra):
    env = dict(MPI_ENV, INPUT=str(PLUME), FRAMES="20-22", STYLE=str(STYLE), OUT=str(out), NST3D=str(NST3D_MPI),
               SETTINGS=" ".join([*TRAIN[7:-2], "--steps", str(steps)]))
    # The test cluster is one node: its 2 cores as 2 tasks of 1 core.
    return subprocess.run([tool("sbatch"), "--parsable", "--nodes=1", "--ntasks-per-node=2", "--cpus-per-task=1",
                           "--mem-per-cpu=1G", *extra, str(REPO / "farm" / "slurm" / "nst3d-train.sbatch")],
                          env=env, cwd=tmp_path, check=True, capture_output=True, text=True).stdout.strip()


def test_slurm_trains_on_two_tasks_and_a_stopped_job_resumes(tmp_path, tmp_path_factory):
    need(NST3D_MPI)
    script = (REPO / "farm" / "slurm" / "nst3d-train.sbatch").read_text()
    for line in ("--requeue", "--signal=TERM@60", "--nodes=", "--ntasks-per-node=", "--cpus-per-task="):
        assert f"#SBATCH {line}" in script, line
    one = one_rank(tmp_path_factory, 4)
    out = tmp_path / "a" / "m.safetensors"
    out.parent.mkdir()
    job = sbatch_train(tmp_path, out, 4)
    wait_for(job)
    log = (tmp_path / f"nst3d-train-{job}.log").read_text()
    assert "training on 2 MPI ranks" in log and "trained 4 of 4 steps" in log, log[-3000:]
    # --cpus-per-task=1 became --threads 1: the one-rank run's model.
    assert difference(one, out) <= TOLERANCE

    # The time limit's warning mid-run (--signal=TERM@60 signals the ranks,
    # not srun; `scancel --signal=TERM` does the same at once): the ranks
    # stop after the same step, rank 0 checkpoints, the job ends. Requeued,
    # it resumes and ends with the model of an uninterrupted run.
    # Enough steps that the signal lands mid-run on a fast machine too: a
    # CI machine trained 150 steps in 6 s, faster than the log's step line
    # and the signal's way through Slurm.
    steps = 400
    whole = one_rank(tmp_path_factory, steps)
    out2 = tmp_path / "b" / "m.safetensors"
    out2.parent.mkdir()
    job2 = sbatch_train(tmp_path, out2, steps)
    log2 = tmp_path / f"nst3d-train-{job2}.log"
    t0 = time.time()
    while not (log2.exists() and f"step 3/{steps}" in log2.read_text()):
        assert time.time() - t0 < 300, "the job never reached step 3"
        time.sleep(0.05)
    subprocess.run(["scancel", "--signal=TERM", job2], check=True)
    seen = time.time()
    wait_for(job2)
    text = log2.read_text()
    assert "stopped by SIGTERM" in text and f"trained {steps} of" not in text, text[-3000:]
    last = max(int(m) for m in re.findall(rf"step (\d+)/{steps}", text))
    print(f"signalled at step 3, stopped after step {last} ({time.time() - seen:.1f} s to the job's end)")
    # The stopped job's step daemons gone first: a restart at once can meet
    # the old step's of the same number still closing, and fail to launch.
    while subprocess.run(["pgrep", "-f", f"slurmstepd: \\[{job2}\\."], capture_output=True).returncode == 0:
        assert time.time() - t0 < 300, "the stopped job's steps never ended"
        time.sleep(0.2)
    requeue_now(job2)
    wait_for(job2)
    text = log2.read_text()
    assert "restart 1" in text and "resuming at step" in text, text[-3000:]
    assert text.count(f"trained {steps} of {steps} steps") == 1, text[-3000:]
    assert difference(whole, out2) <= TOLERANCE
