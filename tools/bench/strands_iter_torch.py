#!/usr/bin/env python3
"""PyTorch peer of `nst3d bench strands-iter`: one iteration of strand style
transfer (papers/strand-style-transfer.txt, Alg. 1 without its temporal
lines) on the CPU, written with torch ops and autograd the way the paper's
authors would write it, fed the exact inputs nst3d used.

Inputs: the directory `nst3d bench strands-iter --dump DIR` writes (rest
points, strand offsets, the RBF matrix W as COO, root normals, each rest
point's closest head point and outward direction, camera, strand look,
constraint and AdamW settings, the view's matched NNST targets, the style
hyper-columns and nst3d's render at v = 0).

    python3 tools/bench/strands_iter_torch.py DIR   (run by tools/bench_strands_vs_torch.sh)

One timed iteration, as nst3d's `pipeline::iteration`:
  transport    p' = p + W v (torch.sparse CSR matmul, v is the leaf), roots pinned;
  constraints  differentiated by autograd, as nst3d's ConstraintTape does by hand:
               length preservation root to tip (every segment keeps its deformed
               direction and gets its rest length: a cumulative sum along the strand,
               float64), then the collision projection of eq. 12 with tau, kappa,
               then nst3d's extra hard passes (tau * 0.02, kappa = 1) alternating
               with length preservation until segments are within 0.1 %, at most
               8 passes in all. No BVH: a point's signed distance is measured to
               the tangent plane at its rest position's closest head point (dumped
               by nst3d), and it is pushed along that plane's normal (held fixed, as
               nst3d's backward holds n fixed). nst3d queries the BVH for the exact
               closest point at every pass, so this stage does less work here;
  render       eq. 6-7 as crates/splat and tools/fixtures/splat_reference.py: one
               cylindrical Gaussian per segment of the strands whose root faces the
               camera, EWA projection (float64), 3-sigma truncated shifted footprint,
               alpha clamp 0.99, front-to-back compositing with early stop at
               T < 1e-4. Instead of nst3d's tiles, every (pixel, Gaussian) pair inside
               a Gaussian's 3-sigma bounding box is listed, pairs with q >= 9 are
               dropped, pairs are stably sorted by pixel (so each pixel's list stays
               in depth order) and the transmittance is a segmented cumulative sum of
               log(1 - alpha) (float64). Same image as eq. 7 (checked against
               nst3d's render at v = 0 below);
  VGG-19       conv1_1 .. relu4_1 of ~/.cache/nst3d/vgg_normalised.pth (Gatys: 1x1
               input conv, reflection padding, ceil-mode pooling), taps relu1_1,
               relu2_1, relu3_1, relu4_1;
  NNST loss    hyper-columns (each layer / its channels, bilinear align_corners=True
               to a quarter of the render, concatenated), mean over columns of the
               squared L2 distance to the dumped targets (eq. 3);
  backward     autograd to v; AdamW step (torch.optim.AdamW, same settings).
The view's match (eq. 2: centred cosine nearest neighbour against the style
columns) is done once, before the timed iterations, and timed on its own.

Prints the iteration-0 loss next to nst3d's, a stage breakdown (forward stages
timed inside the autograd forward; the backward is one autograd call), CPU time,
and last `torch_ms_per_iter <median>`.
"""
import argparse
import json
import math
import os
import pathlib
import resource
import statistics
import time
import warnings

import numpy as np
import torch
import torch.nn.functional as F

CUTOFF_Q, MAX_ALPHA, MIN_T = 9.0, 0.99, 1e-4
E9 = math.exp(-0.5 * CUTOFF_Q)
# State-dict keys of conv1_1 .. conv4_1 in the Gatys normalised VGG; pools follow conv1_2, conv2_2, conv3_4.
CONV_KEYS = [2, 5, 9, 12, 16, 19, 22, 25, 29]
TAPS = {0, 2, 4, 8}
POOL_AFTER = {1, 3, 7}


