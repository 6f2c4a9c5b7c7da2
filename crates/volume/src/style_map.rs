//! `--style-map`: where each of several paintings goes. A float map blends
//! two paintings (0: the first `--style`, 1: the second); with
//! `--style-map-labels` its values are labels, `k` picking the `k`-th
//! painting. The map is a grid of the input (`NAME`), of another file
//! (`FILE.vdb:NAME`), or a built-in height ramp over the smoke's box
//! (`@height`, soft, or `@height-split`, a label map cut at mid-height). A
//! grid is sampled in world space, so its resolution and transform may
//! differ from the density's: trilinear for a blend, nearest for labels.
//! A front end holding the map as an array (the Python package's numpy
//! map) passes a [`MapArray`]: one value per voxel of the input density
//! grid's active bounding box, sampled as a grid of the input lying over
//! that box with the density's transform.

use nst3d_core::UpAxis;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{bail, Context, Result};
use nst3d_core::Grid3;
use nst3d_io::vdb::{read_vdb, GridValues, Transform, VdbFile};

/// Where a map's values come from.
#[derive(Clone, Debug, PartialEq)]
pub enum MapSource {
    /// A grid of the input file.
    Input(String),
    /// A grid of another file.
    File(PathBuf, String),
    /// 0 at the bottom of the smoke's box to 1 at its top; `split`: a label
    /// map, 0 below the middle and 1 above.
    Height {
        /// Hard labels instead of the soft ramp.
        split: bool,
    },
    /// An array over the active bounding box of the input's grid `grid`.
    Array {
        /// The values.
        array: MapArray,
        /// The density grid it lies over.
        grid: String,
    },
}

/// A style map held in memory: one value per voxel of the input density
/// grid's active bounding box (`values.dims` its size, x fastest, voxel
/// (0,0,0) at the box's first corner).
#[derive(Clone, PartialEq)]
pub struct MapArray {
    /// The map's values.
    pub values: Arc<Grid3>,
}

impl std::fmt::Debug for MapArray {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "MapArray({:?})", self.values.dims)
    }
}

impl MapSource {
    /// Parses `--style-map`.
    pub fn parse(spec: &str) -> Result<Self> {
        Ok(match spec {
            "@height" => MapSource::Height { split: false },
            "@height-split" => MapSource::Height { split: true },
            s if s.starts_with('@') => bail!("--style-map '{s}': the built-in maps are @height and @height-split"),
            s => match s.rsplit_once(':') {
                Some((file, name)) if file.ends_with(".vdb") && !name.is_empty() => {
                    MapSource::File(file.into(), name.into())
                }
                _ if s.is_empty() => bail!("--style-map is empty"),
                _ => MapSource::Input(s.into()),
            },
        })
    }

    /// Whether the map's values are labels.
    pub fn labels(&self, flag: bool) -> bool {
        flag || matches!(self, MapSource::Height { split: true })
    }

    /// The map of frame `frame` of a sequence: a file given as a pattern
    /// (`####`, `%04d`, as the input's) names that frame's file; anything
    /// else is the same for every frame (a grid of the input is read from
    /// each frame's own file by the caller).
    pub fn at_frame(&self, frame: i64) -> Result<Self> {
        Ok(match self {
            MapSource::File(path, name) if path.to_string_lossy().contains(['#', '%']) => {
                let pattern = path.to_string_lossy();
                let one =
                    nst3d_job::expand_pattern(&pattern, frame).with_context(|| format!("--style-map '{pattern}'"))?;
                MapSource::File(one.into(), name.clone())
            }
            other => other.clone(),
        })
    }
}

/// A map grid ready to sample at world positions.
struct Sampled {
    values: Grid3,
    origin: [i32; 3],
    world_to_index: [[f64; 4]; 3],
}

/// The inverse of an affine index-to-world matrix, as its top three rows.
fn invert(t: &Transform) -> Result<[[f64; 4]; 3]> {
    let m = &t.index_to_world;
    let a = |r: usize, c: usize| m[r][c];
    let det = a(0, 0) * (a(1, 1) * a(2, 2) - a(1, 2) * a(2, 1)) - a(0, 1) * (a(1, 0) * a(2, 2) - a(1, 2) * a(2, 0))
        + a(0, 2) * (a(1, 0) * a(2, 1) - a(1, 1) * a(2, 0));
    if !(det.abs() > 1e-300) {
        bail!("the style map's transform is singular");
    }
    let mut inv = [[0.0; 4]; 3];
    for r in 0..3 {
        for c in 0..3 {
            let (r1, r2, c1, c2) = ((c + 1) % 3, (c + 2) % 3, (r + 1) % 3, (r + 2) % 3);
            inv[r][c] = (a(r1, c1) * a(r2, c2) - a(r1, c2) * a(r2, c1)) / det;
        }
    }
    for r in 0..3 {
        inv[r][3] = -(0..3).map(|c| inv[r][c] * m[c][3]).sum::<f64>();
    }
    Ok(inv)
}

