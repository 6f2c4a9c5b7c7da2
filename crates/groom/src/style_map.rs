//! Where a groom's style map comes from: one value per strand, read from
//! the groom file, a companion text file or the roots' height, and turned
//! into each strand's share of the paintings
//! ([`nst3d_strands::pipeline::StrandShares`]).

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
        (None, Some(name)) => (ply_property(path, name)?, format!("--style-map {name}")),
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

/// The strand or root-vertex property `name` of the `.ply` groom `groom`.
fn ply_property(groom: &Path, name: &str) -> Result<Vec<f32>> {
    if groom.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() != Some("ply") {
        bail!(
            "--style-map {name}: a property is read from a .ply groom, and {} is not one \
             (give {HEIGHT_MAP} or a .txt file with one value per strand)",
            groom.display()
        );
    }
    Ok(nst3d_io::groom::read_ply_strand_attribute(groom, name)?)
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
}
