//! How many voxels per frame one unit of a cache's velocity means.
//!
//! Solvers store velocity in their own units (Houdini: world units per
//! second; Blender's Mantaflow cache: its internal grid units), and the EMA
//! needs voxels per frame. Rather than guess, we ask the data: the scale `s`
//! for which carrying frame `t` along `s·u_t` best predicts frame `t+1`.

use nst3d_core::Grid3;
use nst3d_transport as transport;

/// The scale (voxels per frame per stored unit) that best predicts `next`
/// from `d` advected by `s·u`, searched over displacements of 0.02–8 voxels
/// at the fastest voxel (log-spaced, then refined). Returns `None` when `u`
/// is zero everywhere.
pub fn velocity_scale(d: &Grid3, next: &Grid3, u: &[[f32; 3]]) -> Option<f32> {
    let umax = u.iter().map(|w| (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt()).fold(0f32, f32::max);
    if !(umax > 0.0 && umax.is_finite()) {
        return None;
    }
    let misfit = |s: f32| -> f64 {
        let back: Vec<[f32; 3]> = u.iter().map(|w| [-s * w[0], -s * w[1], -s * w[2]]).collect();
        let pred = transport::advect_linear(d, &back);
        pred.data.iter().zip(&next.data).map(|(a, b)| ((a - b) as f64).powi(2)).sum()
    };
    let candidates: Vec<f32> = (0..=24).map(|k| 0.02 * 400f32.powf(k as f32 / 24.0) / umax).collect();
    let (mut best, mut best_err) = (0.0f32, misfit(0.0));
    for &s in &candidates {
        let e = misfit(s);
        if e < best_err {
            (best, best_err) = (s, e);
        }
    }
    if best == 0.0 {
        return Some(0.0);
    }
    // Golden-section refinement between the neighbouring candidates.
    let ratio = 400f32.powf(1.0 / 24.0);
    let (mut lo, mut hi) = (best / ratio, best * ratio);
    let g = 0.618_034f32;
    for _ in 0..12 {
        let (a, b) = (hi - g * (hi - lo), lo + g * (hi - lo));
        if misfit(a) < misfit(b) {
            hi = b;
        } else {
            lo = a;
        }
    }
    Some(0.5 * (lo + hi))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_known_scale() {
        // A smooth blob moved 1.5 voxels along +y; the cache stores u = 30.
        let dims = [12, 16, 10];
        let mut d = Grid3::zeros(dims);
        for z in 0..10 {
            for y in 0..16 {
                for x in 0..12 {
                    let r2 = (x as f32 - 6.0).powi(2) + (y as f32 - 6.0).powi(2) + (z as f32 - 5.0).powi(2);
                    let i = d.index(x, y, z);
                    d.data[i] = (-r2 / 8.0).exp();
                }
            }
        }
        let next = transport::advect_linear(&d, &vec![[0.0, -1.5, 0.0]; d.len()]);
        let s = velocity_scale(&d, &next, &vec![[0.0, 30.0, 0.0]; d.len()]).unwrap();
        assert!((s * 30.0 - 1.5).abs() < 0.05, "scale {s} gives {} voxels", s * 30.0);
        assert_eq!(velocity_scale(&d, &next, &vec![[0.0; 3]; d.len()]), None);
    }
}