impl Sampled {
    fn value(&self, world: [f64; 3], nearest: bool) -> f32 {
        let w = &self.world_to_index;
        let p: [f64; 3] =
            std::array::from_fn(|r| w[r][0] * world[0] + w[r][1] * world[1] + w[r][2] * world[2] + w[r][3]);
        let local: [f64; 3] = std::array::from_fn(|a| p[a] - self.origin[a] as f64);
        let at = |i: [i64; 3]| -> f32 {
            let d = self.values.dims;
            if (0..3).any(|a| i[a] < 0 || i[a] >= d[a] as i64) {
                return 0.0;
            }
            self.values.data[self.values.index(i[0] as usize, i[1] as usize, i[2] as usize)]
        };
        if nearest {
            return at(local.map(|x| x.round() as i64));
        }
        let base = local.map(|x| x.floor());
        let mut v = 0.0;
        for corner in 0..8 {
            let mut wgt = 1.0;
            let mut i = [0i64; 3];
            for a in 0..3 {
                let up = (corner >> a) & 1 == 1;
                let f = local[a] - base[a];
                wgt *= if up { f } else { 1.0 - f };
                i[a] = base[a] as i64 + up as i64;
            }
            v += wgt as f32 * at(i);
        }
        v
    }
}

/// A grid of `file` (a float grid) as a sampler; `what` names the file in messages.
fn grid_of(file: &VdbFile, name: &str, what: &Path) -> Result<Sampled> {
    let grid = file.grid(name).with_context(|| {
        let names: Vec<&str> = file.grids.iter().map(|g| g.name.as_str()).collect();
        format!("--style-map: {} has no grid named '{name}' (grids: {})", what.display(), names.join(", "))
    })?;
    let world_to_index = invert(&grid.transform)?;
    // A simulation's field may have no voxels yet where its smoke already
    // has some (the first frames of a sequence): 0 everywhere, as outside
    // any grid's active box.
    if matches!(grid.values, GridValues::Float(_)) && grid.active_voxel_count() == 0 {
        return Ok(Sampled { values: Grid3::zeros([1, 1, 1]), origin: [0; 3], world_to_index });
    }
    let (bx, values) = grid
        .to_dense()
        .with_context(|| format!("--style-map: grid '{name}' of {} is not a float grid", what.display()))?;
    Ok(Sampled { values, origin: bx.origin, world_to_index })
}

/// `array` as a sampler: a grid lying over the active bounding box of
/// `file`'s grid `name`, with that grid's transform; an array of another
/// size than the box is an error naming both.
fn array_over(file: &VdbFile, name: &str, array: &MapArray, what: &Path) -> Result<Sampled> {
    let grid = file.grid(name).with_context(|| format!("{}: no grid named '{name}'", what.display()))?;
    let (lo, hi) = grid.active_bbox().with_context(|| format!("{}: grid '{name}' is empty", what.display()))?;
    let size: [usize; 3] = std::array::from_fn(|a| (hi[a] - lo[a] + 1) as usize);
    let got = array.values.dims;
    if got != size {
        bail!(
            "style_map array has shape ({}, {}, {}), but grid '{name}' of {} spans ({}, {}, {}) voxels (its active bounding box, indexed [x, y, z])",
            got[0],
            got[1],
            got[2],
            what.display(),
            size[0],
            size[1],
            size[2]
        );
    }
    Ok(Sampled { values: (*array.values).clone(), origin: lo, world_to_index: invert(&grid.transform)? })
}

/// The map's value at every voxel of a box of `dims` voxels whose voxel
/// (0,0,0) is index `origin` under `transform` (the density's, after any
/// refinement and padding); `input` is the input's file for
/// [`MapSource::Input`]; `inner` is the smoke's own box within it (origin
/// offset and size), which a height ramp spans.
pub struct MapBox<'a> {
    /// Voxels of the box.
    pub dims: [usize; 3],
    /// Index of its voxel (0,0,0).
    pub origin: [i32; 3],
    /// Its index-to-world transform.
    pub transform: &'a Transform,
    /// The smoke's box inside it: offset and size in voxels.
    pub inner: ([usize; 3], [usize; 3]),
    /// Which index axis is up.
    pub up: UpAxis,
}

