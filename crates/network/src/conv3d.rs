//! 3D convolution, PyTorch's `nn.Conv3d` with cubic kernels, zero padding
//! and one stride for all axes: the building block of the feed-forward
//! network (Fig. 9). Unlike VGG, whose weights are frozen, the network is
//! trained, so the backward gives the weight and bias gradients as well as
//! the input gradient.
//!
//! All three products run as matrix products over an im2col matrix, built
//! for a slab of output z-planes at a time so its memory stays bounded
//! whatever the volume's size:
//!
//! - forward: `out[co, v] = Σ_r W[co, r] · col[r, v] + b[co]`,
//! - weight gradient: `dW = Σ_slabs grad_out · colᵀ`,
//! - input gradient: `col' = Wᵀ · grad_out`, scattered back (col2im).
//!
//! `r = (ci, kz, ky, kx)` runs in the weight tensor's own order, so `W` is
//! the `cout x (cin·k³)` row-major matrix PyTorch stores.

use nst3d_core::linalg::{matmul, Parallelism};
use rayon::prelude::*;

use crate::volume::Volume;

/// im2col matrices are built for slabs of output planes holding about this
/// many floats (8 MB), so memory does not grow with the volume.
const COL_FLOATS: usize = 1 << 21;

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

/// The output planes `[z0, z1)` one im2col matrix covers.
#[derive(Clone, Copy)]
struct Slab {
    z0: usize,
    z1: usize,
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

    /// Splits the output's z-planes into slabs whose im2col matrix holds
    /// about [`COL_FLOATS`] values, and at least one slab per thread.
    fn slabs(&self, out: [usize; 3]) -> Vec<Slab> {
        let plane = out[0] * out[1];
        let by_memory = (COL_FLOATS / (self.taps() * plane).max(1)).max(1);
        let by_threads = out[2].div_ceil(2 * rayon::current_num_threads()).max(1);
        let t = by_memory.min(by_threads);
        (0..out[2]).step_by(t).map(|z0| Slab { z0, z1: (z0 + t).min(out[2]) }).collect()
    }

    /// The input coordinate tap `kk` of output coordinate `o` reads, if inside `0..n`.
    fn source(&self, o: usize, kk: usize, n: usize) -> Option<usize> {
        let i = (o * self.stride + kk) as isize - self.pad as isize;
        (i >= 0 && (i as usize) < n).then_some(i as usize)
    }

    /// The `taps() x voxels` im2col matrix of `x` for the output planes of `slab`.
    fn im2col(&self, x: &Volume, out: [usize; 3], slab: Slab) -> Vec<f32> {
        let [nx, ny, nz] = x.dims;
        let [ox, oy, _] = out;
        let cols = (slab.z1 - slab.z0) * oy * ox;
        let k = self.k;
        let mut col = vec![0.0f32; self.taps() * cols];
        for (r, row) in col.chunks_mut(cols).enumerate() {
            let (ci, kz, ky, kx) = (r / (k * k * k), r / (k * k) % k, r / k % k, r % k);
            let src = x.channel(ci);
            for z in slab.z0..slab.z1 {
                let Some(iz) = self.source(z, kz, nz) else { continue };
                for y in 0..oy {
                    let Some(iy) = self.source(y, ky, ny) else { continue };
                    let line = &src[(iz * ny + iy) * nx..][..nx];
                    let dst = &mut row[((z - slab.z0) * oy + y) * ox..][..ox];
                    for (xo, d) in dst.iter_mut().enumerate() {
                        if let Some(ix) = self.source(xo, kx, nx) {
                            *d = line[ix];
                        }
                    }
                }
            }
        }
        col
    }

