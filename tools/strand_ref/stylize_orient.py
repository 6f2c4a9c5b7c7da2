import argparse
from common import *

from stylize import PRESETS, collide, setup, visibility


# ---------------------------------------------------------------- orientation term (not in the paper; its future work)
def load_style(name):
    """make_styles() plus any $STYLE_DIR/style_NAME.png or .jpg (e.g. checks)."""
    st = make_styles()
    if name in st:
        return st[name]
    for ext in ('png', 'jpg'):
        p = os.path.join(os.environ.get('STYLE_DIR', '.'), f'style_{name}.{ext}')
        if os.path.exists(p):
            return grey_of(Image.open(p))
    raise KeyError(name)

def gauss1d(sigma):
    r = max(1, int(math.ceil(3 * sigma)))
    x = torch.arange(-r, r + 1, dtype=torch.float32)
    k = torch.exp(-x * x / (2 * sigma * sigma))
    return k / k.sum()

def blur(x, sigma):
    """x: (C,H,W), separable Gaussian, replicate padding."""
    k = gauss1d(sigma); r = (k.numel() - 1) // 2
    C = x.shape[0]
    y = F.pad(x[None], (r, r, 0, 0), mode='replicate')
    y = F.conv2d(y, k.view(1, 1, 1, -1).expand(C, 1, 1, -1), groups=C)
    y = F.pad(y, (0, 0, r, r), mode='replicate')
    y = F.conv2d(y, k.view(1, 1, -1, 1).expand(C, 1, -1, 1), groups=C)
    return y[0]

def orient_field(img, sigma):
    """Structure tensor of a grey image (H,W) in image coordinates (x right, y down).
    J = G_sigma * [gx^2, gx gy; gx gy, gy^2] (Sobel gradients). Stroke direction t = eigenvector of the
    SMALLER eigenvalue (perpendicular to the dominant gradient), coherence c = ((l1-l2)/(l1+l2+eps))^2,
    eps = 1e-2 * mean trace (flat regions -> c = 0). Returned in doubled-angle form:
    field (3,H,W) = [c cos 2theta, c sin 2theta, c], theta = angle of t, so that bilinear sampling
    averages headless orientations correctly and c (1 - (d.t)^2) = (c - [c cos2th, c sin2th] . [cos2phi, sin2phi]) / 2."""
    sx = torch.tensor([[-1., 0., 1.], [-2., 0., 2.], [-1., 0., 1.]]) / 8
    x = F.pad(img[None, None], (1, 1, 1, 1), mode='replicate')
    gx = F.conv2d(x, sx.view(1, 1, 3, 3))[0, 0]
    gy = F.conv2d(x, sx.t().contiguous().view(1, 1, 3, 3))[0, 0]
    J = blur(torch.stack([gx * gx, gx * gy, gy * gy]), sigma)
    jxx, jxy, jyy = J
    tr = jxx + jyy
    disc = torch.sqrt(((jxx - jyy) ** 2 + 4 * jxy ** 2).clamp(min=0))
    c = (disc / (tr + 1e-2 * tr.mean() + 1e-12)) ** 2
    # gradient (dominant) orientation 2*alpha = atan2(2jxy, jxx-jyy); stroke = alpha + 90 deg -> doubled angle + 180
    c2 = -(jxx - jyy) / (disc + 1e-12)
    s2 = -(2 * jxy) / (disc + 1e-12)
    return torch.stack([c * c2, c * s2, c])

def sample_field(field, gx, gy):
    """field (3,h,w); gx, gy normalised [-1,1] coordinates (align_corners=False); zero outside."""
    g = torch.stack([gx, gy], -1).view(1, 1, -1, 2)
    return F.grid_sample(field[None], g, mode='bilinear', padding_mode='zeros', align_corners=False)[0, :, 0].t()

def layout_coords(x, y, box, sh, sw):
    """Style image laid over the rest hair's screen box (cover fit, centred, aspect kept)."""
    y0, y1, x0, x1 = box
    bw, bh = x1 - x0, y1 - y0
    sc = max(bw / sw, bh / sh)
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    return 2 * (x - cx) / (sw * sc), 2 * (y - cy) / (sh * sc)

