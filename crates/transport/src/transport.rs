//! The two transport modes the optimiser drives: velocity mode, the linear
//! mapping `T(d, v) = I(d, g + v)` (paper eq. 2), and density mode,
//! `d · s` (eq. 5), together with the hard limiters of Sec. 3.3 that keep the
//! stylisation inside artist-set bounds.

use crate::sample::{sample_trilinear_rows, sample_trilinear_rows_backward};
use nst3d_core::Grid3;
use rayon::prelude::*;

/// Row filler for the sampling kernel: positions `g + v(g)` of grid row `r = z·ny + y`.
fn mapped_positions(v: &[[f32; 3]], nx: usize, ny: usize) -> impl Fn(usize, &mut [[f32; 3]]) + Sync + '_ {
    move |r, pos| {
        let (y, z) = ((r % ny) as f32, (r / ny) as f32);
        for (x, (p, vi)) in pos.iter_mut().zip(&v[r * nx..][..nx]).enumerate() {
            *p = [x as f32 + vi[0], y + vi[1], z + vi[2]];
        }
    }
}

/// Velocity mode, linear mapping `d*(g) = I(d, g + v(g))` with trilinear `I`
/// (paper eq. 2). `v` is in voxel units, one `[x, y, z]` vector per voxel in
/// the grid's order; density sampled from outside the grid is 0.
///
/// # Panics
/// If `v.len() != d.len()`.
pub fn advect_linear(d: &Grid3, v: &[[f32; 3]]) -> Grid3 {
    assert_eq!(v.len(), d.len(), "velocity field must have one vector per voxel");
    let [nx, ny, _] = d.dims;
    let data = sample_trilinear_rows(d, d.len(), nx.max(1), mapped_positions(v, nx, ny));
    Grid3::from_vec(d.dims, data)
}

/// Backward of [`advect_linear`] w.r.t. the velocity: *writes*
/// `grad_v = ∂L/∂v` given `grad_out = ∂L/∂d*`. Each voxel's gradient depends
/// only on its own sample, so there is no scatter.
///
/// # Panics
/// If `v`, `grad_out` or `grad_v` do not have one entry per voxel.
pub fn advect_linear_backward(d: &Grid3, v: &[[f32; 3]], grad_out: &[f32], grad_v: &mut [[f32; 3]]) {
    assert_eq!(v.len(), d.len(), "velocity field must have one vector per voxel");
    let [nx, ny, _] = d.dims;
    sample_trilinear_rows_backward(d, d.len(), nx.max(1), mapped_positions(v, nx, ny), grad_out, None, Some(grad_v));
}

/// One pass of the separable tent filter `[1, 2, 1] / 4` along every axis of
/// a per-voxel vector field on a grid of `dims`, zero outside the grid. It is
/// symmetric (its own adjoint), so it serves as forward and backward of the
/// smooth velocity parametrisation `v = S w`.
///
/// # Panics
/// If `w.len()` is not the voxel count of `dims`.
pub fn tent_smooth(w: &[[f32; 3]], dims: [usize; 3]) -> Vec<[f32; 3]> {
    assert_eq!(w.len(), dims.iter().product::<usize>(), "field length must match dims");
    let [nx, ny, nz] = dims;
    let strides = [1, nx, nx * ny];
    let mut cur = w.to_vec();
    for (a, &n) in [nx, ny, nz].iter().enumerate() {
        let st = strides[a];
        let src = cur.clone();
        cur.par_chunks_mut(nx.max(1)).enumerate().for_each(|(r, row)| {
            let (y, z) = (r % ny, r / ny);
            for (x, o) in row.iter_mut().enumerate() {
                let i = r * nx + x;
                let c = [x, y, z][a];
                let mut acc = src[i].map(|t| 0.5 * t);
                if c > 0 {
                    let q = src[i - st];
                    (0..3).for_each(|k| acc[k] += 0.25 * q[k]);
                }
                if c + 1 < n {
                    let q = src[i + st];
                    (0..3).for_each(|k| acc[k] += 0.25 * q[k]);
                }
                *o = acc;
            }
        });
    }
    cur
}

