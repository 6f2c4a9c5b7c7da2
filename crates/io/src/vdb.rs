//! OpenVDB volumes in and out of nst3d.
//!
//! [`read_vdb`] decodes the files OpenVDB 6–12, Houdini and Blender write
//! (file format version 222 and newer): float grids (`Tree_float_5_4_3`,
//! also when stored as half floats) and `vec3s` grids (`Tree_vec3s_5_4_3`,
//! e.g. Mantaflow's staggered `velocity`), with uncompressed, zlib or Blosc
//! (LZ4, LZ4HC, zlib, BloscLZ codecs; byte/bit shuffle) node buffers. Active
//! tiles are expanded into voxels, so a grid is just a set of 8³ leaves
//! ([`SparseGrid`]). Grids of other value types are listed (name, transform,
//! metadata) as [`GridValues::Unsupported`] with their voxels skipped, and
//! any attempt to use their values fails with [`ErrorKind::UnsupportedValueType`].
//!
//! [`write_vdb`] writes format version 224 (what OpenVDB 10 writes) with
//! zlib-compressed, active-value-only node buffers; voxels keep their index
//! coordinates and grids keep name, class, transform and metadata.
//!
//! Dense conversion ([`VdbGrid::to_dense`], [`VdbGrid::from_dense`]) maps the
//! active bounding box onto an [`nst3d_core::Grid3`] (`x` fastest) whose
//! voxel `(0, 0, 0)` sits at index coordinate [`DenseBox::origin`].

mod blosc;
mod read;
mod tree;
mod write;

use std::cmp::Ordering;
use std::path::{Path, PathBuf};

use nst3d_core::Grid3;

use crate::bytes::read_file;
use crate::{Error, ErrorKind};

pub use tree::{leaf_offset, leaf_origin, Leaf, SparseGrid, LEAF_DIM, LEAF_VOXELS};

/// Most voxels a dense conversion or tile expansion may produce (2²⁸, i.e.
/// 1 GiB of `f32`, a 640³ box); bigger requests are refused before allocating.
pub const MAX_DENSE_VOXELS: u64 = 1 << 28;

/// Float values a file's active tiles may expand to per byte of the file. A
/// tile is one stored value standing for up to 4096³ voxels; real caches
/// keep their surfaces in leaves, which makes their files big enough for
/// their tiles, while a few kilobytes claiming a solid gigavoxel region are
/// refused before anything is filled (and in well under a second).
pub const TILE_VALUES_PER_BYTE: u64 = 1024;

/// The tile budget of a file of `len` bytes: [`TILE_VALUES_PER_BYTE`] per
/// byte, at least 2²⁰ values and at most [`MAX_DENSE_VOXELS`].
pub fn tile_budget(len: usize) -> u64 {
    (len as u64).saturating_mul(TILE_VALUES_PER_BYTE).clamp(1 << 20, MAX_DENSE_VOXELS)
}

/// One metadata value, as OpenVDB types them.
#[derive(Clone, Debug, PartialEq)]
pub enum MetaValue {
    /// `bool`
    Bool(bool),
    /// `int32`
    Int32(i32),
    /// `int64`
    Int64(i64),
    /// `float`
    Float(f32),
    /// `double`
    Double(f64),
    /// `string`
    String(String),
    /// `vec3i`
    Vec3i([i32; 3]),
    /// `vec3s`
    Vec3s([f32; 3]),
    /// `vec3d`
    Vec3d([f64; 3]),
    /// Any other type, kept as raw bytes so it can be written back unchanged.
    Other {
        /// OpenVDB type name (e.g. `mat4d`).
        type_name: String,
        /// Serialized value.
        bytes: Vec<u8>,
    },
}

/// Named metadata in file order (file-level or per grid).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Metadata {
    /// `(name, value)` pairs; names are unique.
    pub entries: Vec<(String, MetaValue)>,
}

impl Metadata {
    /// The value named `name`.
    pub fn get(&self, name: &str) -> Option<&MetaValue> {
        self.entries.iter().find(|(n, _)| n == name).map(|(_, v)| v)
    }

    /// The string value named `name`, if it is a string.
    pub fn get_str(&self, name: &str) -> Option<&str> {
        match self.get(name) {
            Some(MetaValue::String(s)) => Some(s),
            _ => None,
        }
    }

    /// Sets `name`, replacing an existing entry in place.
    pub fn insert(&mut self, name: &str, value: MetaValue) {
        match self.entries.iter_mut().find(|(n, _)| n == name) {
            Some(e) => e.1 = value,
            None => self.entries.push((name.to_string(), value)),
        }
    }

