"""Writes the cross test's geometric styles as PNGs (300 x 300, grey):
stripes (diagonal, period 1/7 of the image), stripes_wide (the other
diagonal, period 1/4), spiral (two arms), triangles (a tessellation),
checks (6 x 6), and ramp (a textureless control, luminance 0.2 -> 0.7).

    python3 styles.py OUTDIR
"""
import math
import os
import sys

import numpy as np
from PIL import Image

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))


def geometric(n=300):
    yy, xx = np.mgrid[0:n, 0:n].astype(np.float32)
    c = (n - 1) / 2
    r, th = np.hypot(xx - c, yy - c), np.arctan2(yy - c, xx - c)
    side = n / 6.0
    h = side * math.sqrt(3) / 2
    row = np.floor(yy / h)
    v = yy / h - row
    u = xx / side + 0.5 * (row % 2)
    return {
        'stripes': np.sin((xx + yy) / math.sqrt(2) * 2 * math.pi / (n / 7.0)) > 0,
        'stripes_wide': np.sin((xx - yy) / math.sqrt(2) * 2 * math.pi / (n / 4.0)) > 0,
        'spiral': np.sin(2 * th + r * 2 * math.pi / (n / 5.0)) > 0,
        'triangles': np.abs(u - np.floor(u) - 0.5) < 0.5 * v,
        'checks': ((xx // (n / 6)).astype(int) + (yy // (n / 6)).astype(int)) % 2 == 1,
        'ramp': np.tile(0.2 + 0.5 * xx[:1] / n, (n, 1)),
    }


def main():
    out = sys.argv[1]
    os.makedirs(out, exist_ok=True)
    for name, a in geometric().items():
        img = Image.fromarray((np.asarray(a, np.float32) * 255).astype(np.uint8)).convert('RGB')
        tmp = os.path.join(out, f'.{name}.png')
        img.save(tmp, format='PNG')
        os.replace(tmp, os.path.join(out, f'{name}.png'))


if __name__ == '__main__':
    main()
