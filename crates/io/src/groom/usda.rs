//! Text USD (`.usda`) `BasisCurves`: a small reader for the subset grooms
//! use and a writer of one clean curves layer.
//!
//! The reader parses the whole layer (prims, attributes, metadata, time
//! samples) and gathers every *defined* `BasisCurves` prim in file order
//! (`def` specifiers only: `over`/`class` subtrees and prims with
//! `active = false` are not drawn by USD either, so they are skipped).
//! Per prim: `curveVertexCounts` and `points` (required), `widths` or
//! `primvars:widths` and `primvars:displayColor` with their `interpolation`
//! (constant, uniform, varying, vertex). When an attribute only has
//! `.timeSamples`, the earliest sample is used. Transforms: the
//! `xformOpOrder` of the prim and all its ancestors is applied, with
//! translate, scale, rotateX/Y/Z, rotateXYZ (and the other five orders),
//! orient and transform ops, `!resetXformStack!`, and `!invert!` on
//! translate (the pivot idiom). Other inverted ops are refused as
//! unsupported rather than silently ignored. Widths are not scaled by the
//! transform. Not read: composition (references, payloads, sublayers,
//! inherits), `variantSet` blocks (skipped), normals, `upAxis` and
//! `metersPerUnit` (points are returned in the layer's own axes and units).
//! `type`, `basis` and `wrap` only matter for mapping `varying` primvars;
//! the points are kept as the prim's control points whatever the basis.

use std::fmt::Write as _;
use std::path::Path;

use super::bytes::{corrupt, FormatError};
use super::{read_file, Groom, GroomError, Strand};

/// Reads every defined `BasisCurves` prim of a text USD layer into one
/// groom (see the module notes for what is and is not applied).
pub fn read_usda_curves(path: &Path) -> Result<Groom, GroomError> {
    let bytes = read_file(path)?;
    read_usda_curves_bytes(path, &bytes)
}

/// [`read_usda_curves`] on bytes in memory; `path` only names them in errors.
pub fn read_usda_curves_bytes(path: &Path, bytes: &[u8]) -> Result<Groom, GroomError> {
    let groom = parse(bytes).map_err(|e| GroomError::from_format(path, e))?;
    groom.validate_for(path)?;
    Ok(groom)
}

// ---------------------------------------------------------------- tokens

#[derive(Clone, Debug, PartialEq)]
enum Tok {
    Ident(String),
    Num(f64),
    Str(String),
    /// `</a/b>` prim or property path.
    Path(String),
    /// `@file@` asset path.
    Asset(String),
    Punct(char),
}

