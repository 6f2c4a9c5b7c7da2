//! Value representations to [`Value`]s: a 64-bit word per field holding a
//! type code, flags (array, inlined, compressed) and a 48-bit payload that
//! is either the value itself (small scalars, tokens, string indices,
//! vectors and diagonal matrices of small integers) or the offset of its
//! bytes in the file. Arrays of integers and floats may be compressed
//! (integer coding, or a lookup table of distinct values and coded
//! indices). Dictionaries, time samples and nested values point onwards
//! with relative offsets; nesting is bounded, and so is the number of
//! elements decoded per file, so a forged file cannot loop or balloon.

use std::cell::Cell;

use super::codec::{read_ints, Coded};
use super::sections::{Tables, NO_PARENT};
use super::toc::Toc;
use super::value::{code, Arc, Comp, NumType, Nums, Shape, TextKind, Value};
use crate::bytes::{corrupt, Reader};
use crate::ErrorKind;

const ARRAY: u64 = 1 << 63;
const INLINED: u64 = 1 << 62;
const COMPRESSED: u64 = 1 << 61;
const ARRAY_EDIT: u64 = 1 << 60;
const PAYLOAD: u64 = (1 << 48) - 1;

/// Arrays shorter than this are never compressed.
const MIN_COMPRESSED: usize = 16;

/// Deepest nesting of values in values (dictionaries, time samples).
const MAX_NESTING: usize = 16;

/// Deepest path the reader spells out.
const MAX_PATH_DEPTH: usize = 1024;

/// Decodes value representations of one file.
pub(super) struct Unpacker<'a> {
    pub(super) bytes: &'a [u8],
    pub(super) t: &'a Tables,
    toc: &'a Toc,
    /// Elements (numbers, strings) still allowed to be decoded.
    budget: Cell<usize>,
}

impl<'a> Unpacker<'a> {
    pub(super) fn new(bytes: &'a [u8], t: &'a Tables, toc: &'a Toc) -> Self {
        // Real files store each value once and refer to it from many specs;
        // a groom's decoding stays far below this.
        let budget = bytes.len().saturating_mul(16).saturating_add(1 << 18);
        Unpacker { bytes, t, toc, budget: Cell::new(budget) }
    }

    fn spend(&self, n: usize) -> Result<(), ErrorKind> {
        let left = self.budget.get().checked_sub(n);
        self.budget.set(left.ok_or_else(|| corrupt("the file's values decode to far more data than it holds"))?);
        Ok(())
    }

