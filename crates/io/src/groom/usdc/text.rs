//! A crate file's specs written out as a text layer, so that the one USD
//! reader (prims, transforms, curves, primvars, composition) reads both
//! forms the same way. What is written: the layer's `defaultPrim`,
//! `upAxis`, `metersPerUnit` and `subLayers`; every prim with its
//! specifier, type, `active`, references and payloads; on `BasisCurves`
//! prims and untyped ones (overs that may add primvars) every attribute,
//! on other prims only their `xformOp`s and `xformOpOrder`; per attribute
//! its type, `uniform`, `custom`, default, time samples, `interpolation`,
//! `elementSize` and `doc`. Relationships, connections, variant sets and
//! other metadata are left out: the groom reader does not use them.

use std::collections::{HashMap, HashSet};
use std::fmt::Write as _;

use super::sections::NO_PARENT;
use super::unpack::Unpacker;
use super::value::{Comp, Nums, Shape, SpecKind, TextKind, Value};
use crate::bytes::corrupt;
use crate::ErrorKind;

/// Deepest prim nesting written (the text reader takes no deeper).
const MAX_DEPTH: usize = 60;

/// `x` in the shortest text that reads back as the same `f32`.
pub(crate) fn f32_text(x: f32) -> String {
    let a = x.abs();
    if x.is_nan() {
        "nan".into()
    } else if x.is_infinite() {
        if x > 0.0 { "inf" } else { "-inf" }.into()
    } else if a == 0.0 || (1e-5..1e16).contains(&a) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

/// `x` in the shortest text that reads back as the same `f64`.
pub(crate) fn f64_text(x: f64) -> String {
    let a = x.abs();
    if x.is_nan() {
        "nan".into()
    } else if x.is_infinite() {
        if x > 0.0 { "inf" } else { "-inf" }.into()
    } else if a == 0.0 || (1e-5..1e16).contains(&a) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

/// A quoted string literal.
pub(crate) fn quoted(s: &str) -> String {
    let mut q = String::with_capacity(s.len() + 2);
    q.push('"');
    for c in s.chars() {
        match c {
            '"' => q.push_str("\\\""),
            '\\' => q.push_str("\\\\"),
            '\n' => q.push_str("\\n"),
            '\t' => q.push_str("\\t"),
            c => q.push(c),
        }
    }
    q.push('"');
    q
}

/// An asset path literal, or `None` if no delimiter can hold it.
pub(crate) fn asset(s: &str) -> Option<String> {
    if !s.contains('@') {
        Some(format!("@{s}@"))
    } else if !s.contains("@@@") {
        Some(format!("@@@{s}@@@"))
    } else {
        None
    }
}

/// Whether `s` is a name the text reader takes as one identifier
/// (namespaced with `:` for properties).
fn is_ident(s: &str, namespaced: bool) -> bool {
    let mut c = s.chars();
    c.next().is_some_and(|f| f.is_ascii_alphabetic() || f == '_')
        && c.all(|x| x.is_ascii_alphanumeric() || x == '_' || (namespaced && x == ':'))
}

/// One element (`k`-th of `n` components each) of a numeric value.
fn element(out: &mut String, nums: &Nums, comp: Comp, shape: Shape, k: usize) {
    let n = shape.components();
    let one = |i: usize| match nums {
        Nums::F(v) if comp == Comp::Double => f64_text(v[i]),
        Nums::F(v) => f32_text(v[i] as f32),
        Nums::I(v) => v[i].to_string(),
        Nums::U(v) => v[i].to_string(),
    };
    match shape {
        Shape::Scalar | Shape::TimeCode => out.push_str(&one(k)),
        Shape::Vec(_) | Shape::Quat => {
            // Quaternions are stored imaginary part first, written real first.
            let order: Vec<usize> = if shape == Shape::Quat { vec![3, 0, 1, 2] } else { (0..n).collect() };
            let parts: Vec<String> = order.iter().map(|&c| one(k * n + c)).collect();
            let _ = write!(out, "({})", parts.join(", "));
        }
        Shape::Matrix(m) => {
            let rows: Vec<String> = (0..m)
                .map(|r| format!("({})", (0..m).map(|c| one(k * n + r * m + c)).collect::<Vec<_>>().join(", ")))
                .collect();
            let _ = write!(out, "({})", rows.join(", "));
        }
    }
}

/// `v` as a text value, or `None` for what the text form here leaves out.
pub(crate) fn value_text(v: &Value) -> Option<String> {
    let list = |items: Vec<String>| format!("[{}]", items.join(", "));
    Some(match v {
        Value::Num { ty, array, nums } => {
            let n = ty.shape.components();
            let count = nums.len() / n.max(1);
            let mut s = String::with_capacity(count * 12 + 2);
            if *array {
                s.push('[');
            }
            for k in 0..count {
                if k > 0 {
                    s.push_str(", ");
                }
                element(&mut s, nums, ty.comp, ty.shape, k);
            }
            if *array {
                s.push(']');
            } else if count != 1 {
                return None;
            }
            s
        }
        Value::Text { kind, array, items } => {
            let one = |s: &String| if *kind == TextKind::Asset { asset(s) } else { Some(quoted(s)) };
            let texts = items.iter().map(one).collect::<Option<Vec<_>>>()?;
            match (array, texts.as_slice()) {
                (true, _) => list(texts),
                (false, [one]) => one.clone(),
                _ => return None,
            }
        }
        Value::Tokens(t) => list(t.iter().map(|s| quoted(s)).collect()),
        Value::Doubles(d) => list(d.iter().map(|&x| f64_text(x)).collect()),
        Value::Block => "None".into(),
        Value::Samples(s) => {
            let items: Vec<String> =
                s.iter().filter_map(|(t, v)| value_text(v).map(|v| format!("{}: {v}", f64_text(*t)))).collect();
            format!("{{ {} }}", items.join(", "))
        }
        _ => return None,
    })
}

/// Builds the text from the decoded tables.
struct Writer<'a, 'u> {
    u: &'u Unpacker<'a>,
    /// (parent node, name, is property) to spec index.
    index: HashMap<(u32, &'a str, bool), usize>,
    /// Specs already written (each is written once, however often listed).
    done: HashSet<usize>,
    out: String,
}

impl<'a> Writer<'a, '_> {
    /// The (name, value representation) fields of spec `s`.
    fn fields(&self, s: usize) -> Result<Vec<(&'a str, u64)>, ErrorKind> {
        let t = self.u.t;
        let start = t.specs[s].1 as usize;
        let mut out = Vec::new();
        for &f in t.field_sets.get(start..).unwrap_or(&[]).iter().take_while(|&&f| f != u32::MAX) {
            let (name, rep) =
                *t.fields.get(f as usize).ok_or_else(|| corrupt(format!("field index {f} out of range")))?;
            out.push((self.u.token(name)?, rep));
        }
        Ok(out)
    }

    /// The decoded value of field `name` of spec `s`.
    fn field(&self, s: usize, name: &str) -> Result<Option<Value>, ErrorKind> {
        match self.fields(s)?.into_iter().find(|f| f.0 == name) {
            Some((_, rep)) => Ok(Some(self.u.value(rep, 0)?)),
            None => Ok(None),
        }
    }

    /// Token list field `name` of spec `s` (empty if absent).
    fn names(&self, s: usize, name: &str) -> Result<Vec<String>, ErrorKind> {
        Ok(match self.field(s, name)? {
            Some(Value::Tokens(t)) | Some(Value::Text { items: t, .. }) => t,
            _ => Vec::new(),
        })
    }

    /// The spec of child `name` (a property if `property`) of spec `s`.
    fn child(&self, s: usize, name: &str, property: bool) -> Option<usize> {
        let node = (*self.u.t.path_nodes.get(self.u.t.specs[s].0 as usize)?)?;
        self.index.get(&(node, name, property)).copied()
    }

    fn layer(&mut self, root: usize) -> Result<(), ErrorKind> {
        self.out.push_str("#usda 1.0\n(\n");
        for key in ["defaultPrim", "upAxis"] {
            if let Some(t) = self.field(root, key)?.as_ref().and_then(Value::as_text) {
                let _ = writeln!(self.out, "    {key} = {}", quoted(t));
            }
        }
        if let Some(Value::Num { array: false, nums: Nums::F(m), .. }) = self.field(root, "metersPerUnit")? {
            let _ = writeln!(self.out, "    metersPerUnit = {}", f64_text(m[0]));
        }
        if let Some(Value::Strings(layers)) = self.field(root, "subLayers")? {
            let items: Vec<String> = layers.iter().filter_map(|l| asset(l)).collect();
            let _ = writeln!(self.out, "    subLayers = [{}]", items.join(", "));
        }
        self.out.push_str(")\n\n");
        for name in self.names(root, "primChildren")? {
            if let Some(c) = self.child(root, &name, false) {
                self.prim(c, &name, 0)?;
            }
        }
        Ok(())
    }
}

impl Writer<'_, '_> {
    fn prim(&mut self, s: usize, name: &str, depth: usize) -> Result<(), ErrorKind> {
        if depth > MAX_DEPTH {
            return Err(corrupt("prims nested too deep"));
        }
        if SpecKind::of_code(self.u.t.specs[s].2) != SpecKind::Prim || !self.done.insert(s) {
            return Ok(());
        }
        let pad = "    ".repeat(depth);
        let specifier = match self.field(s, "specifier")? {
            Some(Value::Specifier(0)) => "def",
            Some(Value::Specifier(2)) => "class",
            _ => "over",
        };
        let type_name = self.field(s, "typeName")?.and_then(|v| v.as_text().map(str::to_string));
        let type_name = type_name.filter(|t| is_ident(t, false));
        let _ = write!(
            self.out,
            "{pad}{specifier} {}{}",
            type_name.as_deref().map_or(String::new(), |t| format!("{t} ")),
            quoted(name)
        );
        let mut meta = Vec::new();
        if let Some(Value::Num { nums: Nums::I(a), array: false, .. }) = self.field(s, "active")? {
            if a.first() == Some(&0) {
                meta.push("active = false".to_string());
            }
        }
        for (field, key) in [("references", "references"), ("payload", "payload")] {
            if let Some(Value::Arcs(arcs)) = self.field(s, field)? {
                let items: Vec<String> = arcs
                    .iter()
                    .filter_map(|a| {
                        let prim = if a.prim.is_empty() { String::new() } else { format!("<{}>", a.prim) };
                        if a.asset.is_empty() {
                            Some(prim)
                        } else {
                            asset(&a.asset).map(|x| x + &prim)
                        }
                    })
                    .filter(|x| !x.is_empty())
                    .collect();
                meta.push(format!("prepend {key} = [{}]", items.join(", ")));
            }
        }
        if meta.is_empty() {
            self.out.push('\n');
        } else {
            let _ = write!(self.out, " (\n{pad}    {}\n{pad})\n", meta.join(&format!("\n{pad}    ")));
        }
        let _ = writeln!(self.out, "{pad}{{");
        let all = matches!(type_name.as_deref(), None | Some("BasisCurves"));
        for prop in self.names(s, "properties")? {
            if all || prop.starts_with("xformOp") {
                if let Some(a) = self.child(s, &prop, true) {
                    self.attribute(a, &prop, &pad)?;
                }
            }
        }
        for c in self.names(s, "primChildren")? {
            if let Some(k) = self.child(s, &c, false) {
                self.prim(k, &c, depth + 1)?;
            }
        }
        let _ = writeln!(self.out, "{pad}}}");
        Ok(())
    }

    fn attribute(&mut self, s: usize, name: &str, pad: &str) -> Result<(), ErrorKind> {
        if SpecKind::of_code(self.u.t.specs[s].2) != SpecKind::Attribute
            || !is_ident(name, true)
            || !self.done.insert(s)
        {
            return Ok(());
        }
        let Some(ty) = self.field(s, "typeName")?.and_then(|v| v.as_text().map(str::to_string)) else { return Ok(()) };
        if !is_ident(ty.strip_suffix("[]").unwrap_or(&ty), false) {
            return Ok(());
        }
        let mut head = String::new();
        if let Some(Value::Num { nums: Nums::I(c), .. }) = self.field(s, "custom")? {
            if c.first().is_some_and(|&c| c != 0) {
                head.push_str("custom ");
            }
        }
        if let Some(Value::Variability(1)) = self.field(s, "variability")? {
            head.push_str("uniform ");
        }
        let _ = write!(head, "{ty} {name}");
        let mut meta = Vec::new();
        if let Some(i) = self.field(s, "interpolation")?.as_ref().and_then(Value::as_text) {
            meta.push(format!("interpolation = {}", quoted(i)));
        }
        if let Some(Value::Num { nums: Nums::I(n), array: false, .. }) = self.field(s, "elementSize")? {
            meta.push(format!("elementSize = {}", n[0]));
        }
        if let Some(d) = self.field(s, "documentation")?.as_ref().and_then(Value::as_text) {
            meta.push(format!("doc = {}", quoted(d)));
        }
        let value = self.field(s, "default")?.as_ref().and_then(value_text);
        let samples = self.field(s, "timeSamples")?.as_ref().and_then(value_text);
        // A bare declaration says nothing a time-sampled statement does not.
        if value.is_none() && meta.is_empty() && samples.is_some() {
            let _ = writeln!(self.out, "{pad}    {head}.timeSamples = {}", samples.unwrap_or_default());
            return Ok(());
        }
        let _ = write!(self.out, "{pad}    {head}");
        if let Some(v) = value {
            let _ = write!(self.out, " = {v}");
        }
        // Metadata indented as for a prim at the layer's top, whatever the
        // depth: a primvar's text is then the same wherever its prim sat.
        if !meta.is_empty() {
            let _ = write!(self.out, " (\n        {}\n    )", meta.join("\n        "));
        }
        self.out.push('\n');
        if let Some(samples) = samples {
            let _ = writeln!(self.out, "{pad}    {head}.timeSamples = {samples}");
        }
        Ok(())
    }
}

/// The layer of a decoded crate file as text (module notes).
pub(super) fn layer_text(u: &Unpacker) -> Result<String, ErrorKind> {
    let t = u.t;
    let mut index = HashMap::new();
    let mut root = None;
    for (s, &(path, _, kind)) in t.specs.iter().enumerate() {
        let Some(Some(node)) = t.path_nodes.get(path as usize) else { continue };
        let n = t.nodes[*node as usize];
        if n.parent == NO_PARENT {
            if SpecKind::of_code(kind) == SpecKind::PseudoRoot {
                root.get_or_insert(s);
            }
            continue;
        }
        index.insert((n.parent, u.token(n.token)?, n.property), s);
    }
    let root = root.ok_or_else(|| corrupt("crate file has no layer (pseudo-root) spec"))?;
    let mut w = Writer { u, index, done: HashSet::new(), out: String::new() };
    w.layer(root)?;
    Ok(w.out)
}
