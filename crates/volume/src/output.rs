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
    color: Option<(&str, &[Grid3])>,
) -> Result<Vec<String>> {
    let mut out = VdbGrid::from_dense(grid_name, transform.clone(), origin, density, 0.0);
    if let Some(g) = file.grid(grid_name) {
        out.metadata = g.metadata.clone();
        out.class = g.class.clone();
    }
    let extra = color.map(|(name, c)| color_grid(name, transform, origin, density, c));
    write_stylized_grids(path, file, out, extra)
}

/// The colour grid's name when `--color-grid` is not given: a colour grid
/// the input already has (`Cd`, `color`) keeps its name; else the DCC the
/// other grids come from — Houdini writes `vel` (its colour attribute is
/// `Cd`), Blender's Mantaflow `velocity`, `flame`, `heat` (its Principled
/// Volume reads `color`); else the up axis: y-up pipelines (Houdini, USD)
/// `Cd`, z-up (Blender) `color`.
pub fn color_grid_name(file: &VdbFile, up: nst3d_core::UpAxis) -> &'static str {
    let has = |n: &str| file.grid(n).is_some();
    if has("Cd") {
        "Cd"
    } else if has("color") {
        "color"
    } else if has("vel") {
        "Cd"
    } else if ["velocity", "flame", "heat"].iter().any(|n| has(n)) {
        "color"
    } else if up == nst3d_core::UpAxis::Y {
        "Cd"
    } else {
        "color"
    }
}

/// The colour grid (vec3, class `unknown`) over the voxels where `density`
/// is non-zero: an RGB multiplier of the density's emission, 1 = white.
pub fn color_grid(name: &str, transform: &Transform, origin: [i32; 3], density: &Grid3, color: &[Grid3]) -> VdbGrid {
    let masked: Vec<Grid3> = color
        .iter()
        .map(|c| {
            Grid3::from_vec(
                c.dims,
                c.data.iter().zip(&density.data).map(|(c, d)| if *d > 0.0 { *c } else { 0.0 }).collect(),
            )
        })
        .collect();
    VdbGrid::from_dense_vec3(name, "unknown", transform.clone(), origin, [&masked[0], &masked[1], &masked[2]], 0.0)
}

/// [`write_stylized`] with the stylized grid already built (sparse, with the
/// name, class, metadata and transform it is to have).
pub fn write_stylized_grid(path: &Path, file: &VdbFile, stylized: VdbGrid) -> Result<Vec<String>> {
    write_stylized_grids(path, file, stylized, None)
}

/// [`write_stylized_grid`] plus an optional extra grid (the colour), which
/// replaces an input grid of its name or is appended after the others.
pub fn write_stylized_grids(
    path: &Path,
    file: &VdbFile,
    stylized: VdbGrid,
    extra: Option<VdbGrid>,
) -> Result<Vec<String>> {
    let mut extra = extra;
    let mut dropped = Vec::new();
    let mut grids = Vec::with_capacity(file.grids.len());
    let mut stylized = Some(stylized);
    for g in &file.grids {
        if g.name == stylized.as_ref().map_or("", |s| s.name.as_str()) {
            grids.push(stylized.take().expect("one grid of that name"));
        } else if g.name == extra.as_ref().map_or("", |s| s.name.as_str()) {
            grids.push(extra.take().expect("one grid of that name"));
        } else if matches!(g.values, GridValues::Unsupported { .. }) {
            dropped.push(format!("grid '{}' ({})", g.name, g.values.type_name()));
        } else {
            grids.push(g.clone());
        }
    }
    grids.extend(extra);
    write_vdb(path, &grids)?;
    Ok(dropped)
}