fn tokenize(text: &str) -> Result<Vec<(Tok, usize)>, FormatError> {
    let b = text.as_bytes();
    let mut toks = Vec::new();
    let mut i = 0;
    let mut line = 1;
    while i < b.len() {
        let c = b[i];
        match c {
            b'\n' => {
                line += 1;
                i += 1;
            }
            c if c.is_ascii_whitespace() => i += 1,
            b'#' => {
                while i < b.len() && b[i] != b'\n' {
                    i += 1;
                }
            }
            b'"' | b'\'' => {
                let triple = b.len() >= i + 3 && b[i + 1] == c && b[i + 2] == c;
                let q = if triple { 3 } else { 1 };
                let start_line = line;
                let mut j = i + q;
                let mut s = Vec::new();
                loop {
                    if j >= b.len() {
                        return Err(corrupt(format!("line {start_line}: unterminated string")));
                    }
                    if b[j] == b'\\' && j + 1 < b.len() {
                        let e = b[j + 1];
                        s.push(match e {
                            b'n' => b'\n',
                            b't' => b'\t',
                            other => other,
                        });
                        j += 2;
                        continue;
                    }
                    if b[j] == c && (!triple || (j + 2 < b.len() && b[j + 1] == c && b[j + 2] == c)) {
                        j += q;
                        break;
                    }
                    if b[j] == b'\n' {
                        if !triple {
                            return Err(corrupt(format!("line {start_line}: newline in string")));
                        }
                        line += 1;
                    }
                    s.push(b[j]);
                    j += 1;
                }
                toks.push((Tok::Str(String::from_utf8_lossy(&s).into_owned()), start_line));
                i = j;
            }
            b'<' => {
                let end = b[i..]
                    .iter()
                    .position(|&x| x == b'>')
                    .ok_or_else(|| corrupt(format!("line {line}: unterminated path")))?;
                toks.push((Tok::Path(text[i + 1..i + end].to_string()), line));
                i += end + 1;
            }
            b'@' => {
                let (open, close) = if b[i..].starts_with(b"@@@") { (3, "@@@") } else { (1, "@") };
                let rest = &text[i + open..];
                let end = rest.find(close).ok_or_else(|| corrupt(format!("line {line}: unterminated asset path")))?;
                toks.push((Tok::Asset(rest[..end].to_string()), line));
                i += open + end + close.len();
            }
            b'(' | b')' | b'[' | b']' | b'{' | b'}' | b'=' | b',' | b':' | b';' => {
                toks.push((Tok::Punct(c as char), line));
                i += 1;
            }
            c if c.is_ascii_digit()
                || ((c == b'-' || c == b'+' || c == b'.')
                    && b.get(i + 1).is_some_and(|d| d.is_ascii_digit() || *d == b'.' || *d == b'i' || *d == b'n')) =>
            {
                let mut j = i + 1;
                while j < b.len() && (b[j].is_ascii_alphanumeric() || matches!(b[j], b'.' | b'+' | b'-')) {
                    j += 1;
                }
                let s = &text[i..j];
                let v: f64 = s.parse().map_err(|_| corrupt(format!("line {line}: bad number '{s}'")))?;
                toks.push((Tok::Num(v), line));
                i = j;
            }
            c if c.is_ascii_alphabetic() || c == b'_' || c == b'!' => {
                let mut j = i + 1;
                while j < b.len() && (b[j].is_ascii_alphanumeric() || matches!(b[j], b'_' | b':' | b'.' | b'!')) {
                    j += 1;
                }
                let s = &text[i..j];
                let tok = match s {
                    "inf" => Tok::Num(f64::INFINITY),
                    "nan" => Tok::Num(f64::NAN),
                    _ => Tok::Ident(s.to_string()),
                };
                toks.push((tok, line));
                i = j;
            }
            _ => {
                return Err(corrupt(format!(
                    "line {line}: unexpected character {:?}",
                    text[i..].chars().next().unwrap_or('?')
                )))
            }
        }
    }
    Ok(toks)
}

// ---------------------------------------------------------------- values

#[derive(Clone, Debug, PartialEq)]
enum Val {
    Num(f64),
    Str(String),
    Ident(String),
    /// Tuples and arrays alike.
    List(Vec<Val>),
    /// `timeSamples` dictionaries: `(time, value)`.
    Samples(Vec<(f64, Val)>),
    /// Anything the curves reader never looks at (paths, assets, dicts).
    Other,
}

impl Val {
    fn as_f64(&self) -> Option<f64> {
        match self {
            Val::Num(x) => Some(*x),
            _ => None,
        }
    }

    fn as_str(&self) -> Option<&str> {
        match self {
            Val::Str(s) | Val::Ident(s) => Some(s),
            _ => None,
        }
    }

    fn as_list(&self) -> Option<&[Val]> {
        match self {
            Val::List(v) => Some(v),
            _ => None,
        }
    }

    fn as_vec3(&self) -> Option<[f64; 3]> {
        match self.as_list()? {
            [a, b, c] => Some([a.as_f64()?, b.as_f64()?, c.as_f64()?]),
            _ => None,
        }
    }
}

/// Nesting limit, so hostile input cannot overflow the stack.
const MAX_DEPTH: usize = 64;

struct Parser {
    toks: Vec<(Tok, usize)>,
    i: usize,
}

/// An attribute: value (if authored) and its `interpolation` metadata.
#[derive(Debug)]
struct Attr {
    name: String,
    value: Option<Val>,
    interpolation: Option<String>,
}

#[derive(Debug)]
struct Prim {
    specifier: String,
    type_name: Option<String>,
    name: String,
    active: bool,
    attrs: Vec<Attr>,
    children: Vec<Prim>,
}

impl Prim {
    /// Authored default value of `name`, else its earliest time sample.
    fn value(&self, name: &str) -> Option<&Val> {
        if let Some(v) = self.attrs.iter().rev().find(|a| a.name == name).and_then(|a| a.value.as_ref()) {
            return Some(v);
        }
        let ts = format!("{name}.timeSamples");
        match self.attrs.iter().rev().find(|a| a.name == ts)?.value.as_ref()? {
            Val::Samples(s) => s.iter().min_by(|a, b| a.0.total_cmp(&b.0)).map(|(_, v)| v),
            _ => None,
        }
    }

