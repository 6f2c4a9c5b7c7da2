//! Tokens of a text USD layer: identifiers, numbers, strings, paths, asset
//! paths and punctuation, each with the line it starts on so parse errors
//! can name it, and its byte range so attributes can be copied verbatim.

use crate::bytes::corrupt;
use crate::ErrorKind;

/// One token.
#[derive(Clone, Debug, PartialEq)]
pub(super) enum Tok {
    Ident(String),
    Num(f64),
    Str(String),
    /// `</a/b>` prim or property path.
    Path(String),
    /// `@file@` asset path.
    Asset(String),
    Punct(char),
}

/// A token, the line it starts on and the bytes of the text it spans.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct Token {
    pub(super) tok: Tok,
    pub(super) line: usize,
    pub(super) span: std::ops::Range<usize>,
}

/// Splits a layer into tokens; comments are dropped.
pub(super) fn tokenize(text: &str) -> Result<Vec<Token>, ErrorKind> {
    let b = text.as_bytes();
    let mut toks: Vec<(Tok, usize)> = Vec::new();
    let mut spans = Vec::new();
    let mut i = 0;
    let mut line = 1;
    while i < b.len() {
        let c = b[i];
        let (start, before) = (i, toks.len());
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
                let start_line = line;
                let (s, j) = string(b, i, &mut line)?;
                toks.push((Tok::Str(s), start_line));
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
        if toks.len() > before {
            spans.push(start..i);
        }
    }
    Ok(toks.into_iter().zip(spans).map(|((tok, line), span)| Token { tok, line, span }).collect())
}

/// The string literal (quoted by `'`, `"` or either tripled) starting at
/// `b[i]`: its text, escapes resolved, and the index after it; `line`
/// moves past the newlines of a triple-quoted one.
fn string(b: &[u8], i: usize, line: &mut usize) -> Result<(String, usize), ErrorKind> {
    let (c, start_line) = (b[i], *line);
    let triple = b.len() >= i + 3 && b[i + 1] == c && b[i + 2] == c;
    let q = if triple { 3 } else { 1 };
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
            *line += 1;
        }
        s.push(b[j]);
        j += 1;
    }
    Ok((String::from_utf8_lossy(&s).into_owned(), j))
}
