#!/usr/bin/python3
"""OpenVDB <-> numpy for the feed-forward reference, through OpenVDB's own
Python binding (Debian python3-openvdb, so run with /usr/bin/python3).

  vdb_npz.py read  IN.vdb OUT.npz [--grid density]   dense active box, [x, y, z]
  vdb_npz.py write IN.vdb VALUES.npy OUT.vdb [--grid density]
      IN's grids copied, the density grid's active box replaced by VALUES
"""
import sys
import numpy as np
import pyopenvdb as vdb


def read(path, name):
    g = vdb.read(path, name)
    lo, hi = g.evalActiveVoxelBoundingBox()
    shape = tuple(h - l + 1 for l, h in zip(lo, hi))
    a = np.zeros(shape, np.float32)
    g.copyToArray(a, ijk=lo)
    return g, np.array(lo), a


def main():
    args = sys.argv[1:]
    name = "density"
    if "--grid" in args:
        i = args.index("--grid")
        name = args[i + 1]
        del args[i:i + 2]
    if args[0] == "read":
        _, lo, a = read(args[1], name)
        np.savez(args[2], density=a, origin=lo)
    elif args[0] == "write":
        grids = vdb.readAllGridMetadata(args[1])
        out = []
        for meta in grids:
            g = vdb.read(args[1], meta.name)
            if meta.name == name:
                _, lo, a = read(args[1], name)
                v = np.ascontiguousarray(np.load(args[2]), dtype=np.float32)  # a transposed save loads Fortran-ordered, which copyFromArray misreads
                assert v.shape == a.shape, (v.shape, a.shape)
                g.clear()
                g.copyFromArray(v, ijk=tuple(int(x) for x in lo), tolerance=1e-6)
            out.append(g)
        vdb.write(args[3], grids=out)
    else:
        sys.exit(__doc__)


if __name__ == "__main__":
    main()