/// Per-voxel magnitude limiter `‖v‖ ≤ vmax` (paper Sec. 3.3): vectors longer
/// than `vmax` are shortened to it, keeping their direction, so the artist's
/// single parameter bounds how far the stylisation can move smoke. Applied as
/// a projection after each optimiser step; a negative `vmax` acts as 0.
pub fn limit_velocity(v: &mut [[f32; 3]], vmax: f32) {
    let vmax = vmax.max(0.0);
    v.par_iter_mut().for_each(|vi| {
        let n2 = vi[0] * vi[0] + vi[1] * vi[1] + vi[2] * vi[2];
        if n2 > vmax * vmax {
            let k = vmax / n2.sqrt();
            *vi = vi.map(|c| c * k);
        }
    });
}

/// Density mode `d* = d · s` (paper eq. 5): the optimiser may only modulate
/// existing smoke, never create it where `d = 0`.
///
/// # Panics
/// If `s.len() != d.len()`.
pub fn modulate(d: &Grid3, s: &[f32]) -> Grid3 {
    assert_eq!(s.len(), d.len(), "scale field must have one value per voxel");
    let mut out = vec![0f32; d.len()];
    out.par_iter_mut().zip(d.data.par_iter().zip(s)).for_each(|(o, (a, b))| *o = a * b);
    Grid3::from_vec(d.dims, out)
}

/// Backward of [`modulate`] w.r.t. the scale: *writes* `grad_s = grad_out · d`.
///
/// # Panics
/// If `grad_out` or `grad_s` do not have one entry per voxel.
pub fn modulate_backward(d: &Grid3, grad_out: &[f32], grad_s: &mut [f32]) {
    assert_eq!(grad_out.len(), d.len(), "grad_out must have one value per voxel");
    assert_eq!(grad_s.len(), d.len(), "grad_s must have one value per voxel");
    grad_s.par_iter_mut().zip(grad_out.par_iter().zip(&d.data)).for_each(|(g, (a, b))| *g = a * b);
}

