//! One number per strand from a kept primvar: a style map painted on the
//! curves in the DCC (a Houdini or Maya attribute exported as a primvar).

use super::curves::expand;
use super::parse::{body_prim, Val};
use super::primvars::{UsdPrimvar, UsdPrimvars};

/// Scalar types a map may be (`[]` arrays of them too).
const SCALARS: [&str; 9] = ["float", "double", "half", "int", "uint", "int64", "uint64", "uchar", "bool"];

impl UsdPrimvars {
    /// One number per strand, in the groom's strand order, from the
    /// scalar primvar `name` (`primvars:` may be left out): each curve's
    /// value where it is `uniform`, its root point's where it is `vertex`
    /// or `varying`, the one value where it is `constant` (with no
    /// `interpolation`, whichever its length fits, as the reader expands
    /// widths). `:indices` are followed; a time-sampled primvar gives its
    /// earliest sample, as the reader's points do. Errs with why, naming
    /// the primvar.
    pub fn strand_values(&self, name: &str) -> Result<Vec<f32>, String> {
        let full = if name.starts_with("primvars:") { name.to_string() } else { format!("primvars:{name}") };
        let Some(primvar) = self.primvars.iter().find(|p| p.name == full) else {
            return Err(self.missing(&full));
        };
        if !SCALARS.contains(&primvar.type_name.trim_end_matches("[]")) {
            return Err(format!("{full} is a {}: a map is one number per curve or point", primvar.type_name));
        }
        let (mut values, element_size) = numbers(primvar)?;
        if element_size > 1 {
            return Err(format!("{full} has several numbers per element: a map is one per curve or point"));
        }
        if let Some(indices) = self.primvars.iter().find(|p| p.name == format!("{full}:indices")) {
            values = numbers(indices)?
                .0
                .iter()
                .map(|&i| values.get(i as usize).copied())
                .collect::<Option<_>>()
                .ok_or_else(|| format!("{full}:indices points past its {} values", values.len()))?;
        }
        let per_point = expand(&values, primvar.interpolation.as_deref(), &self.curve_points, false, "linear", false)
            .ok_or_else(|| {
            format!("{full}: {} values fit no interpolation of {} curves", values.len(), self.curve_points.len())
        })?;
        Ok(per_point.iter().map(|curve| curve.first().copied().unwrap_or(f32::NAN)).collect())
    }

    /// Why there is no primvar `full`: dropped (and why), or which scalar
    /// primvars there are.
    fn missing(&self, full: &str) -> String {
        if let Some(why) = self.dropped.iter().find(|d| d.starts_with(&format!("{full} "))) {
            return why.clone();
        }
        let scalars: Vec<&str> = self
            .primvars
            .iter()
            .filter(|p| SCALARS.contains(&p.type_name.trim_end_matches("[]")) && !p.name.ends_with(":indices"))
            .map(|p| p.name.as_str())
            .collect();
        if scalars.is_empty() {
            format!("the groom's curves have no {full} (nor any other number primvar)")
        } else {
            format!("the groom's curves have no {full} (number primvars: {})", scalars.join(", "))
        }
    }
}

/// The numbers of a primvar's value (a default, else its earliest sample)
/// and its `elementSize` metadata (1 where not authored), from one parse
/// of its declaration (a vertex primvar holds a number per point).
fn numbers(p: &UsdPrimvar) -> Result<(Vec<f32>, usize), String> {
    let prim = body_prim(&p.declaration).map_err(|e| format!("{}: {e}", p.name))?;
    let Some(prim) = prim else { return Err(format!("{} has no value", p.name)) };
    let meta = prim.attrs.iter().flat_map(|a| a.meta.iter());
    let element_size =
        meta.filter(|(key, _)| key == "elementSize").find_map(|(_, v)| v.as_f64()).map_or(1, |n| n as usize);
    let value = prim.value(&p.name).ok_or_else(|| format!("{} has no value", p.name))?;
    let number = |v: &Val| match v {
        Val::Ident(b) if b == "true" || b == "false" => Some(f32::from(b == "true")),
        v => v.as_f64().map(|x| x as f32),
    };
    let values = match value {
        Val::List(items) => items.iter().map(number).collect::<Option<_>>(),
        v => number(v).map(|x| vec![x]),
    };
    Ok((values.ok_or_else(|| format!("{} holds something other than numbers", p.name))?, element_size))
}

