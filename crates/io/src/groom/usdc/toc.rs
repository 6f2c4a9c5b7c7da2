//! The bootstrap header (`PXR-USDC`, the version, where the table of
//! contents is) and the table of contents (named sections: start and size).

use crate::bytes::{corrupt, unsupported, Reader};
use crate::ErrorKind;

/// The file's first 8 bytes.
pub(crate) const MAGIC: &[u8; 8] = b"PXR-USDC";

/// Bytes of the bootstrap header: magic, 8 version bytes, the table of
/// contents' offset and 8 reserved `i64`s.
pub(super) const BOOTSTRAP_LEN: usize = 88;

/// The version the writer writes: the one the reference library writes by
/// default, which every reader since 2019 opens...
pub(super) const WRITE_VERSION: (u8, u8, u8) = (0, 8, 0);

/// ...unless the file holds a time code, which takes 0.9.0 (as the
/// reference library upgrades such a file).
pub(super) const TIME_CODE_VERSION: (u8, u8, u8) = (0, 9, 0);

/// One named section.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct Section {
    pub(super) name: String,
    pub(super) start: usize,
    pub(super) size: usize,
}

/// The version and the sections.
#[derive(Debug)]
pub(super) struct Toc {
    pub(super) version: (u8, u8, u8),
    pub(super) sections: Vec<Section>,
}

impl Toc {
    /// The bytes of section `name`, if the file has it.
    pub(super) fn section<'a>(&self, bytes: &'a [u8], name: &str) -> Option<&'a [u8]> {
        self.sections.iter().find(|s| s.name == name).map(|s| &bytes[s.start..s.start + s.size])
    }

    /// Whether the file's version is at least `v`.
    pub(super) fn at_least(&self, v: (u8, u8, u8)) -> bool {
        self.version >= v
    }
}

/// Reads the bootstrap header and the table of contents, checking every
/// section lies inside the file.
pub(super) fn read_toc(bytes: &[u8]) -> Result<Toc, ErrorKind> {
    let mut r = Reader::new(bytes, 0);
    if r.take(8, "crate file header")? != MAGIC {
        return Err(corrupt("not a USD crate file (no PXR-USDC header)"));
    }
    let v = r.array::<8>("crate file version")?;
    let version = (v[0], v[1], v[2]);
    if version.0 != 0 || version < (0, 4, 0) {
        return Err(unsupported(format!(
            "crate file version {}.{}.{} (this reader takes 0.4.0 and later, as written since 2017)",
            v[0], v[1], v[2]
        )));
    }
    let toc = r.u64("table of contents offset")?;
    r.take(BOOTSTRAP_LEN - 24, "crate file header")?;
    let toc = usize::try_from(toc).ok().filter(|&t| t < bytes.len());
    let toc = toc.ok_or_else(|| corrupt("table of contents past the end of the file (truncated?)"))?;
    r.seek(toc);
    let n = r.u64("section count")?;
    r.ensure(n, 32, "sections")?;
    let mut sections = Vec::with_capacity(n as usize);
    for _ in 0..n {
        let raw = r.take(16, "section name")?;
        let name = String::from_utf8_lossy(&raw[..raw.iter().position(|&c| c == 0).unwrap_or(16)]).into_owned();
        let (start, size) = (r.i64("section start")?, r.i64("section size")?);
        let fits = usize::try_from(start)
            .ok()
            .zip(usize::try_from(size).ok())
            .filter(|&(s, z)| s.checked_add(z).is_some_and(|e| e <= bytes.len()));
        let (start, size) =
            fits.ok_or_else(|| corrupt(format!("section {} lies outside the file", name.escape_debug())))?;
        sections.push(Section { name, start, size });
    }
    Ok(Toc { version, sections })
}

/// The bootstrap header of a file of `version` whose table of contents is
/// at `toc_offset`.
pub(super) fn bootstrap(version: (u8, u8, u8), toc_offset: u64) -> [u8; BOOTSTRAP_LEN] {
    let mut b = [0u8; BOOTSTRAP_LEN];
    b[..8].copy_from_slice(MAGIC);
    (b[8], b[9], b[10]) = version;
    b[16..24].copy_from_slice(&toc_offset.to_le_bytes());
    b
}

/// Appends the table of contents.
pub(super) fn write_toc(out: &mut Vec<u8>, sections: &[Section]) {
    out.extend_from_slice(&(sections.len() as u64).to_le_bytes());
    for s in sections {
        let mut name = [0u8; 16];
        name[..s.name.len()].copy_from_slice(s.name.as_bytes());
        out.extend_from_slice(&name);
        out.extend_from_slice(&(s.start as i64).to_le_bytes());
        out.extend_from_slice(&(s.size as i64).to_le_bytes());
    }
}
