//! The smooth velocity parametrisation of velocity mode: the density moves
//! by `v = S w`, where `w` are the optimised parameters and `S` is one pass
//! of the separable tent `[1, 2, 1] / 4` along x, y and z, zero outside the
//! grid (docs/design/volumes.md says why per-voxel velocities turn
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
    let mut out = vec![[0f32; 3]; w.len()];
    tent_smooth_into(w.as_flattened(), 3, dims, out.as_flattened_mut());
    out
}

/// [`tent_smooth`] for a field of `comps` interleaved values per voxel
/// (1 for a scalar field such as the density scale).
///
/// # Panics
/// If `w.len()` is not `comps` times the voxel count of `dims`.
pub fn tent_smooth_flat(w: &[f32], comps: usize, dims: [usize; 3]) -> Vec<f32> {
    let mut out = vec![0f32; w.len()];
    tent_smooth_into(w, comps, dims, &mut out);
    out
}

/// z-planes per unit of parallel work. Each unit smooths the plane on
/// either side of its range again, so this trades 2/8 extra in-plane work
/// for never writing or re-reading a whole-grid intermediate.
const PLANES_PER_UNIT: usize = 8;

/// [`tent_smooth_flat`] into `out` (same length as `w`, overwritten).
///
/// Each unit of work walks its z-planes with a ring of three x-then-y
/// smoothed planes, which stay in cache, so the grid is read once and
/// written once: the pass is bound by memory, and this is about half the
/// traffic of smoothing a whole scratch grid in x and y before z.
///
/// # Panics
/// If `w` or `out` is not `comps` times the voxel count of `dims` long.
pub fn tent_smooth_into(w: &[f32], comps: usize, dims: [usize; 3], out: &mut [f32]) {
    assert_eq!(w.len(), comps * dims.iter().product::<usize>(), "field length must match dims");
    assert_eq!(out.len(), w.len(), "output length must match the field");
    let [nx, ny, nz] = dims;
    let (row, plane) = (comps * nx, comps * nx * ny);
    if w.is_empty() {
        return;
    }
    // Plane z smoothed along x (into the scratch `xs`), then y (into `dst`).
    let smooth_xy = |z: usize, xs: &mut [f32], dst: &mut [f32]| {
        for (o, r) in xs.chunks_mut(row).zip(w[z * plane..][..plane].chunks(row)) {
            tent_line(o, r, comps);
        }
        tent_line(dst, xs, row);
    };
    out.par_chunks_mut(plane * PLANES_PER_UNIT).enumerate().for_each_init(
        || (vec![0f32; plane], [vec![0f32; plane], vec![0f32; plane], vec![0f32; plane]]),
        |(xs, ring), (unit, o)| {
            // ring[z % 3] holds plane z smoothed in x and y, for z - 1 ..= z + 1.
            let z0 = unit * PLANES_PER_UNIT;
            if z0 > 0 {
                smooth_xy(z0 - 1, xs, &mut ring[(z0 - 1) % 3]);
            }
            smooth_xy(z0, xs, &mut ring[z0 % 3]);
            for (z, o) in (z0..).zip(o.chunks_mut(plane)) {
                if z + 1 < nz {
                    smooth_xy(z + 1, xs, &mut ring[(z + 1) % 3]);
                }
                let lo = (z > 0).then(|| &ring[(z - 1) % 3][..]);
                let hi = (z + 1 < nz).then(|| &ring[(z + 1) % 3][..]);
                tent3(o, lo, &ring[z % 3], hi);
            }
        },
    );
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
        // nz = 17, 9: several units of PLANES_PER_UNIT planes, one of them short.
        for dims in [[6, 5, 4], [1, 1, 1], [1, 3, 2], [2, 1, 5], [9, 2, 1], [3, 4, 17], [2, 2, 9]] {
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
