"""Minimal independent reference of Coban et al. 2025, Sec. 3 (static, no temporal).
VGG-19 (Gatys-normalised, AdaIN layout), NNST loss eq. 2-3, RBF field eq. 5,
length preservation root->tip, soft differentiable strand splatting.
"""
import math, time, json, sys, os
import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F
from PIL import Image, ImageDraw

torch.set_num_threads(1)
DEV = torch.device('cpu')
VGG_PATH = os.environ.get('NST3D_VGG19', os.path.expanduser('~/.cache/nst3d/vgg_normalised.pth'))

# ---------------------------------------------------------------- VGG
def build_vgg(upto=31):
    layers = [nn.Conv2d(3, 3, 1)]
    cfg = [64, 64, 'M', 128, 128, 'M', 256, 256, 256, 256, 'M', 512, 512, 512, 512, 'M', 512, 512, 512, 512]
    cin = 3
    for c in cfg:
        if c == 'M':
            layers.append(nn.MaxPool2d(2, 2, ceil_mode=True))
        else:
            layers += [nn.ReflectionPad2d(1), nn.Conv2d(cin, c, 3), nn.ReLU()]
            cin = c
    seq = nn.Sequential(*layers)[:upto]
    sd = torch.load(VGG_PATH, map_location='cpu')
    # Only the layers kept are loaded, so a file cut after them loads too.
    seq.load_state_dict({k: v for k, v in sd.items() if int(k.split('.')[0]) < upto})
    for p in seq.parameters():
        p.requires_grad_(False)
    return seq.eval()

TAPS = {3: 'relu1_1', 10: 'relu2_1', 17: 'relu3_1', 30: 'relu4_1'}
_VGG = None
def vgg():
    global _VGG
    if _VGG is None:
        _VGG = build_vgg(31)
    return _VGG

def vgg_feats(img):
    """img: (H,W) grey or (3,H,W) in [0,1]. Returns list of (C,h,w)."""
    if img.dim() == 2:
        img = img[None].expand(3, -1, -1)
    x = img[None]
    out = []
    for i, l in enumerate(vgg()):
        x = l(x)
        if i in TAPS:
            out.append(x[0])
    return out

NORM = 'sqrt'
def hypercols(feats, grid):
    """NNST-style hypercolumns: each layer /channels^0.5? (we use / sqrt(C)),
    resized to grid (h,w) bilinear, concatenated. Returns (N, D)."""
    cols = []
    for f in feats:
        C = f.shape[0]
        g = F.interpolate(f[None], size=grid, mode='bilinear', align_corners=True)[0]
        cols.append(g.reshape(C, -1) / (math.sqrt(C) if NORM == 'sqrt' else C))
    return torch.cat(cols, 0).t().contiguous()

def nn_match(content_cols, style_cols):
    """eq. 2: cosine NN on zero-centred features; the matched style columns
    (the targets) and their indices."""
    c = content_cols - content_cols.mean(0, keepdim=True)
    s = style_cols - style_cols.mean(0, keepdim=True)
    c = c / (c.norm(dim=1, keepdim=True) + 1e-8)
    s = s / (s.norm(dim=1, keepdim=True) + 1e-8)
    idx = (c @ s.t()).argmax(1)
    return style_cols[idx], idx

def nn_targets(content_cols, style_cols):
    """eq. 2's targets alone."""
    return nn_match(content_cols, style_cols)[0]

def gram(f):
    C = f.shape[0]
    x = f.reshape(C, -1)
    return x @ x.t() / x.shape[1]

# ---------------------------------------------------------------- styles
def grey_of(pil):
    a = np.asarray(pil.convert('RGB'), dtype=np.float32) / 255.0
    return 0.299 * a[..., 0] + 0.587 * a[..., 1] + 0.114 * a[..., 2]