/// A map ready to be read at any voxel of the density's index space: a
/// grid sampled at the voxel's world position, or the height ramp over
/// the smoke's index box. A sparse frame reads it voxel by voxel, with no
/// dense box.
pub struct VoxelMap<'a> {
    values: Values,
    transform: &'a Transform,
    nearest: bool,
}

enum Values {
    Grid(Sampled),
    /// The ramp along index axis `axis` from `lo` over `size` voxels.
    Height {
        axis: usize,
        lo: f32,
        size: f32,
        split: bool,
    },
}

impl<'a> VoxelMap<'a> {
    /// `source` for a density whose index space maps to the world by
    /// `transform` and whose smoke spans the index box `smoke` (first
    /// voxel, size), which a height ramp spans; `input` is the input's
    /// file for [`MapSource::Input`]; labels are read at the nearest voxel
    /// where `nearest`.
    pub fn new(
        source: &MapSource,
        input: Option<(&VdbFile, &Path)>,
        transform: &'a Transform,
        smoke: ([i32; 3], [usize; 3]),
        up: UpAxis,
        nearest: bool,
    ) -> Result<Self> {
        let values = match source {
            MapSource::Height { split } => {
                let axis = match up {
                    UpAxis::Y => 1,
                    UpAxis::Z => 2,
                };
                Values::Height { axis, lo: smoke.0[axis] as f32, size: smoke.1[axis].max(2) as f32, split: *split }
            }
            MapSource::Input(name) => {
                let (file, path) =
                    input.context("--style-map NAME reads a grid of the input file; pass FILE.vdb:NAME")?;
                Values::Grid(grid_of(file, name, path)?)
            }
            MapSource::File(path, name) => Values::Grid(grid_of(&read_vdb(path)?, name, path)?),
            MapSource::Array { array, grid } => {
                let (file, path) = input.context("a style map array lies over the input file's density grid")?;
                Values::Grid(array_over(file, grid, array, path)?)
            }
        };
        Ok(Self { values, transform, nearest })
    }

    /// The map's value at index `ijk`.
    pub fn at(&self, ijk: [i32; 3]) -> f32 {
        match &self.values {
            Values::Height { axis, lo, size, split } => {
                let h = ((ijk[*axis] as f32 - lo) / (size - 1.0)).clamp(0.0, 1.0);
                if *split {
                    (h >= 0.5) as u8 as f32
                } else {
                    h
                }
            }
            Values::Grid(g) => g.value(self.transform.index_to_world(ijk.map(|v| v as f64)), self.nearest),
        }
    }
}

/// The map sampled on `b` (see [`MapSource`]), labels rounded where `nearest`.
pub fn sample(source: &MapSource, input: Option<(&VdbFile, &Path)>, b: &MapBox, nearest: bool) -> Result<Grid3> {
    let smoke_lo: [i32; 3] = std::array::from_fn(|a| b.origin[a] + b.inner.0[a] as i32);
    let map = VoxelMap::new(source, input, b.transform, (smoke_lo, b.inner.1), b.up, nearest)?;
    let mut out = Grid3::zeros(b.dims);
    for z in 0..b.dims[2] {
        for y in 0..b.dims[1] {
            for x in 0..b.dims[0] {
                let i = out.index(x, y, z);
                out.data[i] = map.at([x as i32 + b.origin[0], y as i32 + b.origin[1], z as i32 + b.origin[2]]);
            }
        }
    }
    Ok(out)
}

/// One weight grid per painting from the sampled map: a blend of two
/// (`1 − m`, `m`, the map clamped to [0, 1]) or labels (one-hot of the
/// rounded value). A label that is not the index of a painting, where
/// there is smoke, is an error.
pub fn regions(map: &Grid3, density: &Grid3, paintings: usize, labels: bool) -> Result<Vec<Grid3>> {
    let mut out = vec![Grid3::zeros(map.dims); paintings];
    let mut w = vec![0.0; paintings];
    for (i, &m) in map.data.iter().enumerate() {
        weights(m, density.data[i] > 0.0, labels, &mut w)?;
        out.iter_mut().zip(&w).for_each(|(r, w)| r.data[i] = *w);
    }
    Ok(out)
}

