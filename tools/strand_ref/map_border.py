"""Across a style map's border on a groom: does the border leave a band of
strands the optimiser did not move (a halo)?

    python3 tools/strand_ref/map_border.py MAP.txt REST.ply MAPPED.ply

Strands are binned by their root's signed distance from the border (along
the root coordinate that follows the map most closely, as a fraction of
the groom's width there); each bin prints the map's mean value and how far
the mapped result moved its strands from rest (mean point distance over
the mean strand length). A halo is a dip of the bins nearest the border
below their side's mean, or more unmoved strands there than on the side.
"""
import sys

import numpy as np

sys.path.insert(0, __import__('os').path.dirname(__file__))
from common import read_ply  # noqa: E402


def main():
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    values = np.loadtxt(sys.argv[1])
    rest, mapped = read_ply(sys.argv[2]), read_ply(sys.argv[3])
    assert len(values) == len(rest) == len(mapped), 'one map value per strand, the same strands in both grooms'
    roots = rest[:, 0, :]
    corr = [np.corrcoef(roots[:, k], values)[0, 1] for k in range(3)]
    axis = int(np.argmax(np.abs(corr)))
    x = roots[:, axis] * np.sign(corr[axis])
    border = 0.5 * (x[values < 0.5].max() + x[values >= 0.5].min()) if (values < 0.5).any() else x.min()
    if (values > 0.01).any() and (values < 0.99).any() and ((values > 0.3) & (values < 0.7)).any():
        border = np.median(x[(values > 0.3) & (values < 0.7)])  # a soft map: where it crosses one half
    s = (x - border) / (x.max() - x.min())
    length = np.linalg.norm(np.diff(rest, axis=1), axis=2).sum(1).mean()
    moved = np.linalg.norm(mapped - rest, axis=2).mean(1) / length
    print(f'border along {"xyz"[axis]}; s = signed distance from it / width (second painting > 0)')
    print(f'{"s":>6} {"strands":>7} {"map":>5} {"moved":>6}')
    edges = np.linspace(-0.5, 0.5, 21)
    for lo, hi in zip(edges[:-1], edges[1:]):
        k = (s >= lo) & (s < hi)
        if k.sum() >= 5:
            print(f'{(lo + hi) / 2:6.3f} {k.sum():7d} {values[k].mean():5.2f} {moved[k].mean():6.3f}')
    for side, sel in (('first', s < 0), ('second', s >= 0)):
        near = sel & (np.abs(s) < 0.05)
        print(f'{side} painting\'s side: within 5 % of the border moved {moved[near].mean():.3f} against the side\'s '
              f'{moved[sel].mean():.3f} ({moved[near].mean() / moved[sel].mean():.2f}x); unmoved (< 0.02): '
              f'{np.mean(moved[near] < 0.02):.1%} near the border, {np.mean(moved[sel] < 0.02):.1%} on the side')


if __name__ == '__main__':
    main()
