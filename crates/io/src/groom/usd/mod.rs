//! USD grooms in any of USD's three forms: text layers (`.usda`), crate
//! files (`.usdc`, or `.usd` starting with `PXR-USDC`) and `.usdz`
//! packages (the root layer is the package's first file). Every form is
//! read the same way: the layer becomes a prim tree (a crate file through
//! its text form, `super::usdc`), sublayers, references and payloads are
//! followed ([`compose`]), then the curves and primvars are read from the
//! composed tree (`super::usda`). The stage's `upAxis` and
//! `metersPerUnit` are the root layer's. Writers: `.usdc` and `.usdz`
//! hold the same `BasisCurves` layer the `.usda` writer writes.

mod compose;

use std::path::Path;

pub use compose::UsdAssets;

use super::usda::parse::{self, Val};
use super::usda::{curves, primvars, write::check, xform};
use super::{checked, usdc, usdz, Groom, GroomFile, UsdPrimvars};
use crate::bytes::{corrupt, read_file};
use crate::{Error, ErrorKind};

/// The strands (and, if `with_primvars`, the other primvars) of the stage
/// whose root layer is `bytes`, before the file is named in errors or the
/// groom is validated.
fn decode(
    path: &Path,
    bytes: &[u8],
    assets: UsdAssets,
    with_primvars: bool,
) -> Result<(Groom, UsdPrimvars), ErrorKind> {
    let (mut stage, root_layer) = compose::Stage::open(path, bytes, assets)?;
    let root = stage.composed(root_layer, 0)?;
    let (mut strands, mut read) = (Vec::new(), Vec::new());
    curves::walk(&root, &xform::IDENTITY, &mut strands, &mut read)?;
    if strands.is_empty() && !stage.notes.is_empty() {
        return Err(corrupt(format!("no curves found; {}", stage.notes[0])));
    }
    let mut kept = UsdPrimvars::default();
    if with_primvars {
        kept = primvars::gather(&stage.texts, &read);
        kept.dropped.splice(0..0, stage.notes.iter().cloned());
        // USD knows only these two axes; anything else is not one a DCC
        // would honour, so the writer's default stands.
        kept.up_axis = stage
            .meta(root_layer, "upAxis")
            .and_then(|v| v.as_str())
            .filter(|a| matches!(*a, "Y" | "Z"))
            .map(str::to_string);
        kept.meters_per_unit =
            stage.meta(root_layer, "metersPerUnit").and_then(|v| v.as_f64()).filter(|m| m.is_finite() && *m > 0.0);
        kept.files = packaged_assets(&stage, &kept);
    }
    Ok((super::Groom { strands }, kept))
}

/// The files inside the stage's packages that the asset-valued primvars
/// of `kept` name.
fn packaged_assets(stage: &compose::Stage, kept: &UsdPrimvars) -> Vec<(String, Vec<u8>)> {
    fn assets(v: &Val, out: &mut Vec<String>) {
        match v {
            Val::Asset(a) => out.push(a.clone()),
            Val::List(l) => l.iter().for_each(|x| assets(x, out)),
            Val::Samples(s) => s.iter().for_each(|(_, x)| assets(x, out)),
            _ => {}
        }
    }
    let mut names = Vec::new();
    for p in kept.primvars.iter().filter(|p| p.type_name.starts_with("asset")) {
        for a in parse::statements(&p.declaration).unwrap_or_default() {
            a.value.iter().for_each(|v| assets(v, &mut names));
        }
    }
    names.sort();
    names.dedup();
    names.into_iter().filter_map(|n| stage.packaged_file(&n).map(|d| (n, d))).collect()
}

/// Reads the curves of a USD file in any form (text, crate file,
/// package), following its sublayers, references and payloads as
/// `assets` allows, with its other primvars, `upAxis` and
/// `metersPerUnit` ([`GroomFile`]).
pub fn read_usd_curves_file_bytes(path: &Path, bytes: &[u8], assets: UsdAssets) -> Result<GroomFile, Error> {
    let (groom, usd_primvars) = decode(path, bytes, assets, true).map_err(Error::at(path))?;
    Ok(GroomFile { groom: checked(path, Ok(groom))?, usd_primvars })
}

/// [`read_usd_curves_file_bytes`] on a file, following files next to it.
pub fn read_usd_curves_file(path: &Path) -> Result<GroomFile, Error> {
    let bytes = read_file(path)?;
    read_usd_curves_file_bytes(path, &bytes, UsdAssets::Files)
}

