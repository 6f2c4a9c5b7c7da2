//! The layer's structure: prims with their specifier, type, attributes
//! (value, time samples, `interpolation`, and where each attribute's
//! statement lies in the text, so a primvar can be copied verbatim) and
//! children. Only what the curves reader looks at is kept; everything else
//! is parsed and skipped.

use std::ops::Range;

use super::lexer::{tokenize, Tok, Token};
use crate::bytes::corrupt;
use crate::ErrorKind;

/// An attribute or metadata value.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Val {
    Num(f64),
    Str(String),
    Ident(String),
    /// Tuples and arrays alike.
    List(Vec<Val>),
    /// `timeSamples` dictionaries: `(time, value)`.
    Samples(Vec<(f64, Val)>),
    /// `@asset@`.
    Asset(String),
    /// `</prim>` or `</prim.property>`.
    Path(String),
    /// A reference or payload `@asset@</prim>`: layer and prim (a bare
    /// asset or path is an [`Val::Asset`] or [`Val::Path`]).
    Arc(String, String),
    /// Anything the curves reader never looks at (dictionaries).
    Other,
}

impl Val {
    pub(crate) fn as_f64(&self) -> Option<f64> {
        match self {
            Val::Num(x) => Some(*x),
            _ => None,
        }
    }

    pub(crate) fn as_str(&self) -> Option<&str> {
        match self {
            Val::Str(s) | Val::Ident(s) => Some(s),
            _ => None,
        }
    }

    pub(crate) fn as_list(&self) -> Option<&[Val]> {
        match self {
            Val::List(v) => Some(v),
            _ => None,
        }
    }

    pub(crate) fn as_vec3(&self) -> Option<[f64; 3]> {
        match self.as_list()? {
            [a, b, c] => Some([a.as_f64()?, b.as_f64()?, c.as_f64()?]),
            _ => None,
        }
    }
}

/// Nesting limit, so hostile input cannot overflow the stack.
const MAX_DEPTH: usize = 64;

struct Parser {
    toks: Vec<Token>,
    i: usize,
    /// The layer index given to every attribute.
    layer: usize,
}

/// An attribute: value (if authored) and its `interpolation` metadata, and
/// the byte ranges of its statement in the layer's text.
#[derive(Clone, Debug)]
pub(crate) struct Attr {
    pub(crate) name: String,
    pub(crate) value: Option<Val>,
    pub(crate) interpolation: Option<String>,
    /// Declared `uniform`.
    pub(crate) uniform: bool,
    /// Declared `custom`.
    pub(crate) custom: bool,
    /// Every `( key = value )` metadata entry it could read.
    pub(crate) meta: Vec<(String, Val)>,
    /// Which layer of a composed stage the statement comes from (an index
    /// into the texts the spans below point into).
    pub(crate) layer: usize,
    /// The declared type (`float[]`, `color3f`), `None` for a bare
    /// `name = value` statement.
    pub(crate) type_name: Option<String>,
    /// The whole statement, qualifiers to metadata.
    pub(crate) span: Range<usize>,
    /// Qualifiers, type and name.
    pub(super) head: Range<usize>,
    /// The value after `=`, if authored.
    pub(super) value_span: Option<Range<usize>>,
    /// The `( ... )` metadata, if any.
    pub(super) meta_span: Option<Range<usize>>,
}

/// A prim and its subtree.
#[derive(Clone, Debug)]
pub(crate) struct Prim {
    /// `def`, `over` or `class`.
    pub(crate) specifier: String,
    pub(crate) type_name: Option<String>,
    pub(crate) name: String,
    /// The prim's `active` metadata, if authored.
    pub(crate) active: Option<bool>,
    /// Its references and payloads, strongest first: [`Val::Arc`],
    /// [`Val::Asset`] (the layer's default prim) or [`Val::Path`] (a prim of
    /// the same layer).
    pub(crate) arcs: Vec<Val>,
    pub(crate) attrs: Vec<Attr>,
    pub(crate) children: Vec<Prim>,
}

