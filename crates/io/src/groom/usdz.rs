//! `.usdz` packages: a zip archive whose entries are stored uncompressed,
//! each entry's data starting on a 64-byte boundary (padding goes in the
//! local header's extra field), the first entry being the package's root
//! layer. The reader walks the local headers from the start of the file,
//! as USD's own reader does, and takes stored entries only; the writer
//! writes one root layer entry, its central directory and the end record.

use crate::bytes::{corrupt, unsupported, Reader};
use crate::ErrorKind;

const LOCAL: u32 = 0x0403_4b50;
const CENTRAL: u32 = 0x0201_4b50;
const END: u32 = 0x0605_4b50;

/// Whether `bytes` start like a zip archive.
pub(crate) fn is_zip(bytes: &[u8]) -> bool {
    bytes.starts_with(&LOCAL.to_le_bytes())
}

/// The name of the first entry, from the first local header alone.
pub(crate) fn first_name(bytes: &[u8]) -> Option<String> {
    if !is_zip(bytes) || bytes.len() < 30 {
        return None;
    }
    let n = u16::from_le_bytes([bytes[26], bytes[27]]) as usize;
    bytes.get(30..30 + n).map(|b| String::from_utf8_lossy(b).to_ascii_lowercase())
}

/// The entries of a package, in file order: (name, data).
pub(crate) fn entries(bytes: &[u8]) -> Result<Vec<(String, &[u8])>, ErrorKind> {
    let mut r = Reader::new(bytes, 0);
    let mut out = Vec::new();
    while r.remaining() >= 4 && u32::from_le_bytes(bytes[r.pos()..r.pos() + 4].try_into().expect("4")) == LOCAL {
        r.u32("zip entry")?;
        r.u16("zip version")?;
        let flags = r.u16("zip flags")?;
        let method = r.u16("zip method")?;
        r.u32("zip time")?;
        let crc = r.u32("zip crc")?;
        let size = r.u32("zip size")?;
        let full = r.u32("zip size")?;
        let (name_len, extra_len) = (r.u16("zip name")?, r.u16("zip extra")?);
        let name = String::from_utf8_lossy(r.take(name_len as usize, "zip entry name")?).into_owned();
        r.take(extra_len as usize, "zip extra field")?;
        if method != 0 || flags & 0x9 != 0 || size != full {
            return Err(unsupported(format!(
                "usdz entry '{}' is compressed or encrypted (a usdz package stores its files as they are)",
                name.escape_debug()
            )));
        }
        if size == u32::MAX {
            return Err(unsupported("zip64 usdz packages"));
        }
        let data = r.take(size as usize, "usdz entry data")?;
        if crc32fast::hash(data) != crc {
            return Err(corrupt(format!("usdz entry '{}' fails its checksum", name.escape_debug())));
        }
        out.push((name, data));
    }
    if out.is_empty() {
        return Err(corrupt("not a usdz package (no zip entry at its start)"));
    }
    Ok(out)
}

/// Normalises a package path: `/` separators, no `.` or empty parts, `..`
/// resolved; `None` if it climbs out of the package.
pub(crate) fn normalize(path: &str) -> Option<String> {
    let mut parts: Vec<&str> = Vec::new();
    for p in path.split(['/', '\\']) {
        match p {
            "" | "." => {}
            ".." => {
                parts.pop()?;
            }
            p => parts.push(p),
        }
    }
    Some(parts.join("/"))
}

