//! USC-HairSalon `.data` files: `i32` strand count, then per strand an `i32`
//! point count `n` and `n × 3 × f32` points, little-endian, nothing else.
//!
//! The dataset grows one "strand" per scalp sample and stores bald samples
//! as strands of 0 or 1 point; those placeholders are not curves, so the
//! reader skips them (strand indices then count real strands only).

use std::path::Path;

use super::{checked, Groom, Strand};
use crate::bytes::{corrupt, read_file, Reader};
use crate::{Error, ErrorKind};

/// Reads a USC-HairSalon `.data` file (placeholder strands of fewer than
/// two points are skipped, see the module notes).
pub fn read_hairsalon(path: &Path) -> Result<Groom, Error> {
    let bytes = read_file(path)?;
    read_hairsalon_bytes(path, &bytes)
}

/// [`read_hairsalon`] on bytes in memory; `path` only names them in errors.
pub fn read_hairsalon_bytes(path: &Path, bytes: &[u8]) -> Result<Groom, Error> {
    checked(path, parse(bytes))
}

/// True when `bytes` parse as HairSalon and end exactly where the counts
/// say; the format has no magic number, so this is how content detection
/// recognises it.
pub(crate) fn looks_like_hairsalon(bytes: &[u8]) -> bool {
    bytes.len() >= 4 && parse(bytes).is_ok()
}

fn parse(bytes: &[u8]) -> Result<Groom, ErrorKind> {
    let mut r = Reader::new(bytes, 0);
    let count = r.i32("HairSalon strand count")?;
    if count < 0 {
        return Err(corrupt(format!("negative strand count {count}")));
    }
    // Each strand needs at least its 4-byte point count.
    r.ensure(count as u64, 4, "HairSalon strands")?;
    let mut strands = Vec::with_capacity(count as usize);
    for i in 0..count {
        let n = r.i32("HairSalon point count")?;
        if n < 0 {
            return Err(corrupt(format!("strand {i} has negative point count {n}")));
        }
        r.ensure(n as u64, 12, "HairSalon points")?;
        let points: Vec<[f32; 3]> = (0..n).map(|_| r.vec3("HairSalon points")).collect::<Result<_, _>>()?;
        if points.len() >= 2 {
            strands.push(Strand::new(points));
        }
    }
    if r.remaining() != 0 {
        return Err(corrupt(format!("{} unexpected bytes after the last strand", r.remaining())));
    }
    Ok(Groom { strands })
}