    /// Adds the `taps() x voxels` matrix `col` of `slab` back onto the
    /// input positions it was read from: the transpose of [`Conv3d::im2col`],
    /// into `dst`, which holds input planes `z_lo..` of every channel
    /// (`planes` of them).
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
        let cols = (slab.z1 - slab.z0) * oy * ox;
        let k = self.k;
        for (r, row) in col.chunks(cols).enumerate() {
            let (ci, kz, ky, kx) = (r / (k * k * k), r / (k * k) % k, r / k % k, r % k);
            let chan = &mut dst[ci * planes * ny * nx..][..planes * ny * nx];
            for z in slab.z0..slab.z1 {
                let Some(iz) = self.source(z, kz, nz) else { continue };
                for y in 0..oy {
                    let Some(iy) = self.source(y, ky, ny) else { continue };
                    let line = &mut chan[((iz - z_lo) * ny + iy) * nx..][..nx];
                    let src = &row[((z - slab.z0) * oy + y) * ox..][..ox];
                    for (xo, s) in src.iter().enumerate() {
                        if let Some(ix) = self.source(xo, kx, nx) {
                            line[ix] += s;
                        }
                    }
                }
            }
        }
    }

    /// `conv3d(x, W) + b`.
    ///
    /// # Panics
    /// If `x` does not have `cin` channels or is smaller than the kernel.
    pub fn forward(&self, x: &Volume) -> Volume {
        self.check_input(x);
        let out = self.out_dims(x.dims);
        let plane = out[0] * out[1];
        let n_out: usize = out.iter().product();
        let taps = self.taps();
        let parts: Vec<(Slab, Vec<f32>)> = self
            .slabs(out)
            .into_par_iter()
            .map(|slab| {
                let col = self.im2col(x, out, slab);
                let cols = (slab.z1 - slab.z0) * plane;
                let mut o = vec![0.0f32; self.cout * cols];
                matmul(self.cout, cols, taps, &mut o, &self.weight, (taps, 1), &col, (cols, 1), 1.0, Parallelism::None);
                (slab, o)
            })
            .collect();
        let mut y = Volume::zeros(self.cout, out);
        for (slab, o) in parts {
            let cols = (slab.z1 - slab.z0) * plane;
            for co in 0..self.cout {
                let dst = &mut y.data[co * n_out + slab.z0 * plane..][..cols];
                let b = self.bias[co];
                dst.iter_mut().zip(&o[co * cols..][..cols]).for_each(|(d, v)| *d = v + b);
            }
        }
        y
    }

    /// Backward of [`Conv3d::forward`] at input `x`: the parameters'
    /// gradients and, when `want_input`, the input's (the first layer of a
    /// network does not need it).
    ///
    /// # Panics
    /// If `grad_out` is not the size [`Conv3d::forward`] returns for `x`.
    pub fn backward(&self, x: &Volume, grad_out: &Volume, want_input: bool) -> (Option<Volume>, Conv3dGrads) {
        self.check_input(x);
        let out = self.out_dims(x.dims);
        assert_eq!((grad_out.channels, grad_out.dims), (self.cout, out), "conv3d backward: gradient size");
        let plane = out[0] * out[1];
        let n_out: usize = out.iter().product();
        let taps = self.taps();
        let [nx, ny, nz] = x.dims;
        // Each slab: its weight gradient, and its input gradient over the
        // input planes it reads, summed below in slab order (deterministic
        // for a given thread count).
        type Part = (Vec<f32>, Option<(usize, usize, Vec<f32>)>);
        let parts: Vec<Part> = self
            .slabs(out)
            .into_par_iter()
            .map(|slab| {
                let col = self.im2col(x, out, slab);
                let cols = (slab.z1 - slab.z0) * plane;
                let g = &grad_out.data[slab.z0 * plane..];
                let mut dw = vec![0.0f32; self.cout * taps];
                // dW (cout x taps) = grad_out band (cout x cols, rows n_out apart) · colᵀ.
                matmul(self.cout, taps, cols, &mut dw, g, (n_out, 1), &col, (1, cols), 1.0, Parallelism::None);
                let dx = want_input.then(|| {
                    let mut dcol = vec![0.0f32; taps * cols];
                    // col' (taps x cols) = Wᵀ · grad_out band.
                    matmul(
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
                    let z_lo = (slab.z0 * self.stride).saturating_sub(self.pad);
                    let z_hi = ((slab.z1 - 1) * self.stride + self.k).saturating_sub(self.pad).min(nz);
                    let planes = z_hi - z_lo;
                    let mut local = vec![0.0f32; self.cin * planes * ny * nx];
                    self.col2im(&dcol, x.dims, out, slab, &mut local, z_lo, planes);
                    (z_lo, planes, local)
                });
                (dw, dx)
            })
            .collect();
        let mut grads = Conv3dGrads { weight: vec![0.0; self.weight.len()], bias: vec![0.0; self.cout] };
        let mut dx = want_input.then(|| Volume::zeros(self.cin, x.dims));
        let chan = nz * ny * nx;
        for (dw, part) in parts {
            grads.weight.iter_mut().zip(&dw).for_each(|(a, b)| *a += b);
            if let (Some(dx), Some((z_lo, planes, local))) = (dx.as_mut(), part) {
                let len = planes * ny * nx;
                for ci in 0..self.cin {
                    let dst = &mut dx.data[ci * chan + z_lo * ny * nx..][..len];
                    dst.iter_mut().zip(&local[ci * len..][..len]).for_each(|(a, b)| *a += b);
                }
            }
        }
        for co in 0..self.cout {
            grads.bias[co] = grad_out.channel(co).iter().map(|&v| v as f64).sum::<f64>() as f32;
        }
        (dx, grads)
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

    /// The network's three shapes of layer: 5³ stride 2, 3³ stride 2, 3³ stride 1.
    const SHAPES: [(usize, usize, usize, usize, usize, [usize; 3]); 4] = [
        (1, 3, 5, 2, 2, [7, 6, 9]),
        (2, 3, 3, 2, 1, [6, 5, 7]),
        (3, 2, 3, 1, 1, [5, 4, 6]),
        (2, 2, 3, 1, 1, [1, 2, 3]),
    ];

    #[test]
    fn forward_matches_the_definition() {
        for (i, &(cin, cout, k, s, p, dims)) in SHAPES.iter().enumerate() {
            let c = layer(cin, cout, k, s, p, 10 + i as u64);
            let x = Volume::from_vec(cin, dims, pseudo_random(cin * dims.iter().product::<usize>(), 3));
            let y = c.forward(&x);
            for (a, b) in y.data.iter().zip(direct(&c, &x)) {
                assert!((*a as f64 - b).abs() < 1e-4, "shape {i}: {a} vs {b}");
            }
        }
    }

    #[test]
    fn gradients_match_finite_differences() {
        for (i, &(cin, cout, k, s, p, dims)) in SHAPES.iter().enumerate() {
            let c = layer(cin, cout, k, s, p, 20 + i as u64);
            let x = Volume::from_vec(cin, dims, pseudo_random(cin * dims.iter().product::<usize>(), 5));
            let out = c.out_dims(dims);
            let w = pseudo_random(cout * out.iter().product::<usize>(), 6);
            let (dx, g) = c.backward(&x, &Volume::from_vec(cout, out, w.clone()), true);
            // The map is linear in each argument, so a large step is exact.
            let r = check_gradient(
                &x.data,
                &dx.unwrap().data,
                |q| dot(&w, &c.forward(&Volume::from_vec(cin, dims, q.to_vec())).data),
                0.1,
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
                0.1,
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
}
