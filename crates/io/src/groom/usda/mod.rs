//! Text USD (`.usda`) `BasisCurves`: a small reader for the subset grooms
//! use and a writer of one clean curves layer.
//!
//! The reader parses the whole layer (prims, attributes, metadata, time
//! samples) and gathers every *defined* `BasisCurves` prim in file order
//! (`def` specifiers only: `over`/`class` subtrees and prims with
//! `active = false` are not drawn by USD either, so they are skipped).
//! Per prim: `curveVertexCounts` and `points` (required), `widths` or
//! `primvars:widths` and `primvars:displayColor` with their `interpolation`
//! (constant, uniform, varying, vertex), expanded to one value per point.
//! [`read_usda_curves_file`] also keeps every other `primvars:*` attribute
//! of those prims as text ([`UsdPrimvars`], see [`mod@primvars`]) for the
//! writer to put back unchanged. When an attribute only has
//! `.timeSamples`, the earliest sample is used. Transforms: the
//! `xformOpOrder` of the prim and all its ancestors is applied, with
//! translate, scale, rotateX/Y/Z, rotateXYZ (and the other five orders),
//! orient and transform ops, `!resetXformStack!`, and `!invert!` on
//! translate (the pivot idiom). Other inverted ops are refused as
//! unsupported rather than silently ignored. Widths are not scaled by the
//! transform. Not read: composition (references, payloads, sublayers,
//! inherits), `variantSet` blocks (skipped), normals. `upAxis` and
//! `metersPerUnit` are not applied (points are returned in the layer's own
//! axes and units); [`read_usda_curves_file`] reports them so the writer
//! can declare the same.
//! `type`, `basis` and `wrap` only matter for mapping `varying` primvars;
//! the points are kept as the prim's control points whatever the basis.
//!
//! One file per job: [`lexer`] splits the text into tokens, [`parse`] builds
//! the prim tree, [`xform`] turns `xformOp`s into matrices, [`curves`] walks
//! the tree into strands, [`mod@primvars`] gathers the other primvars, and
//! [`mod@write`] writes a layer.

mod curves;
mod lexer;
mod parse;
mod primvars;
mod write;
mod xform;

use std::path::Path;

pub use primvars::{UsdPrimvar, UsdPrimvars};
pub use write::{write_usda_curves, write_usda_curves_with};

use super::{checked, Groom, GroomFile};
use crate::bytes::{corrupt, read_file};
use crate::{Error, ErrorKind};

/// Reads every defined `BasisCurves` prim of a text USD layer into one
/// groom (see the module notes for what is and is not applied).
pub fn read_usda_curves(path: &Path) -> Result<Groom, Error> {
    let bytes = read_file(path)?;
    read_usda_curves_bytes(path, &bytes)
}

/// [`read_usda_curves`] on bytes in memory; `path` only names them in errors.
pub fn read_usda_curves_bytes(path: &Path, bytes: &[u8]) -> Result<Groom, Error> {
    checked(path, decode(bytes, false).map(|(g, _)| g))
}

/// [`read_usda_curves`] plus the curves' other primvars, as text
/// ([`UsdPrimvars`]), so that [`write_usda_curves_with`] can write them back.
pub fn read_usda_curves_file(path: &Path) -> Result<GroomFile, Error> {
    let bytes = read_file(path)?;
    read_usda_curves_file_bytes(path, &bytes)
}

/// [`read_usda_curves_file`] on bytes in memory; `path` only names them in
/// errors.
pub fn read_usda_curves_file_bytes(path: &Path, bytes: &[u8]) -> Result<GroomFile, Error> {
    let (groom, usd_primvars) = decode(bytes, true).map_err(Error::at(path))?;
    Ok(GroomFile { groom: checked(path, Ok(groom))?, usd_primvars })
}

/// The layer's strands (and, if `with_primvars`, the other primvars),
/// before the file is named in errors or the groom is validated.
fn decode(bytes: &[u8], with_primvars: bool) -> Result<(Groom, UsdPrimvars), ErrorKind> {
    if !bytes.starts_with(b"#usda ") {
        return Err(corrupt("not a text USD layer (no '#usda' header)"));
    }
    let text = std::str::from_utf8(bytes).map_err(|e| corrupt(format!("USD layer is not UTF-8 ({e})")))?;
    let (root, meta) = parse::layer(text)?;
    let (mut strands, mut read) = (Vec::new(), Vec::new());
    curves::walk(&root, &xform::IDENTITY, &mut strands, &mut read)?;
    let mut primvars = UsdPrimvars::default();
    if with_primvars {
        primvars = primvars::gather(text, &read);
        for (key, value) in &meta {
            match key.as_str() {
                // USD knows only these two; anything else is not an axis a
                // DCC would honour, so the writer's default stands.
                "upAxis" => primvars.up_axis = value.as_str().filter(|a| matches!(*a, "Y" | "Z")).map(str::to_string),
                "metersPerUnit" => primvars.meters_per_unit = value.as_f64().filter(|m| m.is_finite() && *m > 0.0),
                _ => {}
            }
        }
    }
    Ok((Groom { strands }, primvars))
}
