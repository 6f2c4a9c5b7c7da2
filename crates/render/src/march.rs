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

/// The colour march: emission–absorption, `I_ch = Σ_k e_ch,k · τ_k`
/// for each channel `ch`, with the same transmittance
/// `τ_k = exp(−γ · Σ_{j<k} d_j)` as [`march`]. The emission is premultiplied,
/// `e = c · d` for a colour `c` per voxel, so it resamples linearly like the
/// density (colour and density interpolated apart would darken every edge
/// the zero padding touches), and `e = d` (white) is [`march`]'s image in
/// every channel. `emission` holds one grid per channel, each of `g`'s dims;
/// the image has as many channels.
///
/// # Panics
/// If an emission grid's dims differ from `g`'s.
pub fn march_emission(g: &Grid3, emission: &[Grid3], gamma: f32) -> Image {
    let [nx, ny, nz] = g.dims;
    assert!(emission.iter().all(|c| c.dims == g.dims), "march_emission: emission grids must have the density's dims");
    let mut img = Image::zeros(emission.len(), ny, nx);
    if img.data.is_empty() {
        return img;
    }
    // One task per image row `y`, writing that row of every channel.
    let mut rows: Vec<Vec<&mut [f32]>> = (0..ny).map(|_| Vec::with_capacity(emission.len())).collect();
    for (r, row) in img.data.chunks_mut(nx).enumerate() {
        rows[r % ny].push(row);
    }
    rows.into_par_iter().enumerate().for_each(|(y, mut out)| {
        let mut depth = vec![0f32; nx];
        let mut tau = vec![0f32; nx];
        for z in 0..nz {
            let at = (z * ny + y) * nx;
            for ((t, acc), &dv) in tau.iter_mut().zip(&mut depth).zip(&g.data[at..][..nx]) {
                *t = (-gamma * *acc).exp();
                *acc += dv;
            }
            for (o, e) in out.iter_mut().zip(emission) {
                for ((o, &t), &ev) in o.iter_mut().zip(&tau).zip(&e.data[at..][..nx]) {
                    *o += ev * t;
                }
            }
        }
    });
    img
}

