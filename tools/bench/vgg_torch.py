#!/usr/bin/env python3
"""The PyTorch peer of `cargo bench -p nst3d-features --bench vgg`: VGG-19 to
relu4_1 (torchvision layout, random weights) forward, then backward to the
input of d(sum of the four taps' squares), on a 3 x SIZE x SIZE image; and one
3x3 128->128 convolution on a 128² image (the layer oneDNN's AMX kernel was
was timed on). Prints medians in ms and the work in GFLOP/s (the
convolutions' multiply-adds x 2; backward to the input only, as nst3d's).

  python3 tools/bench/vgg_torch.py [--size 256] [--runs 7] [--threads 2] [--bf16]
"""
import argparse
import pathlib
import statistics
import sys
import time

import torch

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2] / ".." / "shared" / "bench"))
try:
    from torch_ref import vgg19_features, STYLE_RELUS  # noqa: E402
except ImportError:  # a copy of the peer beside this file (the device machine)
    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
    from torch_ref import vgg19_features, STYLE_RELUS  # noqa: E402


def vgg_flops(size):
    """Multiply-adds x 2 of the convolutions to relu4_1 at SIZE²."""
    cfg = [(3, 64, 1), (64, 64, 1), (64, 128, 2), (128, 128, 2), (128, 256, 4),
           (256, 256, 4), (256, 256, 4), (256, 256, 4), (256, 512, 8)]
    return sum(2 * 9 * ci * co * (size // d) ** 2 for ci, co, d in cfg)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--bf16", action="store_true")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    torch.manual_seed(0)
    vgg = vgg19_features().eval()
    for p in vgg.parameters():
        p.requires_grad_(False)
    img = torch.rand(1, 3, a.size, a.size)

    def step():
        x = img.clone().requires_grad_(True)
        t0 = time.perf_counter()
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=a.bf16):
            h, outs = x, []
            for i, layer in enumerate(vgg):
                h = layer(h)
                if i in STYLE_RELUS:
                    outs.append(h)
        loss = sum((o.float() ** 2).sum() for o in outs)
        t1 = time.perf_counter()
        loss.backward()
        t2 = time.perf_counter()
        return (t1 - t0) * 1e3, (t2 - t1) * 1e3

    step()
    times = sorted((step() for _ in range(a.runs)), key=lambda t: t[0] + t[1])
    f, b = times[len(times) // 2]
    fl = vgg_flops(a.size)
    print(f"torch vgg19_relu4_1 3x{a.size}x{a.size} threads {a.threads} {'bf16' if a.bf16 else 'fp32'}: "
          f"forward {f:.1f} ms ({fl / f / 1e6:.0f} GFLOP/s), backward {b:.1f} ms ({fl / b / 1e6:.0f} GFLOP/s), "
          f"total {f + b:.1f} ms")

    conv = torch.nn.Conv2d(128, 128, 3, padding=1).eval()
    x = torch.rand(1, 128, 128, 128)
    with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16, enabled=a.bf16):
        conv(x)
        ts = []
        for _ in range(a.runs):
            t0 = time.perf_counter()
            conv(x)
            ts.append((time.perf_counter() - t0) * 1e3)
    c = statistics.median(ts)
    cf = 2 * 9 * 128 * 128 * 128 * 128
    print(f"torch conv3x3 128->128 128x128 {'bf16' if a.bf16 else 'fp32'}: {c:.2f} ms ({cf / c / 1e6:.0f} GFLOP/s)")


if __name__ == "__main__":
    main()
