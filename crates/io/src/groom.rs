//! Hair and fur grooms in and out of nst3d, for the strand stylization
//! pipeline: the optimization target is the strands' control points `p`,
//! which the paper represents as natural cubic splines ([`StrandSpline`]).
//!
//! Readers: cyHair `.hair` ([`read_cyhair`]), USC-HairSalon `.data`
//! ([`read_hairsalon`]), strand PLY as written by hapPLY/hairutil
//! ([`read_ply_strands`]), USD `BasisCurves` in text, crate files or `.usdz`
//! packages, following sublayers and references ([`read_usd_curves_file`]),
//! Alembic Ogawa curves ([`read_alembic_curves`]) and [`read_groom`], which
//! picks one by content. Writers: [`write_usda_curves`],
//! [`write_usdc_curves_with`], [`write_usdz_curves_with`],
//! [`write_ply_strands`].
//!
//! Attributes: per-point widths and colours travel in [`Strand`] (cyHair
//! thickness and colour, PLY `thickness`/`width` and `red`/`green`/`blue`,
//! USD `widths` and `primvars:displayColor`, Alembic widths); the other
//! primvars of a USD layer's curves travel as text beside the groom
//! ([`read_groom_file`], [`GroomFile`], [`UsdPrimvars`]). A tool that moves
//! the points and keeps the strands (as stylization does) gives the result
//! the input's attributes with [`Groom::copy_attributes_from`] and writes
//! the primvars back with [`write_usda_curves_with`] (or the `.usdc` and
//! `.usdz` writers). What each writer can hold: `.usda` everything above
//! (widths and colours per point); `.usdc` and `.usdz` the same, but for
//! primvars whose type has no crate form here ([`usdc_unwritable`]); `.ply`
//! widths and colours (8 bits per channel), no primvars.
//!
//! Conventions: points are taken as stored, in file units and axes. None of
//! the supported binary formats carries a transform, scale or up axis (the
//! Bangs test groom is Y-up in all of them); USD transforms (`xformOp`s on the
//! curve prim and its ancestors) are applied so points come out in world
//! space, while the layer's `upAxis`/`metersPerUnit` are not applied: they
//! are reported in [`UsdPrimvars`] and written back with the points, which
//! stay in the layer's axes and units. Every reader validates what it
//! returns (see [`Groom::validate`]) so a NaN or a one-point strand never
//! reaches the renderer.

use std::path::Path;

mod alembic;
mod cyhair;
mod hairsalon;
pub(crate) mod ply;
mod usd;
mod usda;
mod usdc;
mod usdz;

pub use alembic::{read_alembic_curves, read_alembic_curves_bytes};
pub use cyhair::{read_cyhair, read_cyhair_bytes};
pub use hairsalon::{read_hairsalon, read_hairsalon_bytes};
pub use nst3d_core::groom::{Groom, GroomError, Strand, StrandSpline};
pub use ply::{read_ply_strand_attribute, read_ply_strands, read_ply_strands_bytes, write_ply_strands};
pub use usd::{
    read_usd_curves_file, read_usd_curves_file_bytes, read_usda_curves, read_usda_curves_bytes, read_usda_curves_file,
    read_usda_curves_file_bytes, usdc_unwritable, write_usdc_curves_with, write_usdz_curves_with, UsdAssets,
};
pub use usda::{write_usda_curves, write_usda_curves_with, UsdPrimvar, UsdPrimvars};

use crate::bytes::read_file;
use crate::{Error, ErrorKind};

/// [`Groom::validate`] with the error naming `path`.
pub(crate) fn validate_for(groom: &Groom, path: &Path) -> Result<(), Error> {
    groom.validate().map_err(|e| Error::new(path, e.into()))
}

/// What every reader does with a format's bytes: decode, name the file in
/// any error, and refuse a groom the stylizer could not use.
pub(crate) fn checked(path: &Path, parsed: Result<Groom, ErrorKind>) -> Result<Groom, Error> {
    let groom = parsed.map_err(Error::at(path))?;
    validate_for(&groom, path)?;
    Ok(groom)
}

/// A groom as read from a file: its strands, and what the file holds
/// beyond [`Groom`] that a writer can put back.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GroomFile {
    /// The strands, with their per-point widths and colours.
    pub groom: Groom,
    /// The other primvars of a text USD layer's curves (empty for every
    /// other format).
    pub usd_primvars: UsdPrimvars,
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
    /// Binary USD, a crate file (magic `PXR-USDC`; `.usdc`, or `.usd`).
    Usdc,
    /// A `.usdz` package (a zip archive) whose first file is a USD layer.
    Usdz,
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
    if bytes.starts_with(usdc::MAGIC) {
        return Some(GroomFormat::Usdc);
    }
    if usdz::first_name(bytes).is_some_and(|n| n.ends_with(".usd") || n.ends_with(".usda") || n.ends_with(".usdc")) {
        return Some(GroomFormat::Usdz);
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
        Some("usdc") => return Some(GroomFormat::Usdc),
        Some("usdz") => return Some(GroomFormat::Usdz),
        Some("abc") => return Some(GroomFormat::Alembic),
        _ => {}
    }
    hairsalon::looks_like_hairsalon(bytes).then_some(GroomFormat::HairSalon)
}

/// Reads any supported groom file, choosing the reader with
/// [`detect_groom_format`].
pub fn read_groom(path: &Path) -> Result<Groom, Error> {
    let bytes = read_file(path)?;
    read_groom_bytes(path, &bytes)
}

/// [`read_groom`] plus what the file holds beyond the strands
/// ([`GroomFile`]): for stylizing a groom and writing it back with all its
/// attributes.
pub fn read_groom_file(path: &Path) -> Result<GroomFile, Error> {
    let bytes = read_file(path)?;
    read_groom_file_bytes(path, &bytes)
}

/// [`read_groom_file`] on bytes already in memory.
pub fn read_groom_file_bytes(path: &Path, bytes: &[u8]) -> Result<GroomFile, Error> {
    match detect_groom_format(path, bytes) {
        Some(GroomFormat::Usda | GroomFormat::Usdc | GroomFormat::Usdz) => {
            read_usd_curves_file_bytes(path, bytes, UsdAssets::Files)
        }
        _ => Ok(GroomFile { groom: read_groom_bytes(path, bytes)?, usd_primvars: UsdPrimvars::default() }),
    }
}

/// [`read_groom`] on bytes already in memory; `path` names them in errors
/// and its extension helps detection.
pub fn read_groom_bytes(path: &Path, bytes: &[u8]) -> Result<Groom, Error> {
    match detect_groom_format(path, bytes) {
        Some(GroomFormat::CyHair) => read_cyhair_bytes(path, bytes),
        Some(GroomFormat::HairSalon) => read_hairsalon_bytes(path, bytes),
        Some(GroomFormat::Ply) => read_ply_strands_bytes(path, bytes),
        Some(GroomFormat::Usda | GroomFormat::Usdc | GroomFormat::Usdz) => {
            read_usd_curves_file_bytes(path, bytes, UsdAssets::Files).map(|f| f.groom)
        }
        Some(GroomFormat::Alembic) => read_alembic_curves_bytes(path, bytes),
        None => Err(Error::new(
            path,
            ErrorKind::UnknownFormat {
                what: "groom",
                reason: "no known magic number or extension (.hair, .data, .ply, .usda, .usdc, .usd, .usdz, .abc)"
                    .into(),
            },
        )),
    }
}
