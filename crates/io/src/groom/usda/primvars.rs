//! The primvars of a layer's curves that [`Strand`](crate::groom::Strand)
//! does not hold, kept as text so the writer can put them back unchanged.
//!
//! Every `primvars:*` attribute of the `BasisCurves` prims the reader drew
//! strands from is kept, except `primvars:displayColor` and
//! `primvars:widths` (and their `:indices`), which become the strands'
//! colours and widths and are written from those. With one curves prim each
//! primvar's statements (declaration, `.timeSamples`, `.connect`, with all
//! their metadata) are copied verbatim: the strands keep that prim's curves,
//! in order, so every interpolation still means the same thing. With
//! several prims, which the reader concatenates into one groom, a primvar is
//! merged when every prim declares it once, the same way (type, qualifiers,
//! metadata), with an array value: `uniform`, `vertex` and `varying` arrays
//! are concatenated in prim order, a `constant` one is kept when all prims
//! give the same value. What cannot be kept is listed, with why, in
//! [`UsdPrimvars::dropped`] rather than written wrongly: a primvar missing on
//! some prims, declared differently, constant with different values,
//! time-sampled or indexed across prims, and `varying` on cubic curves
//! (one value per segment end, which has no meaning on the linear curves the
//! writer writes).

use super::curves::CurvesPrim;
use super::lexer::{tokenize, Tok};
use super::parse::Attr;

/// One primvar of the input layer, as text.
#[derive(Clone, Debug, PartialEq)]
pub struct UsdPrimvar {
    /// The attribute's name, `primvars:` included.
    pub name: String,
    /// The declared type, e.g. `float[]` or `color3f[]` (empty if no
    /// statement declares one).
    pub type_name: String,
    /// The `interpolation` metadata, if authored (USD's default is
    /// `constant`).
    pub interpolation: Option<String>,
    /// The statements that declare it, one after the other, as they stood
    /// in the layer (or as merged from several prims): what the writer
    /// writes, indented, into the curves prim.
    pub declaration: String,
}

/// The primvars of a text USD layer's curves that [`Groom`](crate::groom::Groom)
/// does not hold (module notes), read by
/// [`read_usda_curves_file`](crate::groom::read_usda_curves_file) and
/// written back by
/// [`write_usda_curves_with`](crate::groom::write_usda_curves_with).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct UsdPrimvars {
    /// Points per curve of the layer they were read from, in the groom's
    /// strand order: the writer refuses to put them on other curves.
    pub curve_points: Vec<usize>,
    /// The primvars kept, in the order the layer declares them.
    pub primvars: Vec<UsdPrimvar>,
    /// One line per primvar found but not kept, saying why.
    pub dropped: Vec<String>,
    /// The layer's `upAxis` (`"Y"` or `"Z"`), if it declares one. The
    /// reader returns points in the layer's own axes, so a layer written
    /// back with them must say the same axis, or a z-up groom stands on its
    /// back in the DCC.
    pub up_axis: Option<String>,
    /// The layer's `metersPerUnit`, if it declares one (points are kept in
    /// the layer's units, so the writer says the same units).
    pub meters_per_unit: Option<f64>,
    /// Files of the input's `.usdz` package that its asset-valued primvars
    /// name (the path as the primvar writes it, and the bytes), so that a
    /// package written with these primvars can carry them too.
    pub files: Vec<(String, Vec<u8>)>,
}

/// Primvars the reader turns into strand attributes; the writer writes
/// those from the strands.
pub(super) const HELD: [&str; 4] =
    ["primvars:displayColor", "primvars:displayColor:indices", "primvars:widths", "primvars:widths:indices"];

/// `primvars:foo` of `primvars:foo.timeSamples` (primvar names hold no dot).
fn base_name(name: &str) -> &str {
    name.split_once('.').map_or(name, |(base, _)| base)
}

/// One prim's statements of one primvar.
struct Group<'a> {
    name: &'a str,
    attrs: Vec<&'a Attr>,
}

impl Group<'_> {
    fn interpolation(&self) -> Option<&str> {
        self.attrs.iter().find_map(|a| a.interpolation.as_deref())
    }

    fn type_name(&self) -> String {
        self.attrs.iter().find_map(|a| a.type_name.clone()).unwrap_or_default()
    }
}

/// A prim's primvars not in [`HELD`], grouped by name in declaration order.
fn groups<'a>(c: &CurvesPrim<'a>) -> Vec<Group<'a>> {
    let mut out: Vec<Group<'a>> = Vec::new();
    for a in &c.prim.attrs {
        let name = base_name(&a.name);
        if !name.starts_with("primvars:") || HELD.contains(&name) {
            continue;
        }
        match out.iter_mut().find(|g| g.name == name) {
            Some(g) => g.attrs.push(a),
            None => out.push(Group { name, attrs: vec![a] }),
        }
    }
    out
}

