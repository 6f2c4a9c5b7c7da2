//! Decoding of the OpenVDB stream (`io::Archive`, `GridDescriptor`,
//! `RootNode`/`InternalNode`/`LeafNode` topology and buffers).
//!
//! Every read goes through the crate's bounds-checked [`Reader`], which turns
//! a short file into [`ErrorKind::Truncated`]; counts from the file are never
//! used to pre-allocate, so no byte sequence can make the reader panic or
//! balloon.

use std::path::Path;

use super::{
    blosc, tile_budget, GridValues, Leaf, MetaValue, Metadata, SparseGrid, Transform, VdbFile, VdbGrid, LEAF_VOXELS,
};
use crate::bytes::Reader;
use crate::{Error, ErrorKind};

/// `OPENVDB_MAGIC` as stored (little-endian i64 0x56444220).
pub(super) const MAGIC: [u8; 8] = [0x20, 0x42, 0x44, 0x56, 0, 0, 0, 0];
/// First version with per-node mask-compression metadata.
const VERSION_NODE_MASK_COMPRESSION: u32 = 222;
pub(super) const COMPRESS_ZIP: u32 = 0x1;
pub(super) const COMPRESS_ACTIVE_MASK: u32 = 0x2;
pub(super) const COMPRESS_BLOSC: u32 = 0x4;
/// Per-node metadata byte values (`io/Compression.h`).
pub(super) const NO_MASK_OR_INACTIVE_VALS: u8 = 0;
#[allow(dead_code)] // implied: inactive0 = -background unless stated
const NO_MASK_AND_MINUS_BG: u8 = 1;
const NO_MASK_AND_ONE_INACTIVE_VAL: u8 = 2;
const MASK_AND_NO_INACTIVE_VALS: u8 = 3;
const MASK_AND_ONE_INACTIVE_VAL: u8 = 4;
const MASK_AND_TWO_INACTIVE_VALS: u8 = 5;
pub(super) const NO_MASK_AND_ALL_VALS: u8 = 6;
/// Separator OpenVDB puts between a duplicate grid name and its number.
pub(super) const NAME_SEP: char = '\u{1e}';
/// Suffix of the tree type of grids saved as half floats.
pub(super) const HALF_SUFFIX: &str = "_HalfFloat";

/// What OpenVDB's stream adds to the plain byte reads.
trait VdbReads {
    /// `u32` length + bytes (OpenVDB `readString`).
    fn string(&mut self, what: &'static str) -> Result<String, ErrorKind>;
    /// A node mask of `words` 64-bit words.
    fn mask(&mut self, words: usize, what: &'static str) -> Result<Vec<u64>, ErrorKind>;
    /// Corrupt data at the current offset (OpenVDB messages name one).
    fn corrupt(&self, reason: impl Into<String>) -> ErrorKind;
}

impl VdbReads for Reader<'_> {
    fn string(&mut self, what: &'static str) -> Result<String, ErrorKind> {
        let n = self.u32(what)? as usize;
        Ok(String::from_utf8_lossy(self.take(n, what)?).into_owned())
    }

    fn mask(&mut self, words: usize, what: &'static str) -> Result<Vec<u64>, ErrorKind> {
        let raw = self.take(words * 8, what)?;
        Ok(raw.chunks_exact(8).map(|c| u64::from_le_bytes(c.try_into().unwrap())).collect())
    }

    fn corrupt(&self, reason: impl Into<String>) -> ErrorKind {
        ErrorKind::Corrupt { offset: Some(self.pos()), reason: reason.into() }
    }
}

#[inline]
fn bit(mask: &[u64], n: usize) -> bool {
    mask[n >> 6] >> (n & 63) & 1 == 1
}

/// The two voxel value types we decode, with their on-disk encodings.
pub(super) trait Voxel: Copy + PartialEq + std::fmt::Debug {
    /// Bytes of one value at full precision.
    const SIZE: usize;
    /// Bytes of one value saved as half floats.
    const HALF_SIZE: usize;
    fn from_le(b: &[u8]) -> Self;
    fn from_half_le(b: &[u8]) -> Self;
    fn put_le(self, out: &mut Vec<u8>);
    fn put_half_le(self, out: &mut Vec<u8>);
    fn neg(self) -> Self;
}

/// IEEE half to single precision (exact; every half is a float).
#[inline]
fn f16(b: &[u8]) -> f32 {
    let h = u32::from(u16::from_le_bytes([b[0], b[1]]));
    let sign = (h & 0x8000) << 16;
    let exp = (h >> 10) & 0x1f;
    let man = h & 0x3ff;
    let bits = match exp {
        0 if man == 0 => sign,
        // Subnormal half: man * 2^-24, exactly representable as a float.
        0 => return f32::from_bits(sign) + (man as f32) * (1.0 / 16_777_216.0) * if sign != 0 { -1.0 } else { 1.0 },
        31 => sign | 0x7f80_0000 | (man << 13),
        _ => sign | ((exp + 112) << 23) | (man << 13),
    };
    f32::from_bits(bits)
}

impl Voxel for f32 {
    const SIZE: usize = 4;
    const HALF_SIZE: usize = 2;
    fn from_le(b: &[u8]) -> Self {
        f32::from_le_bytes([b[0], b[1], b[2], b[3]])
    }
    fn from_half_le(b: &[u8]) -> Self {
        f16(b)
    }
    fn put_le(self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.to_le_bytes());
    }
    fn put_half_le(self, out: &mut Vec<u8>) {
        out.extend_from_slice(&half::f16::from_f32(self).to_le_bytes());
    }
    fn neg(self) -> Self {
        -self
    }
}

