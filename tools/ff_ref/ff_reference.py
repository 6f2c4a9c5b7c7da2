#!/usr/bin/env python3
"""An independent PyTorch reference of the volumetric paper's feed-forward
training (Sec. 4, Fig. 9, Sec. 5.1), written from the paper, to tell a
limit of the method from a fault of nst3d's implementation.

Two arms on the same frame, the same painting and the same random views:
  net  the Fig. 9 network (conv 5^3 s2, conv 3^3 s2, four conv 3^3, two
       [trilinear x2, conv 3^3], conv 3^3; LeakyReLU 0.01), density mode
       d* = d (1 + tanh o) (eq. 5's bounded scale, s in [0, 2]); Adam under
       OneCycle 5e-6 -> 1e-4, gradient norm clipped at 1, batch 1
  opt  eq. 5 optimised directly: a free scale s per voxel of the frame,
       clamped to [0, 2] after each Adam step (the optimisation the network
       stands in for, seen from the same random views)
Each step draws a P^3 patch at a random place of the frame, rotated by
theta in +-180 deg about x and phi in +-90 deg about y and mirrored half the
time (Sec. 5.1), renders it along a random axis of the patch with the
transmittance march I = sum d tau (gamma = 8/P, exposure gamma), 2x bilinear,
grey to RGB, and scores VGG-19 Gram matrices (relu1_1..relu4_1, the
normalised VGG-19 nst3d uses) against the painting at --style-scale, over
two octaves (the patch box-filtered 2x, gamma and exposure doubled).

--conserve adds nst3d's choice (the patch's total density kept, ln(k)^2
pinned), off by default: the paper has neither.

--train-frames draws each step's patch from a frame picked at random among
FRAME and these (each normalised to [0, 1] by its own peak, as nst3d's
training); the stylized output is FRAME's. --minutes replaces --steps: the
first 20 steps are timed at the schedule's starting rate and the OneCycle
schedule is sized to what fits in the rest. --device cuda runs it on a GPU.

Writes OUT.npy: the stylized frame (same shape as the input), OUT.pt (net:
the state dict, also every --save-every seconds while training) and
OUT.log.csv: step, loss, seconds.

  ff_reference.py FRAME.npz STYLE.jpg OUT --arm net --steps 1500 --patch 48
"""
import argparse, math, os, sys, time
import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F
from PIL import Image

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "strand_ref"))
import common  # noqa: E402
from common import vgg_feats, gram  # noqa: E402  (the normalised VGG-19 loader)


class FeedForward(nn.Module):
    def __init__(self, c=16, out=1):
        super().__init__()
        self.e1 = nn.Conv3d(1, c, 5, stride=2, padding=2)
        self.e2 = nn.Conv3d(c, 2 * c, 3, stride=2, padding=1)
        self.mid = nn.ModuleList([nn.Conv3d(2 * c, 2 * c, 3, padding=1) for _ in range(4)])
        self.d1 = nn.Conv3d(2 * c, c, 3, padding=1)
        self.d2 = nn.Conv3d(c, c, 3, padding=1)
        self.last = nn.Conv3d(c, out, 3, padding=1)

    def forward(self, d):
        a = lambda x: F.leaky_relu(x, 0.01)
        x = a(self.e2(a(self.e1(d))))
        for m in self.mid:
            x = a(m(x))
        up = lambda x: F.interpolate(x, scale_factor=2, mode="trilinear", align_corners=False)
        x = a(self.d2(up(a(self.d1(up(x))))))
        return self.last(x)


def rotation(theta, phi, mirror):
    # Built on the CPU; patch_grid moves it to the frame's device.
    cx, sx, cy, sy = math.cos(theta), math.sin(theta), math.cos(phi), math.sin(phi)
    rx = torch.tensor([[1, 0, 0], [0, cx, -sx], [0, sx, cx]], dtype=torch.float32)
    ry = torch.tensor([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]], dtype=torch.float32)
    r = ry @ rx
    return r @ torch.diag(torch.tensor([-1.0, 1.0, 1.0])) if mirror else r


