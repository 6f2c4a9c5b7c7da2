//! 3D convolution, PyTorch's `nn.Conv3d` with cubic kernels, zero padding
//! and one stride for all axes: the building block of the feed-forward
//! network (Fig. 9). Unlike VGG, whose weights are frozen, the network is
//! trained, so the backward gives the weight and bias gradients as well as
//! the input gradient.
//!
//! The products run as matrix products over an im2col matrix, built for a
//! slab of output rows (an `(z, y)` pair is a row of `x` voxels) at a time,
//! small enough to stay in cache whatever the volume's size:
//!
//! - forward: `out[co, v] = Σ_r W[co, r] · col[r, v] + b[co]`,
//! - weight gradient: `dW = Σ_slabs grad_out · colᵀ`, summed in a fixed
//!   grouping so the result does not depend on the thread count,
//! - input gradient: for stride 1, the forward of the transposed layer
//!   (flipped taps, channels swapped, padding `k − 1 − p`) on `grad_out`; for
//!   stride 2, `col' = Wᵀ · grad_out` scattered back (col2im).
//!
//! `r = (ci, kz, ky, kx)` runs in the weight tensor's own order, so `W` is
//! the `cout x (cin·k³)` row-major matrix PyTorch stores.

use nst3d_core::linalg::{matmul_into_precision, matmul_precision as matmul, Parallelism};
use nst3d_core::precision::{self, Path, Product};
use rayon::prelude::*;

use crate::activation::Act;
use crate::volume::Volume;

mod direct;
pub mod kernels;
mod measure;
mod route;
mod tiles;

pub use measure::{Conv3dProduct, Kernel3d};

use direct::Arith;
use route::Route;

/// im2col matrices are built for slabs of output rows holding about this
/// many floats (1 MB), so they stay in cache.
const COL_FLOATS: usize = 1 << 18;

/// The weight gradient's partial sums are grouped into this many fixed
/// groups of slabs, so its summation order does not depend on threads.
const WEIGHT_GROUPS: usize = 16;

/// A 3D convolution layer with a `k³` kernel.
#[derive(Clone, Debug, PartialEq)]
pub struct Conv3d {
    /// Input channels.
    pub cin: usize,
    /// Output channels.
    pub cout: usize,
    /// Kernel size along every axis.
    pub k: usize,
    /// Stride along every axis.
    pub stride: usize,
    /// Zero padding on every side.
    pub pad: usize,
    /// `cout x cin x k x k x k` (z, y, x taps), PyTorch's layout.
    pub weight: Vec<f32>,
    /// One bias per output channel.
    pub bias: Vec<f32>,
}

/// Gradients of a [`Conv3d`]'s parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct Conv3dGrads {
    /// Same layout as [`Conv3d::weight`].
    pub weight: Vec<f32>,
    /// Same layout as [`Conv3d::bias`].
    pub bias: Vec<f32>,
}

/// Output rows `[r0, r1)` (row `r` is `z = r / oy`, `y = r % oy`) one im2col
/// matrix covers.
#[derive(Clone, Copy, Debug)]
struct Slab {
    r0: usize,
    r1: usize,
}

impl Conv3d {
    /// A layer with zero weights and biases.
    pub fn zeros(cin: usize, cout: usize, k: usize, stride: usize, pad: usize) -> Self {
        Self { cin, cout, k, stride, pad, weight: vec![0.0; cout * cin * k * k * k], bias: vec![0.0; cout] }
    }

    /// Rows of the im2col matrix: `cin · k³`.
    fn taps(&self) -> usize {
        self.cin * self.k * self.k * self.k
    }

    /// Output size for an input of `dims` voxels: `(n + 2p − k) / s + 1`.
    pub fn out_dims(&self, dims: [usize; 3]) -> [usize; 3] {
        dims.map(|n| (n + 2 * self.pad).saturating_sub(self.k) / self.stride + 1)
    }

    fn check_input(&self, x: &Volume) {
        assert_eq!(x.channels, self.cin, "conv3d: input channels");
        assert!(
            x.dims.iter().all(|&n| n + 2 * self.pad >= self.k),
            "conv3d: input {:?} smaller than the kernel",
            x.dims
        );
    }

