//! The direct (implicit GEMM) convolution: the input is copied once into a
//! zero-padded layout whose rows are split into `stride` phases, so the
//! `stride · x + kx` voxels a row of outputs reads at one tap are
//! consecutive and every tap is one offset into the copy: no im2col. Vector
//! lanes run along x ([`super::kernels`]), so any channel count fits.
//!
//! - fp32: forward and the weight gradient on AVX-512 FMAs, or AVX2 ones
//!   in register tiles a third the size (16 registers, not 32);
//! - bf16: the forward reads channel pairs (`u32` lanes) against packed
//!   weight pairs (`vdpbf16ps`), the weight gradient pairs of x positions.
//!
//! Results do not depend on the thread count: every output is one tile's
//! fixed-order sum, and the weight gradient sums fixed groups of positions
//! in order.

use nst3d_core::bf16::from_f32;
use rayon::prelude::*;

use super::kernels::{self, DwArgs, FwdArgs, Isa, VL};
use super::Conv3d;
use crate::activation::Act;
use crate::volume::Volume;

/// The weight gradient's positions are split into this many fixed groups,
/// so its summation order does not depend on threads.
const DW_GROUPS: usize = 16;
/// Fewest vector positions a weight-gradient group takes (a tile's fixed
/// costs amortise over them).
const DW_MIN_POS: usize = 256;

/// The arithmetic of a direct convolution.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Arith {
    /// fp32 operands and sums.
    F32,
    /// bf16 operands, fp32 sums.
    Bf16,
}

/// A layer applied to an input size, and the padded, phase-split layout of
/// its input, copied a few planes at a time (those one task reads, so the
/// copy stays in cache and is never a whole volume): element `(c, z, y, x)`
/// (padded coordinates, `z` counted from the copy's first plane) at
/// `c · cs + (z · py + y) · r + (x % s) · h + x / s`, `cs` the copy's planes
/// times `py · r`.
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
}

