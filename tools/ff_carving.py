#!/usr/bin/python3
"""Where a density stylization removes smoke, by depth inside the input's smoke.

    /usr/bin/python3 tools/ff_carving.py INPUT.vdb RESULT.vdb [RESULT.vdb ...]
    /usr/bin/python3 tools/ff_carving.py --undo DEPTH INPUT.vdb RESULT.vdb OUT.vdb

For each RESULT (any method: the network, the optimisation) it prints the
share of the input's smoke voxels (density above 5 % of the frame's
largest) that the result all but removes (log(result / input) < -2, a
scale under 0.14), overall and by depth inside the smoke (0 is the
surface layer; depth is counted by 6-neighbour erosion), the median log
scale of the voxels that stay, and the mass kept. Reads files with OpenVDB's
own Python binding (Debian python3-openvdb), so it judges files, not code.

With --undo it writes RESULT with its change undone at depth >= DEPTH (the
input's voxels there, scaled to keep that region's mass in RESULT), to
judge how much of a result's strength lies deeper than DEPTH.
docs/design/feedforward.md quotes it.
"""
import sys

import numpy as np
import pyopenvdb as vdb

BINS = [(0, 0), (1, 1), (2, 3), (4, 7), (8, 10**6)]


def density(path, bbox=None):
    grid = next((g for g in vdb.readAll(path)[0] if g.name == "density"), None)
    if grid is None:
        sys.exit(f"{path}: no 'density' grid")
    if bbox is None:
        bbox = grid.evalActiveVoxelBoundingBox()
    lo, hi = bbox
    a = np.zeros(tuple(h - l + 1 for l, h in zip(lo, hi)), np.float32)
    grid.copyToArray(a, ijk=lo)
    return a, bbox


def depth_of(mask):
    depth = np.zeros(mask.shape, int)
    cur, d = mask.copy(), 0
    while cur.any():
        depth[cur] = d
        d += 1
        inner = cur.copy()
        for ax in range(3):
            inner &= np.roll(cur, 1, ax) & np.roll(cur, -1, ax)
        cur = inner
    return depth


def undo(depth_limit, inp_path, result_path, out_path):
    inp, bbox = density(inp_path)
    smoke = inp > 0.05 * inp.max()
    deep = smoke & (depth_of(smoke) >= depth_limit)
    out, _ = density(result_path, bbox)
    new = out.copy()
    new[deep] = inp[deep] * out[deep].sum() / max(inp[deep].sum(), 1e-30)
    grid = next(g for g in vdb.readAll(result_path)[0] if g.name == "density")
    written = vdb.FloatGrid()
    written.name = "density"
    written.transform = grid.transform
    written.copyFromArray(new, ijk=bbox[0], tolerance=0)
    vdb.write(out_path, grids=[written])
    print(f"{out_path}: the change undone at {int(deep.sum())} voxels of depth >= {depth_limit}")


def main():
    if len(sys.argv) == 6 and sys.argv[1] == "--undo":
        return undo(int(sys.argv[2]), *sys.argv[3:])
    if len(sys.argv) < 3 or sys.argv[1].startswith("-"):
        sys.exit(__doc__)
    inp, bbox = density(sys.argv[1])
    smoke = inp > 0.05 * inp.max()
    depth = depth_of(smoke)
    names = ["0", "1", "2-3", "4-7", "8+"]
    counts = [int((smoke & (depth >= a) & (depth <= b)).sum()) for a, b in BINS]
    print(f"{sys.argv[1]}: {int(smoke.sum())} smoke voxels; by depth " + " ".join(f"{n}:{c}" for n, c in zip(names, counts)))
    for path in sys.argv[2:]:
        out, _ = density(path, bbox)
        log = np.log(np.maximum(out, 1e-6) / np.maximum(inp, 1e-6))
        carved = smoke & (log < -2)
        by_depth = []
        for (a, b), c in zip(BINS, counts):
            sel = smoke & (depth >= a) & (depth <= b)
            by_depth.append(f"{carved[sel].mean():.2f}" if c else "-")
        stay = log[smoke & ~carved]
        print(
            f"{path}: carved {carved[smoke].mean():.2f}; by depth " + " ".join(by_depth)
            + f"; median log scale of the rest {np.median(stay):+.2f}; mass {out.sum() / inp.sum():.3f}"
        )


if __name__ == "__main__":
    main()
