//! Trilinear interpolation `I(d, p)` of a voxel grid at continuous positions,
//! the interpolation function of the linear-mapping transport (paper eq. 2)
//! and of the renderer's camera resampling.
//!
//! Semantics are those of PyTorch's `grid_sample(mode="bilinear",
//! padding_mode="zeros", align_corners=True)` expressed in voxel-index
//! coordinates: voxel centres sit at integers, and each of the 8 cell corners
//! that falls outside the grid contributes 0, so values fade linearly to 0 over
//! the voxel beyond the border instead of being clamped.
//!
//! One kernel serves every caller: positions come row by row from a closure
//! `fill_row(row, positions)` writing into a per-thread scratch row, so the
//! transport can derive `g + v(g)` and the renderer its camera lattice on the
//! fly (vectorised, per-row work hoisted) without materialising a position
//! array per voxel.

use nst3d_core::Grid3;
use rayon::prelude::*;

/// Elements per row when positions come from a flat slice: large enough to
/// amortise rayon's per-task cost, small enough to balance two threads.
const FLAT_ROW: usize = 4096;

/// An axis-aligned box of voxels with its own dense `x`-fastest storage: the
/// whole grid, or the part of it one worker's gradient scatter touches.
#[derive(Clone, Copy, Debug)]
struct Region {
    origin: [isize; 3],
    dims: [usize; 3],
}

impl Region {
    fn whole(dims: [usize; 3]) -> Self {
        Self { origin: [0; 3], dims }
    }

    fn len(&self) -> usize {
        self.dims.iter().product()
    }

    /// The box from corner `lo` to corner `hi`, both included; empty when
    /// `lo` is past `hi` (no cell touched).
    fn spanning(lo: [isize; 3], hi: [isize; 3]) -> Self {
        if lo[0] > hi[0] {
            Self { origin: [0; 3], dims: [0; 3] }
        } else {
            Self { origin: lo, dims: std::array::from_fn(|a| (hi[a] - lo[a] + 1) as usize) }
        }
    }
}

/// Lower cell corner and fractional offsets of `p`, or `None` when all eight
/// corners lie outside a grid of `dims` (the sample is then exactly 0 and so
/// are its gradients). The negated comparison also rejects NaN.
#[inline(always)]
fn locate(p: [f32; 3], dims: [usize; 3]) -> Option<([isize; 3], [f32; 3])> {
    let mut c = [0isize; 3];
    let mut f = [0f32; 3];
    for a in 0..3 {
        if !(p[a] > -1.0 && p[a] < dims[a] as f32) {
            return None;
        }
        // `p > -1`, so truncating `p + 1` is the floor (`f32::floor` is a libm
        // call on baseline x86-64, ~10% of the sampling time in profiles).
        let ci = (p[a] + 1.0) as isize - 1;
        c[a] = ci;
        f[a] = p[a] - ci as f32;
    }
    Some((c, f))
}

/// Calls `visit(corner, index)` for each corner of the cell whose lower corner
/// is `c` (grid coordinates) that lies inside `region`; `corner = dx + 2dy + 4dz`
/// and `index` is linear in the region's storage. Cells fully inside take a
/// branch-free path, which is nearly all of them.
#[inline(always)]
fn for_each_corner(region: &Region, c: [isize; 3], mut visit: impl FnMut(usize, usize)) {
    let l = [c[0] - region.origin[0], c[1] - region.origin[1], c[2] - region.origin[2]];
    let [nx, ny, nz] = region.dims.map(|n| n as isize);
    let (sy, sz) = (nx, nx * ny);
    if l[0] >= 0 && l[0] + 1 < nx && l[1] >= 0 && l[1] + 1 < ny && l[2] >= 0 && l[2] + 1 < nz {
        let b = (l[2] * sz + l[1] * sy + l[0]) as usize;
        let (sy, sz) = (sy as usize, sz as usize);
        visit(0, b);
        visit(1, b + 1);
        visit(2, b + sy);
        visit(3, b + sy + 1);
        visit(4, b + sz);
        visit(5, b + sz + 1);
        visit(6, b + sz + sy);
        visit(7, b + sz + sy + 1);
    } else {
        for corner in 0..8 {
            let x = l[0] + (corner & 1) as isize;
            let y = l[1] + ((corner >> 1) & 1) as isize;
            let z = l[2] + (corner >> 2) as isize;
            if (0..nx).contains(&x) && (0..ny).contains(&y) && (0..nz).contains(&z) {
                visit(corner, (z * sz + y * sy + x) as usize);
            }
        }
    }
}

