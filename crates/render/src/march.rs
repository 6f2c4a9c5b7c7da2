//! The transmittance march of the differentiable renderer (paper eq. 6) on a
//! camera-aligned grid: slice `z = 0` is nearest the camera and
//! `I = Σ_k d_k · τ_k` with transmittance `τ_k = exp(−γ · Σ_{j<k} d_j)`,
//! exactly PyTorch reference `render` (`cumsum` along the depth axis).

use nst3d_core::{Grid3, Image};
use rayon::prelude::*;

/// Renders `g` marching along `z` (slice 0 nearest the camera) with
/// absorption `gamma`: a `1 x ny x nx` image, row `y`, column `x`.
pub fn march(g: &Grid3, gamma: f32) -> Image {
    let [nx, ny, nz] = g.dims;
    let mut img = Image::zeros(1, ny, nx);
    if img.data.is_empty() {
        return img;
    }
    // One image row per task: its `nz` source rows are contiguous runs of `nx`.
    img.data.par_chunks_mut(nx).enumerate().for_each(|(y, row)| {
        let mut depth = vec![0f32; nx];
        for z in 0..nz {
            let d = &g.data[(z * ny + y) * nx..][..nx];
            for ((o, acc), &dv) in row.iter_mut().zip(&mut depth).zip(d) {
                *o += dv * (-gamma * *acc).exp();
                *acc += dv;
            }
        }
    });
    img
}

/// Backward of [`march`]: `∂L/∂d` for `grad_img = ∂L/∂I` (`1 x ny x nx`).
///
/// With `S_k = Σ_{j>k} d_j τ_j` the light scattered behind voxel `k`,
/// `∂I/∂d_k = τ_k − γ S_k`; `S_k = I − Σ_{j≤k} d_j τ_j` is read off a running
/// prefix sum, so the cost is O(N³), not O(N⁴).
///
/// # Panics
/// If `grad_img` is not `1 x ny x nx`.
pub fn march_backward(g: &Grid3, gamma: f32, grad_img: &Image) -> Grid3 {
    let [nx, ny, nz] = g.dims;
    assert!(
        grad_img.channels == 1 && grad_img.height == ny && grad_img.width == nx,
        "march_backward: gradient image must be 1 x {ny} x {nx}"
    );
    let mut out = Grid3::zeros(g.dims);
    if out.is_empty() {
        return out;
    }
    // Each task owns every output row with its `y`, so the strided writes stay safe and disjoint.
    let mut by_y: Vec<Vec<&mut [f32]>> = (0..ny).map(|_| Vec::with_capacity(nz)).collect();
    for (r, row) in out.data.chunks_mut(nx).enumerate() {
        by_y[r % ny].push(row);
    }
    by_y.into_par_iter().enumerate().for_each(|(y, mut rows)| {
        let gy = &grad_img.data[y * nx..][..nx];
        // Transmittance of every voxel of this y-slab is kept so the second pass needs no exp.
        let mut tau = vec![0f32; nz * nx];
        let mut depth = vec![0f32; nx];
        let mut total = vec![0f32; nx];
        for z in 0..nz {
            let d = &g.data[(z * ny + y) * nx..][..nx];
            let t = &mut tau[z * nx..][..nx];
            for x in 0..nx {
                t[x] = (-gamma * depth[x]).exp();
                total[x] += d[x] * t[x];
                depth[x] += d[x];
            }
        }
        let prefix = &mut depth;
        prefix.fill(0.0);
        for (z, grow) in rows.iter_mut().enumerate() {
            let d = &g.data[(z * ny + y) * nx..][..nx];
            let t = &tau[z * nx..][..nx];
            for x in 0..nx {
                prefix[x] += d[x] * t[x];
                grow[x] = gy[x] * (t[x] - gamma * (total[x] - prefix[x]));
            }
        }
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::{check_gradient, dot, pseudo_random};

    #[test]
    fn single_column_by_hand() {
        let g = Grid3::from_vec([1, 1, 3], vec![0.5, 1.0, 2.0]);
        let gamma = 0.3f32;
        let want = 0.5 + 1.0 * (-gamma * 0.5).exp() + 2.0 * (-gamma * 1.5).exp();
        assert!((march(&g, gamma).data[0] - want).abs() < 1e-6);
    }

    #[test]
    fn march_gradient_check() {
        let dims = [5, 4, 7];
        let d: Vec<f32> = pseudo_random(140, 11).iter().map(|v| v.abs()).collect();
        let g = Grid3::from_vec(dims, d);
        let gamma = 0.6;
        let w = Image::from_vec(1, 4, 5, pseudo_random(20, 12));
        let grad = march_backward(&g, gamma, &w);
        let r = check_gradient(
            &g.data,
            &grad.data,
            |x| dot(&w.data, &march(&Grid3::from_vec(dims, x.to_vec()), gamma).data),
            1e-3,
            140,
            1e-2,
        );
        assert!(r.max_rel_err < 5e-3, "{r:?}");
    }
}
