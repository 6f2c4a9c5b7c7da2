//! Specs to a crate file: values first (each array or large value at an
//! 8-byte aligned offset, small ones inlined in their representation),
//! then the structural sections (tokens, strings, fields, field sets,
//! paths, specs; compressed as version 0.4.0 and later have them), the
//! table of contents, and the bootstrap header pointing at it. Arrays are
//! written uncompressed, which every reader takes.

use std::collections::HashMap;

use super::codec::{compress, write_ints};
use super::toc::{bootstrap, write_toc, Section, BOOTSTRAP_LEN, TIME_CODE_VERSION, WRITE_VERSION};
use super::value::{code, Comp, NumType, Nums, Shape, Spec, TextKind, Value};

const ARRAY: u64 = 1 << 63;
const INLINED: u64 = 1 << 62;

/// Interned tokens and strings, and the growing file.
struct Packer {
    out: Vec<u8>,
    tokens: Vec<String>,
    token_index: HashMap<String, u32>,
    strings: Vec<u32>,
    string_index: HashMap<u32, u32>,
}

fn rep(kind: u8, flags: u64, payload: u64) -> u64 {
    flags | ((kind as u64) << 48) | (payload & ((1 << 48) - 1))
}

/// `x` if it is exactly an `i8`.
fn small(x: f64) -> Option<i8> {
    (x >= -128.0 && x <= 127.0 && x.fract() == 0.0).then_some(x as i8)
}

impl Packer {
    fn token(&mut self, t: &str) -> u32 {
        if let Some(&i) = self.token_index.get(t) {
            return i;
        }
        let i = self.tokens.len() as u32;
        self.tokens.push(t.to_string());
        self.token_index.insert(t.to_string(), i);
        i
    }

    fn string(&mut self, s: &str) -> u32 {
        let t = self.token(s);
        if let Some(&i) = self.string_index.get(&t) {
            return i;
        }
        let i = self.strings.len() as u32;
        self.strings.push(t);
        self.string_index.insert(t, i);
        i
    }

    /// Pads the file to a multiple of 8 and returns the offset.
    fn align(&mut self) -> u64 {
        self.out.resize(self.out.len().next_multiple_of(8), 0);
        self.out.len() as u64
    }

    fn nums(&mut self, comp: Comp, nums: &Nums) {
        let o = &mut self.out;
        match nums {
            Nums::F(v) => {
                for &x in v {
                    match comp {
                        Comp::Half => o.extend_from_slice(&half::f16::from_f64(x).to_bits().to_le_bytes()),
                        Comp::Float => o.extend_from_slice(&(x as f32).to_le_bytes()),
                        _ => o.extend_from_slice(&x.to_le_bytes()),
                    }
                }
            }
            Nums::I(v) => {
                for &x in v {
                    o.extend_from_slice(&x.to_le_bytes()[..comp.size()]);
                }
            }
            Nums::U(v) => {
                for &x in v {
                    o.extend_from_slice(&x.to_le_bytes()[..comp.size()]);
                }
            }
        }
    }

    /// The inlined 32 bits of a scalar, vector or diagonal matrix, if it
    /// can be inlined.
    fn inline(ty: NumType, nums: &Nums) -> Option<u32> {
        match (ty.shape, nums) {
            // Readers decode an inlined time code as zero: never inline one.
            (Shape::TimeCode, _) => None,
            (Shape::Scalar, Nums::F(v)) => match ty.comp {
                Comp::Half => Some(half::f16::from_f64(v[0]).to_bits() as u32),
                Comp::Float => Some((v[0] as f32).to_bits()),
                _ => ((v[0] as f32) as f64 == v[0]).then(|| (v[0] as f32).to_bits()),
            },
            (Shape::Scalar, Nums::I(v)) => match ty.comp {
                Comp::Int64 => i32::try_from(v[0]).ok().map(|x| x as u32),
                Comp::Bool => Some((v[0] != 0) as u32),
                _ => Some(v[0] as u32),
            },
            (Shape::Scalar, Nums::U(v)) => u32::try_from(v[0]).ok(),
            (Shape::Vec(n), _) => {
                let c: Vec<f64> = match nums {
                    Nums::F(v) => v.clone(),
                    Nums::I(v) => v.iter().map(|&x| x as f64).collect(),
                    Nums::U(v) => v.iter().map(|&x| x as f64).collect(),
                };
                let mut b = [0u8; 4];
                for k in 0..n {
                    b[k] = small(c[k])? as u8;
                }
                Some(u32::from_le_bytes(b))
            }
            (Shape::Matrix(n), Nums::F(v)) => {
                let mut b = [0u8; 4];
                for k in 0..n * n {
                    if k / n == k % n {
                        b[k / n] = small(v[k])? as u8;
                    } else if v[k] != 0.0 {
                        return None;
                    }
                }
                Some(u32::from_le_bytes(b))
            }
            _ => None,
        }
    }