/// A package holding `files` (name, data), the first one its root layer.
pub(crate) fn package(files: &[(&str, &[u8])]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut central = Vec::new();
    for (name, data) in files {
        let at = out.len() as u32;
        let crc = crc32fast::hash(data);
        // Data starts after the 30-byte header, the name and the padding.
        let unpadded = out.len() + 30 + name.len();
        let mut pad = (64 - unpadded % 64) % 64;
        if pad > 0 && pad < 4 {
            pad += 64;
        }
        let mut extra = Vec::new();
        if pad > 0 {
            extra.extend_from_slice(&0x1986u16.to_le_bytes());
            extra.extend_from_slice(&((pad - 4) as u16).to_le_bytes());
            extra.resize(pad, 0);
        }
        let fixed = |sig: u32, o: &mut Vec<u8>| {
            o.extend_from_slice(&sig.to_le_bytes());
            if sig == CENTRAL {
                o.extend_from_slice(&0u16.to_le_bytes());
            }
            // Version 1.0, no flags, stored, a fixed 1980-01-01 time stamp.
            for h in [10u16, 0, 0, 0, 0x21] {
                o.extend_from_slice(&h.to_le_bytes());
            }
            for w in [crc, data.len() as u32, data.len() as u32] {
                o.extend_from_slice(&w.to_le_bytes());
            }
            o.extend_from_slice(&(name.len() as u16).to_le_bytes());
            o.extend_from_slice(&(extra.len() as u16).to_le_bytes());
        };
        fixed(LOCAL, &mut out);
        out.extend_from_slice(name.as_bytes());
        out.extend_from_slice(&extra);
        debug_assert_eq!(out.len() % 64, 0);
        out.extend_from_slice(data);
        fixed(CENTRAL, &mut central);
        // No comment, disk 0, no attributes, then where the entry starts.
        central.extend_from_slice(&[0; 10]);
        central.extend_from_slice(&at.to_le_bytes());
        central.extend_from_slice(name.as_bytes());
        central.extend_from_slice(&extra);
    }
    let dir_at = out.len() as u32;
    out.extend_from_slice(&central);
    out.extend_from_slice(&END.to_le_bytes());
    out.extend_from_slice(&[0; 4]);
    let n = files.len() as u16;
    for h in [n, n] {
        out.extend_from_slice(&h.to_le_bytes());
    }
    out.extend_from_slice(&(central.len() as u32).to_le_bytes());
    out.extend_from_slice(&dir_at.to_le_bytes());
    out.extend_from_slice(&0u16.to_le_bytes());
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packages_round_trip_aligned() {
        let a = b"#usda 1.0\n".to_vec();
        let b = vec![7u8; 100];
        let z = package(&[("groom.usda", &a), ("sub/x.bin", &b)]);
        let e = entries(&z).unwrap();
        assert_eq!(e.len(), 2);
        assert_eq!((e[0].0.as_str(), e[0].1), ("groom.usda", &a[..]));
        assert_eq!((e[1].0.as_str(), e[1].1), ("sub/x.bin", &b[..]));
        for (_, d) in e {
            assert_eq!((d.as_ptr() as usize - z.as_ptr() as usize) % 64, 0, "data 64-byte aligned");
        }
        // The central directory (what zip tools read) names both entries
        // at their local headers.
        let end = z.len() - 22;
        assert_eq!(&z[end..end + 4], &END.to_le_bytes());
        let word = |at: usize| u32::from_le_bytes(z[at..at + 4].try_into().unwrap()) as usize;
        let half = |at: usize| u16::from_le_bytes(z[at..at + 2].try_into().unwrap()) as usize;
        let (mut at, mut names) = (word(end + 16), Vec::new());
        for _ in 0..half(end + 10) {
            assert_eq!(word(at), CENTRAL as usize);
            let (name, extra, comment) = (half(at + 28), half(at + 30), half(at + 32));
            let local = word(at + 42);
            assert_eq!(word(local), LOCAL as usize);
            names.push(String::from_utf8(z[at + 46..at + 46 + name].to_vec()).unwrap());
            at += 46 + name + extra + comment;
        }
        assert_eq!(names, ["groom.usda", "sub/x.bin"]);
        assert_eq!(at, end);
    }

    #[test]
    fn bad_packages_are_errors() {
        let z = package(&[("a.usda", b"#usda 1.0\n")]);
        for cut in [4, 20, 40, 70] {
            assert!(entries(&z[..cut]).is_err(), "cut at {cut}");
        }
        let mut flipped = z.clone();
        flipped[64] ^= 1;
        assert!(entries(&flipped).is_err(), "checksum");
        assert_eq!(normalize("a/./b/../c.usda").as_deref(), Some("a/c.usda"));
        assert_eq!(normalize("../x"), None);
    }
}
