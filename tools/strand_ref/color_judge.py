"""Colour judged region by region on a groom with a style map.

    python3 tools/strand_ref/color_judge.py --rest INPUT.ply --map LABELS.txt --up z \
        --style a=PAINTING_A --style b=PAINTING_B --result mapped=RESULT.usda \
        [--result a_alone=A.usda --result b_alone=B.usda] [--size 256 --style-scale 3]

Each region's strands (label k of the map: painting k) are drawn alone in
their written colours (the `.usda`'s displayColor) from eight views all
round, the colour stage's (azimuths half a step off the front, elevations
0 and 30 degrees), with a root facing the camera. The VGG-19 Gram loss over
the hair's pixels (relu1_1 ... relu4_1) against each painting in colour, at
the render's height times the style scale as the colour stage takes it, is
divided by the loss of the same strands drawn in their own colours'
luminance: the hue's part alone (brightness cancels), lower = nearer.
Median over the views that see the region.
"""
import argparse
import math
import os
import re
import sys

import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image

sys.path.insert(0, os.path.dirname(__file__))
from common import Cam, read_ply, vgg_feats  # noqa: E402
from judge import gram_dist  # noqa: E402


def read_usda(path):
    """Points and displayColor, (strands, points, 3) each, of a .usda nst3d wrote."""
    txt = open(path).read()
    counts = [int(v) for v in re.search(r'curveVertexCounts = \[([^\]]*)\]', txt).group(1).split(',')]
    assert len(set(counts)) == 1, f'{path}: strands of different lengths'

    def array(key):
        body = re.search(key + r' = \[([^\]]*)\]', txt).group(1)
        values = np.array(re.findall(r'[-0-9.e]+', body), dtype=np.float32)
        return torch.from_numpy(values.reshape(len(counts), counts[0], 3))
    return array(r'point3f\[\] points'), array(r'primvars:displayColor')


def render_rgb(P, C, cam, vis, sigma_px=0.7, tip_alpha=0.15):
    """The reference's splat renderer (common.render) with a colour per point."""
    S, n, _ = P.shape
    H = W = cam.size
    x, y, _ = cam.project(P.reshape(-1, 3))
    x, y = x.reshape(S, n), y.reshape(S, n)
    sub = max(2, min(24, int(math.ceil(torch.hypot(x[:, 1:] - x[:, :-1], y[:, 1:] - y[:, :-1]).max().item()))))
    t = torch.linspace(0, 1, sub + 1)[:-1][None, None, :, None]

    def along(X):
        inner = (X[:, :-1, None] * (1 - t) + X[:, 1:, None] * t).reshape(S, -1, 3)
        return torch.cat([inner, X[:, -1:]], 1)
    Q, CQ = along(P), along(C)
    alpha = (1.0 + (tip_alpha - 1.0) * torch.linspace(0, 1, Q.shape[1]))[None] * vis[:, None]
    x, y, _ = cam.project(Q.reshape(-1, 3))
    col, alpha = CQ.reshape(-1, 3), alpha.reshape(-1)
    keep = alpha > 0
    x, y, col, alpha = x[keep], y[keep], col[keep], alpha[keep]
    x0, y0 = torch.floor(x).long(), torch.floor(y).long()
    img_a, img_c = torch.zeros(H * W), torch.zeros(H * W, 3)
    r = int(math.ceil(2.5 * sigma_px))
    for oy in range(-r + 1, r + 1):
        for ox in range(-r + 1, r + 1):
            px, py = x0 + ox, y0 + oy
            ok = (px >= 0) & (px < W) & (py >= 0) & (py < H)
            w = torch.exp(-(((px.float() + .5) - x) ** 2 + ((py.float() + .5) - y) ** 2) / (2 * sigma_px ** 2)) * alpha
            lin = (py * W + px)[ok]
            img_a.index_add_(0, lin, w[ok])
            img_c.index_add_(0, lin, w[ok, None] * col[ok])
    cover = 1 - torch.exp(-img_a)
    return (cover[:, None] * img_c / (img_a[:, None] + 1e-6)).t().reshape(3, H, W)