    fn interpolation(&self, name: &str) -> Option<&str> {
        self.attrs
            .iter()
            .rev()
            .find(|a| a.name == name && a.interpolation.is_some())
            .and_then(|a| a.interpolation.as_deref())
    }
}

impl Parser {
    fn line(&self) -> usize {
        self.toks.get(self.i).or(self.toks.last()).map_or(0, |t| t.1)
    }

    fn peek(&self) -> Option<&Tok> {
        self.toks.get(self.i).map(|t| &t.0)
    }

    fn peek_at(&self, k: usize) -> Option<&Tok> {
        self.toks.get(self.i + k).map(|t| &t.0)
    }

    fn next(&mut self) -> Result<Tok, FormatError> {
        let t = self.toks.get(self.i).map(|t| t.0.clone()).ok_or(FormatError::Truncated {
            what: "USD layer (ends inside a block)",
            offset: self.toks.last().map_or(0, |t| t.1),
            needed: 1,
        })?;
        self.i += 1;
        Ok(t)
    }

    fn err(&self, what: impl std::fmt::Display) -> FormatError {
        corrupt(format!("line {}: {what}", self.line()))
    }

    fn expect(&mut self, c: char) -> Result<(), FormatError> {
        match self.next()? {
            Tok::Punct(p) if p == c => Ok(()),
            other => {
                self.i -= 1;
                Err(self.err(format!("expected '{c}', found {other:?}")))
            }
        }
    }

    fn is_punct(&self, c: char) -> bool {
        self.peek() == Some(&Tok::Punct(c))
    }

    /// Skips one token, or a whole bracketed group if it opens one.
    fn skip_item(&mut self, depth: usize) -> Result<(), FormatError> {
        if depth > MAX_DEPTH {
            return Err(self.err("nesting too deep"));
        }
        let close = match self.next()? {
            Tok::Punct('(') => ')',
            Tok::Punct('[') => ']',
            Tok::Punct('{') => '}',
            _ => return Ok(()),
        };
        while !self.is_punct(close) {
            self.skip_item(depth + 1)?;
        }
        self.i += 1;
        Ok(())
    }

    fn value(&mut self, depth: usize) -> Result<Val, FormatError> {
        if depth > MAX_DEPTH {
            return Err(self.err("nesting too deep"));
        }
        match self.next()? {
            Tok::Num(x) => Ok(Val::Num(x)),
            Tok::Str(s) => Ok(Val::Str(s)),
            Tok::Ident(s) => Ok(Val::Ident(s)),
            Tok::Path(_) | Tok::Asset(_) => Ok(Val::Other),
            Tok::Punct(open @ ('(' | '[')) => {
                let close = if open == '(' { ')' } else { ']' };
                let mut items = Vec::new();
                loop {
                    if self.is_punct(close) {
                        self.i += 1;
                        break;
                    }
                    items.push(self.value(depth + 1)?);
                    if self.is_punct(',') {
                        self.i += 1;
                    } else if !self.is_punct(close) {
                        return Err(self.err(format!("expected ',' or '{close}' in list")));
                    }
                }
                Ok(Val::List(items))
            }
            Tok::Punct('{') => {
                // timeSamples: `{ time: value, ... }`; any other dictionary
                // is skipped whole.
                let start = self.i - 1;
                let mut samples = Vec::new();
                loop {
                    if self.is_punct('}') {
                        self.i += 1;
                        return Ok(Val::Samples(samples));
                    }
                    match (self.peek(), self.peek_at(1)) {
                        (Some(Tok::Num(t)), Some(Tok::Punct(':'))) => {
                            let t = *t;
                            self.i += 2;
                            let v = self.value(depth + 1)?;
                            samples.push((t, v));
                            if self.is_punct(',') {
                                self.i += 1;
                            }
                        }
                        _ => {
                            self.i = start;
                            self.skip_item(depth)?;
                            return Ok(Val::Other);
                        }
                    }
                }
            }
            other => Err(self.err(format!("expected a value, found {other:?}"))),
        }
    }

