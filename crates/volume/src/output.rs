//! The stylized file: the input file with its stylized grid replaced, so it
//! drops into a pipeline in place of the original (same grid name, class,
//! metadata, transform and index space).

use std::path::Path;

use anyhow::Result;
use nst3d_core::Grid3;
use nst3d_io::vdb::{write_vdb, GridValues, Transform, VdbFile, VdbGrid};

/// Writes `file` to `path` (atomically) with grid `grid_name` replaced by
/// `density`, a dense box at index `origin` under `transform`. Grids of
/// value types nst3d cannot carry (e.g. int32 obstacles) are left out;
/// their names and types are returned so the job can say so.
pub fn write_stylized(
    path: &Path,
    file: &VdbFile,
    grid_name: &str,
    transform: &Transform,
    origin: [i32; 3],
    density: &Grid3,
) -> Result<Vec<String>> {
    let mut out = VdbGrid::from_dense(grid_name, transform.clone(), origin, density, 0.0);
    if let Some(g) = file.grid(grid_name) {
        out.metadata = g.metadata.clone();
        out.class = g.class.clone();
    }
    write_stylized_grid(path, file, out)
}

/// [`write_stylized`] with the stylized grid already built (sparse, with the
/// name, class, metadata and transform it is to have).
pub fn write_stylized_grid(path: &Path, file: &VdbFile, stylized: VdbGrid) -> Result<Vec<String>> {
    let mut dropped = Vec::new();
    let mut grids = Vec::with_capacity(file.grids.len());
    let mut stylized = Some(stylized);
    for g in &file.grids {
        if g.name == stylized.as_ref().map_or("", |s| s.name.as_str()) {
            grids.push(stylized.take().expect("one grid of that name"));
        } else if matches!(g.values, GridValues::Unsupported { .. }) {
            dropped.push(format!("grid '{}' ({})", g.name, g.values.type_name()));
        } else {
            grids.push(g.clone());
        }
    }
    write_vdb(path, &grids)?;
    Ok(dropped)
}