    /// Splits the output rows into slabs whose im2col matrix holds about
    /// [`COL_FLOATS`] values. Depends on the shapes only.
    fn slabs(&self, out: [usize; 3], rows_per_slab_max: usize) -> Vec<Slab> {
        let rows = out[1] * out[2];
        let t = (COL_FLOATS / (self.taps() * out[0]).max(1)).clamp(1, rows_per_slab_max.max(1));
        (0..rows).step_by(t).map(|r0| Slab { r0, r1: (r0 + t).min(rows) }).collect()
    }

    /// The input coordinate tap `kk` of output coordinate `o` reads, if inside `0..n`.
    fn source(&self, o: usize, kk: usize, n: usize) -> Option<usize> {
        let i = (o * self.stride + kk) as isize - self.pad as isize;
        (i >= 0 && (i as usize) < n).then_some(i as usize)
    }

    /// The outputs `o` in `0..len` whose tap `kk` reads inside `0..n`: a range.
    fn valid(&self, kk: usize, n: usize, len: usize) -> std::ops::Range<usize> {
        let (s, p) = (self.stride as isize, self.pad as isize);
        // o·s + kk − p ≥ 0 and ≤ n − 1.
        let lo = ((p - kk as isize).max(0) + s - 1) / s;
        let hi = ((n as isize - 1 + p - kk as isize).div_euclid(s) + 1).clamp(0, len as isize);
        (lo as usize).min(hi as usize)..hi as usize
    }

    /// Fills `col` (resized to `taps() x voxels`) with the im2col matrix of
    /// `x` for the output rows of `slab`; every entry is written, so the
    /// buffer can be reused without clearing.
    fn im2col(&self, x: &Volume, out: [usize; 3], slab: Slab, col: &mut Vec<f32>) {
        let [nx, ny, nz] = x.dims;
        let [ox, oy, _] = out;
        let cols = (slab.r1 - slab.r0) * ox;
        let k = self.k;
        col.resize(self.taps() * cols, 0.0);
        for (r, row) in col.chunks_mut(cols).enumerate() {
            let (ci, kz, ky, kx) = (r / (k * k * k), r / (k * k) % k, r / k % k, r % k);
            let src = x.channel(ci);
            let xs = self.valid(kx, nx, ox);
            for (j, dst) in row.chunks_mut(ox).enumerate() {
                let (z, y) = ((slab.r0 + j) / oy, (slab.r0 + j) % oy);
                let (Some(iz), Some(iy)) = (self.source(z, kz, nz), self.source(y, ky, ny)) else {
                    dst.fill(0.0);
                    continue;
                };
                let line = &src[(iz * ny + iy) * nx..][..nx];
                dst[..xs.start].fill(0.0);
                dst[xs.end..].fill(0.0);
                let first = xs.start * self.stride + kx - self.pad;
                if self.stride == 1 {
                    dst[xs.clone()].copy_from_slice(&line[first..][..xs.len()]);
                } else {
                    for (d, i) in dst[xs.clone()].iter_mut().zip((first..).step_by(self.stride)) {
                        *d = line[i];
                    }
                }
            }
        }
    }

    /// Adds the `taps() x voxels` matrix `col` of `slab` back onto the input
    /// positions it was read from (the transpose of [`Conv3d::im2col`]), into
    /// `dst`, which holds input planes `z_lo..z_lo + planes` of every channel.
    #[allow(clippy::too_many_arguments)]
    fn col2im(
        &self,
        col: &[f32],
        dims: [usize; 3],
        out: [usize; 3],
        slab: Slab,
        dst: &mut [f32],
        z_lo: usize,
        planes: usize,
    ) {
        let [nx, ny, nz] = dims;
        let [ox, oy, _] = out;
        let cols = (slab.r1 - slab.r0) * ox;
        let k = self.k;
        for (r, row) in col.chunks(cols).enumerate() {
            let (ci, kz, ky, kx) = (r / (k * k * k), r / (k * k) % k, r / k % k, r % k);
            let chan = &mut dst[ci * planes * ny * nx..][..planes * ny * nx];
            let xs = self.valid(kx, nx, ox);
            for (j, src) in row.chunks(ox).enumerate() {
                let (z, y) = ((slab.r0 + j) / oy, (slab.r0 + j) % oy);
                let (Some(iz), Some(iy)) = (self.source(z, kz, nz), self.source(y, ky, ny)) else { continue };
                let line = &mut chan[((iz - z_lo) * ny + iy) * nx..][..nx];
                let first = xs.start * self.stride + kx - self.pad;
                for (s, i) in src[xs.clone()].iter().zip((first..).step_by(self.stride)) {
                    line[i] += s;
                }
            }
        }
    }