    /// `( key = value ... )` metadata; returns the `(key, value)` pairs it
    /// could read (list-edit forms like `prepend apiSchemas = [...]` are
    /// read under their key name).
    fn metadata(&mut self, depth: usize) -> Result<Vec<(String, Val)>, FormatError> {
        self.expect('(')?;
        let mut out = Vec::new();
        while !self.is_punct(')') {
            match (self.peek().cloned(), self.peek_at(1).cloned()) {
                (Some(Tok::Ident(k)), Some(Tok::Punct('='))) => {
                    self.i += 2;
                    let v = self.value(depth + 1)?;
                    out.push((k, v));
                }
                (Some(Tok::Ident(q)), Some(Tok::Ident(k)))
                    if matches!(q.as_str(), "prepend" | "append" | "add" | "delete" | "reorder")
                        && self.peek_at(2) == Some(&Tok::Punct('=')) =>
                {
                    self.i += 3;
                    let v = self.value(depth + 1)?;
                    out.push((k, v));
                }
                (None, _) => {
                    self.next()?;
                }
                _ => self.skip_item(depth + 1)?,
            }
            if self.is_punct(';') || self.is_punct(',') {
                self.i += 1;
            }
        }
        self.i += 1;
        Ok(out)
    }

    /// `def|over|class [Type] "name" [(meta)] { body }`.
    fn prim(&mut self, depth: usize) -> Result<Prim, FormatError> {
        if depth > MAX_DEPTH {
            return Err(self.err("prims nested too deep"));
        }
        let specifier = match self.next()? {
            Tok::Ident(s) => s,
            _ => return Err(self.err("expected def, over or class")),
        };
        let type_name = match self.peek() {
            Some(Tok::Ident(t)) => {
                let t = t.clone();
                self.i += 1;
                Some(t)
            }
            _ => None,
        };
        let name = match self.next()? {
            Tok::Str(s) => s,
            other => return Err(self.err(format!("expected a prim name string, found {other:?}"))),
        };
        let mut active = true;
        if self.is_punct('(') {
            for (k, v) in self.metadata(depth)? {
                if k == "active" && v.as_str() == Some("false") {
                    active = false;
                }
            }
        }
        self.expect('{')?;
        let mut prim = Prim { specifier, type_name, name, active, attrs: Vec::new(), children: Vec::new() };
        self.body(&mut prim, depth)?;
        Ok(prim)
    }

    /// Statements up to and including the closing `}`.
    fn body(&mut self, prim: &mut Prim, depth: usize) -> Result<(), FormatError> {
        loop {
            match self.peek() {
                Some(Tok::Punct('}')) => {
                    self.i += 1;
                    return Ok(());
                }
                Some(Tok::Punct(';')) => self.i += 1,
                Some(Tok::Ident(k)) if matches!(k.as_str(), "def" | "over" | "class") => {
                    let child = self.prim(depth + 1)?;
                    prim.children.push(child);
                }
                Some(Tok::Ident(k)) if k == "variantSet" => {
                    // `variantSet "name" = { "a" { ... } ... }`: skipped.
                    self.i += 1;
                    self.next()?;
                    self.expect('=')?;
                    self.skip_item(depth + 1)?;
                }
                Some(Tok::Ident(_)) => {
                    let attr = self.attribute(depth)?;
                    prim.attrs.push(attr);
                }
                None => {
                    self.next()?;
                }
                Some(other) => return Err(self.err(format!("unexpected {other:?} in prim body"))),
            }
        }
    }

    /// `[qualifiers] type[[]] name [= value] [(meta)]`, or `[qualifier]
    /// name = value` for list edits like `reorder nameChildren = [...]`.
    fn attribute(&mut self, depth: usize) -> Result<Attr, FormatError> {
        while let Some(Tok::Ident(q)) = self.peek() {
            if matches!(
                q.as_str(),
                "uniform" | "custom" | "varying" | "config" | "prepend" | "append" | "delete" | "add" | "reorder"
            ) && matches!(self.peek_at(1), Some(Tok::Ident(_)))
            {
                self.i += 1;
            } else {
                break;
            }
        }
        let first = match self.next()? {
            Tok::Ident(s) => s,
            _ => return Err(self.err("expected an attribute")),
        };
        let name = if self.is_punct('=') {
            first
        } else {
            if self.is_punct('[') {
                self.i += 1;
                self.expect(']')?;
            }
            match self.next()? {
                Tok::Ident(s) => s,
                other => return Err(self.err(format!("expected an attribute name after '{first}', found {other:?}"))),
            }
        };
        let mut attr = Attr { name, value: None, interpolation: None };
        if self.is_punct('=') {
            self.i += 1;
            attr.value = Some(self.value(depth + 1)?);
        }
        if self.is_punct('(') {
            for (k, v) in self.metadata(depth)? {
                if k == "interpolation" {
                    attr.interpolation = v.as_str().map(str::to_string);
                }
            }
        }
        Ok(attr)
    }
}

