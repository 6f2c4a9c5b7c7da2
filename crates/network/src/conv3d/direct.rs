//! The direct (implicit GEMM) convolution: the input is copied once into a
//! zero-padded layout whose rows are split into `stride` phases, so the
//! `stride · x + kx` voxels a row of outputs reads at one tap are
//! consecutive and every tap is one offset into the copy: no im2col. Vector
//! lanes run along x ([`super::kernels`]), so any channel count fits.
//!
//! - fp32: forward and the weight gradient on AVX-512 FMAs;
//! - bf16: the forward reads channel pairs (`u32` lanes) against packed
//!   weight pairs (`vdpbf16ps`), the weight gradient pairs of x positions.
//!
//! Results do not depend on the thread count: every output is one tile's
//! fixed-order sum, and the weight gradient sums fixed groups of positions
//! in order.

use nst3d_core::bf16::from_f32;
use rayon::prelude::*;

use super::kernels::{self, DwArgs, FwdArgs, VL};
use super::Conv3d;
use crate::volume::Volume;

/// Output rows of one forward task.
const ROWS_PER_TASK: usize = 8;
/// Vector positions per weight-gradient chunk (its operands stay in L1/L2).
const DW_CHUNK: usize = 48;
/// The weight gradient's positions are split into this many fixed groups,
/// so its summation order does not depend on threads.
const DW_GROUPS: usize = 16;
/// Fewest vector positions a weight-gradient group takes.
const MIN_GROUP: usize = 64;
/// Weight-gradient tile: output channels by `(channel, tap)` columns.
const NCO: usize = 4;
const NT: usize = 6;

/// The arithmetic of a direct convolution.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Arith {
    /// fp32 operands and sums.
    F32,
    /// bf16 operands, fp32 sums.
    Bf16,
}

/// A layer applied to an input size, and the padded, phase-split layout of
/// its input: element `(c, z, y, x)` (padded coordinates) at
/// `c · cs + (z · py + y) · r + (x % s) · h + x / s`.
struct Geom {
    s: usize,
    k: usize,
    p: usize,
    n: [usize; 3],
    o: [usize; 3],
    /// Phase length, row length (`s · h`), padded rows.
    h: usize,
    r: usize,
    py: usize,
    /// Channel stride.
    cs: usize,
}

impl Geom {
    /// The layout for vectors of `vl` consecutive outputs along x.
    fn new(l: &Conv3d, n: [usize; 3], vl: usize) -> Self {
        let (s, k, p) = (l.stride, l.k, l.pad);
        let o = l.out_dims(n);
        let h = (n[0] + 2 * p).div_ceil(s).max(o[0].next_multiple_of(vl) + (k - 1) / s);
        let (py, pz) = (n[1] + 2 * p, n[2] + 2 * p);
        Self { s, k, p, n, o, h, r: s * h, py, cs: pz * py * s * h }
    }

    /// One offset per tap, in the weight tensor's `(kz, ky, kx)` order.
    fn offs(&self) -> Vec<usize> {
        let k = self.k;
        (0..k * k * k)
            .map(|t| {
                let (kz, ky, kx) = (t / (k * k), t / k % k, t % k);
                (kz * self.py + ky) * self.r + (kx % self.s) * self.h + kx / self.s
            })
            .collect()
    }

    /// Where output row `(z, y)` reads at tap 0.
    fn base(&self, z: usize, y: usize) -> usize {
        (self.s * z * self.py + self.s * y) * self.r
    }