#[cfg(test)]
mod tests {
    use crate::groom::read_usda_curves_file_bytes;
    use std::path::Path;

    /// Three two-point curves with `decl` among their primvars.
    fn values(decl: &str, name: &str) -> Result<Vec<f32>, String> {
        let text = format!(
            "#usda 1.0\ndef BasisCurves \"hair\"\n{{\n    uniform token type = \"linear\"\n    \
             int[] curveVertexCounts = [2, 2, 2]\n    \
             point3f[] points = [(0,0,0), (0,1,0), (1,0,0), (1,1,0), (2,0,0), (2,1,0)]\n    {decl}\n}}\n"
        );
        let file = read_usda_curves_file_bytes(Path::new("t.usda"), text.as_bytes()).unwrap();
        file.usd_primvars.strand_values(name)
    }

    #[test]
    fn a_map_primvar_gives_each_curve_its_value_or_its_roots() {
        let uniform = "float[] primvars:side = [0, 0.5, 1] (interpolation = \"uniform\")";
        assert_eq!(values(uniform, "side").unwrap(), vec![0.0, 0.5, 1.0]);
        assert_eq!(values(uniform, "primvars:side").unwrap(), vec![0.0, 0.5, 1.0]);
        let vertex = "float[] primvars:m = [0.1, 9, 0.2, 9, 0.3, 9] (interpolation = \"vertex\")";
        assert_eq!(values(vertex, "m").unwrap(), vec![0.1, 0.2, 0.3]);
        let constant = "int primvars:label = 2 (interpolation = \"constant\")";
        assert_eq!(values(constant, "label").unwrap(), vec![2.0; 3]);
        let indexed =
            "int[] primvars:l = [7, 8] (interpolation = \"uniform\")\n    int[] primvars:l:indices = [1, 0, 1]";
        assert_eq!(values(indexed, "l").unwrap(), vec![8.0, 7.0, 8.0]);
        let sampled = "float[] primvars:t.timeSamples = { 2: [5, 5, 5], 1: [1, 2, 3] } (interpolation = \"uniform\")";
        assert_eq!(values(sampled, "t").unwrap(), vec![1.0, 2.0, 3.0]);
    }

    #[test]
    fn a_map_primvar_that_cannot_be_one_says_why() {
        let uniform = "float[] primvars:side = [0, 0.5, 1] (interpolation = \"uniform\")";
        let err = values(uniform, "other").unwrap_err();
        assert!(err.contains("no primvars:other") && err.contains("primvars:side"), "{err}");
        let colour = "color3f[] primvars:tint = [(1,0,0), (0,1,0), (0,0,1)] (interpolation = \"uniform\")";
        assert!(values(colour, "tint").unwrap_err().contains("is a color3f[]"));
        let short = "float[] primvars:side = [0, 1] (interpolation = \"uniform\")";
        assert!(values(short, "side").unwrap_err().contains("2 values fit no interpolation of 3 curves"));
        let pairs = "float[] primvars:p = [1, 2, 3, 4, 5, 6] (interpolation = \"uniform\"\n elementSize = 2)";
        assert!(values(pairs, "p").unwrap_err().contains("several numbers per element"));
        let past = "int[] primvars:l = [7] (interpolation = \"uniform\")\n    int[] primvars:l:indices = [0, 3, 0]";
        assert!(values(past, "l").unwrap_err().contains("points past"));
    }
}
