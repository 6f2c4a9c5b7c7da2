//! Grid resampling between octaves of the multi-scale optimisation: the
//! density is box-filtered down by 2 for a coarse octave, and the coarse
//! velocity (or scale) field is brought back up trilinearly.
//!
//! Both use the voxel-centre convention of PyTorch's `align_corners=False`:
//! coarse voxel `i` covers fine voxels `2i, 2i+1` and sits at fine coordinate
//! `2i + 0.5`, so down- and up-sampling do not shift the smoke.

use nst3d_core::Grid3;
use rayon::prelude::*;

/// Halves the resolution with a 2x2x2 box filter (mean of the children). Odd
/// sizes round up; a border voxel then averages only the children that exist.
pub fn downsample2(g: &Grid3) -> Grid3 {
    let [nx, ny, nz] = g.dims;
    let dims = g.dims.map(|n| n.div_ceil(2));
    let [ox, oy, _] = dims;
    let mut out = Grid3::zeros(dims);
    if out.is_empty() {
        return out;
    }
    out.data.par_chunks_mut(ox).enumerate().for_each(|(r, row)| {
        let (y, z) = (r % oy, r / oy);
        let ys = 2 * y..(2 * y + 2).min(ny);
        let zs = 2 * z..(2 * z + 2).min(nz);
        for (x, o) in row.iter_mut().enumerate() {
            let xs = 2 * x..(2 * x + 2).min(nx);
            let mut sum = 0f32;
            for zz in zs.clone() {
                for yy in ys.clone() {
                    sum += g.data[g.index(xs.start, yy, zz)..][..xs.len()].iter().sum::<f32>();
                }
            }
            *o = sum / (xs.len() * ys.len() * zs.len()) as f32;
        }
    });
    out
}

/// Backward of [`downsample2`]: the gradient w.r.t. the fine grid of `dims`
/// voxels from the gradient w.r.t. the coarse one; each fine voxel gets its
/// parent's gradient divided by the number of children the parent averaged.
///
/// # Panics
/// If `grad` is not the size of `dims` halved (rounded up).
pub fn downsample2_backward(dims: [usize; 3], grad: &Grid3) -> Grid3 {
    assert_eq!(grad.dims, dims.map(|n| n.div_ceil(2)), "coarse gradient must be the fine dims halved");
    let [nx, ny, nz] = dims;
    let mut out = Grid3::zeros(dims);
    if out.is_empty() {
        return out;
    }
    let count = |i: usize, n: usize| (2 * i + 2).min(n) - 2 * i;
    out.data.par_chunks_mut(nx).enumerate().for_each(|(r, row)| {
        let (y, z) = (r % ny, r / ny);
        let (cy, cz) = (y / 2, z / 2);
        for (x, o) in row.iter_mut().enumerate() {
            let cx = x / 2;
            let children = count(cx, nx) * count(cy, ny) * count(cz, nz);
            *o = grad.data[grad.index(cx, cy, cz)] / children as f32;
        }
    });
    out
}

/// Linear-interpolation taps along one axis for resizing `from` -> `to`
/// samples, exactly as PyTorch's `interpolate(..., align_corners=False)`
/// computes them (source index clamped at 0, upper neighbour clamped).
fn axis_taps(from: usize, to: usize) -> Vec<(usize, usize, f32)> {
    let scale = from as f32 / to as f32;
    (0..to)
        .map(|o| {
            let src = ((o as f32 + 0.5) * scale - 0.5).max(0.0);
            let i0 = (src as usize).min(from - 1);
            let i1 = (i0 + 1).min(from - 1);
            (i0, i1, src - i0 as f32)
        })
        .collect()
}