    /// Fills a copy of `x` in the padded layout, `per` channels to an
    /// element, in parallel over padded planes: `row(src rows, dst row)`
    /// writes one row of the volume (`per` source rows, `None` past the
    /// last channel) into the padded row.
    fn pack<T: Copy + Default + Send>(
        &self,
        x: &Volume,
        per: usize,
        row: impl Fn([Option<&[f32]>; 2], &mut [T]) + Sync,
    ) -> Vec<T> {
        let [nx, ny, nz] = self.n;
        let plane = self.py * self.r;
        let mut d = vec![T::default(); x.channels.div_ceil(per) * self.cs];
        d.par_chunks_mut(plane).enumerate().for_each(|(i, dst)| {
            let (c, zz) = (i / (self.cs / plane) * per, i % (self.cs / plane));
            if zz < self.p || zz >= self.p + nz {
                return;
            }
            let z = zz - self.p;
            for y in 0..ny {
                let src = std::array::from_fn(|j| {
                    (j < per && c + j < x.channels).then(|| &x.channel(c + j)[(z * ny + y) * nx..][..nx])
                });
                row(src, &mut dst[(y + self.p) * self.r..][..self.r]);
            }
        });
        d
    }

    /// Writes `f(i)` for every voxel `i` of a row of `n` at its place in
    /// the padded, phase-split row `dst`.
    #[inline(always)]
    fn place<T>(&self, n: usize, dst: &mut [T], f: impl Fn(usize) -> T) {
        if self.s == 1 {
            dst[self.p..][..n].iter_mut().enumerate().for_each(|(i, d)| *d = f(i));
            return;
        }
        for ph in 0..self.s {
            let base = self.p / self.s * self.s + ph;
            let first = if base < self.p { base + self.s } else { base };
            for xx in (first..self.p + n).step_by(self.s) {
                dst[ph * self.h + xx / self.s] = f(xx - self.p);
            }
        }
    }

    /// fp32 copy of `x`.
    fn pack_f32(&self, x: &Volume) -> Vec<f32> {
        self.pack(x, 1, |src, dst: &mut [f32]| {
            let src = src[0].expect("one channel per element");
            wide(|| self.place(src.len(), dst, |i| src[i]))
        })
    }

    /// bf16 copy of `x`, channels in pairs: lane `u32` = (channel `2c`, `2c + 1`).
    fn pack_pairs(&self, x: &Volume) -> Vec<u32> {
        self.pack(x, 2, |src, dst: &mut [u32]| {
            let a = src[0].expect("a first channel");
            wide(|| match src[1] {
                Some(b) => self.place(a.len(), dst, |i| from_f32(a[i]) as u32 | (from_f32(b[i]) as u32) << 16),
                None => self.place(a.len(), dst, |i| from_f32(a[i]) as u32),
            })
        })
    }

    /// bf16 copy of `x`, one channel after another.
    fn pack_bf16(&self, x: &Volume) -> Vec<u16> {
        self.pack(x, 1, |src, dst: &mut [u16]| {
            let src = src[0].expect("one channel per element");
            wide(|| self.place(src.len(), dst, |i| from_f32(src[i])))
        })
    }
}

