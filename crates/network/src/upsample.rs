//! Trilinear ×2 upsampling, the decoder's "upsample then convolve" step of
//! Fig. 9, as PyTorch's `F.interpolate(scale_factor=2, mode="trilinear",
//! align_corners=False)` computes it.
//!
//! With a factor of 2 the weights are fixed: fine sample `2i` is
//! `3/4 x[i] + 1/4 x[i−1]` and `2i+1` is `3/4 x[i] + 1/4 x[i+1]`, the
//! neighbour clamped at the border. The filter is separable: the forward
//! blends along z, then y, then x, a fine plane at a time; the backward
//! runs the transposes in the opposite order.

use rayon::prelude::*;

use crate::volume::Volume;

use std::mem::MaybeUninit;

/// The two coarse samples fine sample `f` of a ×2 axis of `n` samples
/// blends, 3/4 and 1/4: `f / 2`, and its neighbour on `f`'s side, clamped.
fn taps(f: usize, n: usize) -> (usize, usize) {
    let i = f / 2;
    (i, if f.is_multiple_of(2) { i.saturating_sub(1) } else { (i + 1).min(n - 1) })
}

/// `dst[j] = 3/4 a[j] + 1/4 b[j]`.
fn blend(dst: &mut [f32], a: &[f32], b: &[f32]) {
    dst.iter_mut().zip(a.iter().zip(b)).for_each(|(d, (a, b))| *d = 0.75 * a + 0.25 * b);
}

/// One row ×2 along x: `dst` (2n values, written once) from `row` (n).
fn up_row(dst: &mut [MaybeUninit<f32>], row: &[f32]) {
    let n = row.len();
    for (i, pair) in dst.chunks_exact_mut(2).enumerate() {
        let (lo, hi) = (row[i.saturating_sub(1)], row[(i + 1).min(n - 1)]);
        pair[0].write(0.75 * row[i] + 0.25 * lo);
        pair[1].write(0.75 * row[i] + 0.25 * hi);
    }
}

/// `x` upsampled ×2 along x, y and z (trilinear, `align_corners=False`).
///
/// One fine plane a task: its two coarse planes blended, then each fine
/// row from two blended rows, then ×2 along the row, straight into the
/// result (every value written once, nothing zeroed first).
pub fn upsample2(x: &Volume) -> Volume {
    let [nx, ny, nz] = x.dims;
    let dims = x.dims.map(|n| 2 * n);
    let fine_plane = 4 * nx * ny;
    let mut data: Vec<f32> = Vec::with_capacity(x.channels * 2 * nz * fine_plane);
    data.spare_capacity_mut().par_chunks_mut(fine_plane).enumerate().for_each_init(
        || (vec![0.0f32; nx * ny], vec![0.0f32; nx]),
        |(plane, row), (cz, dst)| {
            let (c, z) = (cz / (2 * nz), cz % (2 * nz));
            let (a, b) = taps(z, nz);
            let src = x.channel(c);
            blend(plane, &src[a * nx * ny..][..nx * ny], &src[b * nx * ny..][..nx * ny]);
            for (y, out) in dst.chunks_exact_mut(2 * nx).enumerate() {
                let (a, b) = taps(y, ny);
                blend(row, &plane[a * nx..][..nx], &plane[b * nx..][..nx]);
                up_row(out, row);
            }
        },
    );
    // SAFETY: the tasks above wrote every value of the capacity (one fine plane each).
    unsafe { data.set_len(data.capacity()) };
    Volume::from_vec(x.channels, dims, data)
}

/// The transpose of one ×2 axis at coarse sample `i` of `n`: the two fine
/// samples that read it at 3/4 (`2i`, `2i + 1`) and the two that read it
/// at 1/4 (`2i − 1`, `2i + 2`; at a border the clamped neighbour is the
/// sample itself, so the outer fine sample counts there once more).
fn down_taps(i: usize, n: usize) -> [usize; 4] {
    let lo = if i > 0 { 2 * i - 1 } else { 0 };
    let hi = if i + 1 < n { 2 * i + 2 } else { 2 * n - 1 };
    [2 * i, 2 * i + 1, lo, hi]
}

/// `dst[j] = 3/4 (a[j] + b[j]) + 1/4 (lo[j] + hi[j])`, each value written once.
fn gather(dst: &mut [MaybeUninit<f32>], [a, b, lo, hi]: [&[f32]; 4]) {
    for (j, d) in dst.iter_mut().enumerate() {
        d.write(0.75 * (a[j] + b[j]) + 0.25 * (lo[j] + hi[j]));
    }
}

