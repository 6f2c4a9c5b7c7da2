//! A groom as crate file specs: the same single `BasisCurves` prim
//! `/Groom` the text writer writes (linear, non-periodic, counts, extent,
//! points, per-point widths and `displayColor`, the input's other primvars,
//! the layer's `upAxis` and `metersPerUnit`), typed. Points, widths and
//! colours go in as the `f32`s they are. The other primvars, held as the
//! text of their declarations, are parsed back into typed values by their
//! declared type (`float[]`, `texCoord2f[]`, `token`, `matrix4d`, ...)
//! with their `uniform`/`custom` qualifiers, `interpolation`,
//! `elementSize`, `doc` and time samples; one whose type or value has no
//! crate form here (dictionaries, connections, unknown types) is left out
//! and named by [`unwritable`].

use super::value::{Comp, NumType, Nums, Shape, Spec, SpecKind, TextKind, Value};
use crate::groom::usda::parse::{statements, Val};
use crate::groom::{Groom, UsdPrimvar, UsdPrimvars};

/// What a value type name stores.
enum Elem {
    Num(NumType),
    Text(TextKind),
}

/// The element type of a value type name (without `[]`).
fn elem(base: &str) -> Option<Elem> {
    let scalar = |c| Some(Elem::Num(NumType::scalar(c)));
    match base {
        "bool" => return scalar(Comp::Bool),
        "uchar" => return scalar(Comp::UChar),
        "int" => return scalar(Comp::Int),
        "uint" => return scalar(Comp::UInt),
        "int64" => return scalar(Comp::Int64),
        "uint64" => return scalar(Comp::UInt64),
        "half" => return scalar(Comp::Half),
        "float" => return scalar(Comp::Float),
        "double" => return scalar(Comp::Double),
        "timecode" => return Some(Elem::Num(NumType { comp: Comp::Double, shape: Shape::TimeCode })),
        "string" => return Some(Elem::Text(TextKind::String)),
        "token" => return Some(Elem::Text(TextKind::Token)),
        "asset" => return Some(Elem::Text(TextKind::Asset)),
        "frame4d" => return Some(Elem::Num(NumType { comp: Comp::Double, shape: Shape::Matrix(4) })),
        _ => {}
    }
    let num = |comp, shape| Some(Elem::Num(NumType { comp, shape }));
    let size = |n: &str| n.parse::<usize>().ok().filter(|n| (2..=4).contains(n));
    let letter = |c: &str| match c {
        "h" => Some(Comp::Half),
        "f" => Some(Comp::Float),
        "d" => Some(Comp::Double),
        _ => None,
    };
    if let Some(n) = base.strip_prefix("matrix").and_then(|r| r.strip_suffix('d')) {
        return num(Comp::Double, Shape::Matrix(size(n)?));
    }
    if let Some(c) = base.strip_prefix("quat") {
        return num(letter(c)?, Shape::Quat);
    }
    // Vectors named by their components: half2, float3, double4, int2.
    for (prefix, comp) in [("half", Comp::Half), ("float", Comp::Float), ("double", Comp::Double), ("int", Comp::Int)] {
        if let Some(n) = base.strip_prefix(prefix).and_then(size) {
            return num(comp, Shape::Vec(n));
        }
    }
    // Vectors named by their role: point3f, normal3h, color4d, texCoord2f.
    for role in ["point", "normal", "vector", "color", "texCoord"] {
        if let Some(rest) = base.strip_prefix(role).filter(|r| r.len() == 2 && r.is_ascii()) {
            return num(letter(&rest[1..])?, Shape::Vec(size(&rest[..1])?));
        }
    }
    None
}

/// A number of a text value (`true`/`false` for bools).
fn number(v: &Val) -> Option<f64> {
    match v {
        Val::Num(x) => Some(*x),
        Val::Ident(s) if s == "true" => Some(1.0),
        Val::Ident(s) if s == "false" => Some(0.0),
        _ => None,
    }
}

/// Appends the components of one element `v` of type `ty`, in the order
/// the crate file stores them.
fn components(ty: NumType, v: &Val, out: &mut Vec<f64>) -> Option<()> {
    match ty.shape {
        Shape::Scalar | Shape::TimeCode => out.push(number(v)?),
        Shape::Vec(n) => match v.as_list()? {
            l if l.len() == n => l.iter().try_for_each(|c| number(c).map(|x| out.push(x)))?,
            _ => return None,
        },
        Shape::Quat => match v.as_list()? {
            // Text puts the real part first; the file last.
            [r, i, j, k] => [i, j, k, r].iter().try_for_each(|c| number(c).map(|x| out.push(x)))?,
            _ => return None,
        },
        Shape::Matrix(n) => {
            let rows = v.as_list().filter(|r| r.len() == n)?;
            for row in rows {
                match row.as_list() {
                    Some(r) if r.len() == n => r.iter().try_for_each(|c| number(c).map(|x| out.push(x)))?,
                    _ => return None,
                }
            }
        }
    }
    Some(())
}