    pub(super) fn token(&self, i: u32) -> Result<&'a str, ErrorKind> {
        self.t
            .tokens
            .get(i as usize)
            .map(String::as_str)
            .ok_or_else(|| corrupt(format!("token index {i} out of range")))
    }

    pub(super) fn string(&self, i: u32) -> Result<&'a str, ErrorKind> {
        let t = self.t.strings.get(i as usize).ok_or_else(|| corrupt(format!("string index {i} out of range")))?;
        self.token(*t)
    }

    /// The text of path index `i` (`""` for the empty path).
    pub(super) fn path(&self, i: u32) -> Result<String, ErrorKind> {
        let slot = self.t.path_nodes.get(i as usize).ok_or_else(|| corrupt(format!("path index {i} out of range")))?;
        match slot {
            Some(node) => self.node_path(*node),
            None => Ok(String::new()),
        }
    }

    /// The text of the path of node `n`.
    pub(super) fn node_path(&self, mut n: u32) -> Result<String, ErrorKind> {
        let mut chain = Vec::new();
        while let Some(node) = self.t.nodes.get(n as usize).filter(|x| x.parent != NO_PARENT) {
            if chain.len() >= MAX_PATH_DEPTH {
                return Err(corrupt("path nested too deep"));
            }
            chain.push((self.token(node.token)?, node.property));
            n = node.parent;
        }
        let mut s = String::from("/");
        for (k, (name, property)) in chain.iter().rev().enumerate() {
            if *property {
                s.push('.');
            } else if k > 0 && !name.starts_with('{') {
                s.push('/');
            }
            s.push_str(name);
        }
        Ok(s)
    }

    /// A reader at the payload offset of `rep`.
    fn at(&self, rep: u64) -> Result<Reader<'a>, ErrorKind> {
        let off = (rep & PAYLOAD) as usize;
        if off >= self.bytes.len() {
            return Err(corrupt(format!("value offset {off} past the end of the file")));
        }
        Ok(Reader::new(self.bytes, off))
    }

    /// Decodes the value representation `rep`.
    pub(super) fn value(&self, rep: u64, depth: usize) -> Result<Value, ErrorKind> {
        if depth > MAX_NESTING {
            return Err(corrupt("values nested too deep"));
        }
        let kind = ((rep >> 48) & 0xFF) as u8;
        if rep & ARRAY_EDIT != 0 {
            return Ok(Value::Other(kind));
        }
        let array = rep & ARRAY != 0;
        if let Some(ty) = NumType::of_code(kind) {
            return self.number(rep, ty, array);
        }
        let low = (rep & 0xFFFF_FFFF) as u32;
        let text = |k: TextKind| -> Result<Value, ErrorKind> {
            if array {
                return self.text_array(rep, k);
            }
            let s = if k == TextKind::String { self.string(low)? } else { self.token(low)? };
            Ok(Value::Text { kind: k, array: false, items: vec![s.to_string()] })
        };
        match kind {
            code::STRING => text(TextKind::String),
            code::TOKEN => text(TextKind::Token),
            code::ASSET => text(TextKind::Asset),
            code::SPECIFIER => Ok(Value::Specifier(low)),
            code::VARIABILITY => Ok(Value::Variability(low)),
            code::VALUE_BLOCK => Ok(Value::Block),
            code::TOKEN_VECTOR => self.list(rep, |u, i| u.token(i).map(str::to_string)).map(Value::Tokens),
            code::STRING_VECTOR => self.list(rep, |u, i| u.string(i).map(str::to_string)).map(Value::Strings),
            code::PATH_VECTOR => self.list(rep, |u, i| u.path(i)).map(Value::Paths),
            code::DOUBLE_VECTOR => {
                let mut r = self.at(rep)?;
                let n = self.count64(&mut r, 8)?;
                Ok(Value::Doubles((0..n).map(|_| r.f64("doubles")).collect::<Result<_, _>>()?))
            }
            code::REFERENCE_LIST_OP | code::PAYLOAD_LIST_OP => self.arcs(rep, kind == code::REFERENCE_LIST_OP, depth),
            code::PAYLOAD => self.arc(&mut self.at(rep)?, false, depth).map(|a| Value::Arcs(vec![a])),
            code::DICTIONARY if rep & INLINED != 0 => Ok(Value::Dict(Vec::new())),
            code::DICTIONARY => self.dict(&mut self.at(rep)?, depth),
            code::TIME_SAMPLES => self.samples(rep, depth),
            code::VALUE => {
                let mut r = self.at(rep)?;
                let inner = self.nested_rep(&mut r)?;
                self.value(inner, depth + 1)
            }
            other => Ok(Value::Other(other)),
        }
    }

    /// An array length: `u32` before version 0.7.0, `u64` after; checked
    /// against the bytes left for `size`-byte elements unless compressed.
    fn array_len(&self, r: &mut Reader, size: u64) -> Result<usize, ErrorKind> {
        let n = if self.toc.at_least((0, 7, 0)) { r.u64("array length")? } else { r.u32("array length")? as u64 };
        r.ensure(n, size, "array")?;
        Ok(n as usize)
    }

    /// A `u64` count of `size`-byte items, checked against the bytes left.
    fn count64(&self, r: &mut Reader, size: u64) -> Result<usize, ErrorKind> {
        let n = r.u64("count")?;
        r.ensure(n, size, "list")?;
        self.spend(n as usize)?;
        Ok(n as usize)
    }

    /// A list of `u32` indices turned into items by `f`.
    fn list<T>(&self, rep: u64, f: impl Fn(&Self, u32) -> Result<T, ErrorKind>) -> Result<Vec<T>, ErrorKind> {
        let mut r = self.at(rep)?;
        let n = self.count64(&mut r, 4)?;
        (0..n).map(|_| f(self, r.u32("index")?)).collect()
    }

    fn text_array(&self, rep: u64, kind: TextKind) -> Result<Value, ErrorKind> {
        let mut items = Vec::new();
        if rep & PAYLOAD != 0 {
            let mut r = self.at(rep)?;
            if !self.toc.at_least((0, 5, 0)) {
                r.u32("array rank")?;
            }
            let n = self.array_len(&mut r, 4)?;
            self.spend(n)?;
            for _ in 0..n {
                let i = r.u32("text index")?;
                // Token arrays hold token indices; strings and asset paths
                // hold string indices.
                items.push(if kind == TextKind::Token { self.token(i)? } else { self.string(i)? }.to_string());
            }
        }
        Ok(Value::Text { kind, array: true, items })
    }

    /// The representation a nested value's relative offset points to;
    /// leaves the reader after that representation.
    fn nested_rep(&self, r: &mut Reader) -> Result<u64, ErrorKind> {
        let start = r.pos();
        let off = r.i64("nested value offset")?;
        let to = (start as i64).checked_add(off).and_then(|x| usize::try_from(x).ok()).filter(|&x| x < r.len());
        r.seek(to.ok_or_else(|| corrupt("nested value offset out of range"))?);
        r.u64("nested value")
    }
}