/// Trilinear resize of a field of `C`-vectors from `from` to `to` dims; a source with
/// no voxels gives zeros.
fn resize_impl<const C: usize>(
    get: impl Fn(usize) -> [f32; C] + Sync,
    from: [usize; 3],
    to: [usize; 3],
) -> Vec<[f32; C]> {
    let n: usize = to.iter().product();
    let mut out = vec![[0f32; C]; n];
    if n == 0 || from.contains(&0) {
        return out;
    }
    let tx = axis_taps(from[0], to[0]);
    let ty = axis_taps(from[1], to[1]);
    let tz = axis_taps(from[2], to[2]);
    let idx = |x: usize, y: usize, z: usize| (z * from[1] + y) * from[0] + x;
    out.par_chunks_mut(to[0]).enumerate().for_each(|(r, row)| {
        let (y0, y1, fy) = ty[r % to[1]];
        let (z0, z1, fz) = tz[r / to[1]];
        for (o, &(x0, x1, fx)) in row.iter_mut().zip(&tx) {
            let corners = [
                (idx(x0, y0, z0), (1.0 - fx) * (1.0 - fy) * (1.0 - fz)),
                (idx(x1, y0, z0), fx * (1.0 - fy) * (1.0 - fz)),
                (idx(x0, y1, z0), (1.0 - fx) * fy * (1.0 - fz)),
                (idx(x1, y1, z0), fx * fy * (1.0 - fz)),
                (idx(x0, y0, z1), (1.0 - fx) * (1.0 - fy) * fz),
                (idx(x1, y0, z1), fx * (1.0 - fy) * fz),
                (idx(x0, y1, z1), (1.0 - fx) * fy * fz),
                (idx(x1, y1, z1), fx * fy * fz),
            ];
            for (i, w) in corners {
                let v = get(i);
                for c in 0..C {
                    o[c] += w * v[c];
                }
            }
        }
    });
    out
}

/// Trilinear resize of a scalar grid to `dims`, matching PyTorch's
/// `F.interpolate(mode="trilinear", align_corners=False)` (e.g. to bring a
/// coarse density-scale field to the next octave).
pub fn resize_grid(g: &Grid3, dims: [usize; 3]) -> Grid3 {
    let v = resize_impl::<1>(|i| [g.data[i]], g.dims, dims);
    Grid3::from_vec(dims, v.into_iter().map(|[x]| x).collect())
}

/// Trilinear resize of a velocity field from `from` to `to` dims (as
/// [`resize_grid`]); each component is also scaled by `to / from` along its
/// axis because velocities are measured in voxels of their own grid.
///
/// # Panics
/// If `v.len()` is not the voxel count of `from`.
pub fn resize_velocity(v: &[[f32; 3]], from: [usize; 3], to: [usize; 3]) -> Vec<[f32; 3]> {
    assert_eq!(v.len(), from.iter().product::<usize>(), "velocity length must match `from` dims");
    let ratio: [f32; 3] = std::array::from_fn(|a| to[a] as f32 / from[a].max(1) as f32);
    let mut out = resize_impl::<3>(|i| v[i], from, to);
    out.par_iter_mut().for_each(|u| *u = std::array::from_fn(|a| u[a] * ratio[a]));
    out
}

#[cfg(test)]
mod tests {
    #[test]
    fn downsample2_backward_matches_finite_differences() {
        use nst3d_core::gradcheck::{check_gradient, dot, pseudo_random};
        // Odd sizes: border parents average fewer children.
        let dims = [5, 4, 3];
        let g = Grid3::from_vec(dims, pseudo_random(60, 1));
        let w = Grid3::from_vec([3, 2, 2], pseudo_random(12, 2));
        let analytic = downsample2_backward(dims, &w);
        let r = check_gradient(
            &g.data,
            &analytic.data,
            |x| dot(&w.data, &downsample2(&Grid3::from_vec(dims, x.to_vec())).data),
            1e-3,
            60,
            1e-4,
        );
        assert!(r.max_rel_err < 1e-3, "{r:?}");
    }

    use super::*;

    #[test]
    fn downsample_averages_blocks() {
        let g = Grid3::from_vec([3, 2, 2], (0..12).map(|i| i as f32).collect());
        let d = downsample2(&g);
        assert_eq!(d.dims, [2, 1, 1]);
        // Block x in {0,1}: values 0,1,3,4,6,7,9,10 -> mean 5; x = 2: 2,5,8,11 -> 6.5.
        assert_eq!(d.data, vec![5.0, 6.5]);
    }

    #[test]
    fn resize_constant_and_roundtrip() {
        let g = Grid3::from_vec([4, 4, 4], vec![2.5; 64]);
        let up = resize_grid(&g, [8, 7, 9]);
        assert!(up.data.iter().all(|v| (v - 2.5).abs() < 1e-6));
        let v = vec![[1.0, -2.0, 0.5]; 64];
        let vu = resize_velocity(&v, [4, 4, 4], [8, 8, 2]);
        assert!(vu
            .iter()
            .all(|u| (u[0] - 2.0).abs() < 1e-6 && (u[1] + 4.0).abs() < 1e-6 && (u[2] - 0.25).abs() < 1e-6));
    }
}