/// Refuses bytes that are not a text layer.
fn text_only(bytes: &[u8]) -> Result<(), ErrorKind> {
    if bytes.starts_with(b"#usda ") {
        Ok(())
    } else {
        Err(corrupt("not a text USD layer (no '#usda' header)"))
    }
}

/// Reads every defined `BasisCurves` prim of a text USD layer (and of the
/// layers it points to) into one groom (see `super::usda` for what is and
/// is not applied).
pub fn read_usda_curves(path: &Path) -> Result<Groom, Error> {
    let bytes = read_file(path)?;
    read_usda_curves_bytes(path, &bytes)
}

/// [`read_usda_curves`] on bytes in memory read from `path` (named in
/// errors; layers it points to are looked for next to it).
pub fn read_usda_curves_bytes(path: &Path, bytes: &[u8]) -> Result<Groom, Error> {
    let parsed = text_only(bytes).and_then(|_| decode(path, bytes, UsdAssets::Files, false));
    checked(path, parsed.map(|(g, _)| g))
}

/// [`read_usda_curves`] plus the curves' other primvars, as text
/// ([`UsdPrimvars`]), so that a writer can write them back.
pub fn read_usda_curves_file(path: &Path) -> Result<GroomFile, Error> {
    let bytes = read_file(path)?;
    read_usda_curves_file_bytes(path, &bytes)
}

/// [`read_usda_curves_file`] on bytes in memory read from `path`.
pub fn read_usda_curves_file_bytes(path: &Path, bytes: &[u8]) -> Result<GroomFile, Error> {
    text_only(bytes).map_err(Error::at(path))?;
    read_usd_curves_file_bytes(path, bytes, UsdAssets::Files)
}

/// The primvars of `primvars` that [`write_usdc_curves_with`] and
/// [`write_usdz_curves_with`] cannot write (their type or value has no
/// crate form here), each with why; the writers leave them out.
pub fn usdc_unwritable(primvars: &UsdPrimvars) -> Vec<String> {
    usdc::unwritable(primvars)
}

/// The crate file of `groom` with `primvars`, after the checks every USD
/// writer makes.
fn crate_bytes(path: &Path, groom: &Groom, primvars: &UsdPrimvars) -> Result<Vec<u8>, Error> {
    check(path, groom, primvars)?;
    usdc::groom_bytes(groom, primvars)
        .map_err(|why| Error::new(path, ErrorKind::Write(std::io::Error::new(std::io::ErrorKind::InvalidInput, why))))
}

fn write_bytes(path: &Path, bytes: &[u8]) -> Result<(), Error> {
    crate::atomic::write_atomic(path, |w| w.write_all(bytes)).map_err(|e| Error::new(path, ErrorKind::Write(e)))
}

/// Writes `groom` as a USD crate file (`.usdc`) holding the layer
/// [`write_usda_curves_with`](crate::groom::write_usda_curves_with) writes
/// as text: one `BasisCurves` prim `/Groom`, the input's other primvars
/// and its layer's `upAxis` and `metersPerUnit` (those
/// [`usdc_unwritable`] names are left out). Atomic, as every writer.
pub fn write_usdc_curves_with(path: &Path, groom: &Groom, primvars: &UsdPrimvars) -> Result<(), Error> {
    let bytes = crate_bytes(path, groom, primvars)?;
    write_bytes(path, &bytes)
}

/// Writes `groom` as a `.usdz` package whose root layer is the crate file
/// [`write_usdc_curves_with`] writes, named after the package
/// (`bangs.usdz` holds `bangs.usdc`), followed by the files of the input's
/// package that its asset-valued primvars name ([`UsdPrimvars::files`]).
pub fn write_usdz_curves_with(path: &Path, groom: &Groom, primvars: &UsdPrimvars) -> Result<(), Error> {
    let bytes = crate_bytes(path, groom, primvars)?;
    let stem = path.file_stem().and_then(|s| s.to_str()).filter(|s| !s.is_empty() && s.is_ascii()).unwrap_or("groom");
    let layer = format!("{stem}.usdc");
    let mut files: Vec<(&str, &[u8])> = vec![(&layer, &bytes)];
    // The input package's files its asset primvars name, where they were
    // relative to its layer (now the root of this package).
    for (name, data) in &primvars.files {
        if usdz::normalize(name).is_some_and(|n| !n.is_empty() && files.iter().all(|f| f.0 != n)) {
            files.push((name, data));
        }
    }
    write_bytes(path, &usdz::package(&files))
}
