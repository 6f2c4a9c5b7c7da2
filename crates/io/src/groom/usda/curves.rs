//! From parsed prims to strands: the prim walk (specifiers, `active`,
//! inherited transforms) and each `BasisCurves` prim's counts, points and
//! primvars expanded to one value per point. The walk also lists the prims
//! it read, for [`super::primvars`].

use super::parse::{Prim, Val};
use super::xform::{local_xform, mul, transform_point, Mat4};
use crate::bytes::corrupt;
use crate::groom::Strand;
use crate::ErrorKind;

/// Number of `varying` values a curve of `n` vertices carries.
fn varying_count(n: usize, cubic: bool, basis: &str, periodic: bool) -> usize {
    if !cubic {
        return n;
    }
    match basis {
        "bezier" if periodic => n / 3,
        "bezier" => n.saturating_sub(1) / 3 + 1,
        "bspline" | "catmullRom" if periodic => n,
        "bspline" | "catmullRom" => n.saturating_sub(2),
        _ => n,
    }
}

/// Expands a primvar to one value per point, or `None` if its length fits
/// no interpolation. `varying` values are spread linearly along the curve.
pub(super) fn expand<T: Copy + Lerp>(
    values: &[T],
    interpolation: Option<&str>,
    counts: &[usize],
    cubic: bool,
    basis: &str,
    periodic: bool,
) -> Option<Vec<Vec<T>>> {
    let total: usize = counts.iter().sum();
    let by_len = match values.len() {
        1 => "constant",
        l if l == total => "vertex",
        l if l == counts.len() => "uniform",
        _ => "varying",
    };
    let interp = match interpolation {
        // Linear curves: varying and vertex are the same thing.
        Some("varying") if values.len() == total => "vertex",
        Some(i @ ("constant" | "uniform" | "vertex" | "varying")) => i,
        _ => by_len,
    };
    let mut out = Vec::with_capacity(counts.len());
    let mut start = 0;
    for (k, &n) in counts.iter().enumerate() {
        out.push(match interp {
            "constant" => vec![*values.first()?; n],
            "uniform" => vec![*values.get(k)?; n],
            "vertex" => values.get(start..start + n)?.to_vec(),
            _ => {
                let m = varying_count(n, cubic, basis, periodic);
                let v = values.get(start..start + m)?;
                (0..n)
                    .map(|j| {
                        if m == 1 || n == 1 {
                            return v.first().copied();
                        }
                        let t = j as f64 * (m - 1) as f64 / (n - 1) as f64;
                        let i0 = (t.floor() as usize).min(m - 2);
                        Some(T::lerp(v[i0], v[i0 + 1], (t - i0 as f64) as f32))
                    })
                    .collect::<Option<Vec<T>>>()?
            }
        });
        start += match interp {
            "vertex" => n,
            "varying" => varying_count(n, cubic, basis, periodic),
            _ => 0,
        };
    }
    let used = match interp {
        "constant" => 1,
        "uniform" => counts.len(),
        _ => start,
    };
    (used == values.len()).then_some(out)
}

/// Linear interpolation, for spreading `varying` primvars.
pub(super) trait Lerp {
    fn lerp(a: Self, b: Self, t: f32) -> Self;
}

impl Lerp for f32 {
    fn lerp(a: f32, b: f32, t: f32) -> f32 {
        a + (b - a) * t
    }
}

impl Lerp for [f32; 3] {
    fn lerp(a: [f32; 3], b: [f32; 3], t: f32) -> [f32; 3] {
        [0, 1, 2].map(|i| a[i] + (b[i] - a[i]) * t)
    }
}

/// A `BasisCurves` prim the walk read strands from.
pub(crate) struct CurvesPrim<'a> {
    pub(super) prim: &'a Prim,
    /// Points per curve.
    pub(super) counts: Vec<usize>,
    /// `type = "cubic"` (as the reader maps `varying` primvars).
    pub(super) cubic: bool,
}

