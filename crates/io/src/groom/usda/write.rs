//! The writer: one clean `BasisCurves` layer.

use std::fmt::Write as _;
use std::path::Path;

use super::primvars::{UsdPrimvars, HELD};
use crate::groom::{validate_for, Groom};
use crate::{Error, ErrorKind};

/// Writes `groom` as a text USD layer (`upAxis = "Y"`, `defaultPrim =
/// "Groom"`) holding one `BasisCurves` prim `/Groom`.
///
/// `upAxis = "Y"` is a guess when the points come from a format with no
/// axis (PLY, cyHair, Alembic curves): most DCCs' default.
///
/// `type = "linear"`: our strands are sampled hair polylines (as every
/// supported input format stores them), and linear curves draw exactly those
/// points in any USD renderer, whereas cubic Catmull-Rom would drop the
/// first and last segment unless phantom points were added (`wrap =
/// "pinned"` is not read by every DCC). `widths` (vertex interpolation)
/// are written when every strand has widths, `primvars:displayColor`
/// likewise for colours; `extent` bounds points padded by half the widest
/// width. Both are written per point whatever the input's interpolation
/// was: the readers expand constant, uniform and varying values to one per
/// point, and the same value repeated on every point of a strand draws the
/// same. Floats are printed in shortest round-trip form, so reading the
/// layer back gives the same `f32`s.
pub fn write_usda_curves(path: &Path, groom: &Groom) -> Result<(), Error> {
    write_usda_curves_with(path, groom, &UsdPrimvars::default())
}

/// [`write_usda_curves`], plus the input layer's other primvars
/// ([`UsdPrimvars`], as read by
/// [`read_usda_curves_file`](crate::groom::read_usda_curves_file)) written
/// after the colours, each declaration as it was, and the input layer's
/// `upAxis` and `metersPerUnit` (the points are in its axes and units).
/// Fails without writing when the groom's curves are not those the
/// primvars were read from (same number, same points each), or when a
/// primvar is one the writer writes from the strands
/// (`primvars:displayColor`, `primvars:widths`) or is not a `primvars:`
/// attribute. The declarations are not otherwise checked:
/// they are the input layer's text.
pub fn write_usda_curves_with(path: &Path, groom: &Groom, primvars: &UsdPrimvars) -> Result<(), Error> {
    check(path, groom, primvars)?;
    let mut s = String::with_capacity(64 + groom.point_count() * 40);
    let f3 = |s: &mut String, p: &[f32; 3]| {
        let _ = write!(s, "({}, {}, {})", p[0], p[1], p[2]);
    };
    s.push_str("#usda 1.0\n(\n    defaultPrim = \"Groom\"\n    doc = \"Written by nst3d\"\n");
    if let Some(m) = primvars.meters_per_unit {
        let _ = writeln!(s, "    metersPerUnit = {m}");
    }
    let _ = write!(s, "    upAxis = \"{}\"\n)\n\n", primvars.up_axis.as_deref().unwrap_or("Y"));
    s.push_str(
        "def BasisCurves \"Groom\"\n{\n    uniform token type = \"linear\"\n    uniform token wrap = \"nonperiodic\"\n",
    );
    s.push_str("    int[] curveVertexCounts = [");
    for (i, st) in groom.strands.iter().enumerate() {
        let _ = write!(s, "{}{}", if i > 0 { ", " } else { "" }, st.points.len());
    }
    s.push_str("]\n");
    let all_widths = groom.strands.iter().all(|st| st.widths.is_some());
    let max_width = if all_widths {
        groom.strands.iter().flat_map(|st| st.widths.iter().flatten()).fold(0f32, |a, &w| a.max(w))
    } else {
        0.0
    };
    if let Some((lo, hi)) = groom.bbox() {
        let pad = max_width * 0.5;
        s.push_str("    float3[] extent = [");
        f3(&mut s, &lo.map(|c| c - pad));
        s.push_str(", ");
        f3(&mut s, &hi.map(|c| c + pad));
        s.push_str("]\n");
    }
    s.push_str("    point3f[] points = [");
    for (i, p) in groom.strands.iter().flat_map(|st| st.points.iter()).enumerate() {
        if i > 0 {
            s.push_str(", ");
        }
        f3(&mut s, p);
    }
    s.push_str("]\n");
    if all_widths {
        s.push_str("    float[] widths = [");
        for (i, w) in groom.strands.iter().flat_map(|st| st.widths.iter().flatten()).enumerate() {
            let _ = write!(s, "{}{}", if i > 0 { ", " } else { "" }, w);
        }
        s.push_str("] (\n        interpolation = \"vertex\"\n    )\n");
    }
    if groom.strands.iter().all(|st| st.colors.is_some()) {
        s.push_str("    color3f[] primvars:displayColor = [");
        for (i, c) in groom.strands.iter().flat_map(|st| st.colors.iter().flatten()).enumerate() {
            if i > 0 {
                s.push_str(", ");
            }
            f3(&mut s, c);
        }
        s.push_str("] (\n        interpolation = \"vertex\"\n    )\n");
    }
    for p in &primvars.primvars {
        s.push_str("    ");
        s.push_str(&p.declaration);
        s.push('\n');
    }
    s.push_str("}\n");
    crate::atomic::write_atomic(path, |w| w.write_all(s.as_bytes())).map_err(|e| Error::new(path, ErrorKind::Write(e)))
}

/// What every USD writer checks before writing: a valid groom, the
/// primvars' curves are the groom's, and no primvar is one the writer
/// writes from the strands or not a primvar at all.
pub(crate) fn check(path: &Path, groom: &Groom, primvars: &UsdPrimvars) -> Result<(), Error> {
    validate_for(groom, path)?;
    let mismatch = |reason: String| Error::new(path, ErrorKind::TopologyMismatch { reason });
    if !primvars.primvars.is_empty() {
        let counts: Vec<usize> = groom.strands.iter().map(|st| st.points.len()).collect();
        if counts.len() != primvars.curve_points.len() {
            return Err(mismatch(format!(
                "{} strands, the layer its primvars come from has {} curves",
                counts.len(),
                primvars.curve_points.len()
            )));
        }
        if let Some(i) = counts.iter().zip(&primvars.curve_points).position(|(a, b)| a != b) {
            return Err(mismatch(format!(
                "strand {i} has {} points, curve {i} of the layer its primvars come from has {}",
                counts[i], primvars.curve_points[i]
            )));
        }
    }
    if let Some(p) =
        primvars.primvars.iter().find(|p| !p.name.starts_with("primvars:") || HELD.contains(&p.name.as_str()))
    {
        return Err(Error::new(
            path,
            ErrorKind::Write(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!("'{}' is not a primvar the writer can pass through", p.name),
            )),
        ));
    }
    Ok(())
}