/// Trilinear weight of each corner (same corner order as [`for_each_corner`]).
#[inline(always)]
fn weights(f: [f32; 3]) -> [f32; 8] {
    let wx = [1.0 - f[0], f[0]];
    let wy = [1.0 - f[1], f[1]];
    let wz = [1.0 - f[2], f[2]];
    std::array::from_fn(|k| wx[k & 1] * wy[(k >> 1) & 1] * wz[k >> 2])
}

/// Per-axis taps of a sample: the two (clamped, always valid) indices and
/// their weights, already zero for a tap outside the grid, plus the weights'
/// derivatives w.r.t. the position (zero outside `(-1, n)`, where the sample
/// is constantly 0). Branch-free, so rows of samples can vectorise.
#[inline(always)]
fn taps(p: f32, n: usize) -> ([usize; 2], [f32; 2], [f32; 2]) {
    let nf = n as f32;
    let inside = (p > -1.0 && p < nf) as i32 as f32;
    let pc = p.clamp(-1.0, nf);
    // `pc >= -1`, so truncating `pc + 1` is the floor (see `locate`).
    let i0 = (pc + 1.0) as i64 - 1;
    let f = pc - i0 as f32;
    let n = n as i64;
    let v0 = (i0 >= 0 && i0 < n) as i32 as f32;
    let v1 = (i0 + 1 >= 0 && i0 + 1 < n) as i32 as f32;
    let idx = [i0.clamp(0, n - 1) as usize, (i0 + 1).clamp(0, n - 1) as usize];
    (idx, [(1.0 - f) * v0, f * v1], [-v0 * inside, v1 * inside])
}

/// Value and (if `WANT_GRAD`) position gradient of the trilinear sample at `p`.
#[inline(always)]
fn sample_taps<const WANT_GRAD: bool>(data: &[f32], dims: [usize; 3], p: [f32; 3]) -> (f32, [f32; 3]) {
    let (ix, wx, dx) = taps(p[0], dims[0]);
    let (iy, wy, dy) = taps(p[1], dims[1]);
    let (iz, wz, dz) = taps(p[2], dims[2]);
    let last = data.len().saturating_sub(1);
    let (sy, sz) = (dims[0], dims[0] * dims[1]);
    let mut value = 0f32;
    let mut grad = [0f32; 3];
    for c in 0..2 {
        for b in 0..2 {
            let row = iz[c] * sz + iy[b] * sy;
            // Indices are in range by construction; `min` lets the bounds check go.
            let v = [data[(row + ix[0]).min(last)], data[(row + ix[1]).min(last)]];
            let lerp_x = wx[0] * v[0] + wx[1] * v[1];
            value += wz[c] * wy[b] * lerp_x;
            if WANT_GRAD {
                grad[0] += wz[c] * wy[b] * (dx[0] * v[0] + dx[1] * v[1]);
                grad[1] += wz[c] * dy[b] * lerp_x;
                grad[2] += dz[c] * wy[b] * lerp_x;
            }
        }
    }
    (value, grad)
}

/// Trilinear sample of `grid` at `pos` (voxel-index coordinates, voxel centres at
/// integers); outside the grid the value is 0, like `grid_sample` with
/// `padding_mode="zeros", align_corners=True`.
pub fn sample_trilinear(grid: &Grid3, pos: &[[f32; 3]]) -> Vec<f32> {
    sample_trilinear_rows(grid, pos.len(), FLAT_ROW, flat_rows(pos))
}