/// Decoding of numbers, arcs, dictionaries and time samples.
impl Unpacker<'_> {
    fn number(&self, rep: u64, ty: NumType, array: bool) -> Result<Value, ErrorKind> {
        let n = ty.shape.components();
        let nums = if array {
            if rep & PAYLOAD == 0 {
                empty(ty.comp)
            } else {
                self.num_array(rep, ty)?
            }
        } else if rep & INLINED != 0 || (ty.comp.size() <= 4 && ty.shape == Shape::Scalar) {
            inline(ty, (rep & 0xFFFF_FFFF) as u32).ok_or_else(|| corrupt("a value of this type cannot be inlined"))?
        } else {
            let mut r = self.at(rep)?;
            self.spend(n)?;
            read_nums(&mut r, ty.comp, n)?
        };
        Ok(Value::Num { ty, array, nums })
    }

    fn num_array(&self, rep: u64, ty: NumType) -> Result<Nums, ErrorKind> {
        let mut r = self.at(rep)?;
        if !self.toc.at_least((0, 5, 0)) {
            r.u32("array rank")?;
        }
        let compressed = rep & COMPRESSED != 0 && ty.shape == Shape::Scalar;
        let ints = matches!(ty.comp, Comp::Int | Comp::UInt | Comp::Int64 | Comp::UInt64);
        let can = if ints { self.toc.at_least((0, 5, 0)) } else { ty.comp.is_float() && self.toc.at_least((0, 6, 0)) };
        let per = (ty.comp.size() * ty.shape.components()) as u64;
        let n = self.array_len(&mut r, if compressed && can { 0 } else { per })?;
        self.spend(n.saturating_mul(ty.shape.components()))?;
        if !(compressed && can) || n < MIN_COMPRESSED {
            r.ensure(n as u64, per, "array")?;
            return read_nums(&mut r, ty.comp, n * ty.shape.components());
        }
        let rest = &self.bytes[r.pos()..];
        if ints {
            return Ok(match ty.comp {
                Comp::Int64 | Comp::UInt64 => {
                    let v = read_ints::<i64>(rest, n)?.0;
                    if ty.comp == Comp::UInt64 {
                        Nums::U(v.into_iter().map(|x| x as u64).collect())
                    } else {
                        Nums::I(v)
                    }
                }
                Comp::UInt => Nums::I(read_ints::<i32>(rest, n)?.0.into_iter().map(|x| x as u32 as i64).collect()),
                _ => Nums::I(read_ints::<i32>(rest, n)?.0.into_iter().map(Coded::to_i64).collect()),
            });
        }
        match r.u8("float array code")? {
            b'i' => Ok(Nums::F(read_ints::<i32>(&self.bytes[r.pos()..], n)?.0.into_iter().map(|x| x as f64).collect())),
            b't' => {
                let k = r.u32("lookup table size")? as usize;
                r.ensure(k as u64, ty.comp.size() as u64, "lookup table")?;
                let Nums::F(table) = read_nums(&mut r, ty.comp, k)? else { unreachable!("floats") };
                let idx = read_ints::<i32>(&self.bytes[r.pos()..], n)?.0;
                let look = |i: i32| table.get(i as u32 as usize).copied();
                Ok(Nums::F(idx.into_iter().map(look).collect::<Option<_>>().ok_or_else(|| corrupt("lookup index"))?))
            }
            c => Err(corrupt(format!("unknown float array coding {c:#x}"))),
        }
    }

    /// An `SdfReference` (asset, prim, layer offset, custom data) or an
    /// `SdfPayload` (asset, prim, and from 0.8.0 a layer offset).
    fn arc(&self, r: &mut Reader, reference: bool, depth: usize) -> Result<Arc, ErrorKind> {
        let asset = self.string(r.u32("arc asset")?)?.to_string();
        let prim = self.path(r.u32("arc prim")?)?;
        if reference || self.toc.at_least((0, 8, 0)) {
            r.take(16, "arc layer offset")?;
        }
        if reference {
            self.dict(r, depth + 1)?;
        }
        Ok(Arc { asset, prim })
    }

    /// A reference or payload list operation: the arcs it adds.
    fn arcs(&self, rep: u64, reference: bool, depth: usize) -> Result<Value, ErrorKind> {
        let mut r = self.at(rep)?;
        let bits = r.u8("list op header")?;
        let mut out = Vec::new();
        // Explicit, added, deleted, ordered, prepended, appended items, in
        // the order they are stored; deleted and ordered ones add nothing.
        for (bit, adds) in [(2u8, true), (4, true), (32, true), (64, true), (8, false), (16, false)] {
            if bits & bit != 0 {
                let n = self.count64(&mut r, 8)?;
                for _ in 0..n {
                    let a = self.arc(&mut r, reference, depth)?;
                    if adds {
                        out.push(a);
                    }
                }
            }
        }
        Ok(Value::Arcs(out))
    }

    fn dict(&self, r: &mut Reader, depth: usize) -> Result<Value, ErrorKind> {
        if depth > MAX_NESTING {
            return Err(corrupt("dictionaries nested too deep"));
        }
        let n = self.count64(r, 12)?;
        let mut out = Vec::with_capacity(n);
        for _ in 0..n {
            let key = self.string(r.u32("dictionary key")?)?.to_string();
            let rep = self.nested_rep(r)?;
            out.push((key, self.value(rep, depth + 1)?));
        }
        Ok(Value::Dict(out))
    }

    fn samples(&self, rep: u64, depth: usize) -> Result<Value, ErrorKind> {
        let mut r = self.at(rep)?;
        let times = match self.value(self.nested_rep(&mut r)?, depth + 1)? {
            Value::Doubles(t) => t,
            Value::Num { nums: Nums::F(t), ty, .. } if ty.shape == Shape::Scalar => t,
            _ => return Err(corrupt("time samples: times are not doubles")),
        };
        let start = r.pos();
        let off = r.i64("time sample values offset")?;
        let to = (start as i64).checked_add(off).and_then(|x| usize::try_from(x).ok()).filter(|&x| x < r.len());
        r.seek(to.ok_or_else(|| corrupt("time sample values offset out of range"))?);
        let n = self.count64(&mut r, 8)?;
        if n != times.len() {
            return Err(corrupt(format!("{} sample times but {n} values", times.len())));
        }
        let mut out = Vec::with_capacity(n);
        for t in times {
            out.push((t, self.value(r.u64("time sample value")?, depth + 1)?));
        }
        Ok(Value::Samples(out))
    }
}

