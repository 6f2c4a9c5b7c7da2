"""side_by_side.py OUT.png [--size PX] [--up y|z] --row LABEL|REST|STYLE|REF|NST3D|NST3D_LOG ...

The reference and nst3d on the same case, one row each: the style | the input | the reference's
result | nst3d's result (all four drawn by this folder's renderer from the front, so the two
implementations are seen through one camera) | both loss curves. REF is a stylize.py output
prefix (OUT.npy with OUT.json beside it); NST3D is nst3d's .ply and NST3D_LOG the log of
`nst3d strands` (its "[k/n] scale s/3 iteration i/m loss X" lines).

Each loss curve is divided by its scale's first loss (the scales match different style sizes, so
their raw losses do not compare) and smoothed over 5 iterations: below 1 the scale descends.
The reference draws a new camera every iteration, nst3d cycles through 8 cached views per scale,
so single iterations are noisy in both."""
import argparse, json, os, re, sys
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import *
from judge import load
from PIL import ImageDraw


def nst3d_losses(log):
    """(scale, loss) per iteration from an `nst3d strands` log."""
    pat = re.compile(r'scale (\d)/3 iteration \d+/\d+ loss ([0-9.eE+-]+)')
    out = []
    for line in open(log):
        m = pat.search(line)
        if m:
            out.append((int(m.group(1)) - 1, float(m.group(2))))
    return out


def ref_losses(prefix):
    return [(int(s), float(l)) for s, _, l in json.load(open(prefix + '.json'))['hist']]


def relative(curve, win=5):
    """Each loss over its scale's first, then a running mean of `win` within the scale."""
    out, first, buf = [], {}, []
    for s, l in curve:
        if s not in first:
            first[s], buf = l, []
        buf = (buf + [l / first[s]])[-win:]
        out.append((s, sum(buf) / len(buf)))
    return out


def plot(curves, size, lo=0.6, hi=1.4):
    img = Image.new('RGB', (size, size), (255, 255, 255))
    d = ImageDraw.Draw(img)
    m, n = 28, max(len(c) for _, c, _ in curves)
    X = lambda i: m + (size - 2 * m) * i / max(1, n - 1)
    Y = lambda v: m + (size - 2 * m) * (hi - min(hi, max(lo, v))) / (hi - lo)
    d.rectangle([m, m, size - m, size - m], outline=(0, 0, 0))
    d.line([m, Y(1.0), size - m, Y(1.0)], fill=(150, 150, 150))
    for i in range(1, n):  # scale boundaries
        if curves[0][1][i][0] != curves[0][1][i - 1][0]:
            d.line([X(i), m, X(i), size - m], fill=(200, 200, 200))
    for name, c, col in curves:
        pts = [(X(i), Y(v)) for i, (_, v) in enumerate(c)]
        d.line(pts, fill=col, width=2)
    d.text((m, 4), 'loss / scale start (%.1f-%.1f)' % (lo, hi), fill=(0, 0, 0))
    for k, (name, _, col) in enumerate(curves):
        d.text((m + 4 + 110 * k, size - m + 8), name, fill=col)
    return img


def tile(t):
    a = (t.clamp(0, 1).numpy() * 255).astype(np.uint8)
    return Image.fromarray(a).convert('RGB')


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('out')
    ap.add_argument('--size', type=int, default=320)
    ap.add_argument('--up', default='y')
    ap.add_argument('--row', action='append', required=True)
    a = ap.parse_args()
    s = a.size
    rows = []
    for row in a.row:
        label, rest, style, ref, nst, log = row.split('|')
        P = [load(rest), load(ref + '.npy'), load(nst)]
        if a.up == 'z':
            P = [torch.stack([p[..., 0], p[..., 2], -p[..., 1]], -1) for p in P]
        flat = P[0].reshape(-1, 3)
        center = (flat.min(0).values + flat.max(0).values) / 2
        R = (flat - center).norm(dim=1).max().item()
        cam = Cam(center, R, 0, 0, s)
        st = resize_grey(grey_of(Image.open(style)), s)[:, :s]
        st = torch.nn.functional.pad(st, (0, s - st.shape[1]))
        with torch.no_grad():
            tiles = [tile(st)] + [tile(render(p, cam, sigma_px=0.7 * s / 256)) for p in P]
        tiles.append(plot([('reference', relative(ref_losses(ref)), (200, 40, 40)),
                           ('nst3d', relative(nst3d_losses(log)), (30, 60, 200))], s))
        strip = Image.new('RGB', (s * len(tiles), s + 18), (255, 255, 255))
        for i, t in enumerate(tiles):
            strip.paste(t, (i * s, 18))
        ImageDraw.Draw(strip).text((4, 2), '%s: style | input | reference | nst3d | loss curves' % label,
                                   fill=(0, 0, 0))
        rows.append(strip)
    sheet = Image.new('RGB', (rows[0].width, sum(r.height for r in rows)), (255, 255, 255))
    y = 0
    for r in rows:
        sheet.paste(r, (0, y))
        y += r.height
    tmp = a.out + '.tmp.png'
    sheet.save(tmp)
    os.replace(tmp, a.out)


if __name__ == '__main__':
    main()