/// Backward of [`upsample2`]: the gradient w.r.t. its input (of `dims`)
/// from the gradient w.r.t. its output.
///
/// Each coarse value gathers the four fine values that read it, axis by
/// axis (x, then y, one fine plane a task; then z), so every value is
/// written once and nothing is zeroed or accumulated.
///
/// # Panics
/// If `grad` is not twice `dims` along every axis.
pub fn upsample2_backward(grad: &Volume, dims: [usize; 3]) -> Volume {
    assert_eq!(grad.dims, dims.map(|n| 2 * n), "upsample2_backward: gradient size");
    let [nx, ny, nz] = dims;
    let (plane, fine_plane) = (nx * ny, 4 * nx * ny);
    let mut reduced: Vec<f32> = Vec::with_capacity(grad.channels * 2 * nz * plane);
    reduced.spare_capacity_mut().par_chunks_mut(plane).zip(grad.data.par_chunks(fine_plane)).for_each_init(
        || vec![0.0f32; 2 * ny * nx],
        |rows, (dst, fine)| {
            // x: each fine row of 2nx values to nx.
            for (row, f) in rows.chunks_exact_mut(nx).zip(fine.chunks_exact(2 * nx)) {
                for (i, r) in row.iter_mut().enumerate() {
                    let [a, b, lo, hi] = down_taps(i, nx);
                    *r = 0.75 * (f[a] + f[b]) + 0.25 * (f[lo] + f[hi]);
                }
            }
            // y: each coarse row from four of those rows.
            for (y, d) in dst.chunks_exact_mut(nx).enumerate() {
                gather(d, down_taps(y, ny).map(|r| &rows[r * nx..][..nx]));
            }
        },
    );
    // SAFETY: every fine plane's task wrote its whole coarse-sized plane.
    unsafe { reduced.set_len(reduced.capacity()) };
    let mut data: Vec<f32> = Vec::with_capacity(grad.channels * nz * plane);
    data.spare_capacity_mut().par_chunks_mut(plane).enumerate().for_each(|(cz, dst)| {
        let (c, z) = (cz / nz, cz % nz);
        gather(dst, down_taps(z, nz).map(|f| &reduced[(c * 2 * nz + f) * plane..][..plane]));
    });
    // SAFETY: every coarse plane was written above.
    unsafe { data.set_len(data.capacity()) };
    Volume::from_vec(grad.channels, dims, data)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::{check_gradient, dot, pseudo_random};

    #[test]
    fn upsample_gradient_matches_finite_differences() {
        let dims = [3, 4, 2];
        let x = Volume::from_vec(2, dims, pseudo_random(48, 3));
        let w = pseudo_random(48 * 8, 4);
        let g = upsample2_backward(&Volume::from_vec(2, dims.map(|n| 2 * n), w.clone()), dims);
        let r = check_gradient(
            &x.data,
            &g.data,
            |p| dot(&w, &upsample2(&Volume::from_vec(2, dims, p.to_vec())).data),
            1e-2,
            100,
            1e-3,
        );
        assert!(r.max_rel_err < 1e-3, "{r:?}");
    }

    /// Every fine voxel as PyTorch defines it: the 8 coarse corners around
    /// its centre, trilinear weights, borders clamped; sides of 1 included.
    #[test]
    fn matches_the_trilinear_definition() {
        let dims = [3, 1, 5];
        let x = Volume::from_vec(2, dims, pseudo_random(30, 5));
        let y = upsample2(&x);
        let w = |f: usize, n: usize| {
            // Source coordinate (f + 1/2) / 2 − 1/2, clamped at 0 as PyTorch does.
            let s = ((f as f32 + 0.5) / 2.0 - 0.5).max(0.0);
            let i = (s.floor() as usize).min(n - 1);
            (i, (i + 1).min(n - 1), s - i as f32)
        };
        for c in 0..2 {
            for z in 0..10 {
                for yy in 0..2 {
                    for xx in 0..6 {
                        let ([x0, x1, fx], [y0, y1, fy], [z0, z1, fz]) = (
                            {
                                let (a, b, f) = w(xx, 3);
                                [a as f32, b as f32, f]
                            },
                            {
                                let (a, b, f) = w(yy, 1);
                                [a as f32, b as f32, f]
                            },
                            {
                                let (a, b, f) = w(z, 5);
                                [a as f32, b as f32, f]
                            },
                        );
                        let at = |i: f32, j: f32, k: f32| {
                            x.channel(c)[((k as usize) * dims[1] + j as usize) * dims[0] + i as usize]
                        };
                        let mut want = 0.0;
                        for (k, wk) in [(z0, 1.0 - fz), (z1, fz)] {
                            for (j, wj) in [(y0, 1.0 - fy), (y1, fy)] {
                                for (i, wi) in [(x0, 1.0 - fx), (x1, fx)] {
                                    want += wk * wj * wi * at(i, j, k);
                                }
                            }
                        }
                        let got = y.channel(c)[(z * 2 + yy) * 6 + xx];
                        assert!((got - want).abs() < 1e-6, "c{c} ({xx},{yy},{z}): {got} vs {want}");
                    }
                }
            }
        }
    }

    /// The backward is the forward's adjoint, `<w, up(x)> = <up*(w), x>`,
    /// on sides of 1, 2 and more.
    #[test]
    fn the_backward_is_the_adjoint() {
        for dims in [[1, 3, 2], [4, 1, 1], [2, 5, 3]] {
            let n: usize = dims.iter().product();
            let x = Volume::from_vec(2, dims, pseudo_random(2 * n, 6));
            let w = Volume::from_vec(2, dims.map(|v| 2 * v), pseudo_random(16 * n, 7));
            let (lhs, rhs) = (dot(&w.data, &upsample2(&x).data), dot(&upsample2_backward(&w, dims).data, &x.data));
            assert!((lhs - rhs).abs() < 1e-4 * (1.0 + lhs.abs()), "{dims:?}: {lhs} vs {rhs}");
        }
    }

    #[test]
    fn constants_stay_constant() {
        let x = Volume::from_vec(1, [2, 3, 1], vec![0.5; 6]);
        assert!(upsample2(&x).data.iter().all(|v| (v - 0.5).abs() < 1e-7));
    }
}
