//! Sparse grids become dense boxes of voxels for the optimiser and the
//! renderer, and several grids (the frames of a simulation, a result and its
//! original) share one box so cameras and fields line up between them.

use std::path::Path;

use anyhow::{bail, Context, Result};
use nst3d_core::Grid3;
use nst3d_io::vdb::{DenseBox, GridValues, VdbFile, VdbGrid};

/// The float grid `grid` of `file` (read from `path`, for messages): an
/// error naming the grids there are when it is missing, or its value type
/// when it holds no densities.
pub fn density_grid<'a>(file: &'a VdbFile, path: &Path, grid: &str) -> Result<&'a VdbGrid> {
    let g = file.grid(grid).with_context(|| {
        let names: Vec<&str> = file.grids.iter().map(|g| g.name.as_str()).collect();
        format!("{}: no grid named '{grid}' (grids: {})", path.display(), names.join(", "))
    })?;
    if !matches!(g.values, GridValues::Float(_)) {
        bail!("{}: grid '{grid}' holds {} values, not densities", path.display(), g.values.type_name());
    }
    Ok(g)
}

/// Copies `src`, whose voxel (0,0,0) is index `src_origin`, into `dst`,
/// whose voxel (0,0,0) is index `dst_origin`. Voxels outside `dst` are
/// dropped: one frame's box may stick out of a box fixed by other frames.
pub fn paste(src: &Grid3, src_origin: [i32; 3], dst: &mut Grid3, dst_origin: [i32; 3]) {
    let [nx, ny, nz] = src.dims;
    let dims = dst.dims;
    // Along x a row is clipped on both sides (its first `skip` voxels lie
    // left of `dst`); along y and z whole rows fall outside.
    let ox = i64::from(src_origin[0]) - i64::from(dst_origin[0]);
    let skip = (-ox).max(0) as usize;
    let dx = ox.max(0) as usize;
    if skip >= nx || dx >= dims[0] {
        return;
    }
    let n = (nx - skip).min(dims[0] - dx);
    for z in 0..nz {
        for y in 0..ny {
            let (oy, oz) = (src_origin[1] + y as i32 - dst_origin[1], src_origin[2] + z as i32 - dst_origin[2]);
            if oy < 0 || oz < 0 || oy as usize >= dims[1] || oz as usize >= dims[2] {
                continue;
            }
            let at = dst.index(dx, oy as usize, oz as usize);
            dst.data[at..at + n].copy_from_slice(&src.data[src.index(skip, y, z)..][..n]);
        }
    }
}

/// Surrounds a grid with `m` voxels of empty space on every side.
pub fn pad(g: &Grid3, m: usize) -> Grid3 {
    if m == 0 {
        return g.clone();
    }
    let [nx, ny, nz] = g.dims;
    let mut out = Grid3::zeros([nx + 2 * m, ny + 2 * m, nz + 2 * m]);
    let m = m as i32;
    paste(g, [m; 3], &mut out, [0; 3]);
    out
}

/// Names a colour grid is read under, in order: Houdini's, then Blender's
/// (the names `nst3d volume --color` writes, [`crate::output::color_grid_name`]).
pub const COLOR_GRID_NAMES: [&str; 2] = ["Cd", "color"];

/// A colour grid's three channels densified over its active box.
pub type DenseColor = (DenseBox, [Grid3; 3]);

/// The vec3 colour grid of `file` ([`COLOR_GRID_NAMES`]), densified over its
/// active box; `None` when the file has none.
pub fn color_grid(file: &VdbFile) -> Result<Option<DenseColor>> {
    COLOR_GRID_NAMES
        .iter()
        .filter_map(|n| file.grid(n))
        .find(|c| matches!(c.values, GridValues::Vec3(_)))
        .map(|c| c.to_dense_vec3())
        .transpose()
        .map_err(anyhow::Error::from)
}

/// Colour channels moved into the box `into`, white (1, 1, 1) wherever no
/// channel has a value: smoke without a colour is drawn grey, as a grey
/// result is. `None` (a file without colour) is white everywhere.
pub fn color_in_box(color: Option<&DenseColor>, into: &DenseBox) -> Vec<Grid3> {
    let Some((own, ch)) = color else {
        return vec![Grid3::from_vec(into.dims, vec![1.0; into.dims.iter().product()]); 3];
    };
    let mut ch: Vec<Grid3> = ch.iter().map(|g| in_box(Some((*own, g.clone())), into)).collect();
    for i in 0..ch[0].len() {
        if ch.iter().all(|g| g.data[i] == 0.0) {
            ch.iter_mut().for_each(|g| g.data[i] = 1.0);
        }
    }
    ch
}

/// Smallest box holding both.
pub fn union_box(a: &DenseBox, b: &DenseBox) -> DenseBox {
    let lo: [i32; 3] = std::array::from_fn(|i| a.origin[i].min(b.origin[i]));
    let hi: [i64; 3] = std::array::from_fn(|i| {
        (i64::from(a.origin[i]) + a.dims[i] as i64).max(i64::from(b.origin[i]) + b.dims[i] as i64)
    });
    DenseBox { origin: lo, dims: std::array::from_fn(|i| (hi[i] - i64::from(lo[i])) as usize) }
}

/// A loaded grid moved into the larger box `into`; an empty one (`None`) is all zeros.
pub fn in_box(loaded: Option<(DenseBox, Grid3)>, into: &DenseBox) -> Grid3 {
    let Some((own, d)) = loaded else {
        return Grid3::zeros(into.dims);
    };
    if own == *into {
        return d;
    }
    let mut out = Grid3::zeros(into.dims);
    paste(&d, own.origin, &mut out, into.origin);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paste_places_and_clips() {
        let mut src = Grid3::zeros([2, 2, 2]);
        src.data.iter_mut().enumerate().for_each(|(i, v)| *v = i as f32 + 1.0);
        let padded = pad(&src, 1);
        assert_eq!(padded.dims, [4, 4, 4]);
        assert_eq!(padded.data[padded.index(1, 1, 1)], 1.0);
        assert_eq!(padded.data[padded.index(2, 2, 2)], 8.0);
        assert_eq!(padded.data.iter().sum::<f32>(), 36.0);
        // Half of the source sticks out of the destination along y.
        let mut dst = Grid3::zeros([2, 1, 2]);
        paste(&src, [0, 0, 0], &mut dst, [0, 1, 0]);
        assert_eq!(dst.data, vec![3.0, 4.0, 7.0, 8.0]);
    }

    /// A source sticking out of the destination on the left along x keeps
    /// the part inside (the rows were once dropped whole), and one past
    /// either end along x is dropped without a panic.
    #[test]
    fn paste_clips_rows_on_both_sides_along_x() {
        let mut src = Grid3::zeros([4, 1, 1]);
        src.data = vec![1.0, 2.0, 3.0, 4.0];
        let mut dst = Grid3::zeros([3, 1, 1]);
        paste(&src, [-2, 0, 0], &mut dst, [0, 0, 0]);
        assert_eq!(dst.data, vec![3.0, 4.0, 0.0]);
        let mut dst = Grid3::zeros([3, 1, 1]);
        paste(&src, [1, 0, 0], &mut dst, [0, 0, 0]);
        assert_eq!(dst.data, vec![0.0, 1.0, 2.0]);
        let mut dst = Grid3::zeros([3, 1, 1]);
        paste(&src, [5, 0, 0], &mut dst, [0, 0, 0]);
        paste(&src, [-9, 0, 0], &mut dst, [0, 0, 0]);
        assert_eq!(dst.data, vec![0.0; 3]);
    }
}