/// Numbers of component type `comp` from their text values.
fn nums(comp: Comp, flat: Vec<f64>) -> Option<Nums> {
    if comp.is_float() {
        return Some(Nums::F(flat));
    }
    let whole = |x: &f64| x.fract() == 0.0 && x.is_finite();
    if !flat.iter().all(whole) {
        return None;
    }
    Some(match comp {
        Comp::UInt64 => Nums::U(flat.iter().map(|&x| x as u64).collect()),
        Comp::Bool => Nums::I(flat.iter().map(|&x| (x != 0.0) as i64).collect()),
        _ => Nums::I(flat.iter().map(|&x| x as i64).collect()),
    })
}

/// The typed value of text value `v` declared as `ty` (`float[]`,
/// `token`, ...), time samples included; `None` if it has none here.
pub(super) fn typed(ty: &str, v: &Val) -> Option<Value> {
    if let Val::Samples(s) = v {
        let one = |(t, v): &(f64, Val)| match v {
            Val::Ident(n) if n == "None" => Some((*t, Value::Block)),
            v => Some((*t, typed(ty, v)?)),
        };
        return Some(Value::Samples(s.iter().map(one).collect::<Option<_>>()?));
    }
    if matches!(v, Val::Ident(n) if n == "None") {
        return Some(Value::Block);
    }
    let (base, array) = ty.strip_suffix("[]").map_or((ty, false), |b| (b, true));
    let items: Vec<&Val> = if array { v.as_list()?.iter().collect() } else { vec![v] };
    match elem(base)? {
        Elem::Text(kind) => {
            let one = |v: &&Val| match (kind, v) {
                (TextKind::Asset, Val::Asset(a)) => Some(a.clone()),
                (TextKind::String | TextKind::Token, Val::Str(s)) => Some(s.clone()),
                _ => None,
            };
            Some(Value::Text { kind, array, items: items.iter().map(one).collect::<Option<_>>()? })
        }
        Elem::Num(nt) => {
            let mut flat = Vec::with_capacity(items.len() * nt.shape.components());
            for it in items {
                components(nt, it, &mut flat)?;
            }
            Some(Value::Num { ty: nt, array, nums: nums(nt.comp, flat)? })
        }
    }
}

/// The attribute spec of one primvar of `prim` from its declaration, or
/// why it cannot be written.
fn primvar_spec(prim: &str, p: &UsdPrimvar) -> Result<Spec, String> {
    let stmts = statements(&p.declaration).map_err(|e| e.to_string())?;
    let ty = stmts.iter().find_map(|a| a.type_name.clone()).ok_or("no declared type")?;
    let mut fields =
        vec![("typeName".to_string(), Value::Text { kind: TextKind::Token, array: false, items: vec![ty.clone()] })];
    if stmts.iter().any(|a| a.custom) {
        fields.push((
            "custom".into(),
            Value::Num { ty: NumType::scalar(Comp::Bool), array: false, nums: Nums::I(vec![1]) },
        ));
    }
    if stmts.iter().any(|a| a.uniform) {
        fields.push(("variability".into(), Value::Variability(1)));
    }
    for a in &stmts {
        let (field, v) = match a.name.strip_prefix(&p.name).unwrap_or("?") {
            "" => ("default", &a.value),
            ".timeSamples" => ("timeSamples", &a.value),
            other => return Err(format!("'{}{other}' has no crate form here", p.name)),
        };
        if let Some(v) = v {
            fields.push((field.into(), typed(&ty, v).ok_or_else(|| format!("its {field} value is not a {ty}"))?));
        }
        for (k, m) in &a.meta {
            let value = match (k.as_str(), m) {
                ("interpolation", Val::Str(s)) => {
                    Value::Text { kind: TextKind::Token, array: false, items: vec![s.clone()] }
                }
                ("elementSize", Val::Num(n)) => typed("int", &Val::Num(*n)).ok_or("bad elementSize")?,
                ("doc", Val::Str(s)) => Value::Text { kind: TextKind::String, array: false, items: vec![s.clone()] },
                _ => continue,
            };
            let name = if k == "doc" { "documentation" } else { k.as_str() };
            fields.retain(|f| f.0 != name);
            fields.push((name.to_string(), value));
        }
    }
    Ok(Spec { path: format!("{prim}.{}", p.name), kind: SpecKind::Attribute, fields })
}