def orient_loss(P, cam, vis, field, coords, len0, tip_alpha=0.15):
    """Mean over projected segments of w * c * (1 - (d.t)^2), d = unit 2D segment direction, target sampled
    at the (detached) projected midpoint. w = strand visibility * splat opacity (1 -> tip_alpha) *
    l^2 / (l^2 + len0^2) (l = projected length; foreshortened segments have no reliable direction)."""
    S, n, _ = P.shape
    A = P[:, :-1].reshape(-1, 3); B = P[:, 1:].reshape(-1, 3)
    xa, ya, _ = cam.project(A); xb, yb, _ = cam.project(B)
    dx, dy = xb - xa, yb - ya
    l2 = dx * dx + dy * dy + 1e-12
    cos2, sin2 = (dx * dx - dy * dy) / l2, 2 * dx * dy / l2
    with torch.no_grad():
        mx, my = (xa + xb) / 2, (ya + yb) / 2
        gx, gy = coords(mx, my)
        f = sample_field(field, gx, gy)
        s_par = (torch.arange(n - 1, dtype=torch.float32) + 0.5) / (n - 1)
        w = (1.0 + (tip_alpha - 1.0) * s_par)[None].expand(S, n - 1)
        if vis is not None:
            w = w * vis[:, None]
        w = w.reshape(-1) * (l2 / (l2 + len0 ** 2))
    per = 0.5 * (f[:, 2] - (f[:, 0] * cos2 + f[:, 1] * sin2))
    return (w * per).sum() / w.sum().clamp(min=1e-9), (w * f[:, 2]).sum() / w.sum().clamp(min=1e-9)

def grad_norm(loss, V):
    g, = torch.autograd.grad(loss, V, retain_graph=True)
    return g.norm().item()