    /// `conv3d(x, W) + b`.
    ///
    /// # Panics
    /// If `x` does not have `cin` channels or is smaller than the kernel.
    pub fn forward(&self, x: &Volume) -> Volume {
        self.forward_then(x, Act::Identity)
    }

    /// `act(conv3d(x, W) + b)`, the activation applied as each output is
    /// stored: the same values as [`Conv3d::forward`] then the activation.
    ///
    /// # Panics
    /// As [`Conv3d::forward`].
    pub fn forward_then(&self, x: &Volume, act: Act) -> Volume {
        self.forward_on(precision::path_for(Product::Conv3d), x, act)
    }

    /// [`Conv3d::forward_then`] in the arithmetic of `path` (resolved once on
    /// the calling thread: the products run in parallel tasks).
    fn forward_on(&self, path: Path, x: &Volume, act: Act) -> Volume {
        self.forward_with(path, direct_arith(path), x, act)
    }

    /// The forward on the direct kernels in `direct`'s arithmetic, or on
    /// im2col products in `path`'s.
    fn forward_with(&self, path: Path, direct: Option<Arith>, x: &Volume, act: Act) -> Volume {
        self.check_input(x);
        match route::forward(self, path, direct) {
            Route::Tiles => tiles::forward(self, x, act),
            Route::Direct(arith) => direct::forward(self, arith, x, act),
            Route::Im2col => self.forward_im2col(path, x, act),
        }
    }

    /// The forward on im2col products (the fallback without AVX-512, and
    /// bf16 emulated).
    fn forward_im2col(&self, path: Path, x: &Volume, act: Act) -> Volume {
        let out = self.out_dims(x.dims);
        let n_out: usize = out.iter().product();
        let taps = self.taps();
        let parts: Vec<(Slab, Vec<f32>)> = self
            .slabs(out, usize::MAX)
            .into_par_iter()
            .map_init(Vec::new, |col, slab| {
                self.im2col(x, out, slab, col);
                let cols = (slab.r1 - slab.r0) * out[0];
                let mut o = vec![0.0f32; self.cout * cols];
                matmul(
                    path,
                    self.cout,
                    cols,
                    taps,
                    &mut o,
                    &self.weight,
                    (taps, 1),
                    col,
                    (cols, 1),
                    1.0,
                    Parallelism::None,
                );
                (slab, o)
            })
            .collect();
        let mut y = Volume::zeros(self.cout, out);
        for (slab, o) in parts {
            let cols = (slab.r1 - slab.r0) * out[0];
            for co in 0..self.cout {
                let dst = &mut y.data[co * n_out + slab.r0 * out[0]..][..cols];
                let b = self.bias[co];
                dst.iter_mut().zip(&o[co * cols..][..cols]).for_each(|(d, v)| *d = act.apply(v + b));
            }
        }
        y
    }

    /// The layer whose forward is this layer's input gradient (stride 1):
    /// taps flipped, input and output channels swapped, padding `k − 1 − p`.
    fn transposed(&self) -> Conv3d {
        let k3 = self.k * self.k * self.k;
        let mut t = Conv3d::zeros(self.cout, self.cin, self.k, 1, self.k - 1 - self.pad);
        for co in 0..self.cout {
            for ci in 0..self.cin {
                for tap in 0..k3 {
                    t.weight[(ci * self.cout + co) * k3 + k3 - 1 - tap] = self.weight[(co * self.cin + ci) * k3 + tap];
                }
            }
        }
        t
    }

    /// Backward of [`Conv3d::forward`] at input `x`: the parameters'
    /// gradients and, when `want_input`, the input's (the first layer of a
    /// network does not need it).
    ///
    /// # Panics
    /// If `grad_out` is not the size [`Conv3d::forward`] returns for `x`.
    pub fn backward(&self, x: &Volume, grad_out: &Volume, want_input: bool) -> (Option<Volume>, Conv3dGrads) {
        let path = precision::path_for(Product::Conv3d);
        self.backward_with(path, direct_arith(path), x, grad_out, want_input)
    }

