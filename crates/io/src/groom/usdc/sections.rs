//! The structural sections of a crate file, read into tables: tokens (every
//! name and token in the file), strings (indices of tokens), fields (a name
//! and a value representation each), field sets (runs of field indices, one
//! run per spec), paths (a tree coded as parent/sibling jumps) and specs
//! (path, field set, kind). Version 0.4.0 and later compress all of them.

use super::codec::{decompress, read_ints};
use super::toc::Toc;
use crate::bytes::{corrupt, Reader};
use crate::ErrorKind;

/// Most entries any table may claim: far beyond any groom, small enough
/// that a forged count cannot exhaust memory.
const MAX_ENTRIES: u64 = 1 << 24;

/// No parent: the node is the absolute root.
pub(super) const NO_PARENT: u32 = u32::MAX;

/// One path: its parent (an earlier node, or [`NO_PARENT`]), its last
/// element's token and whether that element is a property name.
#[derive(Clone, Copy, Debug)]
pub(super) struct Node {
    pub(super) parent: u32,
    pub(super) token: u32,
    pub(super) property: bool,
}

/// Every structural table of a crate file.
#[derive(Debug, Default)]
pub(super) struct Tables {
    pub(super) tokens: Vec<String>,
    /// Token index of each string.
    pub(super) strings: Vec<u32>,
    /// (name token index, value representation) of each field.
    pub(super) fields: Vec<(u32, u64)>,
    /// Field indices, each spec's run ended by `u32::MAX`.
    pub(super) field_sets: Vec<u32>,
    /// Path nodes, in coded order: a node's parent always comes first.
    pub(super) nodes: Vec<Node>,
    /// Node of each path index.
    pub(super) path_nodes: Vec<Option<u32>>,
    /// (path index, field set index, spec kind) of each spec.
    pub(super) specs: Vec<(u32, u32, u32)>,
}

/// A count read from a section, bounded by [`MAX_ENTRIES`].
fn count(r: &mut Reader, what: &'static str) -> Result<usize, ErrorKind> {
    let n = r.u64(what)?;
    if n > MAX_ENTRIES {
        return Err(corrupt(format!("{what}: {n} is more than a groom file holds")));
    }
    Ok(n as usize)
}

/// `count` compressed integers at the reader's position, moving past them.
fn ints(r: &mut Reader, count: usize) -> Result<Vec<i32>, ErrorKind> {
    let at = r.pos();
    let rest = r.take(r.remaining(), "compressed integers")?;
    let (v, used) = read_ints::<i32>(rest, count)?;
    r.seek(at + used);
    Ok(v)
}

fn tokens(sec: &[u8]) -> Result<Vec<String>, ErrorKind> {
    let mut r = Reader::new(sec, 0);
    let n = count(&mut r, "token count")?;
    let size = r.u64("tokens size")?;
    let packed = r.u64("tokens compressed size")?;
    let packed = r.take(usize::try_from(packed).unwrap_or(usize::MAX), "compressed tokens")?;
    let chars = decompress(packed, usize::try_from(size).unwrap_or(usize::MAX))?;
    let mut out: Vec<String> = chars
        .split(|&c| c == 0)
        .take(n)
        .map(|t| String::from_utf8(t.to_vec()).map_err(|_| corrupt("a token is not UTF-8")))
        .collect::<Result<_, _>>()?;
    if out.len() < n || !chars.ends_with(&[0]) && n > 0 {
        return Err(corrupt(format!("tokens section holds fewer than its {n} tokens")));
    }
    out.truncate(n);
    Ok(out)
}

fn fields(sec: &[u8]) -> Result<Vec<(u32, u64)>, ErrorKind> {
    let mut r = Reader::new(sec, 0);
    let n = count(&mut r, "field count")?;
    let names = ints(&mut r, n)?;
    let size = r.u64("value reps size")?;
    let packed = r.take(usize::try_from(size).unwrap_or(usize::MAX), "compressed value reps")?;
    let reps = decompress(packed, n * 8)?;
    if reps.len() != n * 8 {
        return Err(corrupt("fields section: value reps do not match the field count"));
    }
    Ok(names
        .iter()
        .zip(reps.chunks_exact(8))
        .map(|(&t, b)| (t as u32, u64::from_le_bytes(b.try_into().expect("8"))))
        .collect())
}