impl Voxel for [f32; 3] {
    const SIZE: usize = 12;
    const HALF_SIZE: usize = 6;
    fn from_le(b: &[u8]) -> Self {
        [f32::from_le(&b[0..4]), f32::from_le(&b[4..8]), f32::from_le(&b[8..12])]
    }
    fn from_half_le(b: &[u8]) -> Self {
        [f16(&b[0..2]), f16(&b[2..4]), f16(&b[4..6])]
    }
    fn put_le(self, out: &mut Vec<u8>) {
        self.iter().for_each(|v| v.put_le(out));
    }
    fn put_half_le(self, out: &mut Vec<u8>) {
        self.iter().for_each(|v| v.put_half_le(out));
    }
    fn neg(self) -> Self {
        self.map(|v| -v)
    }
}

/// Decodes a whole file.
pub(super) fn parse(path: &Path, data: &[u8]) -> Result<VdbFile, Error> {
    decode(path, data).map_err(|kind| {
        // OpenVDB messages have always given the whole read that failed as
        // "needed", where the shared reader gives the bytes missing; the read
        // started at `offset`, which never lies past the end.
        let kind = match kind {
            ErrorKind::Truncated { what, offset, needed } => {
                ErrorKind::Truncated { what, offset, needed: needed + (data.len() - offset) }
            }
            kind => kind,
        };
        Error::new(path, kind)
    })
}

/// [`parse`] before the file is named in the error.
fn decode(path: &Path, data: &[u8]) -> Result<VdbFile, ErrorKind> {
    let mut c = Reader::new(data, 0);
    if data.len() < 8 || data[..8] != MAGIC {
        return Err(ErrorKind::NotVdb);
    }
    c.seek(8);
    let version = c.u32("header")?;
    if version < VERSION_NODE_MASK_COMPRESSION {
        return Err(ErrorKind::UnsupportedVersion { version });
    }
    let library_version = (c.u32("header")?, c.u32("header")?);
    let has_offsets = c.u8("header")? != 0;
    c.take(36, "header uuid")?;
    let file_metadata = read_metadata(&mut c)?;
    let count = c.i32("grid count")?;
    if count < 0 {
        return Err(c.corrupt(format!("negative grid count {count}")));
    }
    let mut grids: Vec<(String, VdbGrid)> = Vec::new();
    // Float values that tile expansion and instancing may still create in
    // this file, shared by its grids.
    let limit = tile_budget(c.len());
    let mut budget = limit;
    for _ in 0..count {
        let grid = read_grid(&mut c, path, has_offsets, &grids, (&mut budget, limit))?;
        grids.push(grid);
    }
    Ok(VdbFile {
        format_version: version,
        library_version,
        file_metadata,
        grids: grids.into_iter().map(|(_, g)| g).collect(),
    })
}

