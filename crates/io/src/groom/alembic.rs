//! Alembic curves from Ogawa archives: a minimal reader, written here
//! because no maintained pure-Rust Alembic crate reads untrusted files
//! safely (the one Ogawa crate, `ogawa-rs` 0.4, is a self-described work in
//! progress that indexes and allocates from unchecked file values, which can
//! panic or abort; the `alembic` crate is an empty placeholder).
//!
//! Ogawa is a tree of *groups* (a `u64` child count, then `u64` child words)
//! and *data* chunks (a `u64` size, then bytes); a child word with the top
//! bit set is data, a zero group / `0x8000…` data word is empty. Alembic
//! lays objects and properties on it:
//!
//! * archive root group: `[version, file version, top object, metadata,
//!   time samplings, indexed metadata]`;
//! * object group: `[properties compound, child objects…, child headers]`;
//! * compound property group: `[sub-properties…, property headers]`, the
//!   headers packed as in Alembic's `ReadPropertyHeaders` (an info word
//!   carrying type, POD, extent and a size hint for the varints that follow);
//! * array property group: `[sample 0 data, sample 0 dims, sample 1 …]`,
//!   each data chunk starting with a 16-byte content digest.
//!
//! Curves are objects whose `.geom` compound holds the arrays `P` (float32
//! ×3) and `nVertices` (int32); an optional `width` array (float32, one per
//! point or one in all) becomes widths. Only the first time sample is read.
//! `curveBasisAndType` is not applied: points are the stored control points
//! (hairutil writes linear curves). An ancestor Xform with authored values
//! (`.xform/.vals`) is refused as unsupported instead of being ignored;
//! identity Xforms (no `.vals`) are fine.

use std::path::Path;

use super::{checked, Groom, Strand};
use crate::bytes::{corrupt, read_file, unsupported, Reader};
use crate::{Error, ErrorKind};

/// Reads every curves object of an Alembic (Ogawa) archive into one groom,
/// in hierarchy order (see the module notes for what is read).
pub fn read_alembic_curves(path: &Path) -> Result<Groom, Error> {
    let bytes = read_file(path)?;
    read_alembic_curves_bytes(path, &bytes)
}

/// [`read_alembic_curves`] on bytes in memory; `path` only names them in
/// errors.
pub fn read_alembic_curves_bytes(path: &Path, bytes: &[u8]) -> Result<Groom, Error> {
    checked(path, parse(bytes))
}

const DATA_BIT: u64 = 1 << 63;
/// Hierarchy depth and group-visit limits: a corrupt file can make groups
/// point back at their ancestors or share children exponentially.
const MAX_DEPTH: usize = 128;
const MAX_GROUPS: usize = 1 << 20;

struct Ogawa<'a> {
    bytes: &'a [u8],
    groups_left: usize,
}

/// One entry of a compound's property header list.
#[derive(Debug)]
struct PropHeader {
    name: String,
    /// 0 compound, 1 scalar, 2 array.
    kind: u32,
    pod: u32,
    extent: u32,
}

const POD_INT32: u32 = 6;
const POD_FLOAT32: u32 = 10;

impl<'a> Ogawa<'a> {
    /// Child words of the group at child word `word` (empty for 0).
    fn group(&mut self, word: u64) -> Result<Vec<u64>, ErrorKind> {
        if word & DATA_BIT != 0 {
            return Err(corrupt("Ogawa data chunk where a group was expected"));
        }
        if word == 0 {
            return Ok(Vec::new());
        }
        self.groups_left =
            self.groups_left.checked_sub(1).ok_or_else(|| corrupt("Ogawa group graph too large (cyclic?)"))?;
        let pos = usize::try_from(word).map_err(|_| corrupt("Ogawa group offset out of range"))?;
        if pos > self.bytes.len() {
            return Err(corrupt(format!("Ogawa group offset {pos} past end of file")));
        }
        let mut r = Reader::new(self.bytes, pos);
        let n = r.u64("Ogawa group")?;
        r.ensure(n, 8, "Ogawa group children")?;
        (0..n).map(|_| r.u64("Ogawa group children")).collect()
    }