    /// [`Conv3d::backward`] as [`Conv3d::forward_with`] runs the forward.
    fn backward_with(
        &self,
        path: Path,
        direct: Option<Arith>,
        x: &Volume,
        grad_out: &Volume,
        want_input: bool,
    ) -> (Option<Volume>, Conv3dGrads) {
        self.check_input(x);
        let out = self.out_dims(x.dims);
        assert_eq!((grad_out.channels, grad_out.dims), (self.cout, out), "conv3d backward: gradient size");
        let weight = match route::weight_grad(self, path, direct) {
            Route::Tiles => tiles::weight_grad(self, x, grad_out),
            Route::Direct(arith) => direct::weight_grad(self, arith, x, grad_out),
            Route::Im2col => self.weight_grad_im2col(path, x, grad_out),
        };
        // One channel a task, each summed in a fixed order: the same bits on any thread count.
        let bias = (0..self.cout)
            .into_par_iter()
            .map(|co| nst3d_core::math::lane_sum(grad_out.channel(co), None) as f32)
            .collect();
        let grads = Conv3dGrads { weight, bias };
        let dx = want_input.then(|| match self.stride {
            1 => self.transposed().forward_with(path, direct, grad_out, Act::Identity),
            _ => self.input_grad_scatter(path, x.dims, out, grad_out),
        });
        (dx, grads)
    }

    /// The weight gradient on im2col products: slabs in [`WEIGHT_GROUPS`]
    /// fixed runs, each run summed in order, the runs then summed in order.
    fn weight_grad_im2col(&self, path: Path, x: &Volume, grad_out: &Volume) -> Vec<f32> {
        let out = self.out_dims(x.dims);
        let n_out: usize = out.iter().product();
        let taps = self.taps();
        let slabs = self.slabs(out, usize::MAX);
        let per_group = slabs.len().div_ceil(WEIGHT_GROUPS).max(1);
        let partial: Vec<Vec<f32>> = slabs
            .par_chunks(per_group)
            .map_init(Vec::new, |col, group| {
                let mut dw = vec![0.0f32; self.cout * taps];
                for &slab in group {
                    self.im2col(x, out, slab, col);
                    let cols = (slab.r1 - slab.r0) * out[0];
                    let g = &grad_out.data[slab.r0 * out[0]..];
                    // dW (cout x taps) += grad_out band (cout x cols, rows n_out apart) · colᵀ.
                    matmul_into_precision(
                        path,
                        self.cout,
                        taps,
                        cols,
                        &mut dw,
                        taps,
                        true,
                        g,
                        (n_out, 1),
                        col,
                        (1, cols),
                        1.0,
                        Parallelism::None,
                    );
                }
                dw
            })
            .collect();
        let mut weight = vec![0.0; self.weight.len()];
        for dw in partial {
            weight.iter_mut().zip(&dw).for_each(|(a, b)| *a += b);
        }
        weight
    }

    /// The input gradient of a strided layer: `Wᵀ · grad_out` per slab of
    /// whole output planes, scattered (col2im) into the input planes the
    /// slab read, and summed in slab order.
    fn input_grad_scatter(&self, path: Path, dims: [usize; 3], out: [usize; 3], grad_out: &Volume) -> Volume {
        let [nx, ny, nz] = dims;
        let n_out: usize = out.iter().product();
        let taps = self.taps();
        // Whole planes per slab, so a slab's input planes are a z-range.
        let plane_rows = out[1];
        let slabs: Vec<Slab> = self
            .slabs(out, usize::MAX)
            .iter()
            .map(|s| Slab { r0: s.r0 / plane_rows * plane_rows, r1: s.r1.div_ceil(plane_rows) * plane_rows })
            .fold(Vec::new(), |mut v: Vec<Slab>, s| {
                match v.last_mut() {
                    Some(l) if s.r0 < l.r1 => l.r1 = l.r1.max(s.r1),
                    _ => v.push(s),
                }
                v
            });
        let parts: Vec<(usize, usize, Vec<f32>)> = slabs
            .into_par_iter()
            .map(|slab| {
                let cols = (slab.r1 - slab.r0) * out[0];
                let g = &grad_out.data[slab.r0 * out[0]..];
                let mut dcol = vec![0.0f32; taps * cols];
                // col' (taps x cols) = Wᵀ · grad_out band.
                matmul(
                    path,
                    taps,
                    cols,
                    self.cout,
                    &mut dcol,
                    &self.weight,
                    (1, taps),
                    g,
                    (n_out, 1),
                    1.0,
                    Parallelism::None,
                );
                let (z0, z1) = (slab.r0 / plane_rows, slab.r1 / plane_rows);
                let z_lo = (z0 * self.stride).saturating_sub(self.pad);
                let z_hi = ((z1 - 1) * self.stride + self.k).saturating_sub(self.pad).min(nz);
                let planes = z_hi - z_lo;
                let mut local = vec![0.0f32; self.cin * planes * ny * nx];
                self.col2im(&dcol, dims, out, slab, &mut local, z_lo, planes);
                (z_lo, planes, local)
            })
            .collect();
        // One input channel a task, the slabs' parts added in slab order (the
        // same bits on any thread count).
        let chan = nz * ny * nx;
        let mut dx = Volume::from_vec(self.cin, dims, nst3d_core::fill::filled(self.cin * chan, 0.0));
        dx.data.par_chunks_mut(chan).enumerate().for_each(|(ci, dst)| {
            for (z_lo, planes, local) in &parts {
                let len = planes * ny * nx;
                let dst = &mut dst[z_lo * ny * nx..][..len];
                dst.iter_mut().zip(&local[ci * len..][..len]).for_each(|(a, b)| *a += b);
            }
        });
        dx
    }
}