impl Prim {
    /// Authored default value of `name`, else its earliest time sample.
    pub(crate) fn value(&self, name: &str) -> Option<&Val> {
        if let Some(v) = self.attrs.iter().rev().find(|a| a.name == name).and_then(|a| a.value.as_ref()) {
            return Some(v);
        }
        let ts = format!("{name}.timeSamples");
        match self.attrs.iter().rev().find(|a| a.name == ts)?.value.as_ref()? {
            Val::Samples(s) => s.iter().min_by(|a, b| a.0.total_cmp(&b.0)).map(|(_, v)| v),
            _ => None,
        }
    }

    /// The `interpolation` metadata of attribute `name`, if authored.
    pub(crate) fn interpolation(&self, name: &str) -> Option<&str> {
        self.attrs
            .iter()
            .rev()
            .find(|a| a.name == name && a.interpolation.is_some())
            .and_then(|a| a.interpolation.as_deref())
    }
}

impl Parser {
    fn line(&self) -> usize {
        self.toks.get(self.i).or(self.toks.last()).map_or(0, |t| t.line)
    }

    fn peek(&self) -> Option<&Tok> {
        self.toks.get(self.i).map(|t| &t.tok)
    }

    fn peek_at(&self, k: usize) -> Option<&Tok> {
        self.toks.get(self.i + k).map(|t| &t.tok)
    }

    /// Where the next token starts in the text (the end of the text after
    /// the last token).
    fn here(&self) -> usize {
        self.toks.get(self.i).map_or_else(|| self.toks.last().map_or(0, |t| t.span.end), |t| t.span.start)
    }

    /// Where the last consumed token ends in the text.
    fn consumed_end(&self) -> usize {
        self.i.checked_sub(1).and_then(|k| self.toks.get(k)).map_or(0, |t| t.span.end)
    }

    fn next(&mut self) -> Result<Tok, ErrorKind> {
        let t = self.toks.get(self.i).map(|t| t.tok.clone()).ok_or(ErrorKind::Truncated {
            what: "USD layer (ends inside a block)",
            offset: self.toks.last().map_or(0, |t| t.line),
            needed: 1,
        })?;
        self.i += 1;
        Ok(t)
    }

    fn err(&self, what: impl std::fmt::Display) -> ErrorKind {
        corrupt(format!("line {}: {what}", self.line()))
    }

