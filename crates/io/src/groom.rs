//! Hair and fur grooms in and out of nst3d, for the strand stylization
//! pipeline: the optimization target is the strands' control points `p`,
//! which the paper represents as natural cubic splines ([`StrandSpline`]).
//!
//! Readers: cyHair `.hair` ([`read_cyhair`]), USC-HairSalon `.data`
//! ([`read_hairsalon`]), strand PLY as written by hapPLY/hairutil
//! ([`read_ply_strands`]), text USD `BasisCurves` ([`read_usda_curves`]),
//! Alembic Ogawa curves ([`read_alembic_curves`]) and [`read_groom`], which
//! picks one by content. Writers: [`write_usda_curves`], [`write_ply_strands`].
//!
//! Conventions: points are taken as stored, in file units and axes. None of
//! the supported binary formats carries a transform, scale or up axis (the
//! Bangs test groom is Y-up in all of them); USD transforms (`xformOp`s on the
//! curve prim and its ancestors) are applied so points come out in world
//! space, while the layer's `upAxis`/`metersPerUnit` are reported by nothing
//! and applied by nothing. Every reader validates what it returns (see
//! [`Groom::validate`]) so a NaN or a one-point strand never reaches the
//! renderer.

use std::path::{Path, PathBuf};

mod alembic;
pub(crate) mod bytes;
mod cyhair;
mod hairsalon;
pub(crate) mod ply;
mod spline;
mod usda;

pub use alembic::{read_alembic_curves, read_alembic_curves_bytes};
pub use cyhair::{read_cyhair, read_cyhair_bytes};
pub use hairsalon::{read_hairsalon, read_hairsalon_bytes};
pub use ply::{read_ply_strands, read_ply_strands_bytes, write_ply_strands};
pub use spline::StrandSpline;
pub use usda::{read_usda_curves, read_usda_curves_bytes, write_usda_curves};

use bytes::FormatError;

/// One hair strand: a polyline of control points from root to tip, plus
/// optional per-point attributes when the file carries them.
#[derive(Clone, Debug, PartialEq)]
pub struct Strand {
    /// Control points, root first.
    pub points: Vec<[f32; 3]>,
    /// Per-point width (diameter, file units), when the file stores one.
    pub widths: Option<Vec<f32>>,
    /// Per-point linear RGB colour in `[0, 1]`, when the file stores one.
    pub colors: Option<Vec<[f32; 3]>>,
}

impl Strand {
    /// A strand with points only.
    pub fn new(points: Vec<[f32; 3]>) -> Self {
        Self { points, widths: None, colors: None }
    }
}

/// A groom: the set of strands stylized together.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Groom {
    /// Strands in file order.
    pub strands: Vec<Strand>,
}

impl Groom {
    /// Total number of control points over all strands.
    pub fn point_count(&self) -> usize {
        self.strands.iter().map(|s| s.points.len()).sum()
    }

    /// Number of strands.
    pub fn strand_count(&self) -> usize {
        self.strands.len()
    }

