//! Encoding of grids as an OpenVDB 10 stream (format 224).
//!
//! The upper tree levels are rebuilt from the leaf origins (root → 32³ node →
//! 16³ node → leaf), every node buffer is written with
//! `COMPRESS_ZIP | COMPRESS_ACTIVE_MASK`: only active values, zlib-deflated
//! when that is smaller, which is what OpenVDB itself does for fog volumes.

use std::collections::BTreeMap;
use std::io::Write;

use super::read::{
    Voxel, COMPRESS_ACTIVE_MASK, COMPRESS_ZIP, HALF_SUFFIX, MAGIC, NAME_SEP, NO_MASK_AND_ALL_VALS,
    NO_MASK_OR_INACTIVE_VALS,
};
use super::{GridValues, Leaf, MetaValue, Metadata, SparseGrid, Transform, VdbGrid};

/// Format version OpenVDB 10 writes.
const FORMAT_VERSION: u32 = 224;
/// Metadata the writer derives from the grid itself rather than copying.
const DERIVED_META: [&str; 8] = [
    "name",
    "class",
    "is_saved_as_half_float",
    "file_bbox_min",
    "file_bbox_max",
    "file_voxel_count",
    "file_mem_bytes",
    "file_compression",
];

fn put_u32(out: &mut Vec<u8>, v: u32) {
    out.extend_from_slice(&v.to_le_bytes());
}

fn put_str(out: &mut Vec<u8>, s: &str) {
    put_u32(out, s.len() as u32);
    out.extend_from_slice(s.as_bytes());
}

fn put_mask(out: &mut Vec<u8>, mask: &[u64]) {
    for w in mask {
        out.extend_from_slice(&w.to_le_bytes());
    }
}

/// Encodes a whole file.
pub(super) fn encode(grids: &[VdbGrid]) -> Vec<u8> {
    let mut file_meta = Metadata::default();
    file_meta.insert("creator", MetaValue::String("nst3d".into()));
    let mut out = Vec::new();
    out.extend_from_slice(&MAGIC);
    put_u32(&mut out, FORMAT_VERSION);
    put_u32(&mut out, 10);
    put_u32(&mut out, 0);
    out.push(1); // grid offsets present: readers may seek per grid
                 // Placeholder, replaced below by a hash of everything after it.
    let uuid_at = out.len();
    out.extend_from_slice(&[b'0'; 36]);
    put_metadata(&mut out, &file_meta);
    put_u32(&mut out, grids.len() as u32);
    for (i, grid) in grids.iter().enumerate() {
        // OpenVDB numbers repeated or empty names so each is unique.
        let dup = grid.name.is_empty() || grids.iter().filter(|g| g.name == grid.name).count() > 1;
        let unique = if dup { format!("{}{NAME_SEP}{i}", grid.name) } else { grid.name.clone() };
        put_grid(&mut out, grid, &unique);
    }
    let id = content_uuid(&out[uuid_at + 36..]);
    out[uuid_at..uuid_at + 36].copy_from_slice(id.as_bytes());
    out
}

/// A 36-character UUID-shaped string derived from the file's content, so the
/// same grids always give the same bytes (farm re-runs and caches compare
/// files); OpenVDB only compares the UUID for equality.
fn content_uuid(content: &[u8]) -> String {
    // Two FNV-1a 64-bit hashes with different offsets make 128 bits.
    let fnv = |seed: u64| content.iter().fold(seed, |h, &b| (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01B3));
    let hex = format!("{:016X}{:016X}", fnv(0xCBF2_9CE4_8422_2325), fnv(0x6C62_272E_07BB_0142));
    format!("{}-{}-{}-{}-{}", &hex[0..8], &hex[8..12], &hex[12..16], &hex[16..20], &hex[20..32])
}