fn empty(comp: Comp) -> Nums {
    match comp {
        Comp::UInt64 => Nums::U(Vec::new()),
        c if c.is_float() => Nums::F(Vec::new()),
        _ => Nums::I(Vec::new()),
    }
}

/// `n` components of type `comp` in file order.
fn read_nums(r: &mut Reader, comp: Comp, n: usize) -> Result<Nums, ErrorKind> {
    r.ensure(n as u64, comp.size() as u64, "numbers")?;
    let what = "numbers";
    Ok(match comp {
        Comp::Bool | Comp::UChar => Nums::I(r.take(n, what)?.iter().map(|&b| b as i64).collect()),
        Comp::Int => Nums::I((0..n).map(|_| r.i32(what).map(i64::from)).collect::<Result<_, _>>()?),
        Comp::UInt => Nums::I((0..n).map(|_| r.u32(what).map(i64::from)).collect::<Result<_, _>>()?),
        Comp::Int64 => Nums::I((0..n).map(|_| r.i64(what)).collect::<Result<_, _>>()?),
        Comp::UInt64 => Nums::U((0..n).map(|_| r.u64(what)).collect::<Result<_, _>>()?),
        Comp::Half => {
            Nums::F((0..n).map(|_| r.u16(what).map(|h| half::f16::from_bits(h).to_f64())).collect::<Result<_, _>>()?)
        }
        Comp::Float => Nums::F((0..n).map(|_| r.f32(what).map(f64::from)).collect::<Result<_, _>>()?),
        Comp::Double => Nums::F((0..n).map(|_| r.f64(what)).collect::<Result<_, _>>()?),
    })
}

/// A value stored in the representation's low 32 bits: a scalar of up to
/// 32 bits, a 64-bit scalar that fits 32, or a vector (diagonal matrix) of
/// 8-bit integers.
fn inline(ty: NumType, x: u32) -> Option<Nums> {
    let bytes = x.to_le_bytes();
    let small = |n: usize| bytes[..n].iter().map(|&b| b as i8 as f64).collect::<Vec<f64>>();
    Some(match (ty.shape, ty.comp) {
        (Shape::Scalar | Shape::TimeCode, c) => match c {
            Comp::Bool | Comp::UChar => Nums::I(vec![(x & 0xFF) as i64]),
            Comp::Int | Comp::Int64 => Nums::I(vec![x as i32 as i64]),
            Comp::UInt => Nums::I(vec![x as i64]),
            Comp::UInt64 => Nums::U(vec![x as u64]),
            Comp::Half => Nums::F(vec![half::f16::from_bits(x as u16).to_f64()]),
            Comp::Float | Comp::Double => Nums::F(vec![f32::from_bits(x) as f64]),
        },
        (Shape::Vec(n), Comp::Int) => Nums::I(bytes[..n].iter().map(|&b| b as i8 as i64).collect()),
        (Shape::Vec(n), _) => Nums::F(small(n)),
        (Shape::Matrix(n), _) => {
            let d = small(n);
            Nums::F((0..n * n).map(|k| if k / n == k % n { d[k / n] } else { 0.0 }).collect())
        }
        (Shape::Quat, _) => return None,
    })
}