    /// Writes `v` (if it is not inlined) and returns its representation.
    fn value(&mut self, v: &Value) -> Result<u64, String> {
        Ok(match v {
            Value::Num { ty, array: true, nums } => {
                if nums.len() == 0 {
                    return Ok(rep(ty.code(), ARRAY, 0));
                }
                let at = self.align();
                self.out.extend_from_slice(&((nums.len() / ty.shape.components()) as u64).to_le_bytes());
                self.nums(ty.comp, nums);
                rep(ty.code(), ARRAY, at)
            }
            Value::Num { ty, array: false, nums } => match Self::inline(*ty, nums) {
                Some(bits) => rep(ty.code(), INLINED, bits as u64),
                None => {
                    let at = self.align();
                    self.nums(ty.comp, nums);
                    rep(ty.code(), 0, at)
                }
            },
            Value::Text { kind, array: false, items } => {
                let s = items.first().map_or("", String::as_str);
                let i = if *kind == TextKind::String { self.string(s) } else { self.token(s) };
                rep(kind.code(), INLINED, i as u64)
            }
            Value::Text { kind, array: true, items } => {
                let idx: Vec<u32> = items
                    .iter()
                    .map(|s| if *kind == TextKind::Token { self.token(s) } else { self.string(s) })
                    .collect();
                if idx.is_empty() {
                    return Ok(rep(kind.code(), ARRAY, 0));
                }
                let at = self.index_list(&idx);
                rep(kind.code(), ARRAY, at)
            }
            Value::Tokens(t) => {
                let idx: Vec<u32> = t.iter().map(|s| self.token(s)).collect();
                rep(code::TOKEN_VECTOR, 0, self.index_list(&idx))
            }
            Value::Strings(t) => {
                let idx: Vec<u32> = t.iter().map(|s| self.string(s)).collect();
                rep(code::STRING_VECTOR, 0, self.index_list(&idx))
            }
            Value::Doubles(d) => rep(code::DOUBLE_VECTOR, 0, self.doubles(d)),
            Value::Specifier(s) => rep(code::SPECIFIER, INLINED, *s as u64),
            Value::Variability(s) => rep(code::VARIABILITY, INLINED, *s as u64),
            Value::Block => rep(code::VALUE_BLOCK, INLINED, 0),
            Value::Samples(s) => self.samples(s)?,
            other => return Err(format!("a crate file cannot be given {other:?} here")),
        })
    }

    /// A `u64` count and `u32` indices; returns their offset.
    fn index_list(&mut self, idx: &[u32]) -> u64 {
        let at = self.align();
        self.out.extend_from_slice(&(idx.len() as u64).to_le_bytes());
        for i in idx {
            self.out.extend_from_slice(&i.to_le_bytes());
        }
        at
    }

    fn doubles(&mut self, d: &[f64]) -> u64 {
        let at = self.align();
        self.out.extend_from_slice(&(d.len() as u64).to_le_bytes());
        for x in d {
            self.out.extend_from_slice(&x.to_le_bytes());
        }
        at
    }