// ---------------------------------------------------------------- transforms

/// Column-vector affine transform (`p' = M p`).
type Mat4 = [[f64; 4]; 4];

const IDENTITY: Mat4 = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]];

fn mul(a: &Mat4, b: &Mat4) -> Mat4 {
    let mut c = [[0.0; 4]; 4];
    for i in 0..4 {
        for j in 0..4 {
            c[i][j] = (0..4).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    c
}

fn translate(t: [f64; 3]) -> Mat4 {
    let mut m = IDENTITY;
    for a in 0..3 {
        m[a][3] = t[a];
    }
    m
}

fn scale(s: [f64; 3]) -> Mat4 {
    let mut m = IDENTITY;
    for a in 0..3 {
        m[a][a] = s[a];
    }
    m
}

/// Right-handed rotation by `deg` degrees about axis 0, 1 or 2.
fn rotate(axis: usize, deg: f64) -> Mat4 {
    let (s, c) = deg.to_radians().sin_cos();
    let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
    let mut m = IDENTITY;
    m[u][u] = c;
    m[u][v] = -s;
    m[v][u] = s;
    m[v][v] = c;
    m
}

fn transform_point(m: &Mat4, p: [f32; 3]) -> [f32; 3] {
    let p = [p[0] as f64, p[1] as f64, p[2] as f64];
    let mut out = [0f32; 3];
    for (a, o) in out.iter_mut().enumerate() {
        *o = (m[a][0] * p[0] + m[a][1] * p[1] + m[a][2] * p[2] + m[a][3]) as f32;
    }
    out
}

/// The prim's local transform from its `xformOpOrder`, and whether it
/// resets the inherited stack.
fn local_xform(prim: &Prim) -> Result<(Mat4, bool), FormatError> {
    let Some(order) = prim.value("xformOpOrder") else {
        return Ok((IDENTITY, false));
    };
    let ops = order.as_list().ok_or_else(|| corrupt(format!("prim '{}': xformOpOrder is not a list", prim.name)))?;
    let mut m = IDENTITY;
    let mut reset = false;
    for op in ops {
        let op =
            op.as_str().ok_or_else(|| corrupt(format!("prim '{}': xformOpOrder entry is not a token", prim.name)))?;
        if op == "!resetXformStack!" {
            reset = true;
            m = IDENTITY;
            continue;
        }
        let (inverse, attr) = match op.strip_prefix("!invert!") {
            Some(a) => (true, a),
            None => (false, op),
        };
        let bad = |why: &str| corrupt(format!("prim '{}': {op}: {why}", prim.name));
        let kind = attr.strip_prefix("xformOp:").ok_or_else(|| bad("not an xformOp"))?.split(':').next().unwrap_or("");
        let v = prim.value(attr).ok_or_else(|| bad("op listed but has no value"))?;
        let vec3 = || v.as_vec3().ok_or_else(|| bad("expected 3 numbers"));
        let num = || v.as_f64().ok_or_else(|| bad("expected a number"));
        if inverse && kind != "translate" {
            return Err(FormatError::Unsupported(format!(
                "prim '{}': inverted op {op} (only inverted translates are read)",
                prim.name
            )));
        }
        let op_m = match kind {
            "translate" => {
                let t = vec3()?;
                translate(if inverse { t.map(|x| -x) } else { t })
            }
            "scale" => scale(vec3()?),
            "rotateX" => rotate(0, num()?),
            "rotateY" => rotate(1, num()?),
            "rotateZ" => rotate(2, num()?),
            r if r.len() == 9 && r.starts_with("rotate") => {
                // rotateXYZ applies X first: M = R_Z R_Y R_X.
                let angles = vec3()?;
                let mut rm = IDENTITY;
                for (k, ch) in r[6..].chars().enumerate() {
                    let axis = match ch {
                        'X' => 0,
                        'Y' => 1,
                        'Z' => 2,
                        _ => return Err(bad("unknown rotation order")),
                    };
                    rm = mul(&rotate(axis, angles[k]), &rm);
                }
                rm
            }
            "orient" => {
                let q = match v.as_list() {
                    Some([w, x, y, z]) => [w, x, y, z].map(|c| c.as_f64().unwrap_or(f64::NAN)),
                    _ => return Err(bad("expected a quaternion (w, x, y, z)")),
                };
                let n = q.iter().map(|c| c * c).sum::<f64>().sqrt();
                let [w, x, y, z] = q.map(|c| c / n);
                [
                    [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y), 0.0],
                    [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x), 0.0],
                    [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y), 0.0],
                    [0.0, 0.0, 0.0, 1.0],
                ]
            }
            "transform" => {
                // USD matrices are row-vector (`p' = p M`, translation in the
                // last row): transpose into our column-vector convention.
                let rows = v.as_list().filter(|r| r.len() == 4).ok_or_else(|| bad("expected a 4x4 matrix"))?;
                let mut m4 = IDENTITY;
                for (i, row) in rows.iter().enumerate() {
                    let row = row.as_list().filter(|r| r.len() == 4).ok_or_else(|| bad("expected a 4x4 matrix"))?;
                    for (j, x) in row.iter().enumerate() {
                        m4[j][i] = x.as_f64().ok_or_else(|| bad("expected numbers"))?;
                    }
                }
                m4
            }
            other => return Err(FormatError::Unsupported(format!("prim '{}': xformOp kind '{other}'", prim.name))),
        };
        m = mul(&m, &op_m);
    }
    Ok((m, reset))
}