    /// Removes `name` if present.
    pub fn remove(&mut self, name: &str) {
        self.entries.retain(|(n, _)| n != name);
    }
}

/// A linear index-to-world transform.
#[derive(Clone, Debug, PartialEq)]
pub struct Transform {
    /// OpenVDB map type it was read as (`UniformScaleMap`, `AffineMap`, ...);
    /// informational, the writer picks the simplest map that fits the matrix.
    pub map_type: String,
    /// World-space size of a voxel along index x, y, z.
    pub voxel_size: [f64; 3],
    /// Column-vector matrix: `world[r] = Σ_c m[r][c] * [i, j, k, 1][c]`, so
    /// the translation is column 3 (the transpose of OpenVDB's own layout).
    pub index_to_world: [[f64; 4]; 4],
}

impl Transform {
    /// Scale `voxel_size` then translate by `translation` (the common
    /// simulation-domain transform).
    pub fn scale_translate(voxel_size: [f64; 3], translation: [f64; 3]) -> Self {
        let mut m = [[0.0; 4]; 4];
        for a in 0..3 {
            m[a][a] = voxel_size[a];
            m[a][3] = translation[a];
        }
        m[3][3] = 1.0;
        Self::from_matrix("ScaleTranslateMap", m)
    }

    /// Uniform voxel size, voxel `(0,0,0)` centred on the world origin.
    pub fn uniform(voxel_size: f64) -> Self {
        Self::scale_translate([voxel_size; 3], [0.0; 3])
    }

    /// From a column-vector matrix; voxel size is the length of each mapped
    /// index axis, as OpenVDB's `voxelSize()`.
    pub fn from_matrix(map_type: &str, index_to_world: [[f64; 4]; 4]) -> Self {
        let m = index_to_world;
        let len = |c: usize| (m[0][c] * m[0][c] + m[1][c] * m[1][c] + m[2][c] * m[2][c]).sqrt();
        Self { map_type: map_type.to_string(), voxel_size: [len(0), len(1), len(2)], index_to_world }
    }

    /// World position of index-space point `ijk` (voxel centres are integers).
    pub fn index_to_world(&self, ijk: [f64; 3]) -> [f64; 3] {
        let m = &self.index_to_world;
        let mut w = [0.0; 3];
        for (r, wr) in w.iter_mut().enumerate() {
            *wr = m[r][0] * ijk[0] + m[r][1] * ijk[1] + m[r][2] * ijk[2] + m[r][3];
        }
        w
    }
}

/// Voxel values of a grid.
#[derive(Clone, Debug, PartialEq)]
pub enum GridValues {
    /// Scalar grid (`Tree_float_5_4_3`): density, temperature, ...
    Float(SparseGrid<f32>),
    /// Vector grid (`Tree_vec3s_5_4_3`): velocity, ...
    Vec3(SparseGrid<[f32; 3]>),
    /// A grid of another value type (e.g. Houdini's `Tree_int32_5_4_3`
    /// obstacles); its name, transform and metadata are read, its voxels are
    /// skipped, and converting or writing it fails with
    /// [`ErrorKind::UnsupportedValueType`].
    Unsupported {
        /// Tree type name from the grid descriptor.
        tree_type: String,
    },
}

impl GridValues {
    /// OpenVDB value type name (`float` or `vec3s`).
    pub fn type_name(&self) -> &'static str {
        match self {
            GridValues::Float(_) => "float",
            GridValues::Vec3(_) => "vec3s",
            GridValues::Unsupported { .. } => "unsupported",
        }
    }
}

/// One named grid of a file.
#[derive(Clone, Debug, PartialEq)]
pub struct VdbGrid {
    /// Grid name (`density`, `velocity`, ...).
    pub name: String,
    /// Grid class: `fog volume`, `level set`, `staggered` or `unknown`.
    pub class: String,
    /// Index-to-world transform.
    pub transform: Transform,
    /// Voxel values (the background value lives in the [`SparseGrid`]).
    pub values: GridValues,
    /// All grid metadata as stored (including `name` and `class`); the writer
    /// regenerates `name`, `class`, `is_saved_as_half_float` and the
    /// `file_*` statistics from the fields above.
    pub metadata: Metadata,
    /// Whether values were (or will be) stored as 16-bit half floats.
    pub saved_as_half: bool,
    /// File the grid was read from, used in error messages.
    pub source_path: Option<PathBuf>,
}