/// Runs `f` compiled for AVX-512 where the CPU has it, so the conversion
/// loops inlined into it vectorise.
#[inline(always)]
fn wide<R>(f: impl FnOnce() -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    if kernels::unit().f32 {
        // SAFETY: the CPU has the enabled features (checked by `unit`).
        return unsafe { with_avx512(f) };
    }
    f()
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx2,fma")]
unsafe fn with_avx512<R>(f: impl FnOnce() -> R) -> R {
    f()
}

/// A raw pointer the forward's tasks write disjoint outputs through.
#[derive(Clone, Copy)]
struct Out(*mut f32);
// SAFETY: tasks write disjoint elements (each output belongs to one vector).
unsafe impl Send for Out {}
unsafe impl Sync for Out {}

/// One output vector: where its row reads (tap 0), where it writes, how
/// many of its lanes are inside the volume.
#[derive(Clone, Copy)]
struct Vector {
    base: usize,
    out: usize,
    len: usize,
}

/// `conv3d(x, W) + b` on the direct kernels.
pub fn forward(l: &Conv3d, arith: Arith, x: &Volume) -> Volume {
    let g = Geom::new(l, x.dims, VL);
    let mut y = Volume::zeros(l.cout, g.o);
    match (arith, l.cout) {
        (Arith::F32, c) if c >= 8 => run_fwd::<f32, 3, 8>(l, &g, x, &mut y),
        (Arith::F32, c) if c >= 4 => run_fwd::<f32, 6, 4>(l, &g, x, &mut y),
        (Arith::F32, _) => run_fwd::<f32, 12, 1>(l, &g, x, &mut y),
        (Arith::Bf16, c) if c >= 8 => run_fwd::<u32, 3, 8>(l, &g, x, &mut y),
        (Arith::Bf16, c) if c >= 4 => run_fwd::<u32, 6, 4>(l, &g, x, &mut y),
        (Arith::Bf16, _) => run_fwd::<u32, 12, 1>(l, &g, x, &mut y),
    }
    y
}

/// An element type of the forward: its packing and its tile kernel.
trait Lane: Copy + Send + Sync + Sized {
    /// Values packed together per lane (1 for fp32, 2 for bf16 pairs).
    const PER: usize;
    fn pack_input(g: &Geom, x: &Volume) -> Vec<Self>;
    fn pack_weight(a: f32, b: f32) -> Self;
    fn tile<const NV: usize, const NC: usize>(a: &FwdArgs<Self, NV>, out: &mut [f32]);
}

impl Lane for f32 {
    const PER: usize = 1;
    fn pack_input(g: &Geom, x: &Volume) -> Vec<f32> {
        g.pack_f32(x)
    }
    fn pack_weight(a: f32, _: f32) -> f32 {
        a
    }
    fn tile<const NV: usize, const NC: usize>(a: &FwdArgs<f32, NV>, out: &mut [f32]) {
        #[cfg(target_arch = "x86_64")]
        if kernels::unit().f32 {
            // SAFETY: the unit is present and checked; the driver keeps every read in bounds.
            return unsafe { kernels::fwd_f32_avx512::<NV, NC>(a, out) };
        }
        kernels::fwd_f32_scalar::<NV, NC>(a, out)
    }
}

impl Lane for u32 {
    const PER: usize = 2;
    fn pack_input(g: &Geom, x: &Volume) -> Vec<u32> {
        g.pack_pairs(x)
    }
    fn pack_weight(a: f32, b: f32) -> u32 {
        from_f32(a) as u32 | (from_f32(b) as u32) << 16
    }
    fn tile<const NV: usize, const NC: usize>(a: &FwdArgs<u32, NV>, out: &mut [f32]) {
        #[cfg(target_arch = "x86_64")]
        if kernels::unit().bf16 {
            // SAFETY: as for fp32.
            return unsafe { kernels::fwd_bf16_avx512::<NV, NC>(a, out) };
        }
        kernels::fwd_bf16_scalar::<NV, NC>(a, out)
    }
}

/// The weights as `[block of NC outputs][input (pair)][tap][NC]`, zero past
/// `cout` and past `cin`.
fn pack_weights<T: Lane, const NC: usize>(l: &Conv3d) -> Vec<T> {
    let k3 = l.k * l.k * l.k;
    let chans = l.cin.div_ceil(T::PER);
    let w = |co: usize, ci: usize, t: usize| {
        if co < l.cout && ci < l.cin {
            l.weight[(co * l.cin + ci) * k3 + t]
        } else {
            0.0
        }
    };
    let blocks = l.cout.div_ceil(NC);
    let mut out = Vec::with_capacity(blocks * chans * k3 * NC);
    for b in 0..blocks {
        for i in 0..chans {
            for t in 0..k3 {
                for c in 0..NC {
                    let co = b * NC + c;
                    out.push(T::pack_weight(w(co, i * T::PER, t), w(co, i * T::PER + 1, t)));
                }
            }
        }
    }
    out
}

/// Every output vector of row `(z, y)`.
fn row_vectors(g: &Geom, z: usize, y: usize) -> impl Iterator<Item = Vector> + '_ {
    let [ox, oy, _] = g.o;
    (0..ox.div_ceil(VL)).map(move |v| Vector {
        base: g.base(z, y) + v * VL,
        out: (z * oy + y) * ox + v * VL,
        len: VL.min(ox - v * VL),
    })
}