    /// Bytes of the data chunk at child word `word`.
    fn data(&self, word: u64) -> Result<&'a [u8], ErrorKind> {
        if word & DATA_BIT == 0 {
            return Err(corrupt("Ogawa group where a data chunk was expected"));
        }
        let pos = word & !DATA_BIT;
        if pos == 0 {
            return Ok(&[]);
        }
        let pos = usize::try_from(pos).map_err(|_| corrupt("Ogawa data offset out of range"))?;
        if pos > self.bytes.len() {
            return Err(corrupt(format!("Ogawa data offset {pos} past end of file")));
        }
        let mut r = Reader::new(self.bytes, pos);
        let size = r.u64("Ogawa data size")?;
        r.ensure(size, 1, "Ogawa data")?;
        r.take(size as usize, "Ogawa data")
    }

    /// A compound property: its sub-property headers and child words.
    fn compound(&mut self, word: u64) -> Result<Vec<(PropHeader, u64)>, ErrorKind> {
        let children = self.group(word)?;
        let Some((&last, props)) = children.split_last() else {
            return Ok(Vec::new());
        };
        let headers = parse_property_headers(self.data(last)?)?;
        if headers.len() != props.len() {
            return Err(corrupt(format!(
                "compound has {} property headers for {} properties",
                headers.len(),
                props.len()
            )));
        }
        Ok(headers.into_iter().zip(props.iter().copied()).collect())
    }

    /// First sample of an array property, as raw little-endian bytes
    /// (the 16-byte digest stripped).
    fn first_array_sample(&mut self, word: u64) -> Result<&'a [u8], ErrorKind> {
        let children = self.group(word)?;
        let Some(&first) = children.first() else {
            return Ok(&[]);
        };
        let d = self.data(first)?;
        if d.is_empty() {
            return Ok(d);
        }
        d.get(16..).ok_or_else(|| corrupt("Alembic array sample shorter than its digest"))
    }

    fn object(&mut self, word: u64, depth: usize, under_xform: bool, out: &mut Vec<Strand>) -> Result<(), ErrorKind> {
        if depth > MAX_DEPTH {
            return Err(corrupt("Alembic object hierarchy too deep"));
        }
        let children = self.group(word)?;
        let mut under_xform = under_xform;
        if let Some(&props) = children.first() {
            for (h, w) in self.compound(props)? {
                if h.kind != 0 {
                    continue;
                }
                match h.name.as_str() {
                    ".geom" => self.curves(w, under_xform, out)?,
                    ".xform" if self.compound(w)?.iter().any(|(h, _)| h.name == ".vals") => {
                        under_xform = true;
                    }
                    _ => {}
                }
            }
        }
        // Children between the properties and the trailing header chunk.
        if children.len() > 2 {
            for &child in &children[1..children.len() - 1] {
                self.object(child, depth + 1, under_xform, out)?;
            }
        }
        Ok(())
    }

    fn curves(&mut self, geom: u64, under_xform: bool, out: &mut Vec<Strand>) -> Result<(), ErrorKind> {
        let props = self.compound(geom)?;
        let find = |name: &str, pod: u32, extent: u32| {
            props
                .iter()
                .find(|(h, _)| h.name == name && h.kind == 2 && h.pod == pod && h.extent == extent)
                .map(|(_, w)| *w)
        };
        let (Some(p), Some(nv)) = (find("P", POD_FLOAT32, 3), find("nVertices", POD_INT32, 1)) else {
            return Ok(()); // Not a curves object (a mesh, points, ...).
        };
        if under_xform {
            return Err(unsupported("curves under an Xform with authored values (transforms are not applied)"));
        }
        let width = find("width", POD_FLOAT32, 1);
        let floats = |b: &[u8]| -> Vec<f32> {
            b.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect()
        };
        let pb = self.first_array_sample(p)?;
        if pb.len() % 12 != 0 {
            return Err(corrupt(format!("P sample of {} bytes is not a float3 array", pb.len())));
        }
        let points: Vec<[f32; 3]> = floats(pb).chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        let nb = self.first_array_sample(nv)?;
        if nb.len() % 4 != 0 {
            return Err(corrupt(format!("nVertices sample of {} bytes is not an int32 array", nb.len())));
        }
        let mut counts = Vec::with_capacity(nb.len() / 4);
        let mut total = 0usize;
        for c in nb.chunks_exact(4) {
            let n = i32::from_le_bytes([c[0], c[1], c[2], c[3]]);
            if n < 0 {
                return Err(corrupt(format!("negative curve vertex count {n}")));
            }
            total = total.saturating_add(n as usize);
            counts.push(n as usize);
        }
        if total != points.len() {
            return Err(corrupt(format!("nVertices add up to {total} but P has {} points", points.len())));
        }
        let widths = match width {
            Some(w) => {
                let w = floats(self.first_array_sample(w)?);
                match w.len() {
                    1 => Some(vec![w[0]; total]),
                    n if n == total => Some(w),
                    _ => None, // varying/uniform widths: not kept.
                }
            }
            None => None,
        };
        let mut start = 0;
        for n in counts {
            out.push(Strand {
                points: points[start..start + n].to_vec(),
                widths: widths.as_ref().map(|w| w[start..start + n].to_vec()),
                colors: None,
            });
            start += n;
        }
        Ok(())
    }
}

