//! Where a groom's style map comes from: one value per strand, read from
//! the groom file (a `.ply` property, a USD primvar), a companion text
//! file or the roots' height, and turned into each strand's share of the
//! paintings ([`nst3d_strands::pipeline::StrandShares`]).

use std::path::Path;

use anyhow::{bail, Context, Result};
use nst3d_core::Groom;
use nst3d_strands::pipeline::{MapKind, StrandScene, StrandShares};

use crate::settings::StrandSettings;

/// The built-in map: each root's height along the up axis, 0 at the lowest
/// root and 1 at the highest (a soft split of two paintings down the hair).
pub const HEIGHT_MAP: &str = "@height";

/// One map value per strand of `groom` (y-up, in file order; read from
/// the file `path` when the map is one of its properties), or `None`
/// without a map.
pub fn map_values(s: &StrandSettings, path: &Path, groom: &Groom) -> Result<Option<Vec<f32>>> {
    let n = groom.strand_count();
    let (values, spec) = match (&s.style_map_values, s.style_map.as_deref()) {
        (Some(v), _) => (v.clone(), "the style map array".to_string()),
        (None, None) => return Ok(None),
        (None, Some(HEIGHT_MAP)) => (root_heights(groom), HEIGHT_MAP.to_string()),
        (None, Some(spec)) if spec.ends_with(".txt") => (read_text_map(Path::new(spec))?, spec.to_string()),
        (None, Some(name)) => (file_property(path, name)?, format!("--style-map {name}")),
    };
    if values.len() != n {
        bail!("{spec}: {} values for {n} strands", values.len());
    }
    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
        bail!("{spec}: strand {i} has no finite value ({})", values[i]);
    }
    StrandShares::check_values(&values, kind(s), s.paintings().len())?;
    Ok(Some(values))
}

/// The shares of the paintings of every strand of `scene` (guides then
/// proxies) from the guides' `values`.
pub fn shares(s: &StrandSettings, scene: &StrandScene, values: &[f32]) -> Result<StrandShares> {
    Ok(StrandShares::from_guides(scene, values, kind(s), s.paintings().len())?)
}

/// How the settings' map values pick the paintings.
pub fn kind(s: &StrandSettings) -> MapKind {
    if s.style_map_labels {
        MapKind::Labels
    } else {
        MapKind::Blend
    }
}

/// Each root's height (y) mapped to `[0, 1]` over the roots.
fn root_heights(groom: &Groom) -> Vec<f32> {
    let y: Vec<f32> = groom.strands.iter().map(|s| s.points.first().map_or(0.0, |p| p[1])).collect();
    let (lo, hi) = y.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
    let span = (hi - lo).max(f32::MIN_POSITIVE);
    y.iter().map(|&v| ((v - lo) / span).clamp(0.0, 1.0)).collect()
}

/// Whitespace-separated numbers, one per strand.
fn read_text_map(path: &Path) -> Result<Vec<f32>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("--style-map {}", path.display()))?;
    text.split_whitespace()
        .enumerate()
        .map(|(i, w)| {
            w.parse::<f32>()
                .with_context(|| format!("--style-map {}: value {} is not a number: {w}", path.display(), i + 1))
        })
        .collect()
}

/// The property `name` of the groom file `groom`: a strand or root-vertex
/// property of a `.ply`, a primvar of a USD groom (each curve's value, or
/// its root point's).
fn file_property(groom: &Path, name: &str) -> Result<Vec<f32>> {
    let ext = groom.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("ply") => Ok(nst3d_io::groom::read_ply_strand_attribute(groom, name)?),
        Some("usd" | "usda" | "usdc" | "usdz") => {
            let file = nst3d_io::groom::read_usd_curves_file(groom)?;
            file.usd_primvars.strand_values(name).map_err(|e| anyhow::anyhow!("--style-map {name}: {e}"))
        }
        _ => bail!(
            "--style-map {name}: a property is read from a .ply or USD groom, and {} is neither \
             (give {HEIGHT_MAP} or a .txt file with one value per strand)",
            groom.display()
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::groom::Strand;

    #[test]
    fn the_height_map_runs_from_the_lowest_root_to_the_highest() {
        let groom = Groom {
            strands: [0.0f32, 2.0, 1.0].iter().map(|&y| Strand::new(vec![[0.0, y, 0.0], [1.0, y, 0.0]])).collect(),
        };
        assert_eq!(root_heights(&groom), vec![0.0, 1.0, 0.5]);
    }

    #[test]
    fn a_usd_grooms_primvar_is_its_map() {
        let path = std::env::temp_dir().join(format!("nst3d_style_map_{}.usda", std::process::id()));
        let text = "#usda 1.0\ndef BasisCurves \"hair\"\n{\n    uniform token type = \"linear\"\n    \
                    int[] curveVertexCounts = [2, 2, 2]\n    \
                    point3f[] points = [(0,0,0), (0,1,0), (1,0,0), (1,1,0), (2,0,0), (2,1,0)]\n    \
                    float[] primvars:side = [0, 1, 1] (interpolation = \"uniform\")\n}\n";
        std::fs::write(&path, text).unwrap();
        let groom = nst3d_io::groom::read_groom(&path).unwrap();
        let mut s = StrandSettings::new(&path, "head.ply", "a.png", "out.usda");
        s.more_styles = vec!["b.png".into()];
        s.style_map = Some("side".into());
        let values = map_values(&s, &path, &groom);
        s.style_map = Some("front".into());
        let missing = map_values(&s, &path, &groom).unwrap_err().to_string();
        std::fs::remove_file(&path).unwrap();
        assert_eq!(values.unwrap(), Some(vec![0.0, 1.0, 1.0]));
        assert!(missing.contains("no primvars:front (number primvars: primvars:side)"), "{missing}");
    }
}