/// `MetaMap::readMeta`: count, then name, type name, `u32` size, value.
fn read_metadata(c: &mut Reader) -> Result<Metadata, ErrorKind> {
    let n = c.u32("metadata count")?;
    let mut meta = Metadata::default();
    for _ in 0..n {
        let name = c.string("metadata name")?;
        let type_name = c.string("metadata type")?;
        let size = c.u32("metadata size")? as usize;
        let b = c.take(size, "metadata value")?;
        let f32_at = |o: usize| f32::from_le_bytes(b[o..o + 4].try_into().unwrap());
        let i32_at = |o: usize| i32::from_le_bytes(b[o..o + 4].try_into().unwrap());
        let f64_at = |o: usize| f64::from_le_bytes(b[o..o + 8].try_into().unwrap());
        let value = match (type_name.as_str(), size) {
            ("string", _) => MetaValue::String(String::from_utf8_lossy(b).into_owned()),
            ("bool", 1) => MetaValue::Bool(b[0] != 0),
            ("int32", 4) => MetaValue::Int32(i32_at(0)),
            ("int64", 8) => MetaValue::Int64(i64::from_le_bytes(b.try_into().unwrap())),
            ("float", 4) => MetaValue::Float(f32_at(0)),
            ("double", 8) => MetaValue::Double(f64_at(0)),
            ("vec3i", 12) => MetaValue::Vec3i([i32_at(0), i32_at(4), i32_at(8)]),
            ("vec3s", 12) => MetaValue::Vec3s([f32_at(0), f32_at(4), f32_at(8)]),
            ("vec3d", 24) => MetaValue::Vec3d([f64_at(0), f64_at(8), f64_at(16)]),
            // Types starting with "__" (delayed-load offsets) describe this
            // particular file layout and are dropped, as OpenVDB does.
            (t, _) if t.starts_with("__") => continue,
            _ => MetaValue::Other { type_name, bytes: b.to_vec() },
        };
        meta.insert(&name, value);
    }
    Ok(meta)
}

/// `Transform::read`: map type name, then the map's fields.
fn read_transform(c: &mut Reader, grid: &str) -> Result<Transform, ErrorKind> {
    let map = c.string("transform type")?;
    let mut m = [[0.0; 4]; 4];
    m[3][3] = 1.0;
    match map.as_str() {
        "UniformScaleMap" | "ScaleMap" | "UniformScaleTranslateMap" | "ScaleTranslateMap" => {
            let translate = if map.ends_with("TranslateMap") { c.vec3d("transform")? } else { [0.0; 3] };
            let scale = c.vec3d("transform")?;
            // voxel size, inverse scale, inverse scale², inverse twice scale:
            // all derived from `scale`.
            c.take(4 * 24, "transform")?;
            for a in 0..3 {
                m[a][a] = scale[a];
                m[a][3] = translate[a];
            }
        }
        "TranslationMap" => {
            let t = c.vec3d("transform")?;
            for a in 0..3 {
                m[a][a] = 1.0;
                m[a][3] = t[a];
            }
        }
        "AffineMap" | "UnitaryMap" => {
            // OpenVDB's Mat4d is row-major for row vectors (translation in
            // row 3); transpose into our column-vector form.
            for r in 0..4 {
                for row in m.iter_mut() {
                    row[r] = c.f64("transform")?;
                }
            }
        }
        _ => return Err(ErrorKind::UnsupportedTransform { grid: grid.to_string(), map }),
    }
    Ok(Transform::from_matrix(&map, m))
}