def patch_grid(shape_zyx, centre_xyz, r, p):
    """grid_sample coordinates of a p^3 patch centred at centre (voxels, x y z), rotated by r."""
    dev = centre_xyz.device
    u = torch.arange(p, dtype=torch.float32, device=dev) - (p - 1) / 2
    zz, yy, xx = torch.meshgrid(u, u, u, indexing="ij")
    local = torch.stack([xx, yy, zz], -1)  # (p, p, p, 3) as x y z
    world = local @ r.t().to(dev) + centre_xyz
    size = torch.tensor([shape_zyx[2], shape_zyx[1], shape_zyx[0]], dtype=torch.float32, device=dev)
    return (2 * world / (size - 1) - 1)[None]


def render(d, gamma, exposure):
    """d: (depth, h, w); the march of eq. 6 with slice 0 nearest the camera."""
    tau = torch.exp(-gamma * (torch.cumsum(d, 0) - d))
    return exposure * (d * tau).sum(0)


def style_loss(img, targets):
    img = F.interpolate(img[None, None], scale_factor=2, mode="bilinear", align_corners=False)[0, 0]
    return sum(F.mse_loss(gram(f), t) for f, t in zip(vgg_feats(img), targets))


def patch_loss(d, axis, gamma, targets, octaves=2):
    total = 0.0
    for k in range(octaves):
        v = d.movedim(axis, 0)
        total = total + style_loss(render(v, gamma * 2 ** k, gamma * 2 ** k), targets)
        if k + 1 < octaves:
            d = F.avg_pool3d(d[None, None], 2)[0, 0]
    return total


def load_frame(path):
    """An npz of vdb_npz.py as (z, y, x) in [0, 1], and its peak."""
    dens = np.load(path)["density"]  # [x, y, z]
    scale = float(dens.max())
    return torch.from_numpy(np.ascontiguousarray(dens.transpose(2, 1, 0)) / scale).float(), scale


def style_targets(path, scale):
    im = Image.open(path).convert("RGB")
    im = im.resize((max(1, round(im.width * scale)), max(1, round(im.height * scale))), Image.BICUBIC)
    a = np.asarray(im, np.float32) / 255.0
    grey = torch.from_numpy(0.299 * a[..., 0] + 0.587 * a[..., 1] + 0.114 * a[..., 2])
    grey = grey.to(next(common.vgg().parameters()).device)
    with torch.no_grad():
        return [gram(f) for f in vgg_feats(grey)]