def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('--groom', default='grass')
    ap.add_argument('--preset', default=None)
    ap.add_argument('--style', default='spiral')
    ap.add_argument('--mode', default='radius')
    ap.add_argument('--k', type=int, default=8)
    ap.add_argument('--radius', type=float, default=0.1)
    ap.add_argument('--kmax', type=int, default=48)
    ap.add_argument('--size', type=int, default=256)
    ap.add_argument('--iters', default='20,30,50')
    ap.add_argument('--lr-scale', type=float, default=1.0)
    ap.add_argument('--sigma', type=float, default=0.7)
    ap.add_argument('--style-mult', type=float, default=1.0)
    ap.add_argument('--seed', type=int, default=0)
    ap.add_argument('--out', required=True)
    ap.add_argument('--norm', default='sqrt')
    ap.add_argument('--orient', default='layout', help='none | layout (style laid over the hair box) | match (NNST correspondence)')
    ap.add_argument('--lam', type=float, default=None, help='absolute weight of the orientation term (overrides --lam-rel)')
    ap.add_argument('--lam-rel', type=float, default=1.0, help='lambda = lam_rel * |grad NNST| / |grad orient| at the first iteration')
    ap.add_argument('--osigma', type=float, default=3.0, help='structure tensor sigma, px at the scale style size')
    a = ap.parse_args()
    import common; common.NORM = a.norm
    torch.manual_seed(a.seed); rng = np.random.default_rng(a.seed)
    pre = PRESETS[a.preset or (a.groom if a.groom in PRESETS else 'short')]
    P0, Nr, center, R = setup(a.groom, a.size)
    S, n, _ = P0.shape
    rest_len = (P0[:, 1:] - P0[:, :-1]).norm(dim=-1)
    t0 = time.time()
    O, idx, w = build_field(P0, pre['rho'], a.mode, k=a.k, radius=a.radius, kmax=a.kmax)
    nz = (w > 0).sum(1).float()
    # fraction of a point's weight from other strands
    strand_of_sample = torch.arange(S * n)[torch.floor((torch.arange(S * n) + 1) * pre['rho'] + 0.5) > torch.floor(torch.arange(S * n) * pre['rho'] + 0.5)] // n
    own = (strand_of_sample[idx] == (torch.arange(S * n) // n)[:, None]).float()
    cross_w = (w * (1 - own)).sum(1).mean().item()
    print(f'groom {a.groom}: {S} strands x {n}, R={R:.3f}; samples {O.shape[0]}; nbrs/pt {nz.mean():.1f}; weight from other strands {cross_w:.2f}; field {time.time()-t0:.1f}s', flush=True)
    V = torch.zeros(O.shape[0], 3, requires_grad=True)
    st = load_style(a.style)
    iters = [int(x) for x in a.iters.split(',')]
    scale_px = a.size / pre['render']
    opt = torch.optim.AdamW([V], lr=pre['lrs'][0] * a.lr_scale, weight_decay=0.01)
    hist = []
    lam = None; len0 = None
    for l in range(3):
        hs = max(16, int(round(pre['styles'][l] * scale_px * a.style_mult)))
        simg = resize_grey(st, hs)
        with torch.no_grad():
            sf = vgg_feats(simg)
            sgrid = (sf[2].shape[1], sf[2].shape[2])
            scols = hypercols(sf, sgrid)
            ofield = orient_field(simg, a.osigma)
            # field at the style's relu3_1 grid points (align_corners=True positions), for the match mode
            sfy = torch.linspace(0, simg.shape[0] - 1, sgrid[0]); sfx = torch.linspace(0, simg.shape[1] - 1, sgrid[1])
            ofield_grid = ofield[:, sfy.round().long()][:, :, sfx.round().long()].reshape(3, -1)
        for g in opt.param_groups:
            g['lr'] = pre['lrs'][l] * a.lr_scale
        for it in range(iters[l]):
            az = rng.uniform(-pre['ang'], pre['ang']); el = rng.uniform(-pre['ang'], pre['ang'])
            cam = Cam(center, R, az, el, a.size)
            vis = visibility(P0, Nr, cam)
            with torch.no_grad():
                I0 = render(P0, cam, a.sigma, vis=vis)
                f0 = vgg_feats(I0)
                grid = (f0[2].shape[1], f0[2].shape[2])
                T, jidx = nn_match(hypercols(f0, grid), scols)
                if a.orient == 'layout':
                    m = I0 > 0.02
                    ys, xs = torch.nonzero(m, as_tuple=True)
                    box = (ys.min().item(), ys.max().item() + 1, xs.min().item(), xs.max().item() + 1)
                    field = ofield
                    coords = lambda x, y, box=box: layout_coords(x, y, box, simg.shape[0], simg.shape[1])
                elif a.orient == 'match':
                    field = ofield_grid[:, jidx].reshape(3, grid[0], grid[1])
                    coords = lambda x, y: (2 * x / a.size - 1, 2 * y / a.size - 1)
                if a.orient != 'none' and len0 is None:
                    x0_, y0_, _ = cam.project(P0.reshape(-1, 3))
                    x0_ = x0_.reshape(S, n); y0_ = y0_.reshape(S, n)
                    len0 = 0.25 * torch.hypot(x0_[:, 1:] - x0_[:, :-1], y0_[:, 1:] - y0_[:, :-1]).median().item()
            P = transport(P0, V, idx, w)
            P = length_preserve(P, rest_len, P0)
            P = collide(P, a.groom, P0)
            I = render(P, cam, a.sigma, vis=vis)
            cols = hypercols(vgg_feats(I), grid)
            loss_n = ((cols - T) ** 2).sum(1).mean()
            if a.orient != 'none':
                lo, cbar = orient_loss(P, cam, vis, field, coords, len0)
                if lam is None:
                    gn, go = grad_norm(loss_n, V), grad_norm(lo, V)
                    lam = a.lam if a.lam is not None else a.lam_rel * gn / max(go, 1e-12)
                    print(f'|grad NNST| {gn:.4e} |grad orient| {go:.4e} -> lambda {lam:.4e}', flush=True)
                loss = loss_n + lam * lo
            else:
                lo = cbar = torch.tensor(0.0); loss = loss_n
            opt.zero_grad(); loss.backward(); opt.step()
            hist.append((l, it, loss_n.item(), lo.item(), cbar.item()))
            if it % 10 == 0 or it == iters[l] - 1:
                print(f'scale {l} it {it} nnst {loss_n.item():.4e} orient {lo.item():.4f} (c-mean {cbar.item():.3f}) |V|max {V.detach().abs().max():.4f} t {time.time()-t0:.0f}s', flush=True)
    with torch.no_grad():
        P = collide(length_preserve(transport(P0, V, idx, w), rest_len, P0), a.groom, P0)
    np.save(a.out + '.npy', P.numpy())
    json.dump(dict(args=vars(a), lam=lam, hist=hist, time=time.time() - t0, cross_w=cross_w), open(a.out + '.json', 'w'))
    print('done', time.time() - t0)

if __name__ == '__main__':
    main()