/// Grid descriptor plus grid body. Returns the unique name (for instance
/// lookups) and the grid.
fn read_grid(
    c: &mut Reader,
    path: &Path,
    has_offsets: bool,
    done: &[(String, VdbGrid)],
    (budget, limit): (&mut u64, u64),
) -> Result<(String, VdbGrid), ErrorKind> {
    let unique = c.string("grid name")?;
    let name = unique.split(NAME_SEP).next().unwrap_or("").to_string();
    let mut tree_type = c.string("grid type")?;
    let saved_as_half = tree_type.ends_with(HALF_SUFFIX);
    if saved_as_half {
        tree_type.truncate(tree_type.len() - HALF_SUFFIX.len());
    }
    let parent = c.string("grid instance parent")?;
    let end_pos = if has_offsets {
        c.i64("grid offsets")?;
        c.i64("grid offsets")?;
        Some(c.i64("grid offsets")?)
    } else {
        None
    };
    let is_float = tree_type == "Tree_float_5_4_3";
    let supported = is_float || tree_type == "Tree_vec3s_5_4_3";
    // Without the descriptor's end offset there is no way past a tree we
    // cannot decode.
    if !supported && end_pos.is_none() {
        return Err(ErrorKind::UnsupportedValueType { grid: name, tree_type });
    }
    let compression = c.u32("grid compression")?;
    let metadata = read_metadata(c)?;
    let transform = read_transform(c, &name)?;
    let values = if !supported {
        let end = end_pos.and_then(|e| usize::try_from(e).ok()).filter(|&e| e >= c.pos() && e <= c.len());
        match end {
            Some(e) => c.seek(e),
            None => return Err(c.corrupt(format!("grid '{name}' has a bad end offset"))),
        }
        GridValues::Unsupported { tree_type: tree_type.clone() }
    } else if !parent.is_empty() {
        // An instance shares the tree of a grid written before it.
        // A copy costs memory like the parent's voxels did: many instances
        // of one big grid in a small file are refused too.
        match done.iter().find(|(u, _)| *u == parent) {
            Some((_, p)) => {
                let floats = match &p.values {
                    GridValues::Float(g) => g.leaf_count() as u128 * LEAF_VOXELS as u128,
                    GridValues::Vec3(g) => 3 * g.leaf_count() as u128 * LEAF_VOXELS as u128,
                    GridValues::Unsupported { .. } => 0,
                };
                charge(budget, limit, floats, &name)?;
                p.values.clone()
            }
            None => return Err(c.corrupt(format!("grid '{name}' instances missing grid '{parent}'"))),
        }
    } else {
        let mut dec = TreeDecoder { c: &mut *c, compression, half: saved_as_half, grid: &name, budget: *budget, limit };
        let values =
            if is_float { GridValues::Float(dec.tree::<f32>()?) } else { GridValues::Vec3(dec.tree::<[f32; 3]>()?) };
        *budget = dec.budget;
        values
    };
    if let Some(end) = end_pos {
        // Trust the descriptor's end offset when it is sane, so trailing
        // data we do not interpret cannot desynchronise the next grid.
        if let Ok(end) = usize::try_from(end) {
            if end >= c.pos() && end <= c.len() {
                c.seek(end);
            }
        }
    }
    let class = metadata.get_str("class").unwrap_or("unknown").to_string();
    let grid =
        VdbGrid { name, class, transform, values, metadata, saved_as_half, source_path: Some(path.to_path_buf()) };
    Ok((unique, grid))
}

/// Takes `floats` from what is left of the file's tile budget `limit`, or
/// refuses naming the file's whole claim with them.
fn charge(budget: &mut u64, limit: u64, floats: u128, grid: &str) -> Result<(), ErrorKind> {
    if floats > u128::from(*budget) {
        let values = floats + u128::from(limit - *budget);
        return Err(ErrorKind::TileExpansion { grid: grid.to_string(), values, limit });
    }
    *budget -= floats as u64;
    Ok(())
}

/// Topology of a 16³ (`InternalNode<Leaf, 4>`) node.
struct Node4<T> {
    origin: [i32; 3],
    child_mask: Vec<u64>,
    value_mask: Vec<u64>,
    values: Vec<T>,
    leaf_masks: Vec<([i32; 3], Vec<u64>)>,
}