/// Clamps the density scale to `[smin, smax]` (the constraint of eq. 5),
/// applied after each optimiser step. If `smin > smax`, `smax` wins (no panic).
pub fn clamp_scale(s: &mut [f32], smin: f32, smax: f32) {
    s.par_iter_mut().for_each(|x| *x = x.max(smin).min(smax));
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::{check_gradient, dot, pseudo_random};

    fn velocity(n: usize, seed: u64, scale: f32) -> Vec<[f32; 3]> {
        let r = pseudo_random(3 * n, seed);
        // Keep fractional parts away from 0 so finite differences never cross a kink.
        (0..n)
            .map(|i| {
                std::array::from_fn(|a| {
                    let x = r[3 * i + a] * scale;
                    let f = x - x.floor();
                    if (f - 0.5).abs() > 0.4 {
                        x.floor() + 0.5
                    } else {
                        x
                    }
                })
            })
            .collect()
    }

    #[test]
    fn zero_velocity_is_identity() {
        let dims = [6, 5, 4];
        let d = Grid3::from_vec(dims, pseudo_random(120, 1));
        assert_eq!(advect_linear(&d, &vec![[0.0; 3]; 120]), d);
    }

    #[test]
    fn integer_shift_moves_density() {
        let dims = [6, 5, 4];
        let d = Grid3::from_vec(dims, pseudo_random(120, 2));
        let out = advect_linear(&d, &vec![[1.0, 0.0, -1.0]; 120]);
        assert_eq!(out.at(2, 3, 1), d.at(3, 3, 0));
        assert_eq!(out.at(5, 3, 1), 0.0);
        assert_eq!(out.at(2, 3, 0), 0.0);
    }

    #[test]
    fn advect_gradient_check() {
        let dims = [7, 6, 5];
        let n = 210;
        let d = Grid3::from_vec(dims, pseudo_random(n, 3));
        let v = velocity(n, 4, 1.7);
        let w = pseudo_random(n, 5);
        let mut gv = vec![[0f32; 3]; n];
        advect_linear_backward(&d, &v, &w, &mut gv);
        let flat: Vec<f32> = v.iter().flatten().copied().collect();
        let gflat: Vec<f32> = gv.iter().flatten().copied().collect();
        let r = check_gradient(
            &flat,
            &gflat,
            |x| {
                let vv: Vec<[f32; 3]> = x.chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
                dot(&w, &advect_linear(&d, &vv).data)
            },
            1e-3,
            630,
            1e-2,
        );
        assert!(r.max_rel_err < 1e-2, "{r:?}");
    }

    #[test]
    fn modulate_gradient_check() {
        let dims = [4, 3, 5];
        let d = Grid3::from_vec(dims, pseudo_random(60, 6));
        let s = pseudo_random(60, 7);
        let w = pseudo_random(60, 8);
        let mut gs = vec![0f32; 60];
        modulate_backward(&d, &w, &mut gs);
        let r = check_gradient(&s, &gs, |x| dot(&w, &modulate(&d, x).data), 1e-2, 60, 1e-3);
        assert!(r.max_rel_err < 1e-3, "{r:?}");
    }

    /// Every velocity starts at 0, on voxel centres, where the trilinear
    /// sample has a kink. The gradient there must be the central difference:
    /// on a bump symmetric about x = 3 the x-gradients of x = 2 and x = 4 are
    /// opposite and the one at the peak is 0. The forward difference gave
    /// (d3 - d2, 0 - d3 ... ): a peak voxel pulled towards -x and both
    /// flanks' gradients shifted half a voxel towards +x.
    #[test]
    fn gradient_at_voxel_centres_is_the_central_difference() {
        let dims = [7, 3, 3];
        let bump = [0.0, 0.2, 0.6, 1.0, 0.6, 0.2, 0.0];
        let d = Grid3::from_vec(dims, (0..63).map(|i| bump[i % 7]).collect());
        let mut gv = vec![[0f32; 3]; 63];
        advect_linear_backward(&d, &vec![[0.0; 3]; 63], &vec![1.0; 63], &mut gv);
        let at = |x: usize| gv[(3 + 1) * 7 + x]; // the middle row y = 1, z = 1
        assert_eq!(at(3)[0], 0.0, "peak: no slope to either side");
        assert!((at(2)[0] - 0.4).abs() < 1e-6 && (at(4)[0] + 0.4).abs() < 1e-6, "{:?} {:?}", at(2), at(4));
        for x in 1..6 {
            assert!((at(x)[0] + at(6 - x)[0]).abs() < 1e-6, "asymmetric at x = {x}: {:?}", gv);
        }
        // The border voxel's slope sees the zero padding beyond it.
        assert!((at(0)[0] - 0.1).abs() < 1e-6);
        // Uniform along y and z: the central difference is 0 inside, and
        // half the drop to the padding on the faces.
        assert_eq!(at(3)[1], 0.0);
        assert!((gv[3][1] - 0.5).abs() < 1e-6, "face y = 0: {:?}", gv[3]);
    }

    #[test]
    fn tent_is_self_adjoint_and_keeps_the_interior_of_a_constant() {
        let dims = [6, 5, 4];
        let r = pseudo_random(360, 11);
        let a: Vec<[f32; 3]> = r.chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
        let r = pseudo_random(360, 12);
        let b: Vec<[f32; 3]> = r.chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
        let dot3 = |x: &[[f32; 3]], y: &[[f32; 3]]| -> f64 {
            x.iter().zip(y).map(|(p, q)| (0..3).map(|k| (p[k] * q[k]) as f64).sum::<f64>()).sum()
        };
        let (sa, sb) = (tent_smooth(&a, dims), tent_smooth(&b, dims));
        assert!((dot3(&sa, &b) - dot3(&a, &sb)).abs() < 1e-4);
        let c = tent_smooth(&vec![[1.0, -2.0, 0.5]; 120], dims);
        assert_eq!(c[(2 * 5 + 2) * 6 + 2], [1.0, -2.0, 0.5]);
        // A corner keeps (3/4)^3 of it: zero outside the grid.
        assert!((c[0][0] - 0.421875).abs() < 1e-6);
        assert!(c.iter().all(|u| (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt() <= 2.3 + 1e-5));
    }

    #[test]
    fn limiters() {
        let mut v = vec![[3.0, 4.0, 0.0], [0.1, 0.0, 0.0]];
        limit_velocity(&mut v, 1.0);
        assert!((v[0][0] - 0.6).abs() < 1e-6 && (v[0][1] - 0.8).abs() < 1e-6);
        assert_eq!(v[1], [0.1, 0.0, 0.0]);
        let mut s = vec![-1.0, 0.5, 3.0];
        clamp_scale(&mut s, 0.0, 2.0);
        assert_eq!(s, vec![0.0, 0.5, 2.0]);
    }
}