def masked_grams(img, mask):
    """Gram matrices of img's VGG-19 taps over the cells mask covers."""
    out = []
    for f in vgg_feats(img):
        m = F.interpolate(mask[None, None], size=f.shape[1:], mode='area')[0, 0].reshape(-1)
        x = f.reshape(f.shape[0], -1)
        out.append((x * m) @ x.t() / m.sum().clamp(min=1e-6))
    return out


def painting_grams(path, height):
    pil = Image.open(path).convert('RGB')
    pil = pil.resize((max(1, round(pil.width * height / pil.height)), height), Image.BILINEAR)
    img = torch.from_numpy(np.asarray(pil, dtype=np.float32) / 255).permute(2, 0, 1)
    return masked_grams(img, torch.ones(img.shape[1:]))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--rest', required=True, help='the input groom (.ply)')
    ap.add_argument('--map', required=True, help='one label per strand (.txt): 0 the first --style, ...')
    ap.add_argument('--style', action='append', required=True, help='NAME=PAINTING, in the map\'s order')
    ap.add_argument('--result', action='append', required=True, help='NAME=RESULT.usda')
    ap.add_argument('--up', default='y')
    ap.add_argument('--size', type=int, default=256, help='render size (the job\'s --render-size)')
    ap.add_argument('--style-scale', type=float, default=3.0, help='the job\'s style scale')
    a = ap.parse_args()
    torch.set_grad_enabled(False)
    rest = torch.from_numpy(read_ply(a.rest))
    results = [(r.split('=', 1)[0], *read_usda(r.split('=', 1)[1])) for r in a.result]
    if a.up == 'z':  # the reference's cameras are y-up
        turn = lambda P: torch.stack([P[..., 0], P[..., 2], -P[..., 1]], -1)  # noqa: E731
        rest, results = turn(rest), [(n, turn(P), C) for n, P, C in results]
    flat = rest.reshape(-1, 3)
    center = (flat.min(0).values + flat.max(0).values) / 2
    radius = (flat - center).norm(dim=1).max().item()
    cams = [Cam(center, radius, 360.0 * (k + 0.5) / 8, (0.0, 30.0)[k % 2], a.size) for k in range(8)]
    normals = rest[:, 1] - rest[:, 0]
    normals = normals / normals.norm(dim=1, keepdim=True).clamp(min=1e-12)
    labels = torch.tensor(np.loadtxt(a.map)).round().long()
    assert len(labels) == len(rest), f'{a.map}: {len(labels)} labels for {len(rest)} strands'
    styles = [(s.split('=', 1)[0], painting_grams(s.split('=', 1)[1], round(a.size * a.style_scale))) for s in a.style]
    print('colour Gram loss over each region\'s hair / the same strands in their luminance, median of the views that see it')
    print(f'{"result":14} {"region":14}' + ''.join(f' {s:>14}' for s, _ in styles))
    for region, (region_name, _) in enumerate(styles):
        ratios = {n: {s: [] for s, _ in styles} for n, _, _ in results}
        for cam in cams:
            to_eye = cam.eye[None] - rest[:, 0]
            vis = (((normals * to_eye).sum(1) / to_eye.norm(dim=1)) >= 0).float() * (labels == region).float()
            if vis.sum() < 50:
                continue
            for name, P, C in results:
                luma = (C * torch.tensor([0.299, 0.587, 0.114])).sum(-1, keepdim=True).expand_as(C)
                grey = render_rgb(P, luma, cam, vis)
                mask = (grey.sum(0) > 0.02).float()
                g, g0 = masked_grams(render_rgb(P, C, cam, vis), mask), masked_grams(grey, mask)
                for s, gs in styles:
                    ratios[name][s].append(gram_dist(g, gs) / gram_dist(g0, gs))
        for name, _, _ in results:
            print(f'{name:14} {region_name:14}' + ''.join(f' {np.median(ratios[name][s]):14.3f}' for s, _ in styles))


if __name__ == '__main__':
    main()
