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