def make_styles(n=300):
    yy, xx = np.mgrid[0:n, 0:n].astype(np.float32)
    cx = cy = (n - 1) / 2
    dx, dy = xx - cx, yy - cy
    r = np.hypot(dx, dy); th = np.arctan2(dy, dx)
    # spiral: 2 thick arms (Archimedean)
    spiral = (np.sin(2 * th + r * 2 * math.pi / (n / 5.0)) > 0).astype(np.float32)
    # diagonal stripes, period n/7
    per = n / 7.0
    stripes = (np.sin((xx + yy) / math.sqrt(2) * 2 * math.pi / per) > 0).astype(np.float32)
    # triangle tessellation: equilateral triangle grid, alternate black/white
    side = n / 6.0
    h = side * math.sqrt(3) / 2
    row = np.floor(yy / h)
    v = yy / h - row
    u = xx / side + 0.5 * (row % 2)
    fu = u - np.floor(u)
    # up-triangle if within |fu-0.5| < (1-v)/2 roughly (apex at top)
    up = np.abs(fu - 0.5) < 0.5 * v
    tri = up.astype(np.float32)
    styles = {'spiral': spiral, 'stripes': stripes, 'triangles': tri}
    here = os.path.dirname(os.path.abspath(__file__))
    sn = Image.open(os.path.join(here, '../../../shared/data/styles/starry_night.jpg'))
    styles['painting'] = grey_of(sn)
    return styles

def resize_grey(a, h):
    H, W = a.shape
    w = max(16, int(round(W * h / H)))
    im = Image.fromarray((np.clip(a, 0, 1) * 255).astype(np.uint8)).resize((w, h), Image.LANCZOS)
    return torch.from_numpy(np.asarray(im, dtype=np.float32) / 255.0)

# ---------------------------------------------------------------- grooms
def grass(n_strands=800, n_pts=16, W=1.2, D=0.3, L=1.0, seed=0):
    rng = np.random.default_rng(seed)
    roots = np.stack([rng.uniform(-W / 2, W / 2, n_strands), np.zeros(n_strands), rng.uniform(-D / 2, D / 2, n_strands)], 1)
    t = np.linspace(0, L, n_pts)
    P = roots[:, None, :] + t[None, :, None] * np.array([0, 1.0, 0])[None, None, :]
    normals = np.tile(np.array([0, 1.0, 0]), (n_strands, 1))
    return P.astype(np.float32), normals.astype(np.float32)

def furball(n_strands=3000, n_pts=12, R=1.0, L=0.4):
    i = np.arange(n_strands) + 0.5
    phi = np.arccos(1 - 2 * i / n_strands)
    th = math.pi * (1 + 5 ** 0.5) * i
    n = np.stack([np.cos(th) * np.sin(phi), np.cos(phi), np.sin(th) * np.sin(phi)], 1)
    t = np.linspace(0, L, n_pts)
    P = R * n[:, None, :] + t[None, :, None] * n[:, None, :]
    return P.astype(np.float32), n.astype(np.float32)

def write_ply(path, P):
    S, n, _ = P.shape
    with open(path, 'w') as f:
        f.write('ply\nformat ascii 1.0\n')
        f.write(f'element vertex {S*n}\nproperty float x\nproperty float y\nproperty float z\n')
        f.write(f'element strand {S}\nproperty ushort nsegs\nend_header\n')
        for p in P.reshape(-1, 3):
            f.write(f'{p[0]:.6f} {p[1]:.6f} {p[2]:.6f}\n')
        for s in range(S):
            f.write(f'{n-1}\n')

def read_ply(path):
    with open(path, 'rb') as f:
        data = f.read()
    hdr_end = data.index(b'end_header') + len(b'end_header\n')
    hdr = data[:hdr_end].decode()
    lines = hdr.splitlines()
    assert 'ascii' in hdr or 'binary_little_endian' in hdr, hdr
    # parse elements
    elems = []
    for ln in lines:
        t = ln.split()
        if not t: continue
        if t[0] == 'element': elems.append([t[1], int(t[2]), []])
        elif t[0] == 'property':
            if t[1] == 'list': elems[-1][2].append(('list', t[2], t[3], t[4]))
            else: elems[-1][2].append((t[1], t[2]))
    body = data[hdr_end:]
    if 'ascii' in hdr:
        toks = body.split(); pos = 0; out = {}
        for name, cnt, props in elems:
            rows = []
            for _ in range(cnt):
                row = []
                for pr in props:
                    if pr[0] == 'list':
                        k = int(toks[pos]); pos += 1
                        row.append([float(x) for x in toks[pos:pos + k]]); pos += k
                    else:
                        row.append(float(toks[pos])); pos += 1
                rows.append(row)
            out[name] = (props, rows)
    else:
        tm = {'float': 'f4', 'float32': 'f4', 'double': 'f8', 'uchar': 'u1', 'uint8': 'u1', 'ushort': 'u2', 'uint16': 'u2',
              'int': 'i4', 'int32': 'i4', 'uint': 'u4', 'uint32': 'u4', 'char': 'i1', 'short': 'i2', 'int16': 'i2'}
        pos = 0; out = {}
        for name, cnt, props in elems:
            assert all(p[0] != 'list' for p in props), 'list props unsupported'
            dt = np.dtype([(p[1], '<' + tm[p[0]]) for p in props])
            arr = np.frombuffer(body, dtype=dt, count=cnt, offset=pos); pos += dt.itemsize * cnt
            out[name] = (props, arr)
    v = out['vertex']
    if isinstance(v[1], np.ndarray):
        xyz = np.stack([v[1]['x'], v[1]['y'], v[1]['z']], 1).astype(np.float32)
    else:
        names = [p[-1] for p in v[0]]
        a = np.array(v[1]); xyz = a[:, [names.index('x'), names.index('y'), names.index('z')]].astype(np.float32)
    s = out['strand']
    if isinstance(s[1], np.ndarray):
        nm = s[0][0][1]; counts = s[1][nm].astype(int)
    else:
        counts = np.array([r[0] for r in s[1]], dtype=int)
    if s[0][0][1] == 'nsegs': counts = counts + 1
    n = counts[0]
    assert (counts == n).all()
    return xyz.reshape(len(counts), n, 3)