/// Backward of [`sample_trilinear`]: *adds* `∂L/∂grid` to `grad_grid` (a
/// scatter, if `Some`) and *writes* `∂L/∂pos` into `grad_pos` (if `Some`),
/// given `grad_out = ∂L/∂samples`.
///
/// # Panics
/// If `grad_out`, `grad_pos` or `grad_grid` do not match `pos` / `grid` in length
/// (a caller bug, not bad user input).
pub fn sample_trilinear_backward(
    grid: &Grid3,
    pos: &[[f32; 3]],
    grad_out: &[f32],
    grad_grid: Option<&mut [f32]>,
    grad_pos: Option<&mut [[f32; 3]]>,
) {
    sample_trilinear_rows_backward(grid, pos.len(), FLAT_ROW, flat_rows(pos), grad_out, grad_grid, grad_pos)
}

/// Row filler of the flat-slice entry points.
fn flat_rows(pos: &[[f32; 3]]) -> impl Fn(usize, &mut [[f32; 3]]) + Sync + '_ {
    move |r, buf| buf.copy_from_slice(&pos[r * FLAT_ROW..][..buf.len()])
}

/// The sampling kernel behind every trilinear resample: returns `len` samples
/// in rows of `row_len` (the last may be shorter); `fill_row(row, positions)`
/// writes the sample positions of one row. Rows are the unit of parallel
/// work, so the filler can hoist per-row work (the `y`, `z` of an advected
/// voxel, or one ray slab of a camera).
///
/// # Panics
/// If `row_len` is 0 while `len` is not.
pub fn sample_trilinear_rows(
    grid: &Grid3,
    len: usize,
    row_len: usize,
    fill_row: impl Fn(usize, &mut [[f32; 3]]) + Sync,
) -> Vec<f32> {
    let mut out = vec![0f32; len];
    if len == 0 {
        return out;
    }
    out.par_chunks_mut(row_len).enumerate().for_each_init(Vec::new, |pos, (r, row)| {
        pos.resize(row.len(), [0f32; 3]);
        fill_row(r, pos);
        for (o, &p) in row.iter_mut().zip(pos.iter()) {
            *o = sample_taps::<false>(&grid.data, grid.dims, p).0;
        }
    });
    out
}

