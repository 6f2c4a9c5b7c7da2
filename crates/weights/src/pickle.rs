//! A small pickle virtual machine: just enough of Python's pickle protocol (0–5 binary
//! opcodes) to read what `torch.save` writes, and nothing that executes code.
//!
//! Containers live in an arena ([`Arena`]) and values refer to them by index, so that
//! pickles that share (`BINGET`) or even cycle through containers cost no copies, and
//! dropping a deeply nested structure never recurses. Calls (`REDUCE`) are interpreted
//! only for the few torch/collections functions a state dict needs; every other call
//! yields an opaque node that the tensor collector ignores.

use std::collections::HashMap;
use std::rc::Rc;

use crate::dtype::StorageKind;

/// Where a parse failed, as a one-line message (the caller prefixes the file name).
pub(crate) type Problem = String;

/// Index of a [`Node`] in an [`Arena`].
pub(crate) type NodeId = usize;

/// A pickle stack value: scalars inline, containers by arena index.
#[derive(Clone, Debug)]
pub(crate) enum Value {
    None,
    Bool(bool),
    /// Wide enough for the 10-byte legacy magic number; longer `LONG1`/`LONG4` values
    /// become [`Value::BigInt`], which nothing torch needs reads.
    Int(i128),
    BigInt,
    /// Floats and bytes occur in pickles (e.g. hyper-parameters) but never describe
    /// tensors, so only their presence is kept.
    Float,
    Str(Rc<str>),
    Bytes,
    Node(NodeId),
}

/// A storage reference produced by a persistent id (`BINPERSID`).
#[derive(Clone, Debug)]
pub(crate) struct StorageRef {
    /// Key of the raw storage: the legacy root key or the zip entry `data/<key>`.
    pub key: String,
    pub kind: StorageKind,
    /// For legacy storage views: element offset of the view into the root storage and
    /// the view's length; `(0, None)` for a whole storage.
    pub view_offset: usize,
    pub view_len: Option<usize>,
}

/// What `_rebuild_tensor_v2(storage, offset, size, stride, ...)` describes.
#[derive(Clone, Debug)]
pub(crate) struct TensorRef {
    pub storage: NodeId,
    pub offset: usize,
    pub shape: Vec<usize>,
    pub strides: Vec<usize>,
}

/// A container or an interpreted call result.
#[derive(Debug)]
pub(crate) enum Node {
    Tuple(Vec<Value>),
    List(Vec<Value>),
    Dict(Vec<(Value, Value)>),
    Global {
        module: String,
        name: String,
    },
    Storage(StorageRef),
    Tensor(TensorRef),
    /// Result of a call or object construction we do not interpret.
    Opaque,
}

/// All containers created while reading one file (shared by its successive pickles).
#[derive(Debug, Default)]
pub(crate) struct Arena {
    pub nodes: Vec<Node>,
}

impl Arena {
    fn push(&mut self, node: Node) -> Value {
        self.nodes.push(node);
        Value::Node(self.nodes.len() - 1)
    }

    /// The node a value refers to, if it is a container.
    pub fn node(&self, v: &Value) -> Option<&Node> {
        match v {
            Value::Node(id) => self.nodes.get(*id),
            _ => None,
        }
    }

    /// The items of a tuple or list value.
    pub fn items(&self, v: &Value) -> Option<&[Value]> {
        match self.node(v)? {
            Node::Tuple(items) | Node::List(items) => Some(items),
            _ => None,
        }
    }
}

/// Interprets a value as a non-negative size/offset.
pub(crate) fn as_usize(v: &Value) -> Option<usize> {
    match v {
        Value::Int(i) => usize::try_from(*i).ok(),
        Value::Bool(b) => Some(*b as usize),
        _ => None,
    }
}

/// Interprets a value as a string.
pub(crate) fn as_str(v: &Value) -> Option<&str> {
    match v {
        Value::Str(s) => Some(s),
        _ => None,
    }
}

/// Runs one pickle starting at `bytes[start]` until its `STOP`; returns the result and
/// the offset just past the `STOP`. Containers go into `arena`.
pub(crate) fn run(arena: &mut Arena, bytes: &[u8], start: usize) -> Result<(Value, usize), Problem> {
    Vm { arena, bytes, pos: start, stack: Vec::new(), marks: Vec::new(), memo: HashMap::new() }.run()
}

struct Vm<'a> {
    arena: &'a mut Arena,
    bytes: &'a [u8],
    pos: usize,
    stack: Vec<Value>,
    /// Stack heights at each `MARK` (pickle's "metastack").
    marks: Vec<usize>,
    /// A map, not a vector: `LONG_BINPUT` indices are arbitrary u32s.
    memo: HashMap<u32, Value>,
}

