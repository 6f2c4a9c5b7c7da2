#!/usr/bin/python3
"""Compares two stylized sequences frame by frame (docs/guide/farm.md, chunk seams).

    /usr/bin/python3 tools/seam_compare.py REF_PATTERN TEST_PATTERN INPUT_PATTERN FRAMES [--seams 30,31,60,61]

Patterns use ####. For every frame it prints

    rel = ||test - ref|| / ||ref - input||

(the difference as a fraction of the stylization itself, the measure of
docs/guide/farm.md) and the largest per-voxel |test - ref|, then max and mean of rel
over the seam frames and over the other frames. Reads with the reference
OpenVDB library (Debian python3-openvdb), not with nst3d, so the comparison
does not trust the code it checks.
"""
import argparse
import sys

import numpy as np

try:
    import pyopenvdb as vdb
except ImportError:
    sys.exit("seam_compare: needs python3-openvdb (apt-get install python3-openvdb python3-numpy)")


def frames_of(spec):
    out = []
    for part in spec.split(","):
        if "-" in part:
            a, b = part.split("-")
            out.extend(range(int(a), int(b) + 1))
        else:
            out.append(int(part))
    return out


def density(pattern, frame, lo, size):
    path = pattern.replace("####", f"{frame:04d}")
    grids = vdb.readAll(path)[0]
    g = next((g for g in grids if g.name == "density"), None)
    if g is None:
        sys.exit(f"seam_compare: {path}: no density grid")
    a = np.zeros((size, size, size), np.float32)
    (bmin, bmax) = g.evalActiveVoxelBoundingBox()
    if g.activeVoxelCount() and (min(bmin) < lo or max(bmax) >= lo + size):
        sys.exit(f"seam_compare: {path}: active box {bmin}-{bmax} outside the comparison box")
    g.copyToArray(a, ijk=(lo, lo, lo))
    return a.astype(np.float64)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("ref")
    ap.add_argument("test")
    ap.add_argument("input")
    ap.add_argument("frames")
    ap.add_argument("--seams", default="", help="frames to summarise separately, e.g. 30,31,60,61,90,91")
    ap.add_argument("--lo", type=int, default=-16, help="lowest index of the comparison box")
    ap.add_argument("--size", type=int, default=160, help="side of the comparison box in voxels")
    args = ap.parse_args()
    seams = set(frames_of(args.seams)) if args.seams else set()
    rels = {}
    print("frame  rel      max|test-ref|  ||ref-input||")
    for f in frames_of(args.frames):
        r = density(args.ref, f, args.lo, args.size)
        t = density(args.test, f, args.lo, args.size)
        i = density(args.input, f, args.lo, args.size)
        styl = np.linalg.norm(r - i)
        rel = np.linalg.norm(t - r) / max(styl, 1e-30)
        rels[f] = rel
        mark = " seam" if f in seams else ""
        print(f"{f:5d}  {rel:.4f}   {np.abs(t - r).max():.4f}         {styl:.3f}{mark}")
    for name, sel in (("seams", [f for f in rels if f in seams]), ("others", [f for f in rels if f not in seams])):
        if sel:
            v = np.array([rels[f] for f in sel])
            worst = sel[int(v.argmax())]
            print(f"{name}: {len(sel)} frames, max rel {v.max():.4f} (frame {worst}), mean rel {v.mean():.4f}")


if __name__ == "__main__":
    main()
