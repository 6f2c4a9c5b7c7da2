"""Cross test of stylized grooms: every result judged against every style.

    python3 judge.py --rest REST.ply --result NAME=FILE [--result ...] --style NAME=IMG [...]
                     [--size 256] [--ang 10] [--style-px 96] [--sheet OUT.png] [--json OUT.json]

Each groom (.ply as nst3d writes it, or the reference's .npy) is drawn by the
reference's soft splat renderer from nine fixed frontal views inside the
preset's +-ang range (the views an optimiser of that preset faces), and each
render is compared with each style by a Gram loss over relu1_1..relu4_1 of
the Gatys-normalised VGG-19 (each layer divided by the style's own Gram
energy, so the four layers count alike). A cell is the median over the views
of result / rest: below 1 the result is nearer the style than the input was.

The pair test: for styles A and B, the result toward A must be nearer A than
the result toward B is, by the margin (and the same for B), where results
are named after their styles. A result named `ramp` (a textureless control)
must be the nearest to no style. Prints every cell and every pair.
"""
import argparse
import json
import math
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import *  # noqa: E402,F401

VIEWS = [(0, 0), (-0.7, 0), (0.7, 0), (0, -0.7), (0, 0.7), (-0.5, -0.5), (0.5, 0.5), (-0.5, 0.5), (0.5, -0.5)]


def load(path):
    if path.endswith('.npy'):
        return torch.from_numpy(np.load(path).astype(np.float32))
    return torch.from_numpy(read_ply(path))


def grams(img):
    return [gram(f) for f in vgg_feats(img)]


def gram_dist(ga, gs):
    return sum(((a - s) ** 2).sum().item() / (s ** 2).sum().item() for a, s in zip(ga, gs))


def structure_tensor(img, sigma):
    """The smoothed structure tensor's entries (jxx, jxy, jyy) of a grey image."""
    a = img.numpy().astype(np.float64)
    gy, gx = np.gradient(a)
    from scipy.ndimage import gaussian_filter
    return tuple(gaussian_filter(t, sigma) for t in (gx * gx, gx * gy, gy * gy))


def orient_hist(img, bins=18, sigma=2.0):
    """Coherence- and energy-weighted histogram of stroke directions (the
    structure tensor's minor eigenvector) over [0, 180) degrees."""
    jxx, jxy, jyy = structure_tensor(img, sigma)
    tr = jxx + jyy
    disc = np.sqrt((jxx - jyy) ** 2 + 4 * jxy ** 2)
    coh = (disc / (tr + 1e-12)) ** 2
    theta = (np.degrees(0.5 * np.arctan2(2 * jxy, jxx - jyy)) + 90.0) % 180.0
    h, _ = np.histogram(theta, bins=bins, range=(0, 180), weights=coh * tr)
    return h / max(h.sum(), 1e-12)


def orient_dist(ha, hb):
    return 0.5 * float(np.abs(ha - hb).sum())


def stroke_field(img, sigma=2.0, gate=None):
    """Doubled-angle stroke field (c cos 2t, c sin 2t, c) of a grey image:
    the structure tensor's minor eigenvector, weighted by the squared
    coherence and, with `gate`, by E/(E + (gate/h)^2) of the gradient energy.
    nst3d's orientation term gates the same way but weighs by the coherence
    unsquared; the judge keeps the stricter square, so loosely brushed
    strokes count for less here than in the term."""
    jxx, jxy, jyy = structure_tensor(img, sigma)
    tr = jxx + jyy
    disc = np.sqrt((jxx - jyy) ** 2 + 4 * jxy ** 2)
    c = (disc / (tr + 1e-12)) ** 2
    c = c * (tr / (tr + (gate / jxx.shape[0]) ** 2) if gate else tr)
    # the stroke runs across the gradient: angle of the minor eigenvector, doubled
    t2 = np.arctan2(-2 * jxy, -(jxx - jyy))
    return c * np.cos(t2), c * np.sin(t2), c


