//! The smooth velocity parametrisation of velocity mode: the density moves
//! by `v = S w`, where `w` are the optimised parameters and `S` is one pass
//! of the separable tent `[1, 2, 1] / 4` along x, y and z, zero outside the
//! grid (docs/VOLUME_LOOK.md, section 2, says why per-voxel velocities turn
//! into voxel-scale noise).
//!
//! `S` is symmetric, so one kernel serves the forward (`v = S w`) and the
//! backward (`∂L/∂w = S ∂L/∂v`). It runs once per direction and iteration, so
//! it is written to touch memory as little as possible: x and y are smoothed
//! plane by plane in cache, z in a second sweep, with one scratch grid.

use rayon::prelude::*;

/// `out = c / 2 + (lo + hi) / 4`, with a missing neighbour read as zero:
/// one tap of the tent along whichever axis `lo`, `c` and `hi` are
/// consecutive samples of (x within a row, y within a plane, z across planes).
fn tent3(out: &mut [f32], lo: Option<&[f32]>, c: &[f32], hi: Option<&[f32]>) {
    match (lo, hi) {
        (Some(lo), Some(hi)) => {
            for (((o, l), c), h) in out.iter_mut().zip(lo).zip(c).zip(hi) {
                *o = 0.5 * c + 0.25 * (l + h);
            }
        }
        (Some(n), None) | (None, Some(n)) => {
            for ((o, n), c) in out.iter_mut().zip(n).zip(c) {
                *o = 0.5 * c + 0.25 * n;
            }
        }
        (None, None) => out.iter_mut().zip(c).for_each(|(o, c)| *o = 0.5 * c),
    }
}

/// One tent pass along a line of `n` samples that are `stride` floats apart
/// (the x axis of a row of `[f32; 3]` vectors has stride 3).
fn tent_line(out: &mut [f32], src: &[f32], stride: usize) {
    let len = src.len();
    if len <= stride {
        tent3(out, None, src, None);
        return;
    }
    tent3(&mut out[..stride], None, &src[..stride], Some(&src[stride..2 * stride]));
    if len > 2 * stride {
        tent3(
            &mut out[stride..len - stride],
            Some(&src[..len - 2 * stride]),
            &src[stride..len - stride],
            Some(&src[2 * stride..]),
        );
    }
    tent3(&mut out[len - stride..], Some(&src[len - 2 * stride..len - stride]), &src[len - stride..], None);
}

/// `S w`: one pass of the separable tent `[1, 2, 1] / 4` along every axis
/// of a per-voxel vector field on a grid of `dims` voxels (x fastest), zero
/// outside the grid. `S` averages with non-negative weights that sum to at
/// most 1, so `‖w‖ ≤ vmax` everywhere implies `‖S w‖ ≤ vmax`, and it is its
/// own adjoint.
///
/// # Panics
/// If `w.len()` is not the voxel count of `dims`.
pub fn tent_smooth(w: &[[f32; 3]], dims: [usize; 3]) -> Vec<[f32; 3]> {
    assert_eq!(w.len(), dims.iter().product::<usize>(), "field length must match dims");
    let out = tent_smooth_flat(w.as_flattened(), 3, dims);
    out.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
}

/// [`tent_smooth`] for a field of `comps` interleaved values per voxel
/// (1 for a scalar field such as the density scale).
///
/// # Panics
/// If `w.len()` is not `comps` times the voxel count of `dims`.
pub fn tent_smooth_flat(w: &[f32], comps: usize, dims: [usize; 3]) -> Vec<f32> {
    assert_eq!(w.len(), comps * dims.iter().product::<usize>(), "field length must match dims");
    let [nx, ny, nz] = dims;
    let (row, plane) = (comps * nx, comps * nx * ny);
    let mut out = vec![0f32; w.len()];
    if w.is_empty() {
        return out;
    }
    // x, then y, inside each z-plane: the plane stays in cache.
    let mut xy = vec![0f32; w.len()];
    xy.par_chunks_mut(plane).zip(w.par_chunks(plane)).for_each_init(
        || vec![0f32; plane],
        |xs, (dst, s)| {
            for (o, r) in xs.chunks_mut(row).zip(s.chunks(row)) {
                tent_line(o, r, comps);
            }
            tent_line(dst, xs, row);
        },
    );
    // z: each output plane from three smoothed planes.
    out.par_chunks_mut(plane).enumerate().for_each(|(z, o)| {
        let at = |k: usize| &xy[k * plane..][..plane];
        let lo = (z > 0).then(|| at(z - 1));
        let hi = (z + 1 < nz).then(|| at(z + 1));
        tent3(o, lo, at(z), hi);
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::pseudo_random;

    fn field(n: usize, seed: u64) -> Vec<[f32; 3]> {
        pseudo_random(3 * n, seed).chunks(3).map(|c| [c[0], c[1], c[2]]).collect()
    }

    /// The tent written out voxel by voxel, 27 taps: what the fused sweeps
    /// must reproduce.
    fn tent_direct(w: &[[f32; 3]], [nx, ny, nz]: [usize; 3]) -> Vec<[f32; 3]> {
        let wt = [0.25f32, 0.5, 0.25];
        let mut out = vec![[0f32; 3]; w.len()];
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    let o = &mut out[(z * ny + y) * nx + x];
                    for (dz, wz) in wt.iter().enumerate() {
                        for (dy, wy) in wt.iter().enumerate() {
                            for (dx, wx) in wt.iter().enumerate() {
                                let (i, j, k) = ((x + dx) as isize - 1, (y + dy) as isize - 1, (z + dz) as isize - 1);
                                if i < 0 || j < 0 || k < 0 || i >= nx as isize || j >= ny as isize || k >= nz as isize {
                                    continue;
                                }
                                let q = w[((k as usize) * ny + j as usize) * nx + i as usize];
                                (0..3).for_each(|a| o[a] += wx * wy * wz * q[a]);
                            }
                        }
                    }
                }
            }
        }
        out
    }

    #[test]
    fn fused_sweeps_match_the_direct_tent() {
        for dims in [[6, 5, 4], [1, 1, 1], [1, 3, 2], [2, 1, 5], [9, 2, 1]] {
            let n = dims.iter().product();
            let w = field(n, 3);
            let (a, b) = (tent_smooth(&w, dims), tent_direct(&w, dims));
            for (p, q) in a.iter().zip(&b) {
                for k in 0..3 {
                    assert!((p[k] - q[k]).abs() < 1e-6, "{dims:?}: {p:?} vs {q:?}");
                }
            }
        }
    }

    #[test]
    fn tent_is_self_adjoint_and_keeps_the_interior_of_a_constant() {
        let dims = [6, 5, 4];
        let (a, b) = (field(120, 11), field(120, 12));
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
}