// ---------------------------------------------------------------- curves

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
fn expand<T: Copy + Lerp>(
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
trait Lerp {
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

fn curves_of(prim: &Prim, world: &Mat4, out: &mut Vec<Strand>) -> Result<(), FormatError> {
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
    Ok(())
}

fn walk(prim: &Prim, parent: &Mat4, out: &mut Vec<Strand>) -> Result<(), FormatError> {
    if prim.specifier != "def" || !prim.active {
        return Ok(());
    }
    let (local, reset) = local_xform(prim)?;
    let world = if reset { local } else { mul(parent, &local) };
    if prim.type_name.as_deref() == Some("BasisCurves") {
        curves_of(prim, &world, out)?;
    }
    for c in &prim.children {
        walk(c, &world, out)?;
    }
    Ok(())
}

fn parse(bytes: &[u8]) -> Result<Groom, FormatError> {
    if !bytes.starts_with(b"#usda ") {
        return Err(corrupt("not a text USD layer (no '#usda' header)"));
    }
    let text = std::str::from_utf8(bytes).map_err(|e| corrupt(format!("USD layer is not UTF-8 ({e})")))?;
    let mut p = Parser { toks: tokenize(text)?, i: 0 };
    if p.is_punct('(') {
        p.metadata(0)?;
    }
    let mut root = Prim {
        specifier: "def".into(),
        type_name: None,
        name: "/".into(),
        active: true,
        attrs: Vec::new(),
        children: Vec::new(),
    };
    while p.peek().is_some() {
        match p.peek() {
            Some(Tok::Ident(k)) if matches!(k.as_str(), "def" | "over" | "class") => {
                let prim = p.prim(0)?;
                root.children.push(prim);
            }
            _ => return Err(p.err("expected a prim (def, over or class) at layer level")),
        }
    }
    let mut strands = Vec::new();
    walk(&root, &IDENTITY, &mut strands)?;
    Ok(Groom { strands })
}

// ---------------------------------------------------------------- writer

/// Writes `groom` as a text USD layer (`upAxis = "Y"`, `defaultPrim =
/// "Groom"`) holding one `BasisCurves` prim `/Groom`.
///
/// `type = "linear"`: our strands are sampled hair polylines (as every
/// supported input format stores them), and linear curves draw exactly those
/// points in any USD renderer, whereas cubic Catmull-Rom would drop the
/// first and last segment unless phantom points were added (`wrap =
/// "pinned"` is not read by every DCC). `widths` (vertex interpolation)
/// are written when every strand has widths, `primvars:displayColor`
/// likewise for colours; `extent` bounds points padded by half the widest
/// width. Floats are printed in shortest round-trip form, so reading the
/// layer back gives the same `f32`s.
pub fn write_usda_curves(path: &Path, groom: &Groom) -> Result<(), GroomError> {
    groom.validate_for(path)?;
    let mut s = String::with_capacity(64 + groom.point_count() * 40);
    let f3 = |s: &mut String, p: &[f32; 3]| {
        let _ = write!(s, "({}, {}, {})", p[0], p[1], p[2]);
    };
    s.push_str("#usda 1.0\n(\n    defaultPrim = \"Groom\"\n    doc = \"Written by nst3d\"\n    upAxis = \"Y\"\n)\n\n");
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
    s.push_str("}\n");
    crate::atomic::write_atomic(path, |w| w.write_all(s.as_bytes()))
        .map_err(|source| GroomError::Write { path: path.into(), source })
}