/// Topology of a 32³ (`InternalNode<Node4, 5>`) node.
struct Node5<T> {
    origin: [i32; 3],
    child_mask: Vec<u64>,
    value_mask: Vec<u64>,
    values: Vec<T>,
    children: Vec<Node4<T>>,
}

struct TreeDecoder<'c, 'a> {
    c: &'c mut Reader<'a>,
    compression: u32,
    half: bool,
    grid: &'c str,
    /// Float values tile expansion may still create in this file.
    budget: u64,
    /// The file's whole tile budget, [`tile_budget`].
    limit: u64,
}

impl TreeDecoder<'_, '_> {
    fn tree<T: Voxel>(&mut self) -> Result<SparseGrid<T>, ErrorKind> {
        let buffers = self.c.i32("tree buffer count")?;
        if buffers != 1 {
            return Err(self.c.corrupt(format!("tree has {buffers} buffers, expected 1")));
        }
        let background = T::from_le(self.c.take(T::SIZE, "background")?);
        let mut grid = SparseGrid::new(background);
        let tiles = self.c.u32("root tile count")?;
        let children = self.c.u32("root child count")?;
        let mut root_tiles = Vec::new();
        for _ in 0..tiles {
            let o = self.c.vec3i("root tile")?;
            let v = T::from_le(self.c.take(T::SIZE, "root tile")?);
            let active = self.c.u8("root tile")? != 0;
            if active {
                root_tiles.push((o, v));
            }
        }
        let mut nodes = Vec::new();
        for _ in 0..children {
            let key = self.c.vec3i("root child origin")?;
            let origin = key.map(|v| v & !4095);
            nodes.push((key, self.node5::<T>(origin, background)?));
        }
        // Buffers follow in the order of the root's std::map, i.e. sorted
        // by child coordinate, whatever order the topology came in.
        nodes.sort_by_key(|n| n.0);
        if nodes.windows(2).any(|w| w[0].0 == w[1].0) {
            return Err(self.c.corrupt("duplicate root child"));
        }
        for (_, n5) in &nodes {
            for n4 in &n5.children {
                for (origin, mask) in &n4.leaf_masks {
                    self.c.take(64, "leaf mask")?;
                    let mut values = Box::new([background; LEAF_VOXELS]);
                    self.values(&mut values[..], mask, background)?;
                    let mut active = [0u64; 8];
                    active.copy_from_slice(mask);
                    grid.insert_leaf(Leaf { origin: *origin, active, values });
                }
            }
        }
        // Active tiles become full leaves: the whole grid's claim is checked
        // against the file's budget before anything is filled.
        let tile_voxels = |value_mask: &[u64], child_mask: &[u64], child_total: u32| -> u128 {
            let tiles: u32 = value_mask.iter().zip(child_mask).map(|(&on, &child)| (on & !child).count_ones()).sum();
            u128::from(tiles) << (3 * child_total)
        };
        let mut claimed = u128::from(root_tiles.len() as u64) << 36;
        for (_, n5) in &nodes {
            claimed += tile_voxels(&n5.value_mask, &n5.child_mask, 7);
            for n4 in &n5.children {
                claimed += tile_voxels(&n4.value_mask, &n4.child_mask, 3);
            }
        }
        let floats = claimed * (std::mem::size_of::<T>() / std::mem::size_of::<f32>()) as u128;
        charge(&mut self.budget, self.limit, floats, self.grid)?;
        for (_, n5) in &nodes {
            for n4 in &n5.children {
                Self::expand_tiles(&mut grid, n4.origin, &n4.child_mask, &n4.value_mask, &n4.values, 4, 3);
            }
            Self::expand_tiles(&mut grid, n5.origin, &n5.child_mask, &n5.value_mask, &n5.values, 5, 7);
        }
        for (o, v) in root_tiles {
            Self::fill(&mut grid, o.map(|x| x & !4095), 4096, v);
        }
        Ok(grid)
    }