class Scene:
    def __init__(self, d):
        ld = lambda n: torch.from_numpy(np.load(d / n))
        self.meta = json.loads((d / "meta.json").read_text())
        self.rest = ld("rest.npy")
        self.undeformed = ld("undeformed.npy")
        offsets = np.load(d / "offsets.npy")
        n = np.diff(offsets)
        if not (n == n[0]).all():
            raise SystemExit("strands of different lengths; this peer expects the preset's fixed point count")
        self.S, self.n = len(n), int(n[0])
        self.offsets = torch.from_numpy(offsets)
        rows, cols, vals = ld("rbf_rows.npy"), ld("rbf_cols.npy"), ld("rbf_vals.npy")
        P, Ns = self.rest.shape[0], self.meta["samples"]
        self.W = torch.sparse_coo_tensor(torch.stack([rows, cols]), vals, (P, Ns)).coalesce().to_sparse_csr()
        self.root_normals = ld("root_normals.npy")
        self.closest, self.outward = ld("closest.npy"), ld("outward.npy")
        self.targets = ld("targets.npy")
        self.style_columns = ld("style_columns.npy")
        self.render0 = ld("render0.npy")
        self.grad0 = ld("grad0.npy") if (d / "grad0.npy").exists() else None
        self.is_root = torch.zeros(P, dtype=torch.bool)
        self.is_root[self.offsets[:-1]] = True
        r = self.rest.double().view(self.S, self.n, 3)
        self.rest_dir = r[:, 1:] - r[:, :-1]
        self.rest_len = self.rest_dir.norm(dim=2, keepdim=True)
        self.rest_dir = self.rest_dir / self.rest_len.clamp_min(1e-30)


def preserve_lengths(sc, x):
    """Root to tip: segment k keeps the deformed direction, gets the rest length."""
    p = x.double().view(sc.S, sc.n, 3)
    d = p[:, 1:] - p[:, :-1]
    nd = d.norm(dim=2, keepdim=True)
    d = torch.where(nd > 1e-30, d / nd.clamp_min(1e-30), sc.rest_dir)
    out = torch.cat([p[:, :1], p[:, :1] + torch.cumsum(sc.rest_len * d, dim=1)], 1)
    return out.view(-1, 3).float()


def project_collisions(sc, x, tau, kappa):
    s = ((x - sc.closest) * sc.outward).sum(1)
    hit = (s < tau) & ~sc.is_root
    push = torch.where(s < 0, -s + kappa * tau, kappa * (tau - s)) * hit
    return x + sc.outward * push[:, None]


def max_segment_error(sc, x):
    p = x.view(sc.S, sc.n, 3)
    l = (p[:, 1:] - p[:, :-1]).norm(dim=2, keepdim=True)
    return float(((l.double() - sc.rest_len).abs() / sc.rest_len.clamp_min(1e-30)).max())


def constrain(sc, x):
    """nst3d's `enforce`, differentiated by autograd (the pass count is data-dependent, not differentiated)."""
    c = sc.meta["collision"]
    y = project_collisions(sc, preserve_lengths(sc, x), c["tau"], c["kappa"])
    for _ in range(1, c["passes"]):
        if max_segment_error(sc, y.detach()) < c["segment_tolerance"]:
            break
        y = project_collisions(sc, preserve_lengths(sc, y), c["tau"] * c["hard_tau_fraction"], 1.0)
    return y