def cover(img, h, w, style_scale=1.0):
    """The style laid over an h x w box as nst3d lays it: cover fit, centred,
    then enlarged by `style_scale`, centred, or shrunk and tiled (below 1)."""
    sh, sw = img.shape
    k = max(h / sh, w / sw) * style_scale
    t = torch.nn.functional.interpolate(img[None, None], size=(max(2, round(sh * k)), max(2, round(sw * k))),
                                        mode='bilinear', align_corners=False)[0, 0]
    th, tw = t.shape
    if th < h or tw < w:  # tiled, a tile's centre at the box's centre
        ry, rx = -(-h // th) + 2, -(-w // tw) + 2
        t = t.repeat(ry | 1, rx | 1)
    y0, x0 = (t.shape[0] - h) // 2, (t.shape[1] - w) // 2
    return t[y0:y0 + h, x0:x0 + w]


def layout_dist(render_field, style_img, style_scale=1.0):
    """Mean misalignment, 1/2 (1 - cos 2(phi - theta)), of the render's strokes
    against the style's strokes laid over the same box, weighted by both
    fields' coherence: 0 = every visible stroke along the style's, 0.5 = at
    random, 1 = across."""
    rc, rs, rw = render_field
    h, w = rw.shape
    sc, ss, sw = stroke_field(cover(style_img, h, w, style_scale), gate=4.0)
    num = (rw * sw - (rc * sc + rs * ss)).sum()
    return float(0.5 * num / max((rw * sw).sum(), 1e-12))


def edge_stats(img):
    """Share of edge energy at diagonal angles (30-60 and 120-150 degrees)."""
    a = img.numpy()
    gy, gx = np.gradient(a)
    mag = np.hypot(gx, gy)
    ang = (np.degrees(np.arctan2(gy, gx)) + 180.0) % 180.0
    diag = ((ang > 30) & (ang < 60)) | ((ang > 120) & (ang < 150))
    return float((mag * diag).sum() / max(mag.sum(), 1e-9))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('--rest', required=True)
    ap.add_argument('--result', action='append', default=[])
    ap.add_argument('--style', action='append', default=[])
    ap.add_argument('--size', type=int, default=256)
    ap.add_argument('--ang', type=float, default=10.0)
    ap.add_argument('--around', type=int, default=0,
                    help='judge from this many azimuths all round (a 360-degree preset; --ang is then the polar range)')
    ap.add_argument('--style-px', type=int, default=96, help='style height at this render size')
    ap.add_argument('--margin', type=float, default=0.10, help='pair margin between two geometric styles')
    ap.add_argument('--painting-margin', type=float, default=0.05, help='pair margin where a painting is in the pair')
    ap.add_argument('--paintings', default='', help='comma-separated style names that are paintings')
    ap.add_argument('--sheet')
    ap.add_argument('--json')
    ap.add_argument('--up', default='y')
    ap.add_argument('--crop', action='store_true', help='judge only the rest hair\'s box of each view')
    ap.add_argument('--cull', type=float, default=None,
                    help='draw only strands whose root faces the camera (cos of the rest root direction and the '
                         'view >= CULL), as nst3d draws a groom on a mesh; default: every strand')
    ap.add_argument('--judge', default='gram', choices=['gram', 'orient', 'layout'],
                    help='gram: VGG-19 Gram loss; orient: distance of stroke-direction histograms; '
                         'layout: stroke misalignment against the style laid over the hair box')
    ap.add_argument('--region', default=None,
                    help='FILE:LO:HI judges one region of a style map: FILE holds one value per strand, and only '
                         'strands whose value lies in [LO, HI] are drawn, each style laid over the box of the '
                         'region on the rest groom (as nst3d lays a style map\'s paintings)')
    ap.add_argument('--style-scale', type=float, default=1.0,
                    help="the style's scale on the hair the results were made with (nst3d's --style-scale): the style is read at --style-px times it and laid over the hair at it")
    a = ap.parse_args()
    rest = load(a.rest)
    results = [('rest', rest)] + [(r.split('=', 1)[0], load(r.split('=', 1)[1])) for r in a.result]
    if a.up == 'z':  # turn a z-up groom so the reference's y-up cameras see it upright
        results = [(n, torch.stack([P[..., 0], P[..., 2], -P[..., 1]], -1)) for n, P in results]
    flat = results[0][1].reshape(-1, 3)
    center = (flat.min(0).values + flat.max(0).values) / 2
    R = (flat - center).norm(dim=1).max().item()
    styles = []
    shist = {}
    for s in a.style:
        name, path = s.split('=', 1)
        img = resize_grey(grey_of(Image.open(path)), round(a.style_px * a.style_scale))
        with torch.no_grad():
            styles.append((name, grams(img), img))
        shist[name] = orient_hist(img)
    if a.around:
        # A 360-degree preset faces the groom from every side: a ring of
        # azimuths, each at the horizon and 0.7 of the polar range up and down.
        cams = [Cam(center, R, 360.0 * k / a.around, el * a.ang, a.size)
                for k in range(a.around) for el in (0.0, -0.7, 0.7)]
    else:
        cams = [Cam(center, R, az * a.ang, el * a.ang, a.size) for az, el in VIEWS]
    # Root normals from the rest groom's first segments (strands grow along
    # their root normal), for --cull.
    P0 = results[0][1]
    normals = P0[:, 1] - P0[:, 0]
    normals = normals / normals.norm(dim=1, keepdim=True).clamp(min=1e-12)

    def visible(cam):
        if a.cull is None:
            return None
        v = cam.eye[None, :] - P0[:, 0]
        return ((normals * v).sum(1) / v.norm(dim=1).clamp(min=1e-12) >= a.cull).float()
    vis = [visible(cam) for cam in cams]
    region = None
    if a.region:
        path, lo, hi = a.region.rsplit(':', 2)
        values = torch.tensor(np.loadtxt(path), dtype=torch.float32).reshape(-1)
        region = ((values >= float(lo)) & (values <= float(hi))).float()
        assert len(region) == P0.shape[0], f'{path}: {len(region)} values for {P0.shape[0]} strands'
    drawn = [(v if v is not None else torch.ones(P0.shape[0])) * region if region is not None else v for v in vis]
    dist = {}
    edges = {}
    renders = {}
    boxes = []
    with torch.no_grad():
        for cam in cams:
            m = render(results[0][1], cam, vis=drawn[cams.index(cam)]) > 0.02
            ys, xs = torch.nonzero(m, as_tuple=True)
            pad = 6
            boxes.append((max(0, ys.min().item() - pad), min(a.size, ys.max().item() + pad + 1),
                          max(0, xs.min().item() - pad), min(a.size, xs.max().item() + pad + 1)))
        for name, P in results:
            per = {s: [] for s, _, _ in styles}
            ed = []
            for ci, cam in enumerate(cams):
                img = render(P, cam, vis=drawn[ci])
                if a.crop:
                    y0, y1, x0, x1 = boxes[ci]
                    img = img[y0:y1, x0:x1]
                if ci == 0:
                    renders[name] = img
                ed.append(edge_stats(img))
                g = grams(img) if a.judge == 'gram' else None
                oh = orient_hist(img)
                rf = stroke_field(img) if a.judge == 'layout' else None
                for s, gs, simg in styles:
                    if a.judge == 'gram':
                        per[s].append(gram_dist(g, gs))
                    elif a.judge == 'orient':
                        per[s].append(orient_dist(oh, shist[s]))
                    else:
                        per[s].append(layout_dist(rf, simg, a.style_scale))
            dist[name] = per
            edges[name] = float(np.median(ed))
    rel = {n: {s: float(np.median(np.array(dist[n][s]) / np.array(dist['rest'][s]))) for s, _, _ in styles}
           for n, _ in results}
    snames = [s for s, _, _ in styles]
    print('result / rest, %s, median of %d views (lower = nearer the style)'
          % ({'gram': 'Gram loss', 'orient': 'stroke-direction histogram distance',
              'layout': 'stroke misalignment against the style laid over the hair'}[a.judge], len(cams)))
    print('%-12s' % 'toward' + ''.join(' | %-10s' % s for s in snames) + ' | diag-edge')
    for n, _ in results:
        print('%-12s' % n + ''.join(' | %-10.3f' % rel[n][s] for s in snames) + ' | %.2f' % edges[n])
    pairs = []
    named = [s for s in snames if s in rel]
    for i, A in enumerate(named):
        for B in named[i + 1:]:
            mA = 1 - rel[A][A] / rel[B][A]
            mB = 1 - rel[B][B] / rel[A][B]
            paint = set(a.paintings.split(','))
            m = a.painting_margin if (A in paint or B in paint) else a.margin
            ok = mA >= m and mB >= m
            pairs.append(dict(a=A, b=B, margin_a=mA, margin_b=mB, need=m, ok=ok))
            print(f'pair {A:>10} / {B:<10}: toward {A} nearer {A} by {mA:+.1%}, toward {B} nearer {B} by {mB:+.1%}'
                  f' (need {m:.0%}) -> {"ok" if ok else "FAIL"}')
    if 'ramp' in rel:
        for s in snames:
            best = min((rel[n][s], n) for n, _ in results if n != 'rest')[1]
            print(f'nearest to {s}: {best}' + ('  (ramp: FAIL)' if best == 'ramp' else ''))
    ramp_nearest = [s for s in snames if 'ramp' in rel and min((rel[n][s], n) for n, _ in results if n != 'rest')[1] == 'ramp']
    print(f'{sum(p["ok"] for p in pairs)} of {len(pairs)} pairs pass; the ramp is nearest to {len(ramp_nearest)} styles')
    if a.json:
        json.dump(dict(rel=rel, edges=edges, pairs=pairs, ramp_nearest=ramp_nearest), open(a.json, 'w'), indent=1)
    if a.sheet:
        tiles = [renders[n] for n, _ in results]
        for s, _, img in styles:
            h = renders['rest'].shape[0]
            t = torch.nn.functional.interpolate(img[None, None], size=(h, h), mode='bilinear')[0, 0]
            tiles.append(t)
        h = max(t.shape[0] for t in tiles)
        tiles = [torch.nn.functional.pad(t, (0, 0, 0, h - t.shape[0])) for t in tiles]
        row = torch.cat([t.clamp(0, 1) for t in tiles], 1)
        to_png(row, a.sheet)


if __name__ == '__main__':
    main()