    /// Expands the active tiles of one internal node with `2^log2` children
    /// per axis, each covering `2^child_total` voxels per axis.
    fn expand_tiles<T: Voxel>(
        grid: &mut SparseGrid<T>,
        origin: [i32; 3],
        child_mask: &[u64],
        value_mask: &[u64],
        values: &[T],
        log2: u32,
        child_total: u32,
    ) {
        for (w, (&on, &child)) in value_mask.iter().zip(child_mask).enumerate() {
            let mut tiles = on & !child;
            while tiles != 0 {
                let n = w * 64 + tiles.trailing_zeros() as usize;
                tiles &= tiles - 1;
                let o = local_origin(origin, n, log2, child_total);
                Self::fill(grid, o, 1 << child_total, values[n]);
            }
        }
    }

    /// Sets every voxel of the cube at `o` with edge `edge` active to `v`
    /// (the caller has charged it to the budget).
    fn fill<T: Voxel>(grid: &mut SparseGrid<T>, o: [i32; 3], edge: i32, v: T) {
        for x in (0..edge).step_by(8) {
            for y in (0..edge).step_by(8) {
                for z in (0..edge).step_by(8) {
                    let origin = [o[0] + x, o[1] + y, o[2] + z];
                    grid.insert_leaf(Leaf { origin, active: [u64::MAX; 8], values: Box::new([v; LEAF_VOXELS]) });
                }
            }
        }
    }

    fn node5<T: Voxel>(&mut self, origin: [i32; 3], bg: T) -> Result<Node5<T>, ErrorKind> {
        let child_mask = self.c.mask(512, "node mask")?;
        let value_mask = self.c.mask(512, "node mask")?;
        let mut values = vec![bg; 32768];
        self.values(&mut values, &value_mask, bg)?;
        let mut children = Vec::new();
        for n in 0..32768 {
            if bit(&child_mask, n) {
                children.push(self.node4(local_origin(origin, n, 5, 7), bg)?);
            }
        }
        Ok(Node5 { origin, child_mask, value_mask, values, children })
    }

    fn node4<T: Voxel>(&mut self, origin: [i32; 3], bg: T) -> Result<Node4<T>, ErrorKind> {
        let child_mask = self.c.mask(64, "node mask")?;
        let value_mask = self.c.mask(64, "node mask")?;
        let mut values = vec![bg; 4096];
        self.values(&mut values, &value_mask, bg)?;
        let mut leaf_masks = Vec::new();
        for n in 0..4096 {
            if bit(&child_mask, n) {
                leaf_masks.push((local_origin(origin, n, 4, 3), self.c.mask(8, "leaf mask")?));
            }
        }
        Ok(Node4 { origin, child_mask, value_mask, values, leaf_masks })
    }