/// Builds the path nodes from the coded tree: each entry names its path
/// index, its element token (negative for a property) and a jump (0: the
/// next entry is a sibling; -1: the next is a child; -2: neither; above 0:
/// the next is a child and the sibling is that many entries on).
fn paths(sec: &[u8]) -> Result<(Vec<Node>, Vec<Option<u32>>), ErrorKind> {
    let mut r = Reader::new(sec, 0);
    let total = count(&mut r, "path count")?;
    let n = count(&mut r, "coded path count")?;
    if total > n + 1 {
        return Err(corrupt(format!("{total} paths but only {n} coded")));
    }
    let (index, element, jump) = (ints(&mut r, n)?, ints(&mut r, n)?, ints(&mut r, n)?);
    let mut nodes = Vec::with_capacity(n);
    let mut path_nodes = vec![None; total];
    if n == 0 {
        return Ok((nodes, path_nodes));
    }
    // (first entry of a run of siblings, their parent node)
    let mut pending = vec![(0usize, NO_PARENT)];
    while let Some((mut i, mut parent)) = pending.pop() {
        loop {
            if i >= n || nodes.len() >= n {
                return Err(corrupt("path tree jumps outside its entries"));
            }
            let here = nodes.len() as u32;
            let e = element[i];
            nodes.push(Node { parent, token: e.unsigned_abs(), property: e < 0 && parent != NO_PARENT });
            let slot = usize::try_from(index[i]).ok().and_then(|k| path_nodes.get_mut(k));
            *slot.ok_or_else(|| corrupt("path index out of range"))? = Some(here);
            let (child, sibling) = (jump[i] > 0 || jump[i] == -1, jump[i] >= 0);
            if child && sibling {
                pending.push((i + jump[i] as usize, parent));
            }
            if child {
                parent = here;
            }
            if !child && !sibling {
                break;
            }
            i += 1;
        }
    }
    Ok((nodes, path_nodes))
}

fn specs(sec: &[u8]) -> Result<Vec<(u32, u32, u32)>, ErrorKind> {
    let mut r = Reader::new(sec, 0);
    let n = count(&mut r, "spec count")?;
    let (p, f, k) = (ints(&mut r, n)?, ints(&mut r, n)?, ints(&mut r, n)?);
    Ok((0..n).map(|i| (p[i] as u32, f[i] as u32, k[i] as u32)).collect())
}

/// Reads every structural section the groom reader needs; a missing one is
/// an empty table.
pub(super) fn read_tables(bytes: &[u8], toc: &Toc) -> Result<Tables, ErrorKind> {
    let mut t = Tables::default();
    if let Some(sec) = toc.section(bytes, "TOKENS") {
        t.tokens = tokens(sec)?;
    }
    if let Some(sec) = toc.section(bytes, "STRINGS") {
        let mut r = Reader::new(sec, 0);
        let n = r.u64("string count")?;
        r.ensure(n, 4, "strings")?;
        t.strings = (0..n).map(|_| r.u32("string")).collect::<Result<_, _>>()?;
    }
    if let Some(sec) = toc.section(bytes, "FIELDS") {
        t.fields = fields(sec)?;
    }
    if let Some(sec) = toc.section(bytes, "FIELDSETS") {
        let mut r = Reader::new(sec, 0);
        let n = count(&mut r, "field set count")?;
        t.field_sets = ints(&mut r, n)?.into_iter().map(|x| x as u32).collect();
    }
    if let Some(sec) = toc.section(bytes, "PATHS") {
        (t.nodes, t.path_nodes) = paths(sec)?;
    }
    if let Some(sec) = toc.section(bytes, "SPECS") {
        t.specs = specs(sec)?;
    }
    Ok(t)
}