/// The primvars of `primvars` that a crate file written here will not
/// hold, each with why.
pub(crate) fn unwritable(primvars: &UsdPrimvars) -> Vec<String> {
    primvars
        .primvars
        .iter()
        .filter_map(|p| primvar_spec("/Groom", p).err().map(|why| format!("{}: {why}", p.name)))
        .collect()
}

fn token(t: &str) -> Value {
    Value::Text { kind: TextKind::Token, array: false, items: vec![t.to_string()] }
}

fn floats(ty: NumType, v: impl Iterator<Item = f32>) -> Value {
    Value::Num { ty, array: true, nums: Nums::F(v.map(f64::from).collect()) }
}

/// Attribute `name` of `/Groom` typed `ty` with `value` and more fields.
fn attr(name: &str, ty: &str, value: Value, more: Vec<(&str, Value)>) -> Spec {
    let mut fields = vec![("typeName".to_string(), token(ty)), ("default".to_string(), value)];
    fields.extend(more.into_iter().map(|(k, v)| (k.to_string(), v)));
    Spec { path: format!("/Groom.{name}"), kind: SpecKind::Attribute, fields }
}

/// The specs of a crate file holding `groom` with `primvars` (module
/// notes); the caller has checked the groom and that the primvars fit it.
pub(super) fn groom_specs(groom: &Groom, primvars: &UsdPrimvars) -> Vec<Spec> {
    let vec3 = NumType { comp: Comp::Float, shape: Shape::Vec(3) };
    let uniform = || vec![("variability", Value::Variability(1))];
    let vertex = || vec![("interpolation", token("vertex"))];
    let counts = groom.strands.iter().map(|s| s.points.len() as i64).collect();
    let mut attrs = vec![
        attr("type", "token", token("linear"), uniform()),
        attr("wrap", "token", token("nonperiodic"), uniform()),
        attr(
            "curveVertexCounts",
            "int[]",
            Value::Num { ty: NumType::scalar(Comp::Int), array: true, nums: Nums::I(counts) },
            vec![],
        ),
    ];
    let all_widths = groom.strands.iter().all(|s| s.widths.is_some());
    let widths = || groom.strands.iter().flat_map(|s| s.widths.iter().flatten().copied());
    if let Some((lo, hi)) = groom.bbox() {
        let pad = if all_widths { widths().fold(0f32, f32::max) * 0.5 } else { 0.0 };
        let corners = lo.map(|c| c - pad).into_iter().chain(hi.map(|c| c + pad));
        attrs.push(attr("extent", "float3[]", floats(vec3, corners), vec![]));
    }
    let points = groom.strands.iter().flat_map(|s| s.points.iter().flatten().copied());
    attrs.push(attr("points", "point3f[]", floats(vec3, points), vec![]));
    if all_widths {
        attrs.push(attr("widths", "float[]", floats(NumType::scalar(Comp::Float), widths()), vertex()));
    }
    if groom.strands.iter().all(|s| s.colors.is_some()) {
        let colors = groom.strands.iter().flat_map(|s| s.colors.iter().flatten().flatten().copied());
        attrs.push(attr("primvars:displayColor", "color3f[]", floats(vec3, colors), vertex()));
    }
    attrs.extend(primvars.primvars.iter().filter_map(|p| primvar_spec("/Groom", p).ok()));
    let names = attrs.iter().map(|a| a.path["/Groom.".len()..].to_string()).collect();
    let mut root = vec![
        ("defaultPrim".to_string(), token("Groom")),
        (
            "documentation".to_string(),
            Value::Text { kind: TextKind::String, array: false, items: vec!["Written by nst3d".into()] },
        ),
    ];
    if let Some(m) = primvars.meters_per_unit {
        root.push((
            "metersPerUnit".into(),
            Value::Num { ty: NumType::scalar(Comp::Double), array: false, nums: Nums::F(vec![m]) },
        ));
    }
    root.push(("upAxis".into(), token(primvars.up_axis.as_deref().unwrap_or("Y"))));
    root.push(("primChildren".into(), Value::Tokens(vec!["Groom".into()])));
    let prim = vec![
        ("specifier".to_string(), Value::Specifier(0)),
        ("typeName".to_string(), token("BasisCurves")),
        ("properties".to_string(), Value::Tokens(names)),
    ];
    let mut specs = vec![
        Spec { path: "/".into(), kind: SpecKind::PseudoRoot, fields: root },
        Spec { path: "/Groom".into(), kind: SpecKind::Prim, fields: prim },
    ];
    specs.extend(attrs);
    specs
}
