#!/usr/bin/env python3
"""The PyTorch peer of `cargo bench -p nst3d-loss --bench nnst`'s matching:
N_c = 150² content hyper-columns against N_s = 128² style hyper-columns of
D = 960 (VGG-19 relu1_1..relu4_1 of a 600² render and a 512² style, on the
relu3_1 grid), matched by tools/bench/strands_iter_torch.py's `match`
(centred cosine, blocks of 2048 rows, matmul + argmax). Prints the best of
`--reps` runs in ms; `--bf16` runs it under torch.autocast("cpu", bfloat16).

  python3 tools/bench/nnst_match_torch.py [--threads 2] [--bf16]
"""
import argparse
import contextlib
import pathlib
import sys
import time

import torch

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import strands_iter_torch as peer  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--bf16", action="store_true")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    g = torch.Generator().manual_seed(0)
    content = torch.rand(960, 150, 150, generator=g)
    style = torch.rand(960, 128, 128, generator=g)
    ctx = torch.autocast("cpu", dtype=torch.bfloat16) if a.bf16 else contextlib.nullcontext()
    best = float("inf")
    with torch.no_grad(), ctx:
        for _ in range(a.reps):
            t = time.perf_counter()
            peer.match(content, style)
            best = min(best, (time.perf_counter() - t) * 1e3)
    print(f"nnst match torch{' bf16' if a.bf16 else ''} threads {a.threads}: ms_match {best:.1f}")


if __name__ == "__main__":
    main()