/// Backward of [`sample_trilinear_rows`] (same contract as
/// [`sample_trilinear_backward`]).
///
/// The scatter into `grad_grid` is parallel without atomics: the rows are cut
/// into one contiguous part per thread, each part accumulates into a private
/// buffer covering only the bounding box of the cells it touches (a slab of the
/// grid for a camera lattice or an advection, so the extra memory is about one
/// grid in total), and the buffers are then summed into `grad_grid` in parallel
/// over its z-slices.
///
/// # Panics
/// On length mismatches, as [`sample_trilinear_backward`].
pub fn sample_trilinear_rows_backward(
    grid: &Grid3,
    len: usize,
    row_len: usize,
    fill_row: impl Fn(usize, &mut [[f32; 3]]) + Sync,
    grad_out: &[f32],
    grad_grid: Option<&mut [f32]>,
    grad_pos: Option<&mut [[f32; 3]]>,
) {
    assert_eq!(grad_out.len(), len, "grad_out length must match the sample count");
    if let Some(gp) = &grad_pos {
        assert_eq!(gp.len(), len, "grad_pos length must match the sample count");
    }
    if len == 0 {
        return;
    }
    let whole = Region::whole(grid.dims);
    let rows = len.div_ceil(row_len);

    let Some(grad_grid) = grad_grid else {
        // Only the position gradient: independent per sample, no scatter.
        if let Some(gp) = grad_pos {
            position_gradient_rows(grid, row_len, &fill_row, grad_out, gp);
        }
        return;
    };
    assert_eq!(grad_grid.len(), grid.len(), "grad_grid length must match the grid");

    let parts = rayon::current_num_threads().clamp(1, rows);
    let rows_per_part = rows.div_ceil(parts);
    // Split grad_pos into the parts' element ranges up front so each worker owns its slice.
    let mut pos_slices: Vec<Option<&mut [[f32; 3]]>> = Vec::with_capacity(parts);
    match grad_pos {
        Some(mut rest) => {
            for p in 0..parts {
                let start = (p * rows_per_part * row_len).min(len);
                let end = ((p + 1) * rows_per_part * row_len).min(len);
                let (head, tail) = std::mem::take(&mut rest).split_at_mut(end - start);
                pos_slices.push(Some(head));
                rest = tail;
            }
        }
        None => pos_slices.resize_with(parts, || None),
    }

    let partials: Vec<(Region, Vec<f32>)> = pos_slices
        .into_par_iter()
        .enumerate()
        .map(|(p, mut gp)| {
            let r0 = p * rows_per_part;
            let r1 = ((p + 1) * rows_per_part).min(rows);
            let mut pos = Vec::with_capacity(row_len);
            let fill = |r: usize, pos: &mut Vec<[f32; 3]>| {
                pos.resize(row_len.min(len - r * row_len), [0f32; 3]);
                fill_row(r, pos);
            };
            // Bounding box of the touched cells, clamped to the grid.
            let mut lo = [isize::MAX; 3];
            let mut hi = [isize::MIN; 3];
            for r in r0..r1 {
                fill(r, &mut pos);
                for &p in &pos {
                    if let Some((cell, _)) = locate(p, whole.dims) {
                        for a in 0..3 {
                            lo[a] = lo[a].min(cell[a].max(0));
                            hi[a] = hi[a].max((cell[a] + 1).min(grid.dims[a] as isize - 1));
                        }
                    }
                }
            }
            let region = Region::spanning(lo, hi);
            let mut buf = vec![0f32; region.len()];
            for r in r0..r1 {
                fill(r, &mut pos);
                for (c, &p) in pos.iter().enumerate() {
                    let i = r * row_len + c;
                    let local = i - r0 * row_len;
                    let g = grad_out[i];
                    match locate(p, whole.dims) {
                        None => {
                            if let Some(gp) = gp.as_deref_mut() {
                                gp[local] = [0.0; 3];
                            }
                        }
                        Some((cell, f)) => {
                            if let Some(gp) = gp.as_deref_mut() {
                                gp[local] = sample_taps::<true>(&grid.data, grid.dims, p).1.map(|x| x * g);
                            }
                            let w = weights(f);
                            for_each_corner(&region, cell, |k, j| buf[j] += g * w[k]);
                        }
                    }
                }
            }
            (region, buf)
        })
        .collect();

    add_partials(grad_grid, grid.dims, &partials);
}

/// Sums the threads' private buffers (each covering `region` of a grid of
/// `dims`) into `grad_grid`, in parallel over its z-slices.
fn add_partials(grad_grid: &mut [f32], dims: [usize; 3], partials: &[(Region, Vec<f32>)]) {
    let [nx, ny, _] = dims;
    grad_grid.par_chunks_mut(nx * ny).enumerate().for_each(|(z, slice)| {
        for (region, buf) in partials {
            let [ox, oy, oz] = region.origin.map(|o| o as usize);
            let [dx, dy, dz] = region.dims;
            if z < oz || z >= oz + dz {
                continue;
            }
            for y in oy..oy + dy {
                let src = &buf[((z - oz) * dy + (y - oy)) * dx..][..dx];
                let dst = &mut slice[y * nx + ox..][..dx];
                for (d, s) in dst.iter_mut().zip(src) {
                    *d += s;
                }
            }
        }
    });
}