/// A whole `.vdb` file.
#[derive(Clone, Debug, PartialEq)]
pub struct VdbFile {
    /// File format version from the header (224 for OpenVDB 10).
    pub format_version: u32,
    /// `(major, minor)` of the library that wrote the file.
    pub library_version: (u32, u32),
    /// File-level metadata.
    pub file_metadata: Metadata,
    /// Grids in file order.
    pub grids: Vec<VdbGrid>,
}

impl VdbFile {
    /// The first grid named `name`.
    pub fn grid(&self, name: &str) -> Option<&VdbGrid> {
        self.grids.iter().find(|g| g.name == name)
    }
}

/// Where a dense block sits in index space.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DenseBox {
    /// Index coordinate of dense voxel `(0, 0, 0)`.
    pub origin: [i32; 3],
    /// Size along x, y, z (the `Grid3` dims).
    pub dims: [usize; 3],
}

/// Reads every grid of an OpenVDB file.
pub fn read_vdb(path: &Path) -> Result<VdbFile, Error> {
    let bytes = read_file(path)?;
    read::parse(path, &bytes)
}

/// Decodes an OpenVDB file already in memory; `path` only names it in errors.
pub fn read_vdb_bytes(path: &Path, bytes: &[u8]) -> Result<VdbFile, Error> {
    read::parse(path, bytes)
}

/// Writes `grids` to `path` (format 224, zlib-compressed buffers, half
/// floats where [`VdbGrid::saved_as_half`]), atomically.
pub fn write_vdb(path: &Path, grids: &[VdbGrid]) -> Result<(), Error> {
    let bytes = write_vdb_bytes(path, grids)?;
    crate::atomic::write_atomic(path, |w| w.write_all(&bytes)).map_err(|e| Error::new(path, ErrorKind::Write(e)))
}

/// Encodes `grids` as an OpenVDB file in memory (what [`write_vdb`] writes);
/// `path` only names the output in errors. Fails on an
/// [`GridValues::Unsupported`] grid.
pub fn write_vdb_bytes(path: &Path, grids: &[VdbGrid]) -> Result<Vec<u8>, Error> {
    if let Some(g) = grids.iter().find(|g| matches!(g.values, GridValues::Unsupported { .. })) {
        let GridValues::Unsupported { tree_type } = &g.values else { unreachable!() };
        let kind = ErrorKind::UnsupportedValueType { grid: g.name.clone(), tree_type: tree_type.clone() };
        return Err(Error::new(path, kind));
    }
    Ok(write::encode(grids))
}

impl VdbGrid {
    /// The grid's file in errors, `<memory>` for a grid built in memory.
    fn error(&self, kind: ErrorKind) -> Error {
        Error::new(self.source_path.as_deref().unwrap_or(Path::new("<memory>")), kind)
    }

    /// Number of active voxels.
    pub fn active_voxel_count(&self) -> u64 {
        match &self.values {
            GridValues::Float(g) => g.active_voxel_count(),
            GridValues::Vec3(g) => g.active_voxel_count(),
            GridValues::Unsupported { .. } => 0,
        }
    }

    /// Inclusive `(min, max)` index bounds of the active voxels; `None` for
    /// an empty grid.
    pub fn active_bbox(&self) -> Option<([i32; 3], [i32; 3])> {
        match &self.values {
            GridValues::Float(g) => g.active_bbox(),
            GridValues::Vec3(g) => g.active_bbox(),
            GridValues::Unsupported { .. } => None,
        }
    }

    /// First active voxel holding NaN or ±inf, if any.
    pub fn first_non_finite(&self) -> Option<[i32; 3]> {
        match &self.values {
            GridValues::Float(g) => g.iter_active().find(|(_, v)| !v.is_finite()).map(|(c, _)| c),
            GridValues::Vec3(g) => g.iter_active().find(|(_, v)| v.iter().any(|c| !c.is_finite())).map(|(c, _)| c),
            GridValues::Unsupported { .. } => None,
        }
    }

    /// Whether any active voxel holds NaN or ±inf.
    pub fn has_non_finite(&self) -> bool {
        self.first_non_finite().is_some()
    }

    /// The dense box covering the active voxels, checked against
    /// [`MAX_DENSE_VOXELS`] and for non-finite values.
    fn dense_box(&self) -> Result<DenseBox, Error> {
        let (lo, hi) =
            self.active_bbox().ok_or_else(|| self.error(ErrorKind::EmptyGrid { grid: self.name.clone() }))?;
        let dims = [0, 1, 2].map(|a| (i64::from(hi[a]) - i64::from(lo[a]) + 1) as u128);
        let voxels = dims[0] * dims[1] * dims[2];
        if voxels > u128::from(MAX_DENSE_VOXELS) {
            return Err(self.error(ErrorKind::TooLarge { grid: self.name.clone(), voxels, limit: MAX_DENSE_VOXELS }));
        }
        if let Some(ijk) = self.first_non_finite() {
            return Err(self.error(ErrorKind::NonFinite { grid: self.name.clone(), ijk }));
        }
        Ok(DenseBox { origin: lo, dims: dims.map(|d| d as usize) })
    }