def render(sc, x):
    cam, st = sc.meta["camera"], sc.meta["style"]
    Wd, Hd = cam["width"], cam["height"]
    eye = torch.tensor(cam["eye"], dtype=torch.float32)
    n = sc.n
    # Visibility from the (pinned) roots, fixed per camera.
    roots = x.detach()[sc.offsets[:-1]]
    v = eye[None] - roots
    cosang = (sc.root_normals * v).sum(1) / (sc.root_normals.norm(dim=1) * v.norm(dim=1))
    vis = (cosang >= st["visibility_threshold"]).nonzero()[:, 0]
    k = torch.arange(n - 1)
    a_idx = (sc.offsets[vis][:, None] + k[None]).reshape(-1)
    u = ((k.float() + 0.5) / (n - 1)).repeat(len(vis))
    a, b = x[a_idx].double(), x[a_idx + 1].double()
    R = torch.tensor([cam["right"], cam["down"], cam["forward"]], dtype=torch.float32).double()
    t = (0.5 * (a + b) - eye.double()) @ R.T
    dc = (b - a) @ R.T
    dd = ((b - a) ** 2).sum(1)
    w2 = float(st["width"]) ** 2
    coef = st["length_sigma"] ** 2 - torch.where(dd > 1e-30, w2 / dd.clamp_min(1e-30), torch.zeros_like(dd))
    fx, fy = cam["fx"], cam["fy"]
    iz = 1.0 / t[:, 2]
    j00, j02, j11, j12 = fx * iz, -fx * t[:, 0] * iz * iz, fy * iz, -fy * t[:, 1] * iz * iz
    g0, g1 = j00 * dc[:, 0] + j02 * dc[:, 2], j11 * dc[:, 1] + j12 * dc[:, 2]
    c0 = w2 * (j00 * j00 + j02 * j02) + coef * g0 * g0 + st["dilation"]
    c1 = w2 * (j02 * j12) + coef * g0 * g1
    c2 = w2 * (j11 * j11 + j12 * j12) + coef * g1 * g1 + st["dilation"]
    det = c0 * c2 - c1 * c1
    mx, my = fx * t[:, 0] * iz + cam["cx"], fy * t[:, 1] * iz + cam["cy"]
    with torch.no_grad():
        rx, ry = 3.0 * c0.sqrt() * (1 + 1e-6), 3.0 * c2.sqrt() * (1 + 1e-6)
        x0 = (mx - rx - 0.5).ceil().clamp_min(0)
        x1 = (mx + rx - 0.5).floor().clamp_max(Wd - 1)
        y0 = (my - ry - 0.5).ceil().clamp_min(0)
        y1 = (my + ry - 0.5).floor().clamp_max(Hd - 1)
        keep = (t[:, 2] >= cam["near"]) & (det > 1e-12) & (c0 > 0) & (x0 <= x1) & (y0 <= y1)
        keep = keep.nonzero()[:, 0]
        order = keep[torch.sort(t[keep, 2].float(), stable=True).indices]
    mean_x, mean_y = mx[order].float(), my[order].float()
    ca, cb, cc = (c2 / det)[order].float(), (-c1 / det)[order].float(), (c0 / det)[order].float()
    uu = u[order]
    shade = st["root_shade"] + (st["tip_shade"] - st["root_shade"]) * uu
    opac = st["root_opacity"] + (st["tip_opacity"] - st["root_opacity"]) * uu
    with torch.no_grad():
        X0, Y0 = x0[order].long(), y0[order].long()
        w = x1[order].long() - X0 + 1
        cnt = w * (y1[order].long() - Y0 + 1)
        gid = torch.repeat_interleave(torch.arange(len(order)), cnt)
        local = torch.arange(int(cnt.sum())) - torch.repeat_interleave(torch.cumsum(cnt, 0) - cnt, cnt)
        px, py = X0[gid] + local % w[gid], Y0[gid] + local // w[gid]
        dx = px.float() + 0.5 - mean_x[gid]
        dy = py.float() + 0.5 - mean_y[gid]
        q = (ca[gid] * dx + 2.0 * cb[gid] * dy) * dx + cc[gid] * dy * dy
        inside = q < CUTOFF_Q
        gid, px, py = gid[inside], px[inside], py[inside]
        pix = py * Wd + px
        pix, srt = torch.sort(pix, stable=True)
        gid = gid[srt]
        _, counts = torch.unique_consecutive(pix, return_counts=True)
        start = torch.repeat_interleave(torch.cumsum(counts, 0) - counts, counts)
        pxf, pyf = (pix % Wd).float() + 0.5, (pix // Wd).float() + 0.5
    render.pairs = (int(cnt.sum()), len(pix))
    dx = pxf - mean_x[gid]
    dy = pyf - mean_y[gid]
    q = (ca[gid] * dx + 2.0 * cb[gid] * dy) * dx + cc[gid] * dy * dy
    alpha = (opac[gid] * (torch.exp(-0.5 * q) - E9) / (1 - E9)).clamp(max=MAX_ALPHA)
    l1m = torch.log1p(-alpha.double())
    excl = torch.cumsum(l1m, 0) - l1m
    T = torch.exp(excl - excl[start])
    live = (T >= MIN_T).detach()
    wgt = (alpha * T.float()) * live
    grey = torch.zeros(Hd * Wd).index_add(0, pix, wgt * shade[gid])
    t_final = torch.exp(torch.zeros(Hd * Wd, dtype=torch.float64).index_add(0, pix, l1m * live)).float()
    bg = torch.tensor(st["background"], dtype=torch.float32)
    # White strands: the three channels carry the same shaded grey.
    img = grey[None] + t_final[None] * bg[:, None]
    return img.view(1, 3, Hd, Wd)


def load_vgg(path):
    sd = torch.load(path, map_location="cpu")
    pre = (sd["0.weight"].float(), sd["0.bias"].float())
    convs = [(sd[f"{k}.weight"].float(), sd[f"{k}.bias"].float()) for k in CONV_KEYS]
    return pre, convs


def vgg_taps(vgg, img):
    pre, convs = vgg
    x = F.conv2d(img, *pre)
    taps = []
    for i, (w, b) in enumerate(convs):
        x = F.relu(F.conv2d(F.pad(x, (1, 1, 1, 1), mode="reflect"), w, b))
        if i in TAPS:
            taps.append(x)
        if i in POOL_AFTER:
            x = F.max_pool2d(x, 2, 2, ceil_mode=True)
    return taps


def hypercolumns(taps, grid, layer_weight):
    """Each layer times nst3d's weight (meta.json's `nnst_layer_weight`:
    1/sqrt(C) for the strand pipeline, 1/C as NNST wrote it), on the grid."""
    cols = []
    for f in taps:
        c = f.shape[1]
        f = f / (math.sqrt(c) if layer_weight == "inverse_sqrt_channels" else c)
        if tuple(f.shape[2:]) != grid:
            f = F.interpolate(f, size=grid, mode="bilinear", align_corners=True)
        cols.append(f[0])
    return torch.cat(cols, 0)


def match(content_cols, style_cols, block=2048):
    """Eq. 2: centred cosine nearest style column of every content column."""
    d = content_cols.shape[0]
    c = content_cols.reshape(d, -1)
    s = style_cols.reshape(d, -1)
    c = (c - c.mean(1, keepdim=True)).T.contiguous()
    s = s - s.mean(1, keepdim=True)
    s = s / s.norm(dim=0, keepdim=True).clamp_min(1e-4)
    idx = torch.cat([(c[i:i + block] @ s).argmax(1) for i in range(0, c.shape[0], block)])
    return style_cols.reshape(d, -1)[:, idx].reshape(content_cols.shape)


def main():
    warnings.filterwarnings("ignore", message="Sparse")
    ap = argparse.ArgumentParser()
    ap.add_argument("dump", type=pathlib.Path, help="directory from `nst3d bench strands-iter --dump`")
    ap.add_argument("--iters", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--weights", default=os.path.expanduser("~/.cache/nst3d/vgg_normalised.pth"))
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    sc = Scene(args.dump)
    vgg = load_vgg(args.weights)
    grid = tuple(sc.targets.shape[1:])
    weight = sc.meta["nnst_layer_weight"]  # a dump from before the field: rerun nst3d bench --dump
    m = sc.meta["adamw"]
    v = torch.zeros(sc.meta["samples"], 3, requires_grad=True)
    opt = torch.optim.AdamW([v], lr=m["lr"], betas=(m["beta1"], m["beta2"]), eps=m["eps"],
                            weight_decay=m["weight_decay"])

    # Sanity: the same groom, image and loss as nst3d at v = 0, and the match.
    with torch.no_grad():
        x0 = constrain(sc, torch.where(sc.is_root[:, None], sc.rest, sc.rest + sc.W @ v))
        img0 = render(sc, x0)
        t0 = time.perf_counter()
        feats0 = vgg_taps(vgg, img0)
        tgt = match(hypercolumns(feats0, grid, weight), sc.style_columns)
        match_ms = (time.perf_counter() - t0) * 1e3
    same = float((tgt == sc.targets).all(0).float().mean())
    print(f"max |points - nst3d's| at v=0: {float((x0 - sc.undeformed).abs().max()):.2e} "
          f"(groom extent {float(sc.rest.abs().max()):.0f})")
    print(f"max |render - nst3d's| at v=0: {float((img0[0] - sc.render0).abs().max()):.2e}; "
          f"(pixel, Gaussian) pairs {render.pairs[0]} in boxes, {render.pairs[1]} inside 3 sigma")
    print(f"match_ms {match_ms:.1f}  (once per view, not in the iteration; {100 * same:.2f} % of columns "
          "pick the same target as nst3d)")

    times, cpu, stages = [], [], []
    for it in range(args.iters + 1):
        c0, w0 = time.process_time(), time.perf_counter()
        lap = [w0]
        opt.zero_grad()
        x = torch.where(sc.is_root[:, None], sc.rest, sc.rest + sc.W @ v)
        lap.append(time.perf_counter())
        x = constrain(sc, x)
        lap.append(time.perf_counter())
        img = render(sc, x)
        lap.append(time.perf_counter())
        feats = vgg_taps(vgg, img)
        lap.append(time.perf_counter())
        loss = ((hypercolumns(feats, grid, weight) - sc.targets) ** 2).sum() / (grid[0] * grid[1])
        lap.append(time.perf_counter())
        loss.backward()
        lap.append(time.perf_counter())
        opt.step()
        lap.append(time.perf_counter())
        if it == 0:
            ref = sc.meta["nst3d_loss_iter0"]
            l0 = loss.item()
            print(f"loss_iter0 torch {l0:.6f} nst3d {ref:.6f} (relative difference {abs(l0 - ref) / ref:.1e})")
            if sc.grad0 is not None:
                # Autograd's gradient at v = 0 against nst3d's hand-written chain
                # (constraint tape, splat, VGG and field backwards).
                g, r = v.grad.detach().double().flatten(), sc.grad0.double().flatten()
                cos = float(g @ r / (g.norm() * r.norm()).clamp_min(1e-30))
                rel = float((g - r).norm() / r.norm().clamp_min(1e-30))
                print(f"grad_iter0 cosine {cos:.6f}, relative L2 difference {rel:.1e} "
                      f"(|torch| {float(g.norm()):.3e}, |nst3d| {float(r.norm()):.3e})")
        else:
            times.append((lap[-1] - w0) * 1e3)
            cpu.append((time.process_time() - c0) * 1e3)
            stages.append([(b - a) * 1e3 for a, b in zip(lap, lap[1:])])
    print(f"loss_last {loss.item():.6f}")
    names = ["transport", "constraints", "render", "vgg_forward", "nnst_loss", "backward(all)", "adamw"]
    for k, name in enumerate(names):
        print(f"stage_ms {name:<15} {statistics.median(s[k] for s in stages):.1f}")
    print("iteration_ms " + " ".join(f"{t:.1f}" for t in times))
    print(f"cpu_ms_per_iter {statistics.mean(cpu):.0f}")
    print(f"peak_rss_mb {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f}")
    print(f"torch_ms_per_iter {statistics.median(times):.1f}")


if __name__ == "__main__":
    main()