    /// Writes an `i64` placeholder at an aligned offset, runs `body`, then
    /// points the placeholder (relative to itself) at where the file ends.
    fn forward(&mut self, body: impl FnOnce(&mut Self) -> Result<(), String>) -> Result<(), String> {
        let at = self.align() as usize;
        self.out.extend_from_slice(&0i64.to_le_bytes());
        body(self)?;
        let end = self.out.len();
        self.out[at..at + 8].copy_from_slice(&((end - at) as i64).to_le_bytes());
        Ok(())
    }

    /// Time samples: an offset to the times' representation, then an
    /// offset to the count and representations of the values.
    fn samples(&mut self, s: &[(f64, Value)]) -> Result<u64, String> {
        let at = self.align();
        let times: Vec<f64> = s.iter().map(|x| x.0).collect();
        let mut times_rep = 0;
        self.forward(|p| {
            times_rep = rep(code::DOUBLE_VECTOR, 0, p.doubles(&times));
            Ok(())
        })?;
        self.out.extend_from_slice(&times_rep.to_le_bytes());
        let mut reps = Vec::new();
        self.forward(|p| {
            for (_, v) in s {
                reps.push(p.value(v)?);
            }
            Ok(())
        })?;
        self.out.extend_from_slice(&(reps.len() as u64).to_le_bytes());
        for r in reps {
            self.out.extend_from_slice(&r.to_le_bytes());
        }
        Ok(rep(code::TIME_SAMPLES, 0, at))
    }
}

/// Whether `v` is or holds a time code.
fn has_time_code(v: &Value) -> bool {
    match v {
        Value::Num { ty, .. } => ty.shape == Shape::TimeCode,
        Value::Samples(s) => s.iter().any(|(_, v)| has_time_code(v)),
        _ => false,
    }
}

/// A path's parent and last element (`None` for the root).
fn split(path: &str) -> Option<(&str, &str, bool)> {
    if path == "/" {
        return None;
    }
    if let Some((parent, prop)) = path.rsplit_once('.') {
        return Some((parent, prop, true));
    }
    let (parent, name) = path.rsplit_once('/')?;
    Some((if parent.is_empty() { "/" } else { parent }, name, false))
}

/// The coded path tree of `paths` (every parent listed before its
/// children): path indexes, element tokens (negative for properties) and
/// jumps, in depth-first order.
fn path_tree(p: &mut Packer, paths: &[String]) -> (Vec<i32>, Vec<i32>, Vec<i32>) {
    let mut children: Vec<Vec<usize>> = vec![Vec::new(); paths.len()];
    let mut element = vec![0i32; paths.len()];
    let position: HashMap<&str, usize> = paths.iter().enumerate().map(|(i, s)| (s.as_str(), i)).collect();
    for (i, path) in paths.iter().enumerate() {
        if let Some((parent, name, property)) = split(path) {
            let t = p.token(name) as i32;
            element[i] = if property { -t } else { t };
            if let Some(&k) = position.get(parent) {
                children[k].push(i);
            }
        }
    }
    let (mut index, mut elems, mut jumps) = (Vec::new(), Vec::new(), Vec::new());
    // (path, is last of its siblings), depth first.
    fn visit(
        i: usize,
        last: bool,
        children: &[Vec<usize>],
        element: &[i32],
        out: (&mut Vec<i32>, &mut Vec<i32>, &mut Vec<i32>),
    ) {
        let (index, elems, jumps) = out;
        let me = index.len();
        index.push(i as i32);
        elems.push(element[i]);
        jumps.push(0);
        let kids = &children[i];
        for (k, &c) in kids.iter().enumerate() {
            visit(c, k + 1 == kids.len(), children, element, (&mut *index, &mut *elems, &mut *jumps));
        }
        jumps[me] = match (!kids.is_empty(), !last) {
            (true, true) => (index.len() - me) as i32,
            (false, true) => 0,
            (true, false) => -1,
            (false, false) => -2,
        };
    }
    visit(0, true, &children, &element, (&mut index, &mut elems, &mut jumps));
    (index, elems, jumps)
}