/// Backward of [`march_emission`]: `(∂L/∂d, ∂L/∂e)` for `grad_img = ∂L/∂I`
/// (`channels x ny x nx`).
///
/// `∂I_ch/∂e_ch,k = τ_k`; `∂I_ch/∂d_k = −γ S_ch,k` with `S_ch,k = Σ_{j>k}
/// e_ch,j τ_j` the light emitted behind voxel `k`, read off a running prefix
/// sum as in [`march_backward`]; the channels' density gradients add.
///
/// # Panics
/// If the emission grids or `grad_img` do not match `g`.
pub fn march_emission_backward(g: &Grid3, emission: &[Grid3], gamma: f32, grad_img: &Image) -> (Grid3, Vec<Grid3>) {
    let [nx, ny, nz] = g.dims;
    let channels = emission.len();
    assert!(
        emission.iter().all(|c| c.dims == g.dims),
        "march_emission_backward: emission grids must have the density's dims"
    );
    assert!(
        grad_img.channels == channels && grad_img.height == ny && grad_img.width == nx,
        "march_emission_backward: gradient image must be {channels} x {ny} x {nx}"
    );
    let mut grad_d = Grid3::zeros(g.dims);
    let mut grad_e: Vec<Grid3> = (0..channels).map(|_| Grid3::zeros(g.dims)).collect();
    if grad_d.is_empty() {
        return (grad_d, grad_e);
    }
    // Each task owns every output row with its `y` (density and emission), so
    // the strided writes stay disjoint.
    struct Slab<'a> {
        d: Vec<&'a mut [f32]>,
        e: Vec<Vec<&'a mut [f32]>>,
    }
    let mut slabs: Vec<Slab> = (0..ny)
        .map(|_| Slab { d: Vec::with_capacity(nz), e: (0..channels).map(|_| Vec::with_capacity(nz)).collect() })
        .collect();
    for (r, row) in grad_d.data.chunks_mut(nx).enumerate() {
        slabs[r % ny].d.push(row);
    }
    for (ch, ge) in grad_e.iter_mut().enumerate() {
        for (r, row) in ge.data.chunks_mut(nx).enumerate() {
            slabs[r % ny].e[ch].push(row);
        }
    }
    slabs.into_par_iter().enumerate().for_each(|(y, mut slab)| {
        // Transmittance of every voxel of this y-slab, kept for the second pass.
        let mut tau = vec![0f32; nz * nx];
        let mut depth = vec![0f32; nx];
        let mut total = vec![0f32; channels * nx];
        for z in 0..nz {
            let at = (z * ny + y) * nx;
            let d = &g.data[at..][..nx];
            let t = &mut tau[z * nx..][..nx];
            for x in 0..nx {
                t[x] = (-gamma * depth[x]).exp();
                depth[x] += d[x];
            }
            for (ch, e) in emission.iter().enumerate() {
                for (tot, (&ev, &tv)) in total[ch * nx..][..nx].iter_mut().zip(e.data[at..][..nx].iter().zip(t.iter()))
                {
                    *tot += ev * tv;
                }
            }
        }
        let mut prefix = vec![0f32; channels * nx];
        for z in 0..nz {
            let at = (z * ny + y) * nx;
            let t = &tau[z * nx..][..nx];
            slab.d[z].fill(0.0);
            for (ch, e) in emission.iter().enumerate() {
                let e = &e.data[at..][..nx];
                let gi = &grad_img.data[(ch * ny + y) * nx..][..nx];
                for x in 0..nx {
                    let p = &mut prefix[ch * nx + x];
                    *p += e[x] * t[x];
                    slab.d[z][x] -= gi[x] * gamma * (total[ch * nx + x] - *p);
                    slab.e[ch][z][x] = gi[x] * t[x];
                }
            }
        }
    });
    (grad_d, grad_e)
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

    #[test]
    fn white_emission_is_the_grey_march() {
        let dims = [5, 4, 6];
        let g = Grid3::from_vec(dims, pseudo_random(120, 21).iter().map(|v| v.abs()).collect());
        let white = vec![g.clone(); 3];
        let grey = march(&g, 0.7);
        let rgb = march_emission(&g, &white, 0.7);
        assert_eq!((rgb.channels, rgb.height, rgb.width), (3, 4, 5));
        for ch in 0..3 {
            for (a, b) in rgb.data[ch * 20..][..20].iter().zip(&grey.data) {
                assert!((a - b).abs() <= 1e-6 * (1.0 + b.abs()), "{a} vs {b}");
            }
        }
        // With e = d, the grey march's gradient is the density's plus the emission's.
        let w = Image::from_vec(1, 4, 5, pseudo_random(20, 22));
        let w3 = Image::from_vec(3, 4, 5, [w.data.clone(), vec![0.0; 20], vec![0.0; 20]].concat());
        let (gd, ge) = march_emission_backward(&g, &white, 0.7, &w3);
        let total: Vec<f32> = gd.data.iter().zip(&ge[0].data).map(|(a, b)| a + b).collect();
        for (a, b) in total.iter().zip(&march_backward(&g, 0.7, &w).data) {
            assert!((a - b).abs() <= 1e-5 * (1.0 + b.abs()), "{a} vs {b}");
        }
    }

    #[test]
    fn march_emission_gradient_check() {
        let dims = [4, 3, 6];
        let n = 72;
        let d: Vec<f32> = pseudo_random(n, 31).iter().map(|v| v.abs()).collect();
        let c: Vec<f32> = pseudo_random(3 * n, 32).iter().map(|v| 0.5 + 0.5 * v).collect();
        let gamma = 0.6;
        let split = |x: &[f32]| -> (Grid3, Vec<Grid3>) {
            let g = Grid3::from_vec(dims, x[..n].to_vec());
            let col = (0..3).map(|ch| Grid3::from_vec(dims, x[n + ch * n..][..n].to_vec())).collect();
            (g, col)
        };
        let x0 = [d, c].concat();
        let (g, col) = split(&x0);
        let w = Image::from_vec(3, 3, 4, pseudo_random(36, 33));
        let (gd, gc) = march_emission_backward(&g, &col, gamma, &w);
        let analytic = [gd.data, gc.into_iter().flat_map(|c| c.data).collect()].concat();
        let r = check_gradient(
            &x0,
            &analytic,
            |x| {
                let (g, col) = split(x);
                dot(&w.data, &march_emission(&g, &col, gamma).data)
            },
            1e-3,
            4 * n,
            1e-2,
        );
        assert!(r.max_rel_err < 5e-3, "{r:?}");
    }
}