    /// `io::readCompressedValues`: fills `dest` (a node's full value table)
    /// from the per-node metadata byte, inactive values, selection mask and
    /// the (possibly mask-compressed, half, zlib or Blosc) value buffer.
    fn values<T: Voxel>(&mut self, dest: &mut [T], value_mask: &[u64], bg: T) -> Result<(), ErrorKind> {
        let meta = self.c.u8("node compression metadata")?;
        if meta > NO_MASK_AND_ALL_VALS {
            return Err(self.c.corrupt(format!("unknown node compression metadata {meta}")));
        }
        let mut inactive0 = if meta == NO_MASK_OR_INACTIVE_VALS { bg } else { bg.neg() };
        let mut inactive1 = bg;
        if matches!(meta, NO_MASK_AND_ONE_INACTIVE_VAL | MASK_AND_ONE_INACTIVE_VAL | MASK_AND_TWO_INACTIVE_VALS) {
            inactive0 = T::from_le(self.c.take(T::SIZE, "inactive value")?);
            if meta == MASK_AND_TWO_INACTIVE_VALS {
                inactive1 = T::from_le(self.c.take(T::SIZE, "inactive value")?);
            }
        }
        let selection =
            if matches!(meta, MASK_AND_NO_INACTIVE_VALS | MASK_AND_ONE_INACTIVE_VAL | MASK_AND_TWO_INACTIVE_VALS) {
                Some(self.c.mask(dest.len() / 64, "selection mask")?)
            } else {
                None
            };
        let mask_compressed = self.compression & COMPRESS_ACTIVE_MASK != 0 && meta != NO_MASK_AND_ALL_VALS;
        let count = if mask_compressed { value_mask.iter().map(|w| w.count_ones() as usize).sum() } else { dest.len() };
        let elem = if self.half { T::HALF_SIZE } else { T::SIZE };
        // Half buffers with no values are skipped entirely by OpenVDB.
        let raw = if self.half && count == 0 { Vec::new() } else { self.data(count * elem)? };
        let mut decoded = raw.chunks_exact(elem);
        let mut next = || {
            let b = decoded.next().expect("buffer length checked by data()");
            if self.half {
                T::from_half_le(b)
            } else {
                T::from_le(b)
            }
        };
        if count == dest.len() {
            dest.iter_mut().for_each(|d| *d = next());
            return Ok(());
        }
        if count == 0 && selection.is_none() {
            dest.fill(inactive0);
            return Ok(());
        }
        for (w, &word) in value_mask.iter().enumerate() {
            for (b, d) in dest[w * 64..(w + 1) * 64].iter_mut().enumerate() {
                *d = if word >> b & 1 == 1 {
                    next()
                } else if selection.as_ref().is_some_and(|s| s[w] >> b & 1 == 1) {
                    inactive1
                } else {
                    inactive0
                };
            }
        }
        Ok(())
    }

    /// `io::readData`: a value buffer of exactly `bytes` bytes, raw or as an
    /// `i64` size (negative = stored uncompressed) + zlib/Blosc frame.
    fn data(&mut self, bytes: usize) -> Result<Vec<u8>, ErrorKind> {
        if self.compression & (COMPRESS_BLOSC | COMPRESS_ZIP) == 0 {
            return Ok(self.c.take(bytes, "node values")?.to_vec());
        }
        let start = self.c.pos();
        let n = self.c.i64("compressed size")?;
        if n <= 0 {
            if n.unsigned_abs() != bytes as u64 {
                return Err(self.c.corrupt(format!("stored chunk of {} bytes, expected {bytes}", n.unsigned_abs())));
            }
            return Ok(self.c.take(bytes, "node values")?.to_vec());
        }
        let Ok(n) = usize::try_from(n) else {
            return Err(self.c.corrupt("compressed size overflows"));
        };
        let frame = self.c.take(n, "compressed node values")?;
        let out =
            if self.compression & COMPRESS_BLOSC != 0 { blosc::decompress(frame, bytes) } else { unzip(frame, bytes) };
        out.map_err(|reason| ErrorKind::Corrupt { offset: Some(start), reason })
    }
}

/// Inflates a zlib stream that must hold exactly `bytes` bytes.
fn unzip(frame: &[u8], bytes: usize) -> Result<Vec<u8>, String> {
    use std::io::Read;
    let mut out = Vec::with_capacity(bytes);
    flate2::read::ZlibDecoder::new(frame)
        .take(bytes as u64 + 1)
        .read_to_end(&mut out)
        .map_err(|e| format!("zlib: {e}"))?;
    if out.len() != bytes {
        return Err(format!("zlib chunk inflated to {} bytes, expected {bytes}", out.len()));
    }
    Ok(out)
}

/// Origin of child `n` of an internal node with `2^log2` children per axis
/// (`x` slowest), each child spanning `2^child_total` voxels per axis.
pub(super) fn local_origin(origin: [i32; 3], n: usize, log2: u32, child_total: u32) -> [i32; 3] {
    let n = n as i32;
    let m = (1 << log2) - 1;
    [
        origin[0] + ((n >> (2 * log2)) << child_total),
        origin[1] + (((n >> log2) & m) << child_total),
        origin[2] + ((n & m) << child_total),
    ]
}