/// `text` with every run of whitespace made one space, for comparing
/// declarations written in different styles.
fn normalized(text: &str) -> String {
    text.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// The elements of an array value's text `[a, b, ...]`, each as written;
/// `None` if it is not an array.
fn array_elements(text: &str) -> Option<Vec<&str>> {
    let toks = tokenize(text).ok()?;
    let (first, last) = (toks.first()?, toks.last()?);
    if first.tok != Tok::Punct('[') || last.tok != Tok::Punct(']') || toks.len() < 2 {
        return None;
    }
    let mut out = Vec::new();
    let mut depth = 0usize;
    let mut start: Option<usize> = None;
    let mut end = 0;
    for t in &toks[1..toks.len() - 1] {
        match t.tok {
            Tok::Punct(',') if depth == 0 => {
                out.push(&text[start.take()?..end]);
                continue;
            }
            Tok::Punct('(' | '[' | '{') => depth += 1,
            Tok::Punct(')' | ']' | '}') => depth = depth.checked_sub(1)?,
            _ => {}
        }
        start.get_or_insert(t.span.start);
        end = t.span.end;
    }
    if let Some(s) = start {
        out.push(&text[s..end]);
    }
    (depth == 0).then_some(out)
}

/// The primvars of the curves prims `read` (module notes); `texts` are the
/// layers they were parsed from (each attribute names its own).
pub(crate) fn gather(texts: &[String], read: &[CurvesPrim]) -> UsdPrimvars {
    let curve_points = read.iter().flat_map(|c| c.counts.iter().copied()).collect();
    let mut kept = UsdPrimvars { curve_points, ..Default::default() };
    let per_prim: Vec<Vec<Group>> = read.iter().map(groups).collect();
    let drop = |kept: &mut UsdPrimvars, name: &str, why: String| {
        kept.dropped.push(format!("{name} is not kept: {why}"));
    };

    if let ([c], [groups]) = (read, per_prim.as_slice()) {
        for g in groups {
            if varying_on_cubic(g, c) {
                drop(&mut kept, g.name, CUBIC.into());
                continue;
            }
            kept.primvars.push(UsdPrimvar {
                name: g.name.to_string(),
                type_name: g.type_name(),
                interpolation: g.interpolation().map(str::to_string),
                declaration: g.attrs.iter().map(|a| &texts[a.layer][a.span.clone()]).collect::<Vec<_>>().join("\n"),
            });
        }
        return kept;
    }

    // Several prims: every name in order of first appearance.
    let mut names: Vec<&str> = Vec::new();
    for g in per_prim.iter().flatten() {
        if !names.contains(&g.name) {
            names.push(g.name);
        }
    }
    let indexed = |name: &str| {
        let base = name.strip_suffix(":indices").unwrap_or(name);
        let indices = format!("{base}:indices");
        names.iter().any(|n| *n == indices)
    };
    for &name in &names {
        let found: Vec<(&Group, &CurvesPrim)> = per_prim
            .iter()
            .zip(read)
            .filter_map(|(groups, c)| groups.iter().find(|g| g.name == name).map(|g| (g, c)))
            .collect();
        if found.len() != read.len() {
            drop(&mut kept, name, format!("declared on {} of the {} curves prims", found.len(), read.len()));
            continue;
        }
        match merge(texts, name, &found, indexed(name)) {
            Ok(primvar) => kept.primvars.push(primvar),
            Err(why) => drop(&mut kept, name, why),
        }
    }
    kept
}

/// Why a primvar of cubic curves is dropped when it is varying.
const CUBIC: &str = "varying on cubic curves (one value per segment end) means nothing on the linear curves \
                     nst3d writes";

fn varying_on_cubic(g: &Group, c: &CurvesPrim) -> bool {
    c.cubic && g.interpolation() == Some("varying")
}

/// The primvar `name` of several curves prims merged into one declaration
/// (`found`: its group on each prim; `indexed`: it has indices), or why it
/// is not kept.
fn merge(texts: &[String], name: &str, found: &[(&Group, &CurvesPrim)], indexed: bool) -> Result<UsdPrimvar, String> {
    if indexed {
        return Err("indexed primvars of several curves prims are not merged".into());
    }
    let single: Option<Vec<&Attr>> =
        found.iter().map(|(g, _)| (g.attrs.len() == 1 && g.attrs[0].name == name).then_some(g.attrs[0])).collect();
    let Some(attrs) = single.filter(|a| a.iter().all(|a| a.value_span.is_some())) else {
        return Err("time-sampled, connected or declared more than once on several curves prims".into());
    };
    if found.iter().any(|(g, c)| varying_on_cubic(g, c)) {
        return Err(CUBIC.into());
    }
    // Each statement's text lies in the layer it was read from.
    let span = |a: &Attr, r: &std::ops::Range<usize>| &texts[a.layer][r.clone()];
    let slice = |a: &Attr, r: &Option<std::ops::Range<usize>>| r.as_ref().map_or("", |r| span(a, r));
    let head = normalized(span(attrs[0], &attrs[0].head));
    let meta = normalized(slice(attrs[0], &attrs[0].meta_span));
    if attrs.iter().any(|a| normalized(span(a, &a.head)) != head || normalized(slice(a, &a.meta_span)) != meta) {
        return Err("the curves prims declare it differently".into());
    }
    let (group, _) = found[0];
    let interpolation = group.interpolation().map(str::to_string);
    let declaration = if matches!(interpolation.as_deref(), None | Some("constant")) {
        let value = normalized(slice(attrs[0], &attrs[0].value_span));
        if attrs.iter().any(|a| normalized(slice(a, &a.value_span)) != value) {
            return Err("constant, with different values on different curves prims".into());
        }
        span(attrs[0], &attrs[0].span).to_string()
    } else {
        let Some(elements) =
            attrs.iter().map(|a| array_elements(slice(a, &a.value_span))).collect::<Option<Vec<Vec<&str>>>>()
        else {
            return Err("not an array on every curves prim".into());
        };
        let mut d = format!("{} = [{}]", span(attrs[0], &attrs[0].head), elements.concat().join(", "));
        if let Some(m) = &attrs[0].meta_span {
            d.push(' ');
            d.push_str(span(attrs[0], m));
        }
        d
    };
    Ok(UsdPrimvar { name: name.to_string(), type_name: group.type_name(), interpolation, declaration })
}
