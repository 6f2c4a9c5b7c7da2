#!/usr/bin/env python3
"""The colour grid of a `nst3d volume --color` result as a renderer's albedo.

    python3 tools/color_albedo.py painting OUT.png
        writes a synthetic blue-and-cream "painting" (brush strokes on a
        canvas, 256x256, seeded): a painting none of nst3d's settings were
        tuned on, for the palette check;
    python3 tools/color_albedo.py stats STYLED.vdb [PAINTING_MEAN_R,G,B]
        prints the colour grid's range and percentiles over the smoke's
        voxels and its density-weighted mean colour (weighted by the
        density written beside it), and with the painting's mean colour the
        distance of that mean from it.

Needs numpy and, for `stats`, the reference OpenVDB module (Debian's
python3-openvdb, as tools/test.sh installs it).
"""
import struct
import sys
import zlib

import numpy as np

# The synthetic painting's palette: Prussian and ultramarine blues on cream.
PALETTE = np.array([[0.11, 0.20, 0.42], [0.20, 0.36, 0.66], [0.93, 0.88, 0.74], [0.85, 0.80, 0.62]],
                   dtype=np.float32)


def painting(path, size=256, strokes=900, seed=7):
    rng = np.random.default_rng(seed)
    img = np.tile(PALETTE[2], (size, size, 1))
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32)
    for _ in range(strokes):
        cx, cy = rng.uniform(0, size, 2)
        angle = rng.uniform(0, np.pi)
        length, width = rng.uniform(10, 40), rng.uniform(2, 6)
        u = (xx - cx) * np.cos(angle) + (yy - cy) * np.sin(angle)
        v = -(xx - cx) * np.sin(angle) + (yy - cy) * np.cos(angle)
        mask = (np.abs(u) < length / 2) & (np.abs(v) < width / 2)
        colour = PALETTE[rng.choice(4, p=[0.3, 0.3, 0.2, 0.2])] * rng.uniform(0.9, 1.1)
        img[mask] = colour
    pix = (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)
    raw = b"".join(b"\x00" + pix[y].tobytes() for y in range(size))

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", size, size, 8, 2, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))
    with open(path, "wb") as f:
        f.write(png)
    mean = pix.reshape(-1, 3).mean(axis=0) / 255.0
    print(f"wrote {path}; mean colour {mean[0]:.3f},{mean[1]:.3f},{mean[2]:.3f}")


def dense(grid, bbox, channels):
    (x0, y0, z0), (x1, y1, z1) = bbox
    shape = (x1 - x0 + 1, y1 - y0 + 1, z1 - z0 + 1) + ((3,) if channels == 3 else ())
    a = np.zeros(shape, dtype=np.float32)
    grid.copyToArray(a, ijk=(x0, y0, z0))
    return a


def stats(path, painting_mean=None):
    import pyopenvdb as vdb

    grids = {g.name: g for g in vdb.readAllGridMetadata(path)}
    name = "Cd" if "Cd" in grids else "color"
    density = vdb.read(path, "density")
    color = vdb.read(path, name)
    lo = np.minimum(density.evalActiveVoxelBoundingBox()[0], color.evalActiveVoxelBoundingBox()[0])
    hi = np.maximum(density.evalActiveVoxelBoundingBox()[1], color.evalActiveVoxelBoundingBox()[1])
    bbox = (tuple(int(v) for v in lo), tuple(int(v) for v in hi))
    d = dense(density, bbox, 1)
    c = dense(color, bbox, 3)
    inside = d > 0
    cv = c[inside]
    w = d[inside]
    q = np.percentile(cv, [1, 50, 99])
    mean = (cv * w[:, None]).sum(axis=0) / w.sum()
    print(f"{path}: grid '{name}', {inside.sum()} smoke voxels")
    print(f"  colour min {cv.min():.3f} max {cv.max():.3f}; percentiles 1/50/99: "
          f"{q[0]:.3f} {q[1]:.3f} {q[2]:.3f}; share above 1: {(cv.max(axis=1) > 1.0).mean():.3f}")
    print(f"  density max {d.max():.3f}, sum {d.sum():.1f}")
    print(f"  density-weighted mean colour {mean[0]:.3f},{mean[1]:.3f},{mean[2]:.3f}")
    if painting_mean is not None:
        p = np.array(painting_mean, dtype=np.float64)
        print(f"  distance from the painting's mean {p.round(3).tolist()}: {np.linalg.norm(mean - p):.3f}")
    return mean


if __name__ == "__main__":
    if len(sys.argv) >= 3 and sys.argv[1] == "painting":
        painting(sys.argv[2])
    elif len(sys.argv) >= 3 and sys.argv[1] == "stats":
        pm = [float(v) for v in sys.argv[3].split(",")] if len(sys.argv) > 3 else None
        stats(sys.argv[2], pm)
    else:
        sys.exit(__doc__)