fn curves_of<'a>(prim: &'a Prim, world: &Mat4, out: &mut Vec<Strand>) -> Result<CurvesPrim<'a>, ErrorKind> {
    let path = &prim.name;
    let bad = |why: String| corrupt(format!("BasisCurves '{path}': {why}"));
    let counts: Vec<usize> = prim
        .value("curveVertexCounts")
        .and_then(Val::as_list)
        .ok_or_else(|| bad("no curveVertexCounts".into()))?
        .iter()
        .map(|v| match v.as_f64() {
            Some(x) if x >= 0.0 && x.fract() == 0.0 && x < 1e12 => Ok(x as usize),
            _ => Err(bad(format!("bad curve vertex count {v:?}"))),
        })
        .collect::<Result<_, _>>()?;
    let points: Vec<[f32; 3]> = prim
        .value("points")
        .and_then(Val::as_list)
        .ok_or_else(|| bad("no points".into()))?
        .iter()
        .map(|v| {
            v.as_vec3()
                .map(|p| transform_point(world, p.map(|c| c as f32)))
                .ok_or_else(|| bad(format!("bad point {v:?}")))
        })
        .collect::<Result<_, _>>()?;
    let total: usize = counts.iter().sum();
    if total != points.len() {
        return Err(bad(format!("curveVertexCounts add up to {total} but there are {} points", points.len())));
    }
    let cubic = prim.value("type").and_then(Val::as_str) == Some("cubic");
    let basis = prim.value("basis").and_then(Val::as_str).unwrap_or("bezier");
    let periodic = prim.value("wrap").and_then(Val::as_str) == Some("periodic");

    let width_name = if prim.value("primvars:widths").is_some() { "primvars:widths" } else { "widths" };
    let widths =
        match prim.value(width_name).and_then(Val::as_list) {
            Some(list) => {
                let w: Vec<f32> = list
                    .iter()
                    .map(|v| v.as_f64().map(|x| x as f32).ok_or_else(|| bad(format!("bad width {v:?}"))))
                    .collect::<Result<_, _>>()?;
                Some(expand(&w, prim.interpolation(width_name), &counts, cubic, basis, periodic).ok_or_else(|| {
                    bad(format!("{} widths fit no interpolation of {} curves", w.len(), counts.len()))
                })?)
            }
            None => None,
        };
    let colors = match prim.value("primvars:displayColor").and_then(Val::as_list) {
        Some(list) => {
            let c: Vec<[f32; 3]> = list
                .iter()
                .map(|v| v.as_vec3().map(|c| c.map(|x| x as f32)).ok_or_else(|| bad(format!("bad colour {v:?}"))))
                .collect::<Result<_, _>>()?;
            expand(&c, prim.interpolation("primvars:displayColor"), &counts, cubic, basis, periodic)
        }
        None => None,
    };
    let mut start = 0;
    for (k, &n) in counts.iter().enumerate() {
        out.push(Strand {
            points: points[start..start + n].to_vec(),
            widths: widths.as_ref().map(|w| w[k].clone()),
            colors: colors.as_ref().map(|c| c[k].clone()),
        });
        start += n;
    }
    Ok(CurvesPrim { prim, counts, cubic })
}

/// Appends the strands of every defined, active `BasisCurves` prim under
/// `prim` (itself included), with `parent` its inherited transform, and
/// those prims to `read`.
pub(crate) fn walk<'a>(
    prim: &'a Prim,
    parent: &Mat4,
    out: &mut Vec<Strand>,
    read: &mut Vec<CurvesPrim<'a>>,
) -> Result<(), ErrorKind> {
    if prim.specifier != "def" || prim.active == Some(false) {
        return Ok(());
    }
    let (local, reset) = local_xform(prim)?;
    let world = if reset { local } else { mul(parent, &local) };
    if prim.type_name.as_deref() == Some("BasisCurves") {
        read.push(curves_of(prim, &world, out)?);
    }
    for c in &prim.children {
        walk(c, &world, out, read)?;
    }
    Ok(())
}
