//! cyHair `.hair` files (Cem Yuksel's hair model format).
//!
//! Layout, all little-endian: a 128-byte header — `"HAIR"`, `u32` strand
//! count, `u32` point count, `u32` array flags (bit 0 segments, 1 points,
//! 2 thickness, 3 transparency, 4 colour), `u32` default segments, `f32`
//! default thickness, `f32` default transparency, `3 × f32` default colour,
//! 88 bytes of free text — then the arrays whose flag is set, in that order:
//! `u16` segments per strand, `3 × f32` points, `f32` thickness,
//! `f32` transparency, `3 × f32` colour (all per point). A strand with `k`
//! segments has `k + 1` points.

use std::path::Path;

use super::{checked, Groom, Strand};
use crate::bytes::{corrupt, read_file, Reader};
use crate::{Error, ErrorKind};

const HAS_SEGMENTS: u32 = 1;
const HAS_POINTS: u32 = 2;
const HAS_THICKNESS: u32 = 4;
const HAS_TRANSPARENCY: u32 = 8;
const HAS_COLOR: u32 = 16;
const HEADER_SIZE: usize = 128;

/// Reads a cyHair `.hair` file. Per-point thickness becomes
/// [`Strand::widths`] and per-point colour [`Strand::colors`] when the file
/// stores those arrays (header defaults alone are not copied per point);
/// transparency is not kept.
pub fn read_cyhair(path: &Path) -> Result<Groom, Error> {
    let bytes = read_file(path)?;
    read_cyhair_bytes(path, &bytes)
}

/// [`read_cyhair`] on bytes in memory; `path` only names them in errors.
pub fn read_cyhair_bytes(path: &Path, bytes: &[u8]) -> Result<Groom, Error> {
    checked(path, parse(bytes))
}

fn parse(bytes: &[u8]) -> Result<Groom, ErrorKind> {
    let mut r = Reader::new(bytes, 0);
    if r.array::<4>("cyHair magic")? != *b"HAIR" {
        return Err(corrupt("not a cyHair file (magic is not HAIR)"));
    }
    let hair_count = r.u32("cyHair header")? as usize;
    let point_count = r.u32("cyHair header")? as usize;
    let flags = r.u32("cyHair header")?;
    let default_segments = r.u32("cyHair header")?;
    let _default_thickness = r.f32("cyHair header")?;
    let _default_transparency = r.f32("cyHair header")?;
    let _default_color = r.vec3("cyHair header")?;
    r.take(HEADER_SIZE - r.pos(), "cyHair header")?;

    if flags & HAS_POINTS == 0 {
        return Err(corrupt("cyHair file has no point array (flag bit 1 clear)"));
    }
    // The points must fit in the file before anything sized by the header's
    // counts is made: a 370-byte file claiming a billion strands of default
    // segments used to spend 10 s building their segment list.
    r.ensure(point_count as u64, 12, "cyHair point array")?;
    let segments: Vec<usize> = if flags & HAS_SEGMENTS != 0 {
        r.ensure(hair_count as u64, 2, "cyHair segment array")?;
        (0..hair_count).map(|_| r.u16("cyHair segment array").map(usize::from)).collect::<Result<_, _>>()?
    } else {
        // Without an array every strand has the default count; check the
        // total before materialising `hair_count` entries.
        let total = (hair_count as u64).saturating_mul(default_segments as u64 + 1);
        if total != point_count as u64 {
            return Err(corrupt(format!(
                "{hair_count} strands of {default_segments} default segments need {total} points, header says {point_count}"
            )));
        }
        vec![default_segments as usize; hair_count]
    };
    let needed: usize = segments.iter().map(|s| s + 1).sum();
    if needed != point_count {
        return Err(corrupt(format!("segment counts need {needed} points, header says {point_count}")));
    }
    r.ensure(point_count as u64, 12, "cyHair point array")?;
    let points: Vec<[f32; 3]> = (0..point_count).map(|_| r.vec3("cyHair point array")).collect::<Result<_, _>>()?;
    let thickness = if flags & HAS_THICKNESS != 0 {
        r.ensure(point_count as u64, 4, "cyHair thickness array")?;
        Some((0..point_count).map(|_| r.f32("cyHair thickness array")).collect::<Result<Vec<_>, _>>()?)
    } else {
        None
    };
    if flags & HAS_TRANSPARENCY != 0 {
        r.ensure(point_count as u64, 4, "cyHair transparency array")?;
        r.take(point_count * 4, "cyHair transparency array")?;
    }
    let colors = if flags & HAS_COLOR != 0 {
        r.ensure(point_count as u64, 12, "cyHair colour array")?;
        Some((0..point_count).map(|_| r.vec3("cyHair colour array")).collect::<Result<Vec<_>, _>>()?)
    } else {
        None
    };

    let mut strands = Vec::with_capacity(hair_count);
    let mut start = 0;
    for seg in segments {
        let end = start + seg + 1;
        strands.push(Strand {
            points: points[start..end].to_vec(),
            widths: thickness.as_ref().map(|t| t[start..end].to_vec()),
            colors: colors.as_ref().map(|c| c[start..end].to_vec()),
        });
        start = end;
    }
    Ok(Groom { strands })
}