impl Vm<'_> {
    fn take(&mut self, n: usize) -> Result<&[u8], Problem> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.bytes.len());
        match end {
            Some(end) => {
                let s = &self.bytes[self.pos..end];
                self.pos = end;
                Ok(s)
            }
            None => Err(format!("pickle truncated at byte {}", self.pos)),
        }
    }

    fn take_array<const N: usize>(&mut self) -> Result<[u8; N], Problem> {
        let s = self.take(N)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }

    fn u8(&mut self) -> Result<u8, Problem> {
        Ok(self.take_array::<1>()?[0])
    }

    fn u32(&mut self) -> Result<u32, Problem> {
        Ok(u32::from_le_bytes(self.take_array()?))
    }

    fn u64_len(&mut self) -> Result<usize, Problem> {
        let n = u64::from_le_bytes(self.take_array()?);
        usize::try_from(n).map_err(|_| format!("pickle length {n} too large at byte {}", self.pos))
    }

    fn line(&mut self) -> Result<String, Problem> {
        let rest = &self.bytes[self.pos..];
        let len = rest
            .iter()
            .position(|&b| b == b'\n')
            .ok_or_else(|| format!("pickle truncated in a GLOBAL at byte {}", self.pos))?;
        let s = String::from_utf8_lossy(&rest[..len]).into_owned();
        self.pos += len + 1;
        Ok(s)
    }

    fn pop(&mut self) -> Result<Value, Problem> {
        let floor = self.marks.last().copied().unwrap_or(0);
        if self.stack.len() <= floor {
            return Err(format!("pickle stack underflow at byte {}", self.pos));
        }
        Ok(self.stack.pop().expect("length checked above"))
    }

    fn top(&mut self) -> Result<&mut Value, Problem> {
        let pos = self.pos;
        self.stack.last_mut().ok_or_else(|| format!("pickle stack empty at byte {pos}"))
    }

    /// Pops everything above the last `MARK` and the mark itself.
    fn pop_mark(&mut self) -> Result<Vec<Value>, Problem> {
        let at = self.marks.pop().ok_or_else(|| format!("pickle MARK missing at byte {}", self.pos))?;
        Ok(self.stack.split_off(at))
    }

    fn str_value(&mut self, n: usize) -> Result<Value, Problem> {
        let s = self.take(n)?;
        Ok(Value::Str(Rc::from(String::from_utf8_lossy(s).as_ref())))
    }

    /// Python 2 `str` payloads are bytes; torch files written under Python 2 use them
    /// for state-dict keys, so they are read as Latin-1 text.
    fn latin1_value(&mut self, n: usize) -> Result<Value, Problem> {
        let s: String = self.take(n)?.iter().map(|&b| b as char).collect();
        Ok(Value::Str(Rc::from(s.as_str())))
    }

    fn bytes_value(&mut self, n: usize) -> Result<Value, Problem> {
        self.take(n)?;
        Ok(Value::Bytes)
    }

    /// Little-endian two's-complement integer of `n` bytes (`LONG1`/`LONG4`).
    fn long_value(&mut self, n: usize) -> Result<Value, Problem> {
        let s = self.take(n)?;
        if n > 16 {
            return Ok(Value::BigInt);
        }
        let mut buf = if s.last().is_some_and(|&b| b & 0x80 != 0) { [0xffu8; 16] } else { [0u8; 16] };
        buf[..n].copy_from_slice(s);
        Ok(Value::Int(i128::from_le_bytes(buf)))
    }

    fn memo_get(&self, idx: u32) -> Result<Value, Problem> {
        self.memo.get(&idx).cloned().ok_or_else(|| format!("pickle memo entry {idx} missing at byte {}", self.pos))
    }

    fn memo_put(&mut self, idx: u32) -> Result<(), Problem> {
        let v = self.top()?.clone();
        self.memo.insert(idx, v);
        Ok(())
    }

    fn container_mut(&mut self, target: &Value, op: &str) -> Result<&mut Node, Problem> {
        let pos = self.pos;
        match target {
            Value::Node(id) => {
                self.arena.nodes.get_mut(*id).ok_or_else(|| format!("pickle {op} on a dangling node at byte {pos}"))
            }
            _ => Err(format!("pickle {op} on a non-container at byte {pos}")),
        }
    }

    fn set_items(&mut self, pairs: Vec<Value>) -> Result<(), Problem> {
        if !pairs.len().is_multiple_of(2) {
            return Err(format!("pickle SETITEMS with an odd item count at byte {}", self.pos));
        }
        let target = self.top()?.clone();
        match self.container_mut(&target, "SETITEM")? {
            Node::Dict(entries) => {
                let mut it = pairs.into_iter();
                while let (Some(k), Some(v)) = (it.next(), it.next()) {
                    entries.push((k, v));
                }
                Ok(())
            }
            // Item assignment on an object we do not model (e.g. a custom class): the
            // items cannot matter for tensors.
            Node::Opaque => Ok(()),
            _ => Err(format!("pickle SETITEM on a non-dict at byte {}", self.pos)),
        }
    }

    fn append_items(&mut self, items: Vec<Value>) -> Result<(), Problem> {
        let target = self.top()?.clone();
        match self.container_mut(&target, "APPEND")? {
            Node::List(list) => {
                list.extend(items);
                Ok(())
            }
            Node::Opaque => Ok(()),
            _ => Err(format!("pickle APPEND on a non-list at byte {}", self.pos)),
        }
    }

    fn run(mut self) -> Result<(Value, usize), Problem> {
        loop {
            let at = self.pos;
            let op = self.u8().map_err(|_| format!("pickle ended without STOP at byte {at}"))?;
            if op == b'.' {
                let v = self.pop()?;
                return Ok((v, self.pos));
            }
            let known = self.stack_op(op)?
                || self.scalar_op(op, at)?
                || self.container_op(op, at)?
                || self.memo_op(op)?
                || self.object_op(op, at)?;
            if !known {
                return Err(format!("unsupported pickle opcode 0x{op:02x} at byte {at}"));
            }
        }
    }

    /// Protocol, framing and stack opcodes: PROTO, FRAME, MARK, POP, POP_MARK, DUP. `false`: not one of them.
    fn stack_op(&mut self, op: u8) -> Result<bool, Problem> {
        match op {
            0x80 => {
                let proto = self.u8()?;
                if proto > 5 {
                    return Err(format!("unsupported pickle protocol {proto}"));
                }
            }
            0x95 => {
                self.take(8)?; // FRAME: a length hint only.
            }
            b'(' => self.marks.push(self.stack.len()),
            b'0' => {
                self.pop()?;
            }
            b'1' => {
                self.pop_mark()?;
            }
            b'2' => {
                let v = self.top()?.clone();
                self.stack.push(v);
            }
            _ => return Ok(false),
        }
        Ok(true)
    }

    /// Opcodes that push a scalar: None, booleans, integers, floats (their value is not kept), strings and bytes. `false`: not one of them.
    fn scalar_op(&mut self, op: u8, at: usize) -> Result<bool, Problem> {
        match op {
            b'N' => self.stack.push(Value::None),
            0x88 => self.stack.push(Value::Bool(true)),
            0x89 => self.stack.push(Value::Bool(false)),
            b'J' => {
                let v = i32::from_le_bytes(self.take_array()?);
                self.stack.push(Value::Int(v.into()));
            }
            b'K' => {
                let v = self.u8()?;
                self.stack.push(Value::Int(v.into()));
            }
            b'M' => {
                let v = u16::from_le_bytes(self.take_array()?);
                self.stack.push(Value::Int(v.into()));
            }
            0x8a => {
                let n = self.u8()? as usize;
                let v = self.long_value(n)?;
                self.stack.push(v);
            }
            0x8b => {
                let n = i32::from_le_bytes(self.take_array()?);
                let n = usize::try_from(n).map_err(|_| format!("negative LONG4 length at byte {at}"))?;
                let v = self.long_value(n)?;
                self.stack.push(v);
            }
            b'G' => {
                self.take(8)?;
                self.stack.push(Value::Float);
            }
            b'X' => {
                let n = self.u32()? as usize;
                let v = self.str_value(n)?;
                self.stack.push(v);
            }
            0x8c => {
                let n = self.u8()? as usize;
                let v = self.str_value(n)?;
                self.stack.push(v);
            }
            0x8d => {
                let n = self.u64_len()?;
                let v = self.str_value(n)?;
                self.stack.push(v);
            }
            b'T' => {
                let n = self.u32()? as usize;
                let v = self.latin1_value(n)?;
                self.stack.push(v);
            }
            b'U' => {
                let n = self.u8()? as usize;
                let v = self.latin1_value(n)?;
                self.stack.push(v);
            }
            b'B' => {
                let n = self.u32()? as usize;
                let v = self.bytes_value(n)?;
                self.stack.push(v);
            }
            b'C' => {
                let n = self.u8()? as usize;
                let v = self.bytes_value(n)?;
                self.stack.push(v);
            }
            0x8e => {
                let n = self.u64_len()?;
                let v = self.bytes_value(n)?;
                self.stack.push(v);
            }
            _ => return Ok(false),
        }
        Ok(true)
    }

    /// Opcodes that build tuples, lists, dicts and sets, or add to them. `false`: not one of them.
    fn container_op(&mut self, op: u8, at: usize) -> Result<bool, Problem> {
        match op {
            b'}' => {
                let v = self.arena.push(Node::Dict(Vec::new()));
                self.stack.push(v);
            }
            b']' | 0x8f => {
                // A set (EMPTY_SET) is kept as a list: only its membership could matter.
                let v = self.arena.push(Node::List(Vec::new()));
                self.stack.push(v);
            }
            b')' => {
                let v = self.arena.push(Node::Tuple(Vec::new()));
                self.stack.push(v);
            }
            b't' => {
                let items = self.pop_mark()?;
                let v = self.arena.push(Node::Tuple(items));
                self.stack.push(v);
            }
            0x85..=0x87 => {
                let n = (op - 0x84) as usize;
                let floor = self.marks.last().copied().unwrap_or(0);
                if self.stack.len() < floor + n {
                    return Err(format!("pickle stack underflow in TUPLE{n} at byte {at}"));
                }
                let items = self.stack.split_off(self.stack.len() - n);
                let v = self.arena.push(Node::Tuple(items));
                self.stack.push(v);
            }
            b'l' => {
                let items = self.pop_mark()?;
                let v = self.arena.push(Node::List(items));
                self.stack.push(v);
            }
            b'd' => {
                let items = self.pop_mark()?;
                let v = self.arena.push(Node::Dict(Vec::new()));
                self.stack.push(v);
                self.set_items(items)?;
            }
            0x91 => {
                // FROZENSET: items after the mark.
                let items = self.pop_mark()?;
                let v = self.arena.push(Node::List(items));
                self.stack.push(v);
            }
            b's' => {
                let v = self.pop()?;
                let k = self.pop()?;
                self.set_items(vec![k, v])?;
            }
            b'u' => {
                let items = self.pop_mark()?;
                self.set_items(items)?;
            }
            b'a' => {
                let v = self.pop()?;
                self.append_items(vec![v])?;
            }
            b'e' | 0x90 => {
                let items = self.pop_mark()?;
                self.append_items(items)?;
            }
            _ => return Ok(false),
        }
        Ok(true)
    }

    /// Memo opcodes: PUT, BINPUT, LONG_BINPUT, MEMOIZE, GET, BINGET, LONG_BINGET. `false`: not one of them.
    fn memo_op(&mut self, op: u8) -> Result<bool, Problem> {
        match op {
            b'q' => {
                let i = self.u8()?;
                self.memo_put(i.into())?;
            }
            b'r' => {
                let i = self.u32()?;
                self.memo_put(i)?;
            }
            0x94 => {
                let i = u32::try_from(self.memo.len()).map_err(|_| "pickle memo overflow".to_string())?;
                self.memo_put(i)?;
            }
            b'h' => {
                let i = self.u8()?;
                let v = self.memo_get(i.into())?;
                self.stack.push(v);
            }
            b'j' => {
                let i = self.u32()?;
                let v = self.memo_get(i)?;
                self.stack.push(v);
            }
            _ => return Ok(false),
        }
        Ok(true)
    }

    /// Opcodes of objects: GLOBAL, STACK_GLOBAL, persistent ids (tensor storages), REDUCE, NEWOBJ, NEWOBJ_EX, BUILD. `false`: not one of them.
    fn object_op(&mut self, op: u8, at: usize) -> Result<bool, Problem> {
        match op {
            b'c' => {
                let module = self.line()?;
                let name = self.line()?;
                let v = self.arena.push(Node::Global { module, name });
                self.stack.push(v);
            }
            0x93 => {
                let name = self.pop()?;
                let module = self.pop()?;
                let (Some(module), Some(name)) = (as_str(&module), as_str(&name)) else {
                    return Err(format!("pickle STACK_GLOBAL without strings at byte {at}"));
                };
                let v = self.arena.push(Node::Global { module: module.to_string(), name: name.to_string() });
                self.stack.push(v);
            }
            b'Q' => {
                let pid = self.pop()?;
                let storage = self.persistent_load(&pid).map_err(|e| format!("{e} (persistent id at byte {at})"))?;
                let v = self.arena.push(Node::Storage(storage));
                self.stack.push(v);
            }
            b'R' => {
                let args = self.pop()?;
                let callable = self.pop()?;
                let v = self.reduce(&callable, &args).map_err(|e| format!("{e} (call at byte {at})"))?;
                self.stack.push(v);
            }
            0x81 => {
                // NEWOBJ: cls.__new__(cls, *args) — opaque.
                self.pop()?;
                self.pop()?;
                let v = self.arena.push(Node::Opaque);
                self.stack.push(v);
            }
            0x92 => {
                self.pop()?;
                self.pop()?;
                self.pop()?;
                let v = self.arena.push(Node::Opaque);
                self.stack.push(v);
            }
            b'b' => {
                // BUILD sets attributes (e.g. an OrderedDict's `_metadata`); tensors
                // never depend on them.
                let _state = self.pop()?;
                self.top()?;
            }

            _ => return Ok(false),
        }
        Ok(true)
    }

    /// Torch's storage persistent id: `('storage', storage_type, key, location, numel)`,
    /// plus a sixth `view_metadata` item (`None` or `(view_key, offset, size)`) in the
    /// legacy format.
    fn persistent_load(&self, pid: &Value) -> Result<StorageRef, Problem> {
        let items = self.arena.items(pid).ok_or("persistent id is not a tuple")?;
        if items.len() < 5 || as_str(&items[0]) != Some("storage") {
            return Err("persistent id is not a torch storage".into());
        }
        let kind = match self.arena.node(&items[1]) {
            Some(Node::Global { module, name }) if module == "torch" => {
                StorageKind::from_torch_name(name).ok_or_else(|| format!("unknown storage type torch.{name}"))?
            }
            Some(Node::Global { module, name }) => return Err(format!("unknown storage type {module}.{name}")),
            _ => return Err("storage type is not a class".into()),
        };
        let key = match &items[2] {
            Value::Str(s) => s.to_string(),
            Value::Int(i) => i.to_string(),
            _ => return Err("storage key is not a string".into()),
        };
        let (view_offset, view_len) = match items.get(5) {
            None | Some(Value::None) => (0, None),
            Some(view) => {
                let v =
                    self.arena.items(view).filter(|v| v.len() == 3).ok_or("storage view metadata is not a 3-tuple")?;
                let off = as_usize(&v[1]).ok_or("storage view offset is not a size")?;
                let len = as_usize(&v[2]).ok_or("storage view size is not a size")?;
                (off, Some(len))
            }
        };
        Ok(StorageRef { key, kind, view_offset, view_len })
    }

    fn reduce(&mut self, callable: &Value, args: &Value) -> Result<Value, Problem> {
        let (module, name) = match self.arena.node(callable) {
            Some(Node::Global { module, name }) => (module.as_str(), name.as_str()),
            _ => return Ok(self.arena.push(Node::Opaque)),
        };
        match (module, name) {
            ("torch._utils", "_rebuild_tensor_v2") | ("torch._utils", "_rebuild_tensor") => {
                let tensor = self.rebuild_tensor(args)?;
                Ok(self.arena.push(Node::Tensor(tensor)))
            }
            ("torch._utils", "_rebuild_parameter") | ("torch._utils", "_rebuild_parameter_with_state") => {
                // A Parameter is its data tensor plus autograd flags.
                let items = self.arena.items(args).ok_or("_rebuild_parameter arguments are not a tuple")?;
                items.first().cloned().ok_or_else(|| "_rebuild_parameter without arguments".to_string())
            }
            ("collections", "OrderedDict") => Ok(self.arena.push(Node::Dict(Vec::new()))),
            _ => Ok(self.arena.push(Node::Opaque)),
        }
    }

    fn rebuild_tensor(&self, args: &Value) -> Result<TensorRef, Problem> {
        let items = self.arena.items(args).ok_or("_rebuild_tensor arguments are not a tuple")?;
        if items.len() < 4 {
            return Err("_rebuild_tensor with fewer than 4 arguments".into());
        }
        let storage = match (&items[0], self.arena.node(&items[0])) {
            (Value::Node(id), Some(Node::Storage(_))) => *id,
            _ => return Err("_rebuild_tensor without a storage".into()),
        };
        let offset = as_usize(&items[1]).ok_or("tensor storage offset is not a size")?;
        let dims = |v: &Value, what: &str| -> Result<Vec<usize>, Problem> {
            let list = self.arena.items(v).ok_or_else(|| format!("tensor {what} is not a tuple"))?;
            list.iter().map(|d| as_usize(d).ok_or_else(|| format!("tensor {what} has a non-size entry"))).collect()
        };
        let shape = dims(&items[2], "size")?;
        let strides = dims(&items[3], "stride")?;
        if shape.len() != strides.len() {
            return Err(format!("tensor has {} sizes but {} strides", shape.len(), strides.len()));
        }
        Ok(TensorRef { storage, offset, shape, strides })
    }
}