    /// Axis-aligned bounds `(min, max)` of all points; `None` without points.
    pub fn bbox(&self) -> Option<([f32; 3], [f32; 3])> {
        let mut it = self.strands.iter().flat_map(|s| s.points.iter());
        let first = *it.next()?;
        let (mut lo, mut hi) = (first, first);
        for p in it {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        Some((lo, hi))
    }

    /// Checks the invariants the stylizer relies on: at least one strand,
    /// every strand with at least two points (a spline needs a segment),
    /// finite coordinates, and attribute arrays as long as the point array.
    /// The error names the first offending strand.
    pub fn validate(&self) -> Result<(), GroomError> {
        self.validate_for(Path::new("<groom>"))
    }

    /// [`Groom::validate`] with the error naming `path`.
    pub(crate) fn validate_for(&self, path: &Path) -> Result<(), GroomError> {
        if self.strands.is_empty() {
            return Err(GroomError::NoStrands { path: path.into() });
        }
        let bad = |strand: usize, reason: String| GroomError::InvalidStrand { path: path.into(), strand, reason };
        for (i, s) in self.strands.iter().enumerate() {
            if s.points.len() < 2 {
                return Err(bad(i, format!("has {} point(s), need at least 2", s.points.len())));
            }
            if let Some(j) = s.points.iter().position(|p| p.iter().any(|c| !c.is_finite())) {
                return Err(bad(i, format!("point {j} is not finite: {:?}", s.points[j])));
            }
            if let Some(w) = &s.widths {
                if w.len() != s.points.len() {
                    return Err(bad(i, format!("{} widths for {} points", w.len(), s.points.len())));
                }
                if let Some(j) = w.iter().position(|c| !c.is_finite()) {
                    return Err(bad(i, format!("width {j} is not finite")));
                }
            }
            if let Some(c) = &s.colors {
                if c.len() != s.points.len() {
                    return Err(bad(i, format!("{} colours for {} points", c.len(), s.points.len())));
                }
            }
        }
        Ok(())
    }
}

/// Everything that can go wrong reading or writing a groom. Each message is
/// one line naming the file and the problem.
#[derive(Debug, thiserror::Error)]
pub enum GroomError {
    /// The file could not be opened or read.
    #[error("{path}: cannot read: {source}")]
    Open {
        /// File concerned.
        path: PathBuf,
        /// Underlying error.
        source: std::io::Error,
    },
    /// Neither the content nor the extension says which groom format this is.
    #[error("{path}: not a groom file nst3d reads ({reason})")]
    UnknownFormat {
        /// File concerned.
        path: PathBuf,
        /// Why no format matched.
        reason: String,
    },
    /// The file ends before the structure it announces.
    #[error("{path}: truncated: needed {needed} more bytes at offset {offset} while reading {what}")]
    Truncated {
        /// File concerned.
        path: PathBuf,
        /// What was being decoded.
        what: &'static str,
        /// Byte offset where the read started.
        offset: usize,
        /// Bytes requested.
        needed: usize,
    },
    /// A value in the file is inconsistent.
    #[error("{path}: corrupt: {reason}")]
    Corrupt {
        /// File concerned.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// Valid file using a feature this reader does not implement.
    #[error("{path}: unsupported: {reason}")]
    Unsupported {
        /// File concerned.
        path: PathBuf,
        /// The feature.
        reason: String,
    },
    /// The groom holds no strand at all.
    #[error("{path}: groom has no strands")]
    NoStrands {
        /// File concerned (`<groom>` for in-memory validation).
        path: PathBuf,
    },
    /// One strand breaks an invariant of [`Groom::validate`].
    #[error("{path}: strand {strand} {reason}")]
    InvalidStrand {
        /// File concerned (`<groom>` for in-memory validation).
        path: PathBuf,
        /// Index of the strand in the groom.
        strand: usize,
        /// What is wrong with it.
        reason: String,
    },
    /// A spline cannot be built from the given control points.
    #[error("cannot build strand spline: {reason}")]
    Spline {
        /// What is wrong with the control points.
        reason: String,
    },
    /// Writing the output failed (or the groom does not fit the format).
    #[error("{path}: cannot write: {source}")]
    Write {
        /// File concerned.
        path: PathBuf,
        /// Underlying error.
        source: std::io::Error,
    },
}

impl GroomError {
    /// Attaches the file name to a format-level error.
    pub(crate) fn from_format(path: &Path, e: FormatError) -> Self {
        match e {
            FormatError::Truncated { what, offset, needed } => {
                GroomError::Truncated { path: path.into(), what, offset, needed }
            }
            FormatError::Corrupt(reason) => GroomError::Corrupt { path: path.into(), reason },
            FormatError::Unsupported(reason) => GroomError::Unsupported { path: path.into(), reason },
        }
    }
}

/// Reads a whole file, naming it in the error.
pub(crate) fn read_file(path: &Path) -> Result<Vec<u8>, GroomError> {
    std::fs::read(path).map_err(|source| GroomError::Open { path: path.into(), source })
}

/// The groom formats [`read_groom`] recognises.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GroomFormat {
    /// cyHair `.hair` (magic `HAIR`).
    CyHair,
    /// USC-HairSalon `.data` (no magic: recognised by extension or by its
    /// counts adding up exactly to the file size).
    HairSalon,
    /// Strand PLY (magic `ply`).
    Ply,
    /// Text USD (magic `#usda`).
    Usda,
    /// Alembic Ogawa (magic `Ogawa`).
    Alembic,
}

/// Decides the format of `bytes` from magic numbers first, then from the
/// extension of `path` (HairSalon has no magic), then by checking whether
/// the bytes parse as HairSalon exactly.
pub fn detect_groom_format(path: &Path, bytes: &[u8]) -> Option<GroomFormat> {
    if bytes.starts_with(b"HAIR") {
        return Some(GroomFormat::CyHair);
    }
    if bytes.starts_with(b"ply") {
        return Some(GroomFormat::Ply);
    }
    if bytes.starts_with(b"#usda") {
        return Some(GroomFormat::Usda);
    }
    if bytes.starts_with(b"Ogawa") {
        return Some(GroomFormat::Alembic);
    }
    let ext = path.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase());
    match ext.as_deref() {
        Some("data") => return Some(GroomFormat::HairSalon),
        Some("hair") => return Some(GroomFormat::CyHair),
        Some("ply") => return Some(GroomFormat::Ply),
        Some("usda") | Some("usd") => return Some(GroomFormat::Usda),
        Some("abc") => return Some(GroomFormat::Alembic),
        _ => {}
    }
    hairsalon::looks_like_hairsalon(bytes).then_some(GroomFormat::HairSalon)
}

/// Reads any supported groom file, choosing the reader with
/// [`detect_groom_format`].
pub fn read_groom(path: &Path) -> Result<Groom, GroomError> {
    let bytes = read_file(path)?;
    read_groom_bytes(path, &bytes)
}

/// [`read_groom`] on bytes already in memory; `path` names them in errors
/// and its extension helps detection.
pub fn read_groom_bytes(path: &Path, bytes: &[u8]) -> Result<Groom, GroomError> {
    match detect_groom_format(path, bytes) {
        Some(GroomFormat::CyHair) => read_cyhair_bytes(path, bytes),
        Some(GroomFormat::HairSalon) => read_hairsalon_bytes(path, bytes),
        Some(GroomFormat::Ply) => read_ply_strands_bytes(path, bytes),
        Some(GroomFormat::Usda) => read_usda_curves_bytes(path, bytes),
        Some(GroomFormat::Alembic) => read_alembic_curves_bytes(path, bytes),
        None => Err(GroomError::UnknownFormat {
            path: path.into(),
            reason: "no known magic number or extension (.hair, .data, .ply, .usda, .abc)".into(),
        }),
    }
}