/// Encodes `specs` (the pseudo-root `/` first, every prim before its
/// properties and children) as a crate file.
pub(super) fn pack(specs: &[Spec]) -> Result<Vec<u8>, String> {
    let mut p = Packer {
        out: vec![0; BOOTSTRAP_LEN],
        tokens: Vec::new(),
        token_index: HashMap::new(),
        strings: Vec::new(),
        string_index: HashMap::new(),
    };
    // Token 0 is the root's empty element, so no property token is 0 (a
    // property is coded as a negated token index).
    p.token("");
    let mut fields: Vec<(u32, u64)> = Vec::new();
    let mut field_sets: Vec<i32> = Vec::new();
    let mut spec_rows = Vec::new();
    for (i, s) in specs.iter().enumerate() {
        let set = field_sets.len() as i32;
        for (name, v) in &s.fields {
            let r = p.value(v)?;
            let f = (p.token(name), r);
            field_sets.push(fields.len() as i32);
            fields.push(f);
        }
        field_sets.push(-1);
        spec_rows.push((i as i32, set, s.kind.code() as i32));
    }
    let paths: Vec<String> = specs.iter().map(|s| s.path.clone()).collect();
    let (index, elems, jumps) = path_tree(&mut p, &paths);
    let mut sections = Vec::new();
    let mut section = |p: &mut Packer, name: &str, body: &dyn Fn(&mut Vec<u8>)| {
        let start = p.out.len();
        body(&mut p.out);
        sections.push(Section { name: name.into(), start, size: p.out.len() - start });
    };
    let chars: Vec<u8> = p.tokens.iter().flat_map(|t| t.bytes().chain([0])).collect();
    let n_tokens = p.tokens.len() as u64;
    section(&mut p, "TOKENS", &|o| {
        let packed = compress(&chars);
        for x in [n_tokens, chars.len() as u64, packed.len() as u64] {
            o.extend_from_slice(&x.to_le_bytes());
        }
        o.extend_from_slice(&packed);
    });
    let strings = p.strings.clone();
    section(&mut p, "STRINGS", &|o| {
        o.extend_from_slice(&(strings.len() as u64).to_le_bytes());
        strings.iter().for_each(|s| o.extend_from_slice(&s.to_le_bytes()));
    });
    section(&mut p, "FIELDS", &|o| {
        o.extend_from_slice(&(fields.len() as u64).to_le_bytes());
        write_ints(o, &fields.iter().map(|f| f.0 as i32).collect::<Vec<_>>());
        let reps: Vec<u8> = fields.iter().flat_map(|f| f.1.to_le_bytes()).collect();
        let packed = compress(&reps);
        o.extend_from_slice(&(packed.len() as u64).to_le_bytes());
        o.extend_from_slice(&packed);
    });
    section(&mut p, "FIELDSETS", &|o| {
        o.extend_from_slice(&(field_sets.len() as u64).to_le_bytes());
        write_ints(o, &field_sets);
    });
    section(&mut p, "PATHS", &|o| {
        o.extend_from_slice(&(paths.len() as u64).to_le_bytes());
        o.extend_from_slice(&(index.len() as u64).to_le_bytes());
        write_ints(o, &index);
        write_ints(o, &elems);
        write_ints(o, &jumps);
    });
    section(&mut p, "SPECS", &|o| {
        o.extend_from_slice(&(spec_rows.len() as u64).to_le_bytes());
        write_ints(o, &spec_rows.iter().map(|s| s.0).collect::<Vec<_>>());
        write_ints(o, &spec_rows.iter().map(|s| s.1).collect::<Vec<_>>());
        write_ints(o, &spec_rows.iter().map(|s| s.2).collect::<Vec<_>>());
    });
    let toc = p.out.len() as u64;
    write_toc(&mut p.out, &sections);
    let version = if specs.iter().flat_map(|s| &s.fields).any(|(_, v)| has_time_code(v)) {
        TIME_CODE_VERSION
    } else {
        WRITE_VERSION
    };
    p.out[..BOOTSTRAP_LEN].copy_from_slice(&bootstrap(version, toc));
    Ok(p.out)
}