    fn expect(&mut self, c: char) -> Result<(), ErrorKind> {
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
    fn skip_item(&mut self, depth: usize) -> Result<(), ErrorKind> {
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

    fn value(&mut self, depth: usize) -> Result<Val, ErrorKind> {
        if depth > MAX_DEPTH {
            return Err(self.err("nesting too deep"));
        }
        match self.next()? {
            Tok::Num(x) => Ok(Val::Num(x)),
            Tok::Str(s) => Ok(Val::Str(s)),
            Tok::Ident(s) => Ok(Val::Ident(s)),
            Tok::Path(p) => Ok(Val::Path(p)),
            Tok::Asset(a) => match self.peek() {
                Some(Tok::Path(p)) => {
                    let p = p.clone();
                    self.i += 1;
                    Ok(Val::Arc(a, p))
                }
                _ => Ok(Val::Asset(a)),
            },
            Tok::Punct(open @ ('(' | '[')) => {
                let close = if open == '(' { ')' } else { ']' };
                let mut items = Vec::new();
                loop {
                    if self.is_punct(close) {
                        self.i += 1;
                        break;
                    }
                    items.push(self.value(depth + 1)?);
                    // A reference's layer offset or custom data.
                    if self.is_punct('(') {
                        self.skip_item(depth + 1)?;
                    }
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
    fn metadata(&mut self, depth: usize) -> Result<Vec<(String, Val)>, ErrorKind> {
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
    fn prim(&mut self, depth: usize) -> Result<Prim, ErrorKind> {
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
        let (mut active, mut arcs) = (None, Vec::new());
        if self.is_punct('(') {
            for (k, v) in self.metadata(depth)? {
                match (k.as_str(), v) {
                    ("active", v) => active = v.as_str().map(|a| a != "false").or(v.as_f64().map(|x| x != 0.0)),
                    ("references" | "payload", Val::List(items)) => arcs.extend(items),
                    ("references" | "payload", v) => arcs.push(v),
                    _ => {}
                }
            }
        }
        self.expect('{')?;
        let mut prim = Prim { specifier, type_name, name, active, arcs, attrs: Vec::new(), children: Vec::new() };
        self.body(&mut prim, depth)?;
        Ok(prim)
    }

    /// Statements up to and including the closing `}`.
    fn body(&mut self, prim: &mut Prim, depth: usize) -> Result<(), ErrorKind> {
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
    fn attribute(&mut self, depth: usize) -> Result<Attr, ErrorKind> {
        let start = self.here();
        let (mut uniform, mut custom) = (false, false);
        while let Some(Tok::Ident(q)) = self.peek() {
            if matches!(
                q.as_str(),
                "uniform" | "custom" | "varying" | "config" | "prepend" | "append" | "delete" | "add" | "reorder"
            ) && matches!(self.peek_at(1), Some(Tok::Ident(_)))
            {
                uniform |= q == "uniform";
                custom |= q == "custom";
                self.i += 1;
            } else {
                break;
            }
        }
        let first = match self.next()? {
            Tok::Ident(s) => s,
            _ => return Err(self.err("expected an attribute")),
        };
        let (name, type_name) = if self.is_punct('=') {
            (first, None)
        } else {
            let mut type_name = first;
            if self.is_punct('[') {
                self.i += 1;
                self.expect(']')?;
                type_name.push_str("[]");
            }
            match self.next()? {
                Tok::Ident(s) => (s, Some(type_name)),
                other => {
                    return Err(self.err(format!("expected an attribute name after '{type_name}', found {other:?}")))
                }
            }
        };
        let head = start..self.consumed_end();
        let mut attr = Attr {
            name,
            value: None,
            interpolation: None,
            uniform,
            custom,
            meta: Vec::new(),
            layer: self.layer,
            type_name,
            span: head.clone(),
            head,
            value_span: None,
            meta_span: None,
        };
        if self.is_punct('=') {
            self.i += 1;
            let from = self.here();
            attr.value = Some(self.value(depth + 1)?);
            attr.value_span = Some(from..self.consumed_end());
        }
        if self.is_punct('(') {
            let from = self.here();
            attr.meta = self.metadata(depth)?;
            attr.interpolation =
                attr.meta.iter().rev().find(|m| m.0 == "interpolation").and_then(|m| m.1.as_str()).map(str::to_string);
            attr.meta_span = Some(from..self.consumed_end());
        }
        attr.span.end = self.consumed_end();
        Ok(attr)
    }
}

/// Parses a whole layer (header already checked) into a root prim holding
/// the layer's prims as children, and the layer's own `( ... )` metadata
/// (`upAxis`, `metersPerUnit`, ...).
pub(crate) fn layer(text: &str, layer: usize) -> Result<(Prim, Vec<(String, Val)>), ErrorKind> {
    let mut p = Parser { toks: tokenize(text)?, i: 0, layer };
    let meta = if p.is_punct('(') { p.metadata(0)? } else { Vec::new() };
    let mut root = Prim {
        specifier: "def".into(),
        type_name: None,
        name: "/".into(),
        active: None,
        arcs: Vec::new(),
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
    Ok((root, meta))
}

/// The attribute statements of a prim body (`text` as it would stand
/// between a prim's braces), each with its qualifiers, value and metadata.
pub(crate) fn statements(text: &str) -> Result<Vec<Attr>, ErrorKind> {
    Ok(body_prim(text)?.map(|p| p.attrs).unwrap_or_default())
}

/// A prim whose body is `text` (as [`statements`] reads it), for
/// [`Prim::value`]'s default-else-earliest-sample rule.
pub(crate) fn body_prim(text: &str) -> Result<Option<Prim>, ErrorKind> {
    let (mut root, _) = layer(&format!("def \"P\"\n{{\n{text}\n}}\n"), 0)?;
    Ok(root.children.pop())
}