fn put_metadata(out: &mut Vec<u8>, meta: &Metadata) {
    put_u32(out, meta.entries.len() as u32);
    for (name, value) in &meta.entries {
        put_str(out, name);
        let mut b = Vec::new();
        let ty = match value {
            MetaValue::Bool(v) => {
                b.push(u8::from(*v));
                "bool"
            }
            MetaValue::Int32(v) => {
                b.extend_from_slice(&v.to_le_bytes());
                "int32"
            }
            MetaValue::Int64(v) => {
                b.extend_from_slice(&v.to_le_bytes());
                "int64"
            }
            MetaValue::Float(v) => {
                b.extend_from_slice(&v.to_le_bytes());
                "float"
            }
            MetaValue::Double(v) => {
                b.extend_from_slice(&v.to_le_bytes());
                "double"
            }
            MetaValue::String(s) => {
                b.extend_from_slice(s.as_bytes());
                "string"
            }
            MetaValue::Vec3i(v) => {
                v.iter().for_each(|c| b.extend_from_slice(&c.to_le_bytes()));
                "vec3i"
            }
            MetaValue::Vec3s(v) => {
                v.iter().for_each(|c| b.extend_from_slice(&c.to_le_bytes()));
                "vec3s"
            }
            MetaValue::Vec3d(v) => {
                v.iter().for_each(|c| b.extend_from_slice(&c.to_le_bytes()));
                "vec3d"
            }
            MetaValue::Other { type_name, bytes } => {
                b.extend_from_slice(bytes);
                type_name.as_str()
            }
        };
        put_str(out, ty);
        put_u32(out, b.len() as u32);
        out.extend_from_slice(&b);
    }
}

/// Picks the simplest OpenVDB map that represents the matrix exactly.
fn put_transform(out: &mut Vec<u8>, t: &Transform) {
    let m = &t.index_to_world;
    let diagonal = (0..3).all(|r| (0..3).all(|c| r == c || m[r][c] == 0.0)) && m[3] == [0.0, 0.0, 0.0, 1.0];
    let put_v = |out: &mut Vec<u8>, v: [f64; 3]| v.iter().for_each(|c| out.extend_from_slice(&c.to_le_bytes()));
    if diagonal {
        let scale = [m[0][0], m[1][1], m[2][2]];
        let trans = [m[0][3], m[1][3], m[2][3]];
        let uniform = scale[0] == scale[1] && scale[1] == scale[2];
        let name = match (uniform, trans == [0.0; 3]) {
            (true, true) => "UniformScaleMap",
            (true, false) => "UniformScaleTranslateMap",
            _ => "ScaleTranslateMap",
        };
        put_str(out, name);
        if name != "UniformScaleMap" {
            put_v(out, trans);
        }
        let inv = scale.map(|s| 1.0 / s);
        put_v(out, scale);
        put_v(out, scale.map(f64::abs));
        put_v(out, inv);
        put_v(out, inv.map(|v| v * v));
        put_v(out, inv.map(|v| v / 2.0));
    } else {
        put_str(out, "AffineMap");
        for r in 0..4 {
            for row in m.iter() {
                out.extend_from_slice(&row[r].to_le_bytes());
            }
        }
    }
}

fn put_grid(out: &mut Vec<u8>, grid: &VdbGrid, unique: &str) {
    put_str(out, unique);
    let tree = match grid.values {
        GridValues::Float(_) => "Tree_float_5_4_3",
        GridValues::Vec3(_) => "Tree_vec3s_5_4_3",
        GridValues::Unsupported { .. } => unreachable!("refused by write_vdb_bytes"),
    };
    let half = if grid.saved_as_half { HALF_SUFFIX } else { "" };
    put_str(out, &format!("{tree}{half}"));
    put_str(out, ""); // not an instance
    let offsets_at = out.len();
    out.extend_from_slice(&[0; 24]);
    let grid_pos = out.len();
    put_u32(out, COMPRESS_ZIP | COMPRESS_ACTIVE_MASK);

    let mut meta = Metadata::default();
    for (k, v) in &grid.metadata.entries {
        if !DERIVED_META.contains(&k.as_str()) {
            meta.insert(k, v.clone());
        }
    }
    meta.insert("class", MetaValue::String(grid.class.clone()));
    meta.insert("name", MetaValue::String(grid.name.clone()));
    if grid.saved_as_half {
        meta.insert("is_saved_as_half_float", MetaValue::Bool(true));
    }
    if let Some((lo, hi)) = grid.active_bbox() {
        meta.insert("file_bbox_min", MetaValue::Vec3i(lo));
        meta.insert("file_bbox_max", MetaValue::Vec3i(hi));
    }
    meta.insert("file_voxel_count", MetaValue::Int64(grid.active_voxel_count() as i64));
    meta.entries.sort_by(|a, b| a.0.cmp(&b.0));
    put_metadata(out, &meta);
    put_transform(out, &grid.transform);

    let block_pos = match &grid.values {
        GridValues::Float(g) => put_tree(out, g, grid.saved_as_half),
        GridValues::Vec3(g) => put_tree(out, g, grid.saved_as_half),
        GridValues::Unsupported { .. } => unreachable!("refused by write_vdb_bytes"),
    };
    let end_pos = out.len();
    for (k, v) in [grid_pos, block_pos, end_pos].iter().enumerate() {
        out[offsets_at + 8 * k..offsets_at + 8 * k + 8].copy_from_slice(&(*v as i64).to_le_bytes());
    }
}