fn run_fwd<T: Lane, const NV: usize, const NC: usize>(l: &Conv3d, g: &Geom, x: &Volume, y: &mut Volume) {
    let inp = T::pack_input(g, x);
    let w = pack_weights::<T, NC>(l);
    let offs = g.offs();
    let chans = l.cin.div_ceil(T::PER);
    let [_, oy, oz] = g.o;
    let n_out = y.voxels();
    let out = Out(y.data.as_mut_ptr());
    let rows = oy * oz;
    (0..rows.div_ceil(ROWS_PER_TASK)).into_par_iter().for_each(|task| {
        let vecs: Vec<Vector> = (task * ROWS_PER_TASK..rows.min((task + 1) * ROWS_PER_TASK))
            .flat_map(|r| row_vectors(g, r / oy, r % oy))
            .collect();
        let mut acc = vec![0.0f32; NV * NC * VL];
        for tile in vecs.chunks(NV) {
            // A short last tile repeats its last vector (written twice, the same values).
            let bases = std::array::from_fn(|v| tile[v.min(tile.len() - 1)].base);
            for b in 0..l.cout.div_ceil(NC) {
                let a =
                    FwdArgs { inp: &inp, cs: g.cs, chans, offs: &offs, bases, w: &w[b * chans * offs.len() * NC..] };
                T::tile::<NV, NC>(&a, &mut acc);
                store(l, out, n_out, tile, b * NC, NC, &acc);
            }
        }
    });
}

/// Writes a tile's accumulators (`[v][c][lane]`) plus the bias into the
/// output channels `c0..c0 + nc` that exist.
fn store(l: &Conv3d, out: Out, n_out: usize, tile: &[Vector], c0: usize, nc: usize, acc: &[f32]) {
    for (v, vec) in tile.iter().enumerate() {
        for c in 0..nc.min(l.cout - c0) {
            let b = l.bias[c0 + c];
            let src = &acc[(v * nc + c) * VL..][..vec.len];
            // SAFETY: this vector's outputs are written by this task only, inside the volume.
            let dst = unsafe { std::slice::from_raw_parts_mut(out.0.add((c0 + c) * n_out + vec.out), vec.len) };
            dst.iter_mut().zip(src).for_each(|(d, s)| *d = s + b);
        }
    }
}

/// The weight gradient `dW[co][ci][t] = Σ_v grad_out[co][v] · x[ci][v at tap t]`
/// on the direct kernels.
pub fn weight_grad(l: &Conv3d, arith: Arith, x: &Volume, grad_out: &Volume) -> Vec<f32> {
    match arith {
        Arith::F32 => {
            let g = Geom::new(l, x.dims, VL);
            let inp = g.pack_f32(x);
            let (gp, gs, xs) = pad_rows(&g, grad_out, VL, |v| v);
            run_dw(l, &g, &gp, gs, xs, &inp, VL, |a: &DwArgs<f32, NCO, NT>, acc, lda| dw_f32(a, acc, lda))
        }
        Arith::Bf16 => {
            let g = Geom::new(l, x.dims, 2 * VL);
            let inp = g.pack_bf16(x);
            let (gp, gs, xs) = pad_rows(&g, grad_out, 2 * VL, from_f32);
            run_dw(l, &g, &gp, gs, xs, &inp, 2 * VL, |a: &DwArgs<u16, NCO, NT>, acc, lda| dw_bf16(a, acc, lda))
        }
    }
}

fn dw_f32(a: &DwArgs<f32, NCO, NT>, acc: &mut [f32], lda: usize) {
    #[cfg(target_arch = "x86_64")]
    if kernels::unit().f32 {
        // SAFETY: the unit is present and checked; the driver keeps every read in bounds.
        return unsafe { kernels::dw_f32_avx512(a, acc, lda) };
    }
    kernels::dw_f32_scalar(a, acc, lda)
}

