#!/usr/bin/env python3
"""How far the NNST loss of one strand render could fall if its pixels were
free (docs/design/strands.md, "How far could it fall?").

Reads a view dumped by `nst3d bench strands-iter --size N --dump DIR` (the
render at v = 0 and its matched NNST targets) and runs Adam on the image
itself, grey, through the same VGG-19 taps and hyper-columns as the PyTorch
peer (tools/bench/strands_iter_torch.py), against the same targets:

  --free all    every pixel may take any grey;
  --free hair   only pixels within 2 px of a strand (render > 0.02, dilated
                by a 5x5 max-pool); the empty background stays as rendered.

Prints the loss relative to the render's every 25 steps and writes the
optimized image to DIR/floor_<free>.png. A bound, not a method: no strand
arrangement can do better than free pixels inside the same silhouette.

  python3 tools/bench/nnst_floor.py DIR --free hair --steps 300
"""
import argparse
import json
import os
import pathlib
import sys

import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import strands_iter_torch as peer  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("dump", type=pathlib.Path)
    ap.add_argument("--free", choices=["all", "hair"], default="hair")
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--lr", type=float, default=0.05)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--weights", default=os.path.expanduser("~/.cache/nst3d/vgg_normalised.pth"))
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    vgg = peer.load_vgg(a.weights)
    targets = torch.from_numpy(np.load(a.dump / "targets.npy"))
    render0 = torch.from_numpy(np.load(a.dump / "render0.npy"))
    grid = tuple(targets.shape[1:])
    weight = json.loads((a.dump / "meta.json").read_text())["nnst_layer_weight"]
    grey0 = render0[0].clone()

    def loss_of(img):
        h = peer.hypercolumns(peer.vgg_taps(vgg, img), grid, weight)
        return ((h - targets) ** 2).sum(0).mean()

    if a.free == "hair":
        free = F.max_pool2d((grey0 > 0.02).float()[None, None], 5, 1, 2)[0, 0] > 0
    else:
        free = torch.ones_like(grey0, dtype=torch.bool)
    print(f"free pixels: {float(free.float().mean()):.3f} of the image")
    x = torch.logit(grey0.clamp(0.01, 0.99)).clone().requires_grad_(True)

    def image():
        g = torch.where(free, torch.sigmoid(x), grey0)
        return g[None, None].expand(1, 3, *grey0.shape)

    with torch.no_grad():
        l0 = float(loss_of(render0[None]))
    opt = torch.optim.Adam([x], lr=a.lr)
    for i in range(a.steps):
        opt.zero_grad()
        loss = loss_of(image())
        loss.backward()
        opt.step()
        if i % 25 == 0 or i == a.steps - 1:
            print(f"step {i} loss {float(loss.detach()):.4e} ({float(loss.detach()) / l0:.3f} of the render's {l0:.4e})",
                  flush=True)
    from PIL import Image
    img = (image()[0, 0].detach().numpy() * 255).clip(0, 255).astype(np.uint8)
    Image.fromarray(img).save(a.dump / f"floor_{a.free}.png")


if __name__ == "__main__":
    main()
