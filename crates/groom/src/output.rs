//! Writing a stylized or generated groom: the output file in the chosen
//! format, keeping the input's attributes where the format can hold them,
//! and telling grooms from OpenVDB files.

use std::path::Path;

use anyhow::{Context, Result};
use nst3d_io::groom::{
    usdc_unwritable, write_ply_strands, write_usda_curves_with, write_usdc_curves_with, write_usdz_curves_with,
    GroomFile, UsdPrimvars,
};
use nst3d_strands::FlatStrands;

use crate::settings::OutFormat;

/// Writes `strands` to `path` in `format`, atomically. With `input` (the
/// groom file the strands were made from, in its topology: same strands,
/// same points each) the output keeps the input's attributes unchanged:
/// per-point widths and colours, and in USD (`.usda`, `.usdc`, `.usdz`)
/// the input layer's other primvars ([`attribute_notes`] says what a
/// format cannot hold). Fails,
/// writing nothing, when the topologies differ. Without `input` (generated
/// grooms) only points are written. `colors` (one list per strand, one
/// colour per point: a stylization with colour) replace the input's.
pub fn write_groom(
    path: &Path,
    format: OutFormat,
    strands: &FlatStrands,
    input: Option<&GroomFile>,
    colors: Option<&[Vec<[f32; 3]>]>,
) -> Result<()> {
    let mut g = strands.to_groom();
    let no_primvars = UsdPrimvars::default();
    let mut primvars = &no_primvars;
    if let Some(input) = input {
        g.copy_attributes_from(&input.groom)
            .map_err(|e| anyhow::anyhow!("{}: {}", path.display(), nst3d_io::ErrorKind::from(e)))
            .context("cannot give the output the input's attributes")?;
        primvars = &input.usd_primvars;
    }
    if let Some(colors) = colors {
        if colors.len() != g.strands.len() || colors.iter().zip(&g.strands).any(|(c, s)| c.len() != s.points.len()) {
            anyhow::bail!("{}: the stylized colours do not match the groom's points", path.display());
        }
        for (s, c) in g.strands.iter_mut().zip(colors) {
            s.colors = Some(c.clone());
        }
    }
    match format {
        OutFormat::Usda => write_usda_curves_with(path, &g, primvars)?,
        OutFormat::Usdc => write_usdc_curves_with(path, &g, primvars)?,
        OutFormat::Usdz => write_usdz_curves_with(path, &g, primvars)?,
        OutFormat::Ply => write_ply_strands(path, &g)?,
    }
    Ok(())
}

/// What of `input`'s attributes an output in `format` will not hold, one
/// line each (for the job to say once, before the slow part): primvars the
/// reader could not keep, those a crate file cannot hold in `.usdc` and
/// `.usdz`, any primvar at all in `.ply`, a z-up layer's axis in `.ply`,
/// and colours finer than the 8 bits per channel of `.ply`.
pub fn attribute_notes(input: &GroomFile, format: OutFormat) -> Vec<String> {
    let mut notes = input.usd_primvars.dropped.clone();
    if matches!(format, OutFormat::Usdc | OutFormat::Usdz) {
        for why in usdc_unwritable(&input.usd_primvars) {
            notes.push(format!("a binary USD output cannot hold {why}: write .usda to keep it"));
        }
    }
    if format == OutFormat::Ply {
        let names: Vec<&str> = input.usd_primvars.primvars.iter().map(|p| p.name.as_str()).collect();
        if !names.is_empty() {
            notes.push(format!(
                "a .ply output cannot hold {}: write USD (.usda, .usdc, .usdz) to keep them",
                names.join(", ")
            ));
        }
        // Y is what a reader of the .ply will assume anyway.
        if let Some(axis) = input.usd_primvars.up_axis.as_deref().filter(|&a| a != "Y") {
            notes.push(format!(
                "a .ply output has no up axis (the input layer is {axis}-up; its points are written as they are): \
                 write USD (.usda, .usdc, .usdz) to keep it"
            ));
        }
        let fine = |c: f32| {
            let k = (c.clamp(0.0, 1.0) * 255.0).round();
            ((k as f64 / 255.0) as f32) != c
        };
        if input.groom.strands.iter().flat_map(|s| s.colors.iter().flatten()).flatten().any(|&c| fine(c)) {
            notes.push(
                "colours are rounded to 8 bits per channel in a .ply output: write USD to keep them exactly".into(),
            );
        }
    }
    notes
}

/// Whether `path` names a groom (by its magic number or extension) rather
/// than an OpenVDB file.
pub fn is_groom_file(path: &Path) -> bool {
    if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("vdb")) {
        return false;
    }
    let mut head = [0u8; 64];
    let n = std::fs::File::open(path).and_then(|mut f| std::io::Read::read(&mut f, &mut head)).unwrap_or(0);
    nst3d_io::groom::detect_groom_format(path, &head[..n]).is_some()
}