fn dw_bf16(a: &DwArgs<u16, NCO, NT>, acc: &mut [f32], lda: usize) {
    #[cfg(target_arch = "x86_64")]
    if kernels::unit().bf16 {
        // SAFETY: as for fp32.
        return unsafe { kernels::dw_bf16_avx512(a, acc, lda) };
    }
    kernels::dw_bf16_scalar(a, acc, lda)
}

/// `grad_out` with rows padded with zeros to a multiple of `vl` and
/// channels to a multiple of [`NCO`]: the data, its channel stride and its
/// row length.
fn pad_rows<T: Copy + Default>(
    g: &Geom,
    grad_out: &Volume,
    vl: usize,
    conv: impl Fn(f32) -> T,
) -> (Vec<T>, usize, usize) {
    let [ox, oy, oz] = g.o;
    let xs = ox.next_multiple_of(vl);
    let gs = xs * oy * oz;
    let mut d = vec![T::default(); grad_out.channels.next_multiple_of(NCO) * gs];
    for c in 0..grad_out.channels {
        for (r, row) in grad_out.channel(c).chunks(ox).enumerate() {
            wide(|| d[c * gs + r * xs..][..ox].iter_mut().zip(row).for_each(|(a, b)| *a = conv(*b)));
        }
    }
    (d, gs, xs)
}

/// Sums the weight gradient over fixed groups of vector positions (`vl`
/// values each), in parallel, then the groups in order.
#[allow(clippy::too_many_arguments)]
fn run_dw<T: Sync>(
    l: &Conv3d,
    g: &Geom,
    gp: &[T],
    gs: usize,
    xs: usize,
    inp: &[T],
    vl: usize,
    tile: impl Fn(&DwArgs<T, NCO, NT>, &mut [f32], usize) + Sync,
) -> Vec<f32> {
    let [_, oy, oz] = g.o;
    let offs = g.offs();
    let k3 = offs.len();
    let cols = l.cin * k3;
    let (jp, cop) = (cols.next_multiple_of(NT), l.cout.next_multiple_of(NCO));
    // Column j = (ci, t); padding columns read offset 0 and are dropped.
    let ioffs: Vec<usize> = (0..jp).map(|j| if j < cols { j / k3 * g.cs + offs[j % k3] } else { 0 }).collect();
    let pos: Vec<(usize, usize)> = (0..oz * oy)
        .flat_map(|r| (0..xs / vl).map(move |v| (r * xs + v * vl, g.base(r / oy, r % oy) + v * vl)))
        .collect();
    let groups = (pos.len() / MIN_GROUP).clamp(1, DW_GROUPS);
    let per_group = pos.len().div_ceil(groups);
    let lda = jp * VL;
    let blocks = cop / NCO;
    // Task (group, block of NCO output channels) -> its [NCO][cols] sums.
    let partial: Vec<Vec<f32>> = (0..pos.len().div_ceil(per_group) * blocks)
        .into_par_iter()
        .map(|task| {
            let (group, cb) = (task / blocks, task % blocks);
            let mine = &pos[group * per_group..pos.len().min((group + 1) * per_group)];
            let mut acc = vec![0.0f32; NCO * lda];
            for chunk in mine.chunks(DW_CHUNK) {
                for jb in 0..jp / NT {
                    let a = DwArgs {
                        g: &gp[cb * NCO * gs..],
                        gs,
                        inp,
                        ioffs: std::array::from_fn(|j| ioffs[jb * NT + j]),
                        pos: chunk,
                    };
                    tile(&a, &mut acc[jb * NT * VL..], lda);
                }
            }
            acc.chunks(VL).map(|v| v.iter().sum::<f32>()).collect()
        })
        .collect();
    let mut dw = vec![0.0f32; l.cout * cols];
    for (task, sums) in partial.iter().enumerate() {
        let cb = task % blocks;
        for c in 0..NCO.min(l.cout.saturating_sub(cb * NCO)) {
            let row = &mut dw[(cb * NCO + c) * cols..][..cols];
            row.iter_mut().zip(&sums[c * jp..]).for_each(|(d, s)| *d += s);
        }
    }
    dw
}