# ---------------------------------------------------------------- field
def build_field(P0, rho, mode, k=8, radius=None, kmax=48, seed=0):
    """P0: (S,n,3) tensor. Samples o = subset of control points (uniform stride rho,
    roots excluded from nothing). mode: 'strand' (k nearest samples on own strand),
    'knn' (k nearest anywhere), 'radius' (all samples within radius, up to kmax nearest).
    Cubic kernel phi = (1 - r/h)^3, normalised (Shepard)."""
    S, n, _ = P0.shape
    N = S * n
    flat = P0.reshape(N, 3)
    gi = torch.arange(N)
    take = torch.floor((gi + 1) * rho + 0.5) > torch.floor(gi * rho + 0.5)
    sidx = gi[take]
    O = flat[sidx]
    strand_of_sample = sidx // n
    M = O.shape[0]
    if mode == 'strand':
        idx_all = torch.zeros(N, k, dtype=torch.long); w_all = torch.zeros(N, k)
        for s in range(S):
            js = torch.nonzero(strand_of_sample == s).flatten()
            pts = flat[s * n:(s + 1) * n]
            d = torch.cdist(pts, O[js])
            kk = min(k + 1, js.numel())
            dv, di = d.topk(kk, largest=False)
            h = dv[:, -1:] if js.numel() > k else 2 * dv[:, -1:]
            h = torch.maximum(h, dv[:, :min(k, kk)].max(1, keepdim=True).values * (1 + 1e-6)) + 1e-12
            kk2 = min(k, js.numel())
            phi = (1 - dv[:, :kk2] / h).clamp(min=0) ** 3
            phi = phi / phi.sum(1, keepdim=True).clamp(min=1e-12)
            idx_all[s * n:(s + 1) * n, :kk2] = js[di[:, :kk2]]
            w_all[s * n:(s + 1) * n, :kk2] = phi
        return O, idx_all, w_all
    K = k if mode == 'knn' else kmax
    idx_all = torch.zeros(N, K, dtype=torch.long); w_all = torch.zeros(N, K)
    ch = 2048
    for a in range(0, N, ch):
        d = torch.cdist(flat[a:a + ch], O)
        dv, di = d.topk(K + 1, largest=False)
        if mode == 'knn':
            h = dv[:, -1:] + 1e-12
        else:
            h = torch.full_like(dv[:, -1:], radius)
        phi = (1 - dv[:, :K] / h).clamp(min=0) ** 3
        phi = phi / phi.sum(1, keepdim=True).clamp(min=1e-12)
        idx_all[a:a + ch] = di[:, :K]
        w_all[a:a + ch] = phi
    return O, idx_all, w_all

def transport(P0, V, idx, w):
    S, n, _ = P0.shape
    disp = (w[..., None] * V[idx]).sum(1)
    return P0 + disp.reshape(S, n, 3)

def length_preserve(P, rest_len, P0):
    """root pinned; each segment projected to its rest length, root to tip."""
    pts = [P0[:, 0]]
    for i in range(1, P.shape[1]):
        d = P[:, i] - pts[-1]
        d = d / d.norm(dim=1, keepdim=True).clamp(min=1e-9)
        pts.append(pts[-1] + rest_len[:, i - 1:i] * d)
    return torch.stack(pts, 1)