/// Leaves grouped under their 16³ node (by child index) under their 32³ node
/// (by origin, which is also the root's sort order).
type Layout<'a, T> = BTreeMap<[i32; 3], BTreeMap<usize, BTreeMap<usize, &'a Leaf<T>>>>;

/// Writes topology then buffers; returns where the buffers start.
fn put_tree<T: Voxel>(out: &mut Vec<u8>, g: &SparseGrid<T>, half: bool) -> usize {
    let mut layout: Layout<T> = BTreeMap::new();
    for leaf in g.leaves() {
        let o = leaf.origin;
        let n5 = o.map(|v| v & !4095);
        let i4 = (((o[0] & 4095) >> 7) << 10 | ((o[1] & 4095) >> 7) << 5 | ((o[2] & 4095) >> 7)) as usize;
        let i3 = (((o[0] & 127) >> 3) << 8 | ((o[1] & 127) >> 3) << 4 | ((o[2] & 127) >> 3)) as usize;
        layout.entry(n5).or_default().entry(i4).or_default().insert(i3, leaf);
    }
    out.extend_from_slice(&1i32.to_le_bytes()); // one buffer per tree
    g.background.put_le(out);
    put_u32(out, 0); // no root tiles
    put_u32(out, layout.len() as u32);
    let bg = g.background;
    // Internal nodes carry no tiles of their own: every table entry is the background.
    let tiles5 = vec![bg; 32768];
    let tiles4 = vec![bg; 4096];
    for (n5, node4s) in &layout {
        n5.iter().for_each(|c| out.extend_from_slice(&c.to_le_bytes()));
        let mut child5 = vec![0u64; 512];
        node4s.keys().for_each(|&i| child5[i >> 6] |= 1 << (i & 63));
        put_mask(out, &child5);
        put_mask(out, &[0u64; 512]);
        put_values(out, &tiles5, &[0u64; 512], &child5, bg, half);
        for leaves in node4s.values() {
            let mut child4 = vec![0u64; 64];
            leaves.keys().for_each(|&i| child4[i >> 6] |= 1 << (i & 63));
            put_mask(out, &child4);
            put_mask(out, &[0u64; 64]);
            put_values(out, &tiles4, &[0u64; 64], &child4, bg, half);
            for leaf in leaves.values() {
                put_mask(out, &leaf.active);
            }
        }
    }
    let block_pos = out.len();
    for node4s in layout.values() {
        for leaves in node4s.values() {
            for leaf in leaves.values() {
                put_mask(out, &leaf.active);
                put_values(out, &leaf.values[..], &leaf.active, &[0u64; 8], bg, half);
            }
        }
    }
    block_pos
}

/// `io::writeCompressedValues` restricted to the two cases we produce:
/// every inactive non-child value is the background (store active values
/// only), or not (store all values).
fn put_values<T: Voxel>(out: &mut Vec<u8>, values: &[T], value_mask: &[u64], child_mask: &[u64], bg: T, half: bool) {
    let on = |m: &[u64], n: usize| m[n >> 6] >> (n & 63) & 1 == 1;
    let plain_inactive = (0..values.len()).all(|n| on(value_mask, n) || on(child_mask, n) || values[n] == bg);
    let mut raw = Vec::new();
    let mut count = 0;
    if plain_inactive {
        out.push(NO_MASK_OR_INACTIVE_VALS);
        for n in (0..values.len()).filter(|&n| on(value_mask, n)) {
            put_value(&mut raw, values[n], half);
            count += 1;
        }
    } else {
        out.push(NO_MASK_AND_ALL_VALS);
        for &v in values {
            put_value(&mut raw, v, half);
            count += 1;
        }
    }
    // OpenVDB writes nothing at all for an empty half buffer.
    if half && count == 0 {
        return;
    }
    let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
    let zipped = z.write_all(&raw).and_then(|_| z.finish()).unwrap_or_default();
    if !raw.is_empty() && !zipped.is_empty() && zipped.len() < raw.len() {
        out.extend_from_slice(&(zipped.len() as i64).to_le_bytes());
        out.extend_from_slice(&zipped);
    } else {
        out.extend_from_slice(&(-(raw.len() as i64)).to_le_bytes());
        out.extend_from_slice(&raw);
    }
}

fn put_value<T: Voxel>(out: &mut Vec<u8>, v: T, half: bool) {
    if half {
        v.put_half_le(out)
    } else {
        v.put_le(out)
    }
}