impl Geom {
    /// The layout for vectors of `vl` consecutive outputs along x.
    fn new(l: &Conv3d, n: [usize; 3], vl: usize) -> Self {
        let (s, k, p) = (l.stride, l.k, l.pad);
        let o = l.out_dims(n);
        let h = (n[0] + 2 * p).div_ceil(s).max(o[0].next_multiple_of(vl) + (k - 1) / s);
        Self { s, k, p, n, o, h, r: s * h, py: n[1] + 2 * p }
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

    /// Where output row `(z, y)` reads at tap 0, `z` counted from the
    /// output plane whose first input plane starts the copy.
    fn base(&self, z: usize, y: usize) -> usize {
        (self.s * z * self.py + self.s * y) * self.r
    }

    /// Copies padded planes `z0 .. z0 + n` of `x` into `buf`, `per`
    /// channels to an element: `row(src rows, dst row)` writes one row of
    /// the volume (`per` source rows, `None` past the last channel) into
    /// its padded row. Returns the channel stride. `buf` is reused between
    /// calls: padding is never written, so it stays zero; planes outside
    /// the volume are cleared.
    fn pack<T: Copy + Default>(
        &self,
        x: &Volume,
        (z0, n): (usize, usize),
        per: usize,
        buf: &mut Vec<T>,
        row: impl Fn([Option<&[f32]>; 2], &mut [T]),
    ) -> usize {
        let [nx, ny, nz] = self.n;
        let plane = self.py * self.r;
        let len = x.channels.div_ceil(per) * n * plane;
        if buf.len() != len {
            buf.clear();
            buf.resize(len, T::default());
        }
        for (slot, dst) in buf.chunks_mut(plane).enumerate() {
            let (c, zz) = (slot / n * per, z0 + slot % n);
            if zz < self.p || zz >= self.p + nz {
                dst.fill(T::default());
                continue;
            }
            let z = zz - self.p;
            for y in 0..ny {
                let src = std::array::from_fn(|j| {
                    (j < per && c + j < x.channels).then(|| &x.channel(c + j)[(z * ny + y) * nx..][..nx])
                });
                row(src, &mut dst[(y + self.p) * self.r..][..self.r]);
            }
        }
        n * plane
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

    /// fp32 copy of planes `zs` of `x`.
    fn pack_f32(&self, x: &Volume, zs: (usize, usize), buf: &mut Vec<f32>) -> usize {
        self.pack(x, zs, 1, buf, |src, dst: &mut [f32]| {
            let src = src[0].expect("one channel per element");
            match self.s {
                1 => dst[self.p..][..src.len()].copy_from_slice(src),
                _ => self.place(src.len(), dst, |i| src[i]),
            }
        })
    }

    /// bf16 copy of planes `zs` of `x`, channels in pairs: lane `u32` =
    /// (channel `2c`, `2c + 1`).
    fn pack_pairs(&self, x: &Volume, zs: (usize, usize), buf: &mut Vec<u32>) -> usize {
        self.pack(x, zs, 2, buf, |src, dst: &mut [u32]| {
            let (a, b) = (src[0].expect("a first channel"), src[1]);
            let pair = |i: usize| from_f32(a[i]) as u32 | b.map_or(0, |b| (from_f32(b[i]) as u32) << 16);
            match self.s {
                1 => pairs_row(a, b, &mut dst[self.p..][..a.len()]),
                _ => self.place(a.len(), dst, pair),
            }
        })
    }

    /// bf16 copy of planes `zs` of `x`, one channel after another.
    fn pack_bf16(&self, x: &Volume, zs: (usize, usize), buf: &mut Vec<u16>) -> usize {
        self.pack(x, zs, 1, buf, |src, dst: &mut [u16]| {
            let src = src[0].expect("one channel per element");
            match self.s {
                1 => nst3d_core::bf16::convert(src, &mut dst[self.p..][..src.len()]),
                _ => self.place(src.len(), dst, |i| from_f32(src[i])),
            }
        })
    }
}

/// `dst[i]` = the bf16 pair (`a[i]`, `b[i]`, 0 without `b`), vectorised
/// where AVX-512 is available.
pub(super) fn pairs_row(a: &[f32], b: Option<&[f32]>, dst: &mut [u32]) {
    #[inline(always)]
    fn plain(a: &[f32], b: Option<&[f32]>, dst: &mut [u32]) {
        match b {
            Some(b) => dst.iter_mut().zip(a.iter().zip(b)).for_each(|(d, (x, y))| {
                *d = from_f32(*x) as u32 | (from_f32(*y) as u32) << 16;
            }),
            None => dst.iter_mut().zip(a).for_each(|(d, x)| *d = from_f32(*x) as u32),
        }
    }
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512bw,avx2")]
    unsafe fn wide(a: &[f32], b: Option<&[f32]>, dst: &mut [u32]) {
        plain(a, b, dst)
    }
    #[cfg(target_arch = "x86_64")]
    if nst3d_core::bf16::has_avx512f() {
        // SAFETY: the CPU has the enabled features.
        return unsafe { wide(a, b, dst) };
    }
    plain(a, b, dst)
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
pub fn forward(l: &Conv3d, arith: Arith, x: &Volume, act: Act) -> Volume {
    let g = Geom::new(l, x.dims, VL);
    let n_out = g.o.iter().product::<usize>();
    // Not zeroed first: every output is stored once (a serial memset was a
    // few per cent of a training step).
    let mut y = Vec::<f32>::with_capacity(l.cout * n_out);
    let out = Out(y.as_mut_ptr());
    let avx2 = kernels::unit().f32 == Some(Isa::Avx2);
    match (arith, l.cout) {
        // AVX2 tiles: 2 · NV · NC ≤ 12 accumulators; 4 output channels a
        // block divide the network's 16 and 32.
        (Arith::F32, c) if avx2 && c >= 4 => run_fwd::<f32, 1, 4>(l, &g, x, (out, act)),
        (Arith::F32, _) if avx2 => run_fwd::<f32, 6, 1>(l, &g, x, (out, act)),
        (Arith::F32, c) if c >= 8 => run_fwd::<f32, 3, 8>(l, &g, x, (out, act)),
        (Arith::F32, c) if c >= 4 => run_fwd::<f32, 6, 4>(l, &g, x, (out, act)),
        (Arith::F32, _) => run_fwd::<f32, 12, 1>(l, &g, x, (out, act)),
        (Arith::Bf16, c) if c >= 8 => run_fwd::<u32, 3, 8>(l, &g, x, (out, act)),
        (Arith::Bf16, c) if c >= 4 => run_fwd::<u32, 6, 4>(l, &g, x, (out, act)),
        (Arith::Bf16, _) => run_fwd::<u32, 12, 1>(l, &g, x, (out, act)),
    }
    // SAFETY: the tasks store every (z, y, x) of every channel (each row's
    // vectors cover it; `store` writes each vector's lanes inside the volume).
    unsafe { y.set_len(l.cout * n_out) };
    Volume::from_vec(l.cout, g.o, y)
}

/// An element type of the forward: its packing and its tile kernel.
trait Lane: Copy + Default + Send + Sync + Sized {
    /// Values packed together per lane (1 for fp32, 2 for bf16 pairs).
    const PER: usize;
    fn pack_input(g: &Geom, x: &Volume, zs: (usize, usize), buf: &mut Vec<Self>) -> usize;
    fn pack_weight(a: f32, b: f32) -> Self;
    fn tile<const NV: usize, const NC: usize>(a: &FwdArgs<Self, NV>, out: &mut [f32]);
}

impl Lane for f32 {
    const PER: usize = 1;
    fn pack_input(g: &Geom, x: &Volume, zs: (usize, usize), buf: &mut Vec<f32>) -> usize {
        g.pack_f32(x, zs, buf)
    }
    fn pack_weight(a: f32, _: f32) -> f32 {
        a
    }
    fn tile<const NV: usize, const NC: usize>(a: &FwdArgs<f32, NV>, out: &mut [f32]) {
        // SAFETY: the unit is present and checked; the driver keeps every read in bounds.
        #[cfg(target_arch = "x86_64")]
        match kernels::unit().f32 {
            Some(Isa::Avx512) => return unsafe { kernels::fwd_f32_avx512::<NV, NC>(a, out) },
            Some(Isa::Avx2) => return unsafe { kernels::fwd_f32_avx2::<NV, NC>(a, out) },
            None => {}
        }
        kernels::fwd_f32_scalar::<NV, NC>(a, out)
    }
}

impl Lane for u32 {
    const PER: usize = 2;
    fn pack_input(g: &Geom, x: &Volume, zs: (usize, usize), buf: &mut Vec<u32>) -> usize {
        g.pack_pairs(x, zs, buf)
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

/// Every output vector of row `(z, y)`, reading a copy that starts at
/// output plane `z0`'s first input plane.
fn row_vectors(g: &Geom, z: usize, z0: usize, y: usize) -> impl Iterator<Item = Vector> + '_ {
    let [ox, oy, _] = g.o;
    (0..ox.div_ceil(VL)).map(move |v| Vector {
        base: g.base(z - z0, y) + v * VL,
        out: (z * oy + y) * ox + v * VL,
        len: VL.min(ox - v * VL),
    })
}

/// The forward, a few output planes a task (each task copying the input
/// planes they read: up to four planes, fewer where that leaves the threads
/// too few tasks; the result does not depend on the split).
fn run_fwd<T: Lane, const NV: usize, const NC: usize>(l: &Conv3d, g: &Geom, x: &Volume, (out, act): (Out, Act)) {
    let w = pack_weights::<T, NC>(l);
    let offs = g.offs();
    let chans = l.cin.div_ceil(T::PER);
    let [_, oy, oz] = g.o;
    let n_out = g.o.iter().product::<usize>();
    let per = (oz / (4 * rayon::current_num_threads())).clamp(1, 4);
    let init = || (Vec::new(), vec![0.0f32; NV * NC * VL]);
    (0..oz.div_ceil(per)).into_par_iter().for_each_init(init, |(inp, acc), task| {
        let (z0, z1) = (task * per, oz.min((task + 1) * per));
        let cs = T::pack_input(g, x, (g.s * z0, g.s * (z1 - 1 - z0) + g.k), inp);
        let vecs: Vec<Vector> = (z0..z1).flat_map(|z| (0..oy).flat_map(move |y| row_vectors(g, z, z0, y))).collect();
        for tile in vecs.chunks(NV) {
            // A short last tile repeats its last vector (written twice, the same values).
            let bases = std::array::from_fn(|v| tile[v.min(tile.len() - 1)].base);
            for b in 0..l.cout.div_ceil(NC) {
                let a = FwdArgs { inp, cs, chans, offs: &offs, bases, w: &w[b * chans * offs.len() * NC..] };
                T::tile::<NV, NC>(&a, acc);
                store(l, (out, act), n_out, tile, (b * NC, NC), acc);
            }
        }
    });
}

/// Writes a tile's accumulators (`[v][c][lane]`) plus the bias, through
/// `act`, into the output channels `c0..c0 + nc` that exist.
fn store(l: &Conv3d, (out, act): (Out, Act), n_out: usize, tile: &[Vector], (c0, nc): (usize, usize), acc: &[f32]) {
    for (v, vec) in tile.iter().enumerate() {
        for c in 0..nc.min(l.cout - c0) {
            let b = l.bias[c0 + c];
            let src = &acc[(v * nc + c) * VL..][..vec.len];
            // SAFETY: this vector's outputs are written by this task only, inside the volume.
            let dst = unsafe { std::slice::from_raw_parts_mut(out.0.add((c0 + c) * n_out + vec.out), vec.len) };
            dst.iter_mut().zip(src).for_each(|(d, s)| *d = act.apply(s + b));
        }
    }
}

/// The weight gradient `dW[co][ci][t] = Σ_v grad_out[co][v] · x[ci][v at tap t]`
/// on the direct kernels.
pub fn weight_grad(l: &Conv3d, arith: Arith, x: &Volume, grad_out: &Volume) -> Vec<f32> {
    let ops = |g: Geom| DwOps { l, g, x, grad_out };
    let avx2 = kernels::unit().f32 == Some(Isa::Avx2);
    match (arith, l.cout >= 4) {
        // AVX2 tiles: NCO · NT ≤ 12 accumulators (the 1 × 12 tile below
        // already fits).
        (Arith::F32, true) if avx2 => run_dw::<f32, 2, 6>(&ops(Geom::new(l, x.dims, VL)), VL),
        (Arith::F32, true) => run_dw::<f32, 4, 6>(&ops(Geom::new(l, x.dims, VL)), VL),
        (Arith::F32, false) => run_dw::<f32, 1, 12>(&ops(Geom::new(l, x.dims, VL)), VL),
        (Arith::Bf16, true) => run_dw::<u16, 4, 6>(&ops(Geom::new(l, x.dims, 2 * VL)), 2 * VL),
        (Arith::Bf16, false) => run_dw::<u16, 1, 12>(&ops(Geom::new(l, x.dims, 2 * VL)), 2 * VL),
    }
}

/// The operands of a weight gradient.
struct DwOps<'a> {
    l: &'a Conv3d,
    g: Geom,
    x: &'a Volume,
    grad_out: &'a Volume,
}

/// An element type of the weight gradient and its tile kernel.
trait DwLane: Copy + Default + Send + Sync {
    /// Copies planes of the input ([`Geom::pack`]).
    fn pack(g: &Geom, x: &Volume, zs: (usize, usize), buf: &mut Vec<Self>) -> usize;
    /// Converts a row of the output gradient.
    fn convert(src: &[f32], dst: &mut [Self]);
    fn tile<const NCO: usize, const NT: usize>(a: &DwArgs<Self, NCO, NT>, acc: &mut [f32], lda: usize);
}

impl DwLane for f32 {
    fn pack(g: &Geom, x: &Volume, zs: (usize, usize), buf: &mut Vec<f32>) -> usize {
        g.pack_f32(x, zs, buf)
    }
    fn convert(src: &[f32], dst: &mut [f32]) {
        dst.copy_from_slice(src)
    }
    fn tile<const NCO: usize, const NT: usize>(a: &DwArgs<f32, NCO, NT>, acc: &mut [f32], lda: usize) {
        // SAFETY: the unit is present and checked; the driver keeps every read in bounds.
        #[cfg(target_arch = "x86_64")]
        match kernels::unit().f32 {
            Some(Isa::Avx512) => return unsafe { kernels::dw_f32_avx512(a, acc, lda) },
            Some(Isa::Avx2) => return unsafe { kernels::dw_f32_avx2(a, acc, lda) },
            None => {}
        }
        kernels::dw_f32_scalar(a, acc, lda)
    }
}

impl DwLane for u16 {
    fn pack(g: &Geom, x: &Volume, zs: (usize, usize), buf: &mut Vec<u16>) -> usize {
        g.pack_bf16(x, zs, buf)
    }
    fn convert(src: &[f32], dst: &mut [u16]) {
        nst3d_core::bf16::convert(src, dst)
    }
    fn tile<const NCO: usize, const NT: usize>(a: &DwArgs<u16, NCO, NT>, acc: &mut [f32], lda: usize) {
        #[cfg(target_arch = "x86_64")]
        if kernels::unit().bf16 {
            // SAFETY: as for fp32.
            return unsafe { kernels::dw_bf16_avx512(a, acc, lda) };
        }
        kernels::dw_bf16_scalar(a, acc, lda)
    }
}

/// Output planes `z0..z1` of `grad_out` with rows padded with zeros to
/// `xs` values and channels to `cop`: the data and its channel stride.
fn pad_rows<T: DwLane>(grad_out: &Volume, (z0, z1): (usize, usize), xs: usize, cop: usize) -> (Vec<T>, usize) {
    let [ox, oy, _] = grad_out.dims;
    let gs = (z1 - z0) * oy * xs;
    let mut d = vec![T::default(); cop * gs];
    for c in 0..grad_out.channels {
        let planes = &grad_out.channel(c)[z0 * oy * ox..z1 * oy * ox];
        for (r, row) in planes.chunks(ox).enumerate() {
            T::convert(row, &mut d[c * gs + r * xs..][..ox]);
        }
    }
    (d, gs)
}

/// Sums the weight gradient over fixed groups of output planes (each
/// copying the input planes it reads), in parallel, then the groups in
/// order; vectors hold `vl` positions.
fn run_dw<T: DwLane, const NCO: usize, const NT: usize>(ops: &DwOps, vl: usize) -> Vec<f32> {
    let (l, g) = (ops.l, &ops.g);
    let [ox, _, oz] = g.o;
    let cols = l.cin * g.k * g.k * g.k;
    let (jp, cop) = (cols.next_multiple_of(NT), l.cout.next_multiple_of(NCO));
    let rows_per_plane = g.o[1] * ox.div_ceil(vl);
    let per = oz.div_ceil((oz * rows_per_plane / DW_MIN_POS).clamp(1, oz.min(DW_GROUPS)));
    let partial: Vec<Vec<f32>> = (0..oz.div_ceil(per))
        .into_par_iter()
        .map(|grp| {
            let zs = (grp * per, oz.min((grp + 1) * per));
            dw_group::<T, NCO, NT>(ops, zs, ox.next_multiple_of(vl), vl, (jp, cop))
        })
        .collect();
    let mut dw = vec![0.0f32; l.cout * cols];
    for sums in &partial {
        for (co, row) in dw.chunks_mut(cols).enumerate() {
            row.iter_mut().zip(&sums[co * jp..]).for_each(|(d, s)| *d += s);
        }
    }
    dw
}

/// One group's `[cop][jp]` sums over output planes `zs`: each tile's
/// accumulators stay in registers over all the group's positions.
fn dw_group<T: DwLane, const NCO: usize, const NT: usize>(
    ops: &DwOps,
    (z0, z1): (usize, usize),
    xs: usize,
    vl: usize,
    (jp, cop): (usize, usize),
) -> Vec<f32> {
    let g = &ops.g;
    let [_, oy, _] = g.o;
    let mut inp = Vec::new();
    let cs = T::pack(g, ops.x, (g.s * z0, g.s * (z1 - 1 - z0) + g.k), &mut inp);
    let (gp, gs) = pad_rows::<T>(ops.grad_out, (z0, z1), xs, cop);
    let offs = g.offs();
    let k3 = offs.len();
    let cols = ops.l.cin * k3;
    // Column j = (ci, t); padding columns read offset 0 and are dropped.
    let ioffs: Vec<usize> = (0..jp).map(|j| if j < cols { j / k3 * cs + offs[j % k3] } else { 0 }).collect();
    let pos: Vec<(usize, usize)> = (0..(z1 - z0) * oy)
        .flat_map(|r| (0..xs / vl).map(move |v| (r * xs + v * vl, g.base(r / oy, r % oy) + v * vl)))
        .collect();
    // Blocks of NCO output channels in parallel, each its [NCO][jp] sums.
    let blocks: Vec<Vec<f32>> = (0..cop / NCO)
        .into_par_iter()
        .map(|cb| {
            let mut sums = vec![0.0f32; NCO * jp];
            let mut acc = vec![0.0f32; NCO * NT * VL];
            for jb in 0..jp / NT {
                let a = DwArgs {
                    g: &gp[cb * NCO * gs..],
                    gs,
                    inp: &inp,
                    ioffs: std::array::from_fn(|j| ioffs[jb * NT + j]),
                    pos: &pos,
                };
                acc.fill(0.0);
                T::tile::<NCO, NT>(&a, &mut acc, NT * VL);
                for (i, v) in acc.chunks(VL).enumerate() {
                    sums[i / NT * jp + jb * NT + i % NT] = v.iter().sum::<f32>();
                }
            }
            sums
        })
        .collect();
    let sums = blocks.concat();
    sums
}