/// One voxel's weights, one per painting (`w`, overwritten), from its map
/// value `m` as [`regions`] makes them; `smoke`: the voxel holds smoke (a
/// label outside the paintings is an error there, the first painting
/// elsewhere).
pub fn weights(m: f32, smoke: bool, labels: bool, w: &mut [f32]) -> Result<()> {
    let paintings = w.len();
    if !m.is_finite() {
        bail!("--style-map holds a non-finite value ({m})");
    }
    w.iter_mut().for_each(|v| *v = 0.0);
    if labels {
        let k = m.round();
        if k < 0.0 || k >= paintings as f32 || (m - k).abs() > 0.01 {
            if smoke {
                bail!("--style-map label {m} is not one of the {paintings} paintings (labels 0 to {})", paintings - 1);
            }
            w[0] = 1.0;
        } else {
            w[k as usize] = 1.0;
        }
    } else {
        let m = m.clamp(0.0, 1.0);
        (w[0], w[1]) = (1.0 - m, m);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_every_kind() {
        assert_eq!(MapSource::parse("temperature").unwrap(), MapSource::Input("temperature".into()));
        assert_eq!(MapSource::parse("m.vdb:mask").unwrap(), MapSource::File("m.vdb".into(), "mask".into()));
        assert_eq!(MapSource::parse("@height").unwrap(), MapSource::Height { split: false });
        assert!(MapSource::parse("@nope").is_err());
        let per_frame = MapSource::parse("maps/m_####.vdb:mask").unwrap();
        assert_eq!(per_frame.at_frame(7).unwrap(), MapSource::File("maps/m_0007.vdb".into(), "mask".into()));
        assert_eq!(
            MapSource::parse("m.vdb:mask").unwrap().at_frame(7).unwrap(),
            MapSource::parse("m.vdb:mask").unwrap()
        );
    }

    /// A map on a grid twice as coarse, shifted, is sampled where the
    /// density's voxels are in the world.
    #[test]
    fn samples_in_world_space() {
        // Map: value = its index x, voxel size 2, translated by 1 along x.
        let mut values = Grid3::zeros([8, 2, 2]);
        for i in 0..values.len() {
            values.data[i] = (i % 8) as f32;
        }
        let mt = Transform::scale_translate([2.0; 3], [1.0, 0.0, 0.0]);
        let s = Sampled { values, origin: [0; 3], world_to_index: invert(&mt).unwrap() };
        // Density voxel x sits at world x; the map's index there is (x - 1) / 2.
        for x in [3.0, 5.0, 8.0] {
            assert!((s.value([x, 0.0, 0.0], false) - (x as f32 - 1.0) / 2.0).abs() < 1e-5);
        }
        assert_eq!(s.value([6.2, 0.0, 0.0], true), 3.0);
    }

    /// A map grid with no active voxel reads 0 everywhere (the first
    /// painting), not an error.
    #[test]
    fn an_empty_map_grid_is_zero() {
        let t = Transform::uniform(1.0);
        let empty = nst3d_io::vdb::VdbGrid::from_dense("temperature", t.clone(), [0; 3], &Grid3::zeros([4, 4, 4]), 0.0);
        let file = VdbFile {
            format_version: 224,
            library_version: (10, 0),
            file_metadata: Default::default(),
            grids: vec![empty],
        };
        assert_eq!(file.grids[0].active_voxel_count(), 0);
        let s = grid_of(&file, "temperature", Path::new("f.vdb")).unwrap();
        assert_eq!((s.value([1.0, 2.0, 3.0], false), s.value([0.0; 3], true)), (0.0, 0.0));
    }

    #[test]
    fn labels_outside_the_paintings_are_errors() {
        let d = Grid3::from_vec([3, 1, 1], vec![1.0, 1.0, 0.0]);
        let r = regions(&Grid3::from_vec([3, 1, 1], vec![0.0, 1.0, 7.0]), &d, 2, true).unwrap();
        assert_eq!((r[0].data.clone(), r[1].data.clone()), (vec![1.0, 0.0, 1.0], vec![0.0, 1.0, 0.0]));
        let e = regions(&Grid3::from_vec([3, 1, 1], vec![0.0, 2.0, 0.0]), &d, 2, true).unwrap_err();
        assert!(e.to_string().contains("label 2"), "{e}");
        let r = regions(&Grid3::from_vec([3, 1, 1], vec![0.25, 2.0, -1.0]), &d, 2, false).unwrap();
        assert_eq!(r[1].data, vec![0.25, 1.0, 0.0]);
    }
}
