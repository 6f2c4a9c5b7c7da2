//! The one error type of `nst3d-io`: every reader and writer fails with the
//! file it was working on plus what went wrong ([`ErrorKind`]), so the file
//! is named exactly once and callers match on the kind whatever the format.

use std::fmt;
use std::path::{Path, PathBuf};

/// A failure reading, converting or writing a file: the file (or `<memory>`
/// for data that never came from one) and what went wrong. Its message is one
/// line naming both.
#[derive(Debug)]
pub struct Error {
    path: PathBuf,
    kind: ErrorKind,
}

/// What went wrong, without the file name (the [`Error`] carries that).
/// Format-level decoders return a bare kind, so the byte reader and parsers
/// need not know which file they are reading.
#[derive(Debug)]
pub enum ErrorKind {
    /// The file could not be opened or read.
    Open(std::io::Error),
    /// Writing the output failed (or the data does not fit the format).
    Write(std::io::Error),
    /// Neither the content nor the extension says which format this is.
    UnknownFormat {
        /// What kind of file was expected (`groom`, `mesh`).
        what: &'static str,
        /// Why no format matched.
        reason: String,
    },
    /// The first 8 bytes are not the OpenVDB magic number.
    NotVdb,
    /// OpenVDB file format older than 222 (pre-2013 OpenVDB).
    UnsupportedVersion {
        /// Version found in the header.
        version: u32,
    },
    /// The data ends before the structure it announces.
    Truncated {
        /// What was being decoded.
        what: &'static str,
        /// Byte offset where the read started.
        offset: usize,
        /// Bytes missing (OpenVDB files: bytes requested).
        needed: usize,
    },
    /// A value in the data is inconsistent (bad count, bad index, bad token,
    /// bad compression frame, ...).
    Corrupt {
        /// Byte offset near the problem, for formats that report one.
        offset: Option<usize>,
        /// What is wrong.
        reason: String,
    },
    /// Valid data using a feature this reader does not implement.
    Unsupported {
        /// The feature.
        reason: String,
    },
    /// An OpenVDB grid holds a value type other than float or vec3s.
    UnsupportedValueType {
        /// Grid name.
        grid: String,
        /// Tree type name from the grid descriptor.
        tree_type: String,
    },
    /// An OpenVDB grid's transform is not linear (e.g. a frustum map).
    UnsupportedTransform {
        /// Grid name.
        grid: String,
        /// Map type name.
        map: String,
    },
    /// The grid has no active voxels, so it has no bounding box to densify.
    EmptyGrid {
        /// Grid name.
        grid: String,
    },
    /// A dense conversion or tile expansion would exceed
    /// [`crate::vdb::MAX_DENSE_VOXELS`].
    TooLarge {
        /// Grid name.
        grid: String,
        /// Voxels requested.
        voxels: u128,
        /// The limit, [`crate::vdb::MAX_DENSE_VOXELS`].
        limit: u64,
    },
    /// The file's active tiles (constant regions stored as one value) would
    /// expand to more float values than its [`crate::vdb::tile_budget`],
    /// counted over all its grids (a vec3 voxel is three): a small file must
    /// not claim gigabytes.
    TileExpansion {
        /// Grid whose tiles crossed the limit.
        grid: String,
        /// Float values the file's grids would hold with this grid's tiles.
        values: u128,
        /// The file's budget.
        limit: u64,
    },
    /// An active voxel holds NaN or infinity.
    NonFinite {
        /// Grid name.
        grid: String,
        /// First offending voxel found.
        ijk: [i32; 3],
    },
    /// A float-only operation was asked of a vec3 grid or the reverse.
    WrongValueType {
        /// Grid name.
        grid: String,
        /// Value type the grid has.
        found: &'static str,
        /// Value type the operation needs.
        expected: &'static str,
    },
    /// The groom holds no strand at all.
    NoStrands,
    /// One strand breaks an invariant of [`crate::groom::Groom::validate`].
    InvalidStrand {
        /// Index of the strand in the groom.
        strand: usize,
        /// What is wrong with it.
        reason: String,
    },
    /// A strand's control points fit no spline.
    Spline {
        /// What is wrong with the control points.
        reason: String,
    },
    /// A groom does not have the strands (count, points per strand) of the
    /// groom or layer its attributes come from.
    TopologyMismatch {
        /// The first difference.
        reason: String,
    },
    /// An image file is missing, unreadable or not an image.
    ImageRead {
        /// What went wrong.
        reason: String,
    },
    /// An image has a size the pipeline cannot use.
    ImageSize {
        /// What is wrong with its size.
        reason: String,
    },
    /// Writing an image failed.
    ImageWrite {
        /// What went wrong.
        reason: String,
    },
}