# ---------------------------------------------------------------- camera + render
class Cam:
    def __init__(self, center, R, az_deg, el_deg, size, dist_factor=3.0, base_el=0.0):
        az = math.radians(az_deg); el = math.radians(el_deg + base_el)
        d = dist_factor * R
        fwd_dir = torch.tensor([math.cos(el) * math.sin(az), math.sin(el), math.cos(el) * math.cos(az)])
        self.eye = center + d * fwd_dir
        f = (center - self.eye); f = f / f.norm()
        up = torch.tensor([0.0, 1.0, 0.0])
        r = torch.linalg.cross(f, up); r = r / r.norm()
        u = torch.linalg.cross(r, f)
        self.Rm = torch.stack([r, u, f], 0)  # rows
        half = math.asin(min(0.999, R / d))
        self.focal = (size / 2) / math.tan(half)
        self.size = size
        self.view_dir = fwd_dir  # from center to eye

    def project(self, X):
        Xc = (X - self.eye) @ self.Rm.t()
        z = Xc[:, 2].clamp(min=1e-3)
        x = self.focal * Xc[:, 0] / z + self.size / 2
        y = -self.focal * Xc[:, 1] / z + self.size / 2
        return x, y, z

def render(P, cam, sigma_px=0.7, sub=None, vis=None, root_col=0.2, tip_col=1.0, tip_alpha=0.15):
    """Soft differentiable strand renderer: each segment sampled at sub points,
    isotropic Gaussian splats (sigma_px), additive density; shading dark root ->
    bright tip, opacity 1 -> tip_alpha. Composite: cov = 1-exp(-sum w a),
    colour = sum w a c / sum w a. Black background. vis: (S,) float mask."""
    S, n, _ = P.shape
    H = W = cam.size
    # sub-sampling along the strand (linear)
    if sub is None:
        with torch.no_grad():
            x, y, _ = cam.project(P.detach().reshape(-1, 3))
            x = x.reshape(S, n); y = y.reshape(S, n)
            L = torch.hypot(x[:, 1:] - x[:, :-1], y[:, 1:] - y[:, :-1]).max().item()
        sub = max(2, min(24, int(math.ceil(L / 1.0))))
    t = torch.linspace(0, 1, sub + 1)[:-1]
    A = P[:, :-1]; B = P[:, 1:]
    Q = A[:, :, None, :] * (1 - t)[None, None, :, None] + B[:, :, None, :] * t[None, None, :, None]
    Q = torch.cat([Q.reshape(S, -1, 3), P[:, -1:]], 1)  # (S, m, 3)
    m = Q.shape[1]
    s_par = torch.linspace(0, 1, m)
    col = (root_col + (tip_col - root_col) * s_par)[None].expand(S, m)
    alp = (1.0 + (tip_alpha - 1.0) * s_par)[None].expand(S, m)
    if vis is not None:
        alp = alp * vis[:, None]
    x, y, z = cam.project(Q.reshape(-1, 3))
    col = col.reshape(-1); alp = alp.reshape(-1)
    keep = alp > 0
    x, y, col, alp = x[keep], y[keep], col[keep], alp[keep]
    x0 = torch.floor(x.detach()).long(); y0 = torch.floor(y.detach()).long()
    img_a = torch.zeros(H * W); img_c = torch.zeros(H * W)
    r = int(math.ceil(2.5 * sigma_px))
    for oy in range(-r + 1, r + 1):
        for ox in range(-r + 1, r + 1):
            px = x0 + ox; py = y0 + oy
            ok = (px >= 0) & (px < W) & (py >= 0) & (py < H)
            dx = (px.float() + 0.5) - x; dy = (py.float() + 0.5) - y
            wgt = torch.exp(-(dx * dx + dy * dy) / (2 * sigma_px ** 2)) * alp
            wgt = wgt[ok]; lin = (py * W + px)[ok]
            img_a = img_a.index_add(0, lin, wgt)
            img_c = img_c.index_add(0, lin, wgt * col[ok])
    img_a = img_a.reshape(H, W); img_c = img_c.reshape(H, W)
    cov = 1 - torch.exp(-img_a)
    return cov * img_c / (img_a + 1e-6)

def to_png(img, path):
    a = img.detach().clamp(0, 1).numpy()
    Image.fromarray((a * 255).astype(np.uint8)).save(path)