def pad4(x):
    """(D, H, W) padded at the far side to multiples of 4 (the network's stride)."""
    pads = [(-n) % 4 for n in x.shape]
    return F.pad(x, (0, pads[2], 0, pads[1], 0, pads[0]))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("frame")
    ap.add_argument("style")
    ap.add_argument("out")
    ap.add_argument("--arm", choices=["net", "opt"], default="net")
    ap.add_argument("--steps", type=int, default=1500)
    ap.add_argument("--patch", type=int, default=48)
    ap.add_argument("--style-scale", type=float, default=0.5)
    ap.add_argument("--lr", type=float, default=None, help="net: OneCycle peak (1e-4); opt: Adam rate (0.02)")
    ap.add_argument("--channels", type=int, default=16)
    ap.add_argument("--conserve", action="store_true")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--train-frames", nargs="*", default=[])
    ap.add_argument("--minutes", type=float, default=None)
    ap.add_argument("--save-every", type=float, default=60.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--gamma", default="patch",
                    help="absorption of the training pictures: patch (8/P, nst3d's), frame (each drawn "
                         "frame's automatic one: its densest axis ray gets optical depth 3) or a number")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    torch.manual_seed(a.seed)
    if a.arm == "opt" and a.train_frames:
        sys.exit("--arm opt optimises FRAME's own voxels: it takes no --train-frames")
    dev = torch.device(a.device)
    common.vgg().to(dev)
    d, scale = load_frame(a.frame)
    pool = [d.to(dev)] + [load_frame(f)[0].to(dev) for f in a.train_frames]
    targets = [t.to(dev) for t in style_targets(a.style, a.style_scale)]
    p = a.patch
    if a.gamma == "patch":
        gammas = [8.0 / p] * len(pool)
    elif a.gamma == "frame":  # each frame's own, as the judge and the optimisation draw it
        gammas = [3.0 / max(f.sum(i).max().item() for i in range(3)) for f in pool]
    else:
        gammas = [float(a.gamma)] * len(pool)
    gamma = gammas[0]
    print(f"gamma {gamma:.4f}", flush=True)
    g = torch.Generator().manual_seed(a.seed + 1)
    rnd = lambda: torch.rand(1, generator=g).item()
    schedule = lambda total: torch.optim.lr_scheduler.OneCycleLR(
        opt, max_lr=a.lr or 1e-4, total_steps=max(total, 2), div_factor=20.0)
    timed = 20 if a.minutes else 0  # steps at the starting rate, timed to size the schedule
    if a.arm == "net":
        net = FeedForward(a.channels).to(dev)
        params = list(net.parameters())
        opt = torch.optim.Adam(params, lr=(a.lr or 1e-4) / 20.0)
        sched = None if timed else schedule(a.steps)
    else:
        s = torch.ones_like(pool[0], requires_grad=True)
        params = [s]
        opt = torch.optim.Adam(params, lr=a.lr or 0.02)
        sched = None
    log = open(a.out + ".log.csv", "w")
    t0 = saved = time.time()
    steps = a.steps if not a.minutes else 1 << 62
    step = 0
    while step < steps:
        if timed and step == timed and a.arm == "net":
            per = (time.time() - t0) / timed
            steps = timed + int(0.97 * (a.minutes * 60 - (time.time() - t0)) / per)
            sched = schedule(steps - timed)
            print(f"{per * 1e3:.1f} ms a step: {steps} steps", flush=True)
        which = int(rnd() * len(pool)) % len(pool)
        d, gamma = pool[which], gammas[which]
        hi = torch.tensor([d.shape[2] - 1.0, d.shape[1] - 1.0, d.shape[0] - 1.0])
        centre = (hi * torch.tensor([rnd(), rnd(), rnd()])).to(dev)
        r = rotation((2 * rnd() - 1) * math.pi, (rnd() - 0.5) * math.pi, rnd() < 0.5)
        axis = int(rnd() * 3) % 3
        grid = patch_grid(d.shape, centre, r, p)
        step += 1
        opt.zero_grad()
        if a.arm == "net":
            patch = F.grid_sample(d[None, None], grid, align_corners=True)[0, 0]
            styl = patch * (1 + torch.tanh(net(patch[None, None])[0, 0]))
            pin = 0.0
            if a.conserve:
                k = patch.sum() / styl.sum().clamp(min=1e-12)
                styl = styl * k
                pin = 100 * torch.log(k) ** 2
        else:
            styl = F.grid_sample((d * s)[None, None], grid, align_corners=True)[0, 0]
            pin = 0.0
        if styl.sum() <= 1e-6:
            continue  # an empty patch: no picture to score
        loss = patch_loss(styl, axis, gamma, targets) + pin
        loss.backward()
        if a.arm == "net":
            torch.nn.utils.clip_grad_norm_(params, 1.0)
        opt.step()
        if sched:
            sched.step()
        elif a.arm == "opt":
            with torch.no_grad():
                s.clamp_(0.0, 2.0)
        log.write(f"{step},{loss.item():.6g},{time.time() - t0:.2f}\n")
        if step % 50 == 0:
            log.flush()
            print(f"step {step} loss {loss.item():.4g} {time.time() - t0:.0f}s", flush=True)
        if a.arm == "net" and time.time() - saved > a.save_every:
            save_net(net, a.out + ".pt")
            saved = time.time()
    d = pool[0]
    with torch.no_grad():
        if a.arm == "net":
            x = pad4(d)
            out = (x * (1 + torch.tanh(net(x[None, None])[0, 0])))[: d.shape[0], : d.shape[1], : d.shape[2]]
            out = out * (d.sum() / out.sum())  # each frame keeps its total, as nst3d's inference
            save_net(net, a.out + ".pt")
        else:
            out = d * s
    np.save(a.out + ".npy", (out.cpu().numpy() * scale).transpose(2, 1, 0).astype(np.float32))


def save_net(net, path):
    """The state dict on the CPU, written to a temporary name and renamed."""
    torch.save({k: v.detach().cpu() for k, v in net.state_dict().items()}, path + ".tmp")
    os.replace(path + ".tmp", path)


if __name__ == "__main__":
    main()