impl Error {
    /// `kind` happened on `path`.
    pub(crate) fn new(path: impl Into<PathBuf>, kind: ErrorKind) -> Self {
        Self { path: path.into(), kind }
    }

    /// Attaches `path` to a format-level kind, for `map_err`.
    pub(crate) fn at(path: &Path) -> impl Fn(ErrorKind) -> Error + '_ {
        move |kind| Error::new(path, kind)
    }

    /// The file concerned (`<memory>` for a grid that came from no file).
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// What went wrong.
    pub fn kind(&self) -> &ErrorKind {
        &self.kind
    }
}

impl From<nst3d_core::GroomError> for ErrorKind {
    fn from(e: nst3d_core::GroomError) -> Self {
        match e {
            nst3d_core::GroomError::NoStrands => ErrorKind::NoStrands,
            nst3d_core::GroomError::InvalidStrand { strand, reason } => ErrorKind::InvalidStrand { strand, reason },
            nst3d_core::GroomError::Spline { reason } => ErrorKind::Spline { reason },
            nst3d_core::GroomError::TopologyMismatch { reason } => ErrorKind::TopologyMismatch { reason },
        }
    }
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let path = self.path.display();
        // Image messages have always put the path mid-sentence and spline
        // messages have none; every other kind follows "<path>: <kind>".
        match &self.kind {
            ErrorKind::ImageRead { reason } => write!(f, "cannot read image {path}: {reason}"),
            ErrorKind::ImageSize { reason } => write!(f, "image {path}: {reason}"),
            ErrorKind::ImageWrite { reason } => write!(f, "cannot write image {path}: {reason}"),
            ErrorKind::Spline { .. } => write!(f, "{}", self.kind),
            kind => write!(f, "{path}: {kind}"),
        }
    }
}

impl fmt::Display for ErrorKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ErrorKind::Open(e) => write!(f, "cannot read: {e}"),
            ErrorKind::Write(e) => write!(f, "cannot write: {e}"),
            ErrorKind::UnknownFormat { what, reason } => write!(f, "not a {what} file nst3d reads ({reason})"),
            ErrorKind::NotVdb => write!(f, "not an OpenVDB file (bad magic number)"),
            ErrorKind::UnsupportedVersion { version } => {
                write!(f, "OpenVDB file format version {version} is too old (need 222 or newer)")
            }
            ErrorKind::Truncated { what, offset, needed } => {
                write!(f, "truncated: needed {needed} more bytes at offset {offset} while reading {what}")
            }
            ErrorKind::Corrupt { offset: Some(offset), reason } => write!(f, "corrupt at offset {offset}: {reason}"),
            ErrorKind::Corrupt { offset: None, reason } => write!(f, "corrupt: {reason}"),
            ErrorKind::Unsupported { reason } => write!(f, "unsupported: {reason}"),
            ErrorKind::UnsupportedValueType { grid, tree_type } => write!(
                f,
                "grid '{grid}' has unsupported value type '{tree_type}' (supported: Tree_float_5_4_3, Tree_vec3s_5_4_3)"
            ),
            ErrorKind::UnsupportedTransform { grid, map } => {
                write!(f, "grid '{grid}' has unsupported transform '{map}' (only linear maps are read)")
            }
            ErrorKind::EmptyGrid { grid } => write!(f, "grid '{grid}' is empty (no active voxels)"),
            ErrorKind::TooLarge { grid, voxels, limit } => {
                write!(f, "grid '{grid}' would need {voxels} dense voxels (limit {limit})")
            }
            ErrorKind::TileExpansion { grid, values, limit } => write!(
                f,
                "grid '{grid}': the file's active tiles would expand to {values} voxel values, over the {limit} a file of this size may claim (1024 per byte, at most 2^28)"
            ),
            ErrorKind::NonFinite { grid, ijk } => write!(f, "grid '{grid}' has a non-finite value at voxel {ijk:?}"),
            ErrorKind::WrongValueType { grid, found, expected } => {
                write!(f, "grid '{grid}' holds {found} values, expected {expected}")
            }
            ErrorKind::NoStrands => write!(f, "groom has no strands"),
            ErrorKind::InvalidStrand { strand, reason } => write!(f, "strand {strand} {reason}"),
            ErrorKind::Spline { reason } => write!(f, "cannot build strand spline: {reason}"),
            ErrorKind::TopologyMismatch { reason } => write!(f, "not the same strands: {reason}"),
            ErrorKind::ImageRead { reason } => write!(f, "cannot read image: {reason}"),
            ErrorKind::ImageSize { reason } => write!(f, "image: {reason}"),
            ErrorKind::ImageWrite { reason } => write!(f, "cannot write image: {reason}"),
        }
    }
}

impl std::error::Error for Error {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match &self.kind {
            ErrorKind::Open(e) | ErrorKind::Write(e) => Some(e),
            _ => None,
        }
    }
}
