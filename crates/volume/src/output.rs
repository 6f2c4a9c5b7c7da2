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
    // With a colour, the file gets it as an albedo in [0, 1] and the
    // brightness above white in the density (the same emission).
    let albedo = color.map(|(name, c)| (name, as_albedo(density, c)));
    let density = albedo.as_ref().map_or(density, |(_, (d, _))| d);
    let mut out = VdbGrid::from_dense(grid_name, transform.clone(), origin, density, 0.0);
    if let Some(g) = file.grid(grid_name) {
        out.metadata = g.metadata.clone();
        out.class = g.class.clone();
    }
    let extra = albedo.as_ref().map(|(name, (d, c))| color_grid(name, transform, origin, d, c));
    write_stylized_grids(path, file, out, extra)
}

/// The stylized colour as a renderer's albedo: every voxel's colour in
/// [0, 1], the brightness above white moved into the density.
///
/// nst3d's colour render emits `c · d` per voxel (`c` each channel in
/// [0, 2], 1 = white) and absorbs by `d`; a DCC's volume shader takes the
/// colour as the scattering albedo, in [0, 1], and scatters `albedo · d`
/// under its lights. So a voxel whose brightest channel `m` is above 1 is
/// written as `c / m` with density `d · m`: the same emission, in the
/// shader's range, and a little more opaque (the price of keeping the
/// brightness). Voxels with `m ≤ 1` are written as they are.
pub fn as_albedo(density: &Grid3, color: &[Grid3]) -> (Grid3, Vec<Grid3>) {
    let mut d = density.clone();
    let mut c: Vec<Grid3> = color.to_vec();
    for i in 0..d.data.len() {
        let m = c.iter().map(|g| g.data[i]).fold(0.0f32, f32::max);
        for g in c.iter_mut() {
            g.data[i] = g.data[i].max(0.0);
        }
        if m > 1.0 {
            d.data[i] *= m;
            for g in c.iter_mut() {
                g.data[i] /= m;
            }
        }
    }
    (d, c)
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
/// is non-zero: an RGB multiplier of the density's emission, 1 = white
/// (written through [`as_albedo`], so in [0, 1]).
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

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_io::vdb::read_vdb;

    fn grid(values: &[f32]) -> Grid3 {
        Grid3::from_vec([values.len(), 1, 1], values.to_vec())
    }

    #[test]
    fn albedo_keeps_the_emission_in_range() {
        // A voxel brighter than white, one in range, one with no smoke.
        let d = grid(&[0.5, 0.4, 0.0]);
        let c = vec![grid(&[2.0, 0.2, 1.5]), grid(&[1.0, 0.9, 1.5]), grid(&[0.5, 0.3, 1.5])];
        let (d2, c2) = as_albedo(&d, &c);
        for i in 0..3 {
            for ch in 0..3 {
                assert!((0.0..=1.0).contains(&c2[ch].data[i]), "voxel {i} channel {ch}: {}", c2[ch].data[i]);
                let (before, after) = (c[ch].data[i] * d.data[i], c2[ch].data[i] * d2.data[i]);
                assert!((before - after).abs() < 1e-6, "voxel {i} channel {ch}: emission {after} for {before}");
            }
        }
        assert_eq!(d2.data[0], 1.0, "the brightest channel (2) moves into the density");
        assert_eq!([c2[0].data[0], c2[1].data[0], c2[2].data[0]], [1.0, 0.5, 0.25], "with the hue kept");
        assert_eq!((d2.data[1], c2[1].data[1]), (0.4, 0.9), "a colour in range is written as it is");
        assert_eq!(d2.data[2], 0.0, "no smoke stays no smoke");
    }

    #[test]
    fn the_written_colour_grid_is_an_albedo() {
        let dir = tempfile::tempdir().unwrap();
        let (input, out) = (dir.path().join("in.vdb"), dir.path().join("out.vdb"));
        let t = Transform::uniform(0.1);
        let d = Grid3::from_vec([4, 2, 1], vec![0.2, 0.4, 0.6, 0.8, 0.1, 0.0, 0.3, 0.5]);
        write_vdb(&input, &[VdbGrid::from_dense("density", t.clone(), [0, 0, 0], &d, 0.0)]).unwrap();
        let file = read_vdb(&input).unwrap();
        let c: Vec<Grid3> =
            (0..3).map(|ch| Grid3::from_vec(d.dims, (0..8).map(|i| 0.25 * ((i + ch) % 9) as f32).collect())).collect();
        write_stylized(&out, &file, "density", &t, [0, 0, 0], &d, Some(("Cd", &c))).unwrap();
        let back = read_vdb(&out).unwrap();
        let (_, density) = back.grid("density").unwrap().to_dense().unwrap();
        let (_, color) = back.grid("Cd").unwrap().to_dense_vec3().unwrap();
        let (mut brightest, mut emission_error) = (0.0f32, 0.0f32);
        for i in 0..d.data.len() {
            let (x, y) = (i % 4, i / 4);
            let j = density.index(x, y, 0);
            for ch in 0..3 {
                let v = color[ch].data[color[ch].index(x, y, 0)];
                assert!((0.0..=1.0).contains(&v), "voxel {i} channel {ch}: {v}");
                brightest = brightest.max(c[ch].data[i]);
                emission_error = emission_error.max((v * density.data[j] - c[ch].data[i] * d.data[i]).abs());
            }
        }
        assert!(brightest > 1.5, "the input colour goes above white ({brightest})");
        assert!(emission_error < 1e-6, "the emission c·d is kept ({emission_error})");
    }
}