    /// Dense copy of a float grid over its active bounding box (voxels
    /// outside any leaf take the background, inactive leaf voxels keep their
    /// stored value, as OpenVDB's `copyToDense`). Fails on an empty grid, a
    /// box over [`MAX_DENSE_VOXELS`], a non-finite active value or a vec3 grid.
    pub fn to_dense(&self) -> Result<(DenseBox, Grid3), Error> {
        let GridValues::Float(g) = &self.values else {
            return Err(self.wrong_type("float"));
        };
        let bx = self.dense_box()?;
        let [out] = densify(g, &bx, |v| [v]);
        Ok((bx, out))
    }

    /// Dense copy of a vec3 grid as three component grids (x, y, z), with
    /// the same rules as [`VdbGrid::to_dense`]. Staggered (MAC) grids are
    /// returned as stored: component `c` of voxel `ijk` lives on its lower
    /// face along axis `c`.
    pub fn to_dense_vec3(&self) -> Result<(DenseBox, [Grid3; 3]), Error> {
        let GridValues::Vec3(g) = &self.values else {
            return Err(self.wrong_type("vec3s"));
        };
        let bx = self.dense_box()?;
        Ok((bx, densify(g, &bx, |v| v)))
    }

    fn wrong_type(&self, expected: &'static str) -> Error {
        let grid = self.name.clone();
        self.error(match &self.values {
            GridValues::Unsupported { tree_type } => {
                ErrorKind::UnsupportedValueType { grid, tree_type: tree_type.clone() }
            }
            values => ErrorKind::WrongValueType { grid, found: values.type_name(), expected },
        })
    }

    /// A fog-volume float grid from a dense block whose voxel `(0,0,0)` is at
    /// index `origin`. Voxels with value `<= threshold` become inactive
    /// background (0); the rest are active with their value.
    pub fn from_dense(name: &str, transform: Transform, origin: [i32; 3], grid: &Grid3, threshold: f32) -> VdbGrid {
        let mut sparse = SparseGrid::new(0.0f32);
        // NaN is kept active so `has_non_finite` can report it.
        let keep = |v: f32| !matches!(v.partial_cmp(&threshold), Some(Ordering::Less | Ordering::Equal));
        sparse.insert_region(origin, grid.dims, &grid.data, keep);
        Self::new(name, "fog volume", transform, GridValues::Float(sparse))
    }

    /// A staggered-or-not vec3 grid from three dense component grids (same
    /// dims); voxels whose vector length is `<= threshold` become inactive
    /// background (0, 0, 0).
    pub fn from_dense_vec3(
        name: &str,
        class: &str,
        transform: Transform,
        origin: [i32; 3],
        components: [&Grid3; 3],
        threshold: f32,
    ) -> VdbGrid {
        let mut sparse = SparseGrid::new([0.0f32; 3]);
        let [nx, ny, nz] = components[0].dims;
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    let i = components[0].index(x, y, z);
                    let v = components.map(|c| c.data[i]);
                    let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                    if !matches!(len.partial_cmp(&threshold), Some(Ordering::Less | Ordering::Equal)) {
                        sparse.set_active([origin[0] + x as i32, origin[1] + y as i32, origin[2] + z as i32], v);
                    }
                }
            }
        }
        Self::new(name, class, transform, GridValues::Vec3(sparse))
    }

    /// A grid with no extra metadata, stored at full precision.
    pub fn new(name: &str, class: &str, transform: Transform, values: GridValues) -> VdbGrid {
        VdbGrid {
            name: name.to_string(),
            class: class.to_string(),
            transform,
            values,
            metadata: Metadata::default(),
            saved_as_half: false,
            source_path: None,
        }
    }
}

/// Copies a sparse grid into `N` dense component grids over `bx`.
fn densify<T: Copy, const N: usize>(g: &SparseGrid<T>, bx: &DenseBox, split: impl Fn(T) -> [f32; N]) -> [Grid3; N] {
    let values = g.region(bx.origin, bx.dims);
    std::array::from_fn(|c| Grid3 { dims: bx.dims, data: values.iter().map(|v| split(*v)[c]).collect() })
}