/// The position gradient alone of [`sample_trilinear_rows_backward`]:
/// independent per sample, so parallel over rows with no scatter.
fn position_gradient_rows(
    grid: &Grid3,
    row_len: usize,
    fill_row: &(impl Fn(usize, &mut [[f32; 3]]) + Sync),
    grad_out: &[f32],
    gp: &mut [[f32; 3]],
) {
    gp.par_chunks_mut(row_len).zip(grad_out.par_chunks(row_len)).enumerate().for_each_init(
        Vec::new,
        |pos, (r, (gp_row, g_row))| {
            pos.resize(gp_row.len(), [0f32; 3]);
            fill_row(r, pos);
            for ((gp, &g), &p) in gp_row.iter_mut().zip(g_row).zip(pos.iter()) {
                *gp = sample_taps::<true>(&grid.data, grid.dims, p).1.map(|x| x * g);
            }
        },
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::{check_gradient, dot, pseudo_random};

    fn random_grid(dims: [usize; 3], seed: u64) -> Grid3 {
        let n = dims.iter().product();
        Grid3::from_vec(dims, pseudo_random(n, seed))
    }

    /// Positions spread over and slightly beyond the grid, nudged off integers
    /// so finite differences never straddle a kink.
    fn positions(n: usize, dims: [usize; 3], seed: u64) -> Vec<[f32; 3]> {
        let r = pseudo_random(3 * n, seed);
        (0..n)
            .map(|i| {
                std::array::from_fn(|a| {
                    let span = dims[a] as f32 + 1.0;
                    let p = (r[3 * i + a] * 0.5 + 0.5) * span - 1.0;
                    let f = p - p.floor();
                    if (f - 0.5).abs() > 0.45 {
                        p.floor() + 0.5
                    } else {
                        p
                    }
                })
            })
            .collect()
    }

    #[test]
    fn exact_at_voxel_centres_and_zero_outside() {
        let g = random_grid([4, 3, 5], 1);
        let pos = vec![[2.0, 1.0, 3.0], [0.0, 0.0, 0.0], [3.0, 2.0, 4.0], [-1.0, 1.0, 1.0], [4.0, 0.0, 0.0]];
        let s = sample_trilinear(&g, &pos);
        assert_eq!(s[0], g.at(2, 1, 3));
        assert_eq!(s[1], g.at(0, 0, 0));
        assert_eq!(s[2], g.at(3, 2, 4));
        assert_eq!(s[3], 0.0);
        assert_eq!(s[4], 0.0);
        // Half a voxel outside the border the zero padding halves the value.
        let h = sample_trilinear(&g, &[[-0.5, 1.0, 1.0]]);
        assert!((h[0] - 0.5 * g.at(0, 1, 1)).abs() < 1e-6);
    }

    #[test]
    fn gradient_wrt_grid_and_positions() {
        let dims = [5, 4, 6];
        let g = random_grid(dims, 2);
        let pos = positions(300, dims, 3);
        let w = pseudo_random(pos.len(), 4);
        let mut gg = vec![0f32; g.len()];
        let mut gp = vec![[0f32; 3]; pos.len()];
        sample_trilinear_backward(&g, &pos, &w, Some(&mut gg), Some(&mut gp));

        let r = check_gradient(
            &g.data,
            &gg,
            |d| dot(&w, &sample_trilinear(&Grid3::from_vec(dims, d.to_vec()), &pos)),
            // The samples are linear in the grid, so a large step has no truncation error.
            0.1,
            200,
            1e-2,
        );
        assert!(r.max_rel_err < 1e-3, "grid gradient {r:?}");

        let flat: Vec<f32> = pos.iter().flatten().copied().collect();
        let gflat: Vec<f32> = gp.iter().flatten().copied().collect();
        let r = check_gradient(
            &flat,
            &gflat,
            |p| {
                let pp: Vec<[f32; 3]> = p.chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
                dot(&w, &sample_trilinear(&g, &pp))
            },
            1e-3,
            900,
            1e-2,
        );
        assert!(r.max_rel_err < 1e-2, "position gradient {r:?}");
    }

    #[test]
    fn parallel_scatter_matches_serial_sum() {
        let dims = [9, 7, 8];
        let g = random_grid(dims, 5);
        let pos = positions(20_000, dims, 6);
        let w = pseudo_random(pos.len(), 7);
        let mut gg = vec![1f32; g.len()];
        sample_trilinear_backward(&g, &pos, &w, Some(&mut gg), None);
        let mut expect = vec![1f64; g.len()];
        let whole = Region::whole(dims);
        for (p, &wi) in pos.iter().zip(&w) {
            if let Some((c, f)) = locate(*p, dims) {
                let wt = weights(f);
                for_each_corner(&whole, c, |k, j| expect[j] += (wi * wt[k]) as f64);
            }
        }
        for (a, b) in gg.iter().zip(&expect) {
            assert!((*a as f64 - b).abs() < 1e-4, "{a} vs {b}");
        }
    }
}