/// Decodes a packed property header list (Alembic `ReadPropertyHeaders`).
fn parse_property_headers(b: &[u8]) -> Result<Vec<PropHeader>, ErrorKind> {
    let mut r = Reader::new(b, 0);
    let mut out = Vec::new();
    while r.remaining() > 0 {
        let info = r.u32("Alembic property header")?;
        let kind = match info & 3 {
            0 => 0,
            1 => 1,
            _ => 2,
        };
        let hint = (info >> 2) & 3;
        let varint = |r: &mut Reader| -> Result<u32, ErrorKind> {
            match hint {
                0 => r.u8("Alembic property header").map(u32::from),
                1 => r.u16("Alembic property header").map(u32::from),
                2 => r.u32("Alembic property header"),
                _ => Err(corrupt("bad size hint in Alembic property header")),
            }
        };
        let (mut pod, mut extent) = (0, 0);
        if kind != 0 {
            pod = (info >> 4) & 0xf;
            extent = (info >> 12) & 0xff;
            let _next_sample_index = varint(&mut r)?;
            if info & 0x200 != 0 {
                varint(&mut r)?; // first changed index
                varint(&mut r)?; // last changed index
            }
            if info & 0x100 != 0 {
                varint(&mut r)?; // time sampling index
            }
        }
        let name_len = varint(&mut r)? as usize;
        let name = String::from_utf8_lossy(r.take(name_len, "Alembic property name")?).into_owned();
        if (info >> 20) & 0xff == 0xff {
            let meta_len = varint(&mut r)? as usize;
            r.take(meta_len, "Alembic property metadata")?;
        }
        out.push(PropHeader { name, kind, pod, extent });
    }
    Ok(out)
}

fn parse(bytes: &[u8]) -> Result<Groom, ErrorKind> {
    let mut r = Reader::new(bytes, 0);
    if r.array::<5>("Ogawa magic")? != *b"Ogawa" {
        return Err(corrupt("not an Alembic Ogawa archive (magic is not 'Ogawa')"));
    }
    let _frozen = r.take(1, "Ogawa header")?;
    let _version = r.u16("Ogawa header")?;
    let root = r.u64("Ogawa header")?;
    let mut o = Ogawa { bytes, groups_left: MAX_GROUPS };
    let archive = o.group(root)?;
    if archive.len() < 6 {
        return Err(corrupt(format!("Alembic archive root has {} children, expected at least 6", archive.len())));
    }
    let mut strands = Vec::new();
    o.object(archive[2], 0, false, &mut strands)?;
    Ok(Groom { strands })
}