/// The direct kernels' arithmetic for `path`, where this machine has them
/// (checked against their scalar references before first use); `None`
/// runs the im2col products (bf16 emulated without a bf16 unit, or no
/// AVX-512).
fn direct_arith(path: Path) -> Option<Arith> {
    let unit = kernels::unit();
    match path {
        Path::Fp32 => unit.has_f32().then_some(Arith::F32),
        Path::Bf16Amx | Path::Bf16Avx512 => unit.bf16.then_some(Arith::Bf16),
        Path::Bf16Portable => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::{check_gradient, dot, pseudo_random};

    fn layer(cin: usize, cout: usize, k: usize, stride: usize, pad: usize, seed: u64) -> Conv3d {
        let mut c = Conv3d::zeros(cin, cout, k, stride, pad);
        c.weight = pseudo_random(c.weight.len(), seed);
        c.bias = pseudo_random(cout, seed + 1);
        c
    }

    /// The definition, one output at a time, in f64.
    fn direct(c: &Conv3d, x: &Volume) -> Vec<f64> {
        let out = c.out_dims(x.dims);
        let [nx, ny, nz] = x.dims;
        let mut y = vec![0.0f64; c.cout * out.iter().product::<usize>()];
        for co in 0..c.cout {
            for z in 0..out[2] {
                for yy in 0..out[1] {
                    for xx in 0..out[0] {
                        let mut acc = c.bias[co] as f64;
                        for ci in 0..c.cin {
                            for kz in 0..c.k {
                                for ky in 0..c.k {
                                    for kx in 0..c.k {
                                        let (Some(iz), Some(iy), Some(ix)) =
                                            (c.source(z, kz, nz), c.source(yy, ky, ny), c.source(xx, kx, nx))
                                        else {
                                            continue;
                                        };
                                        let w = c.weight[(((co * c.cin + ci) * c.k + kz) * c.k + ky) * c.k + kx];
                                        acc += w as f64 * x.data[((ci * nz + iz) * ny + iy) * nx + ix] as f64;
                                    }
                                }
                            }
                        }
                        y[((co * out[2] + z) * out[1] + yy) * out[0] + xx] = acc;
                    }
                }
            }
        }
        y
    }

    /// The network's three shapes of layer: 5³ stride 2 (on one input
    /// channel and on two), 3³ stride 2, 3³ stride 1.
    const SHAPES: [(usize, usize, usize, usize, usize, [usize; 3]); 5] = [
        (1, 3, 5, 2, 2, [7, 6, 9]),
        (2, 3, 5, 2, 2, [8, 7, 9]),
        (2, 3, 3, 2, 1, [6, 5, 7]),
        (3, 2, 3, 1, 1, [5, 4, 6]),
        (2, 2, 3, 1, 1, [1, 2, 3]),
    ];

    #[test]
    fn forward_matches_the_definition() {
        nst3d_core::precision::fp32(|| {
            for (i, &(cin, cout, k, s, p, dims)) in SHAPES.iter().enumerate() {
                let c = layer(cin, cout, k, s, p, 10 + i as u64);
                let x = Volume::from_vec(cin, dims, pseudo_random(cin * dims.iter().product::<usize>(), 3));
                let y = c.forward(&x);
                for (a, b) in y.data.iter().zip(direct(&c, &x)) {
                    assert!((*a as f64 - b).abs() < 1e-4, "shape {i}: {a} vs {b}");
                }
            }
        })
    }

    #[test]
    fn gradients_match_finite_differences() {
        nst3d_core::precision::fp32(|| {
            for (i, &(cin, cout, k, s, p, dims)) in SHAPES.iter().enumerate() {
                let c = layer(cin, cout, k, s, p, 20 + i as u64);
                let x = Volume::from_vec(cin, dims, pseudo_random(cin * dims.iter().product::<usize>(), 5));
                let out = c.out_dims(dims);
                let w = pseudo_random(cout * out.iter().product::<usize>(), 6);
                let (dx, g) = c.backward(&x, &Volume::from_vec(cout, out, w.clone()), true);
                // The map is linear in each argument, so a large step is
                // exact, and a step of 1 keeps the forward's f32 rounding
                // (about 1e-5 of a difference quotient here) far below the
                // tolerance; at 0.1 it reached 5e-3 on small entries.
                let r = check_gradient(
                    &x.data,
                    &dx.unwrap().data,
                    |q| dot(&w, &c.forward(&Volume::from_vec(cin, dims, q.to_vec())).data),
                    1.0,
                    150,
                    1e-3,
                );
                assert!(r.max_rel_err < 1e-3, "shape {i} input: {r:?}");
                let mut probe = c.clone();
                let r = check_gradient(
                    &c.weight,
                    &g.weight,
                    |q| {
                        probe.weight.copy_from_slice(q);
                        dot(&w, &probe.forward(&x).data)
                    },
                    1.0,
                    150,
                    1e-3,
                );
                assert!(r.max_rel_err < 1e-3, "shape {i} weight: {r:?}");
                let mut probe = c.clone();
                let r = check_gradient(
                    &c.bias,
                    &g.bias,
                    |q| {
                        probe.bias.copy_from_slice(q);
                        dot(&w, &probe.forward(&x).data)
                    },
                    0.1,
                    10,
                    1e-3,
                );
                assert!(r.max_rel_err < 1e-3, "shape {i} bias: {r:?}");
            }
        })
    }

    #[test]
    fn slabs_do_not_change_the_result() {
        // A volume large enough for several slabs per thread against one slab.
        let c = layer(4, 3, 3, 1, 1, 40);
        let dims = [20, 18, 24];
        let x = Volume::from_vec(4, dims, pseudo_random(4 * 20 * 18 * 24, 7));
        let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        let one = pool.install(|| c.forward(&x));
        let many = rayon::ThreadPoolBuilder::new().num_threads(4).build().unwrap().install(|| c.forward(&x));
        // The same sums per output, only split differently over slabs.
        for (a, b) in one.data.iter().zip(&many.data) {
            assert!((a - b).abs() < 1e-5, "{a} vs {b}");
        }
    }

    /// Forward, input and weight gradients under bf16 (the network's
    /// widths, 16 channels, both strides) within bf16's tolerance of fp32:
    /// 1 % of the largest value (operands rounded to 8 mantissa bits, sums
    /// in fp32).
    #[test]
    fn bf16_matches_fp32_within_tolerance() {
        // Every shape on its bf16 kernel, also where fp32 would be chosen for speed.
        route::by_capability(|| {
            use nst3d_core::precision::{fp32, scoped, Precision};
            let rel = |a: &[f32], b: &[f32]| {
                let m = b.iter().fold(0.0f32, |m, v| m.max(v.abs()));
                a.iter().zip(b).fold(0.0f32, |e, (x, y)| e.max((x - y).abs())) / m
            };
            for (cin, cout, k, s, p, dims) in
                [(16, 16, 3, 1, 1, [9, 8, 10]), (16, 32, 3, 2, 1, [12, 9, 8]), (1, 16, 5, 2, 2, [11, 10, 9])]
            {
                let c = layer(cin, cout, k, s, p, 60);
                let x = Volume::from_vec(cin, dims, pseudo_random(cin * dims.iter().product::<usize>(), 61));
                let out = c.out_dims(dims);
                let g = Volume::from_vec(cout, out, pseudo_random(cout * out.iter().product::<usize>(), 62));
                let run = || {
                    let y = c.forward(&x);
                    let (dx, gr) = c.backward(&x, &g, true);
                    (y, dx.unwrap(), gr)
                };
                let (y32, dx32, g32) = fp32(run);
                let (y16, dx16, g16) = scoped(Precision::Bf16, run);
                assert_ne!(y16.data, y32.data, "the bf16 call did not take the bf16 path");
                for (name, a, b) in [
                    ("forward", &y16.data, &y32.data),
                    ("input gradient", &dx16.data, &dx32.data),
                    ("weight gradient", &g16.weight, &g32.weight),
                    ("bias gradient", &g16.bias, &g32.bias),
                ] {
                    assert!(rel(a, b) < 1e-2, "{cin}->{cout} k{k} s{s} {name}: {}", rel(a, b));
                }
            }
        })
    }

    /// The activation applied in the store gives the values of the
    /// activation applied after the forward, on every kernel this machine
    /// has (tiles, both direct arithmetics, im2col fp32 and bf16, on the
    /// precision paths it has), whole tiles and partial ones.
    #[test]
    fn leaky_relu_in_the_store_equals_it_after() {
        route::by_capability(|| {
            for (i, &(cin, cout)) in [(16, 16), (16, 1), (1, 16), (3, 5), (32, 8)].iter().enumerate() {
                let c = layer(cin, cout, 3, 1, 1, 90 + i as u64);
                let dims = [19, 6, 5];
                let x = Volume::from_vec(cin, dims, pseudo_random(cin * dims.iter().product::<usize>(), 91));
                for path in paths_here() {
                    for direct in [direct_arith(path), None] {
                        let mut want = c.forward_with(path, direct, &x, Act::Identity);
                        crate::activation::leaky_relu(&mut want.data);
                        let got = c.forward_with(path, direct, &x, Act::LeakyRelu);
                        assert_eq!(got.data, want.data, "{cin}->{cout} {path:?} {direct:?}");
                        assert!(got.data.iter().any(|v| *v < 0.0) && got.data.iter().any(|v| *v > 0.0));
                    }
                }
            }
        })
    }

    /// The precision paths this machine can run: fp32, emulated bf16, and
    /// the bf16 units it has (asking AMX of a CPU without it is refused).
    fn paths_here() -> Vec<Path> {
        let mut paths = vec![Path::Fp32, Path::Bf16Portable];
        if nst3d_core::bf16::avx512_bf16_available() {
            paths.push(Path::Bf16Avx512);
        }
        if nst3d_core::bf16::amx::available() {
            paths.push(Path::Bf16Amx);
        }
        paths
    }

    /// What [`products`] returns, in order.
    const PRODUCTS: [&str; 3] = ["forward", "input", "weight"];

    /// The forward, input gradient and weight gradient of `c` on `path` /
    /// `direct`, at a pseudo-random input of `dims` and output gradient
    /// (seeds `seed`, `seed + 1`).
    fn products(c: &Conv3d, dims: [usize; 3], seed: u64, path: Path, direct: Option<Arith>) -> [Vec<f32>; 3] {
        let x = Volume::from_vec(c.cin, dims, pseudo_random(c.cin * dims.iter().product::<usize>(), seed));
        let out = c.out_dims(dims);
        let g = Volume::from_vec(c.cout, out, pseudo_random(c.cout * out.iter().product::<usize>(), seed + 1));
        let y = c.forward_with(path, direct, &x, Act::Identity);
        let (dx, gr) = c.backward_with(path, direct, &x, &g, true);
        [y.data, dx.expect("asked for").data, gr.weight]
    }

    /// Each product's largest difference over the largest reference value.
    fn rel_errors(got: &[Vec<f32>; 3], want: &[Vec<f32>; 3]) -> [f32; 3] {
        std::array::from_fn(|i| {
            let m = want[i].iter().fold(1e-6f32, |m, v| m.max(v.abs()));
            got[i].iter().zip(&want[i]).fold(0.0f32, |e, (x, y)| e.max((x - y).abs())) / m
        })
    }

    /// The AMX tiles (where this CPU has them; elsewhere the same calls take
    /// the AVX512-BF16 or emulated kernels) against im2col's emulated bf16
    /// (the same rounded operands, another summation order) within 1e-4 of
    /// the largest value: 16 and 32 channels in and out, 8 and 1 out (part
    /// of a tile), 1 and 3 in (an odd count, a mostly empty K-slice), both
    /// strides, 3³ and 5³, rows that are not a multiple of 16.
    #[test]
    fn tiles_match_im2col() {
        route::by_capability(|| {
            let shapes = [
                (16, 16, 3, 1, 1, [19, 7, 5]),
                (32, 32, 3, 1, 1, [9, 6, 7]),
                (32, 16, 3, 1, 1, [17, 5, 4]),
                (16, 8, 3, 1, 1, [6, 9, 5]),
                (16, 32, 3, 2, 1, [17, 6, 7]),
                (1, 16, 5, 2, 2, [23, 9, 8]),
                (16, 1, 3, 1, 1, [21, 6, 4]),
                (3, 5, 3, 1, 1, [7, 6, 5]),
            ];
            let amx = nst3d_core::bf16::amx::available();
            for (i, &(cin, cout, k, s, p, dims)) in shapes.iter().enumerate() {
                let c = layer(cin, cout, k, s, p, 80 + i as u64);
                assert_eq!(tiles::takes_forward(&c), amx, "shape {i}");
                assert_eq!(tiles::takes_weight_grad(&c), amx && s == 1 && cin % 16 == 0, "shape {i}");
                let hw = if amx { Path::Bf16Amx } else { Path::Bf16Portable };
                let want = products(&c, dims, 81, Path::Bf16Portable, None);
                let got = products(&c, dims, 81, hw, direct_arith(hw));
                for (name, e) in PRODUCTS.iter().zip(rel_errors(&got, &want)) {
                    assert!(e < 1e-4, "shape {i} {name}: {e}");
                }
            }
        })
    }

    /// The direct kernels (AVX-512 where this machine has them, AVX2 where
    /// it has those, then the scalar references through the same drivers) against the im2col
    /// products: every tile shape (8, 4 and 1 output channels a block),
    /// rows that are not a multiple of 16, both strides, 3³ and 5³.
    /// fp32 within 1e-5 of the largest value (summation order only); bf16
    /// against im2col's emulated bf16 (the same rounded operands) within 1e-4.
    #[test]
    fn direct_matches_im2col() {
        route::by_capability(|| {
            use std::sync::atomic::Ordering;
            let shapes = [
                (3, 16, 3, 1, 1, [19, 7, 5]),
                (16, 4, 3, 1, 1, [21, 6, 4]),
                (5, 1, 3, 1, 1, [33, 5, 3]),
                (1, 16, 5, 2, 2, [23, 9, 8]),
                (16, 32, 3, 2, 1, [17, 6, 7]),
            ];
            // The machine's own kernels, the AVX2 ones (where the CPU has
            // AVX2, so on AVX-512 machines too), the scalar references.
            for (scalar, avx2) in [(false, false), (false, true), (true, false)] {
                kernels::SCALAR_ONLY.store(scalar, Ordering::Relaxed);
                kernels::AVX2_ONLY.store(avx2, Ordering::Relaxed);
                for (arith, path, tol) in [(Arith::F32, Path::Fp32, 1e-5), (Arith::Bf16, Path::Bf16Portable, 1e-4)] {
                    for (i, &(cin, cout, k, s, p, dims)) in shapes.iter().enumerate() {
                        let c = layer(cin, cout, k, s, p, 70 + i as u64);
                        let want = products(&c, dims, 71, path, None);
                        let got = products(&c, dims, 71, path, Some(arith));
                        for (name, e) in PRODUCTS.iter().zip(rel_errors(&got, &want)) {
                            assert!(e < tol, "scalar {scalar} avx2 {avx2} {arith:?} shape {i} {name}: {e}");
                        }
                    }
                }
            }
            kernels::SCALAR_ONLY.store(false, Ordering::Relaxed);
            kernels::AVX2_ONLY.store(false, Ordering::Relaxed);
        })
    }

    /// The vector kernels this machine has agree with their scalar references.
    #[test]
    fn hardware_kernels_pass_their_self_check() {
        use kernels::Isa;
        if nst3d_core::bf16::has_avx512f() {
            assert!(kernels::self_check(Isa::Avx512, false));
        }
        if nst3d_core::microkernel::has_avx2() {
            assert!(kernels::self_check(Isa::Avx2, false));
        }
        if nst3d_core::bf16::has_avx512f() && nst3d_core::bf16::avx512_bf16_available() {
            assert!(kernels::self_check(Isa::Avx512, true));
        }
    }
}
