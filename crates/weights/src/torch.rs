//! PyTorch checkpoints: the legacy sequence-of-pickles format and the zip archive format,
//! both resolved to plain f32 tensors by key.

use std::collections::HashMap;
use std::io::Read;

use crate::dtype::{gather, StorageKind};
use crate::pickle::{self, as_str, Arena, Node, NodeId, Problem, Value};
use crate::{TensorData, TensorMap};

/// The first pickle of a legacy file (`torch.serialization.MAGIC_NUMBER`).
const LEGACY_MAGIC: i128 = 0x1950a86a20f9469cfc6c;
/// The second pickle of a legacy file (`PROTOCOL_VERSION`).
const LEGACY_PROTOCOL: i128 = 1001;
/// How deep nested dicts are searched for tensors (`{"state_dict": {...}}` is depth 2).
const MAX_DICT_DEPTH: usize = 32;
/// Visits allowed while collecting tensors: a pickle can share a dict many times
/// (`BINGET`), which would otherwise make the walk exponential in the file size.
const MAX_VISITS: usize = 1 << 20;

/// Byte prefix of a legacy file: `PROTO 2`, `LONG1` of 10 bytes, then the magic number.
pub(crate) const LEGACY_PREFIX: [u8; 14] =
    [0x80, 0x02, 0x8a, 0x0a, 0x6c, 0xfc, 0x9c, 0x46, 0xf9, 0x20, 0x6a, 0xa8, 0x50, 0x19];

/// Raw bytes of each storage by key, with the storage class they were declared with.
type Storages<'a> = HashMap<String, (StorageKind, &'a [u8])>;

/// Reads a legacy (`_use_new_zipfile_serialization=False`) checkpoint.
pub(crate) fn read_legacy(bytes: &[u8]) -> Result<TensorMap, Problem> {
    let mut arena = Arena::default();
    let (magic, pos) = pickle::run(&mut arena, bytes, 0)?;
    if !matches!(magic, Value::Int(LEGACY_MAGIC)) {
        return Err("not a legacy PyTorch file (bad magic number)".into());
    }
    let (protocol, pos) = pickle::run(&mut arena, bytes, pos)?;
    if !matches!(protocol, Value::Int(LEGACY_PROTOCOL)) {
        return Err(format!("unsupported legacy PyTorch protocol {protocol:?}"));
    }
    let (sys_info, pos) = pickle::run(&mut arena, bytes, pos)?;
    if let Some(Node::Dict(entries)) = arena.node(&sys_info) {
        let big_endian =
            entries.iter().any(|(k, v)| as_str(k) == Some("little_endian") && matches!(v, Value::Bool(false)));
        if big_endian {
            return Err("big-endian checkpoints are not supported".into());
        }
    }
    let (root, pos) = pickle::run(&mut arena, bytes, pos)?;
    let (keys, mut pos) = pickle::run(&mut arena, bytes, pos)?;
    let keys = arena.items(&keys).ok_or("storage key list is not a list")?;

    // Each storage's class, from the tensors that reference it: the file itself records
    // only element counts, so the element size must come from the pickle.
    let mut kinds: HashMap<&str, &StorageKind> = HashMap::new();
    for node in &arena.nodes {
        if let Node::Storage(s) = node {
            if let Some(prev) = kinds.insert(s.key.as_str(), &s.kind) {
                if prev != &s.kind {
                    return Err(format!("storage {} is declared as both {} and {}", s.key, prev.name, s.kind.name));
                }
            }
        }
    }
    let mut storages: Storages = HashMap::new();
    for key in keys {
        let key = match key {
            Value::Str(s) => s.to_string(),
            Value::Int(i) => i.to_string(),
            _ => return Err("storage key list holds a non-string".into()),
        };
        let kind = *kinds.get(key.as_str()).ok_or_else(|| format!("storage {key} is listed but never used"))?;
        let count_bytes = bytes.get(pos..pos + 8).ok_or_else(|| format!("file truncated before storage {key}"))?;
        let count = u64::from_le_bytes(count_bytes.try_into().expect("slice of 8 bytes"));
        pos += 8;
        let len = usize::try_from(count)
            .ok()
            .and_then(|c| c.checked_mul(kind.elem_size))
            .filter(|&n| n <= bytes.len() - pos)
            .ok_or_else(|| format!("file truncated in storage {key} ({count} elements of {})", kind.name))?;
        storages.insert(key, (kind.clone(), &bytes[pos..pos + len]));
        pos += len;
    }
    collect(&arena, &root, &storages, bytes.len())
}

/// Reads a zip (default `torch.save`) checkpoint: `<folder>/data.pkl` plus raw storages
/// in `<folder>/data/<key>`; the folder name is whatever the file was called when saved.
pub(crate) fn read_zip(bytes: &[u8]) -> Result<TensorMap, Problem> {
    let mut zip = zip::ZipArchive::new(std::io::Cursor::new(bytes)).map_err(|e| format!("bad zip archive: {e}"))?;
    let prefix = zip
        .file_names()
        .filter_map(Result::ok)
        .find_map(|n| {
            n.strip_suffix("data.pkl").filter(|p| p.ends_with('/') && p.matches('/').count() == 1).map(str::to_string)
        })
        .ok_or("zip archive has no <folder>/data.pkl: not a PyTorch checkpoint")?;

    if let Ok(order) = read_entry(&mut zip, &format!("{prefix}byteorder"), 64) {
        if order != b"little" {
            return Err(format!("unsupported byte order {:?}", String::from_utf8_lossy(&order)));
        }
    }
    let pkl = read_entry(&mut zip, &format!("{prefix}data.pkl"), bytes.len())?;
    let mut arena = Arena::default();
    let (root, _) = pickle::run(&mut arena, &pkl, 0)?;

    let mut owned: HashMap<String, (StorageKind, Vec<u8>)> = HashMap::new();
    for node in &arena.nodes {
        if let Node::Storage(s) = node {
            if let Some((kind, _)) = owned.get(&s.key) {
                if kind != &s.kind {
                    return Err(format!("storage {} is declared as both {} and {}", s.key, kind.name, s.kind.name));
                }
                continue;
            }
            let data = read_entry(&mut zip, &format!("{prefix}data/{}", s.key), bytes.len())?;
            owned.insert(s.key.clone(), (s.kind.clone(), data));
        }
    }
    let storages: Storages =
        owned.iter().map(|(k, (kind, data))| (k.clone(), (kind.clone(), data.as_slice()))).collect();
    collect(&arena, &root, &storages, bytes.len())
}

/// The contents of one archive entry, refusing entries larger than `limit` before
/// allocating (a corrupt header could claim any size).
fn read_entry<R: std::io::Read + std::io::Seek>(
    zip: &mut zip::ZipArchive<R>,
    name: &str,
    limit: usize,
) -> Result<Vec<u8>, Problem> {
    let mut entry = zip.by_name(name).map_err(|e| format!("zip entry {name}: {e}"))?;
    let size = usize::try_from(entry.size())
        .ok()
        .filter(|&s| s <= limit)
        .ok_or_else(|| format!("zip entry {name} claims {} bytes", entry.size()))?;
    let mut data = Vec::with_capacity(size);
    entry.by_ref().take(size as u64 + 1).read_to_end(&mut data).map_err(|e| format!("zip entry {name}: {e}"))?;
    if data.len() != size {
        return Err(format!("zip entry {name} holds {} bytes, its header says {size}", data.len()));
    }
    Ok(data)
}

/// Finds every tensor in the (possibly nested) dicts under `root` and copies it out of
/// its storage. Nested dict keys are joined with `.` (`{"model": {"w": t}}` → `model.w`).
fn collect(arena: &Arena, root: &Value, storages: &Storages, file_len: usize) -> Result<TensorMap, Problem> {
    if !matches!(arena.node(root), Some(Node::Dict(_))) {
        return Err("checkpoint is not a dict of tensors".into());
    }
    let mut found: Vec<(String, NodeId)> = Vec::new();
    let mut todo: Vec<(NodeId, String, usize)> = vec![(node_id(root), String::new(), 0)];
    let mut visits = 0usize;
    while let Some((id, prefix, depth)) = todo.pop() {
        let Node::Dict(entries) = &arena.nodes[id] else {
            continue;
        };
        for (k, v) in entries {
            visits += 1;
            if visits > MAX_VISITS {
                return Err("checkpoint dicts are shared or nested too often to be a state dict".into());
            }
            let Some(k) = as_str(k) else { continue };
            let name = if prefix.is_empty() { k.to_string() } else { format!("{prefix}.{k}") };
            match arena.node(v) {
                Some(Node::Tensor(_)) => found.push((name, node_id(v))),
                Some(Node::Dict(_)) if depth + 1 < MAX_DICT_DEPTH => todo.push((node_id(v), name, depth + 1)),
                _ => {}
            }
        }
    }

    // A tensor may legitimately read more elements than its storage holds (stride 0),
    // but not absurdly more: this bound keeps a crafted file from exhausting memory.
    let budget = file_len.saturating_mul(8).saturating_add(1 << 20);
    let mut total = 0usize;
    let mut map = TensorMap::new();
    for (name, id) in found {
        let tensor = materialize(arena, id, storages).map_err(|e| format!("tensor {name}: {e}"))?;
        total = total.saturating_add(tensor.data.len());
        if total > budget {
            return Err(format!("tensor {name}: tensors hold far more elements than the file could describe"));
        }
        map.insert(name, tensor);
    }
    Ok(map)
}

fn node_id(v: &Value) -> NodeId {
    match v {
        Value::Node(id) => *id,
        _ => unreachable!("only called on container values"),
    }
}

/// Copies one tensor out of its storage after checking that every element it
/// addresses lies inside that storage.
fn materialize(arena: &Arena, id: NodeId, storages: &Storages) -> Result<TensorData, Problem> {
    let Node::Tensor(t) = &arena.nodes[id] else { unreachable!("collect only yields tensors") };
    let Node::Storage(s) = &arena.nodes[t.storage] else { unreachable!("rebuild_tensor checked the storage") };
    let (kind, raw) = storages.get(&s.key).ok_or_else(|| format!("storage {} is missing", s.key))?;
    let dtype = kind.dtype.ok_or_else(|| {
        format!("unsupported storage type torch.{} (only Float, Half, BFloat16 and Double convert to f32)", kind.name)
    })?;
    let stored = raw.len() / kind.elem_size;
    // Legacy storage views: the tensor's storage is a window of the root storage.
    let view_end = match s.view_len {
        Some(len) => {
            s.view_offset.checked_add(len).filter(|&e| e <= stored).ok_or("storage view exceeds its storage")?
        }
        None => stored,
    };
    let offset = s.view_offset.checked_add(t.offset).ok_or("storage offset overflows")?;
    let numel = t.shape.iter().try_fold(1usize, |acc, &n| acc.checked_mul(n)).ok_or("tensor size overflows")?;
    if numel > 0 {
        let last = t
            .shape
            .iter()
            .zip(&t.strides)
            .try_fold(offset, |acc, (&n, &st)| (n - 1).checked_mul(st).and_then(|d| acc.checked_add(d)))
            .ok_or("tensor extent overflows")?;
        if last >= view_end {
            return Err(format!("tensor reads element {last} of a storage with {view_end}"));
        }
    }
    let numel_limit = raw.len().saturating_mul(8).saturating_add(1 << 20);
    if numel > numel_limit {
        return Err(format!("tensor of {numel} elements is implausibly large for its storage"));
    }
    Ok(TensorData { shape: t.shape.clone(), data: gather(dtype, raw, offset, &t.shape, &t.strides) })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Runs a hand-written pickle and collects its tensors (there are no storages).
    fn collect_pickle(p: &[u8]) -> Result<TensorMap, Problem> {
        let mut arena = Arena::default();
        let (root, _) = pickle::run(&mut arena, p, 0)?;
        collect(&arena, &root, &HashMap::new(), p.len())
    }

    fn short_str(p: &mut Vec<u8>, s: &str) {
        p.push(0x8c);
        p.push(s.len() as u8);
        p.extend_from_slice(s.as_bytes());
    }

    #[test]
    fn self_referencing_dict_terminates() {
        // d = {}; d["self"] = d
        let mut p = vec![0x80, 2, b'}', b'q', 0];
        short_str(&mut p, "self");
        p.extend_from_slice(&[b'h', 0, b's', b'.']);
        assert_eq!(collect_pickle(&p).unwrap().len(), 0);
    }

    #[test]
    fn exponentially_shared_dicts_are_refused_quickly() {
        // d_i = {"x": d_{i-1}, "y": d_{i-1}}: 2^30 paths through 31 dicts.
        let mut p = vec![0x80, 2, b'}', b'r', 0, 0, 0, 0];
        for i in 1u32..=30 {
            p.extend_from_slice(b"}(");
            for key in ["x", "y"] {
                short_str(&mut p, key);
                p.push(b'j');
                p.extend_from_slice(&(i - 1).to_le_bytes());
            }
            p.extend_from_slice(b"ur");
            p.extend_from_slice(&i.to_le_bytes());
        }
        p.push(b'.');
        let err = collect_pickle(&p).unwrap_err();
        assert!(err.contains("shared or nested too often"), "{err}");
    }

    #[test]
    fn deep_nesting_neither_recurses_nor_overflows() {
        let mut p = vec![0x80, 2, b')'];
        p.extend(std::iter::repeat_n(0x85u8, 1_000_000)); // TUPLE1, a million deep
        p.push(b'.');
        let err = collect_pickle(&p).unwrap_err();
        assert!(err.contains("not a dict"), "{err}");
    }

    #[test]
    fn tensor_outside_its_storage_is_refused() {
        // A hand-made 2x2 view of a 5-float storage, first one element too far.
        let mut arena = Arena::default();
        let storage = arena.nodes.len();
        arena.nodes.push(Node::Storage(pickle::StorageRef {
            key: "0".into(),
            kind: StorageKind::from_torch_name("FloatStorage").unwrap(),
            view_offset: 0,
            view_len: None,
        }));
        let tensor = arena.nodes.len();
        arena.nodes.push(Node::Tensor(pickle::TensorRef {
            storage,
            offset: 2,
            shape: vec![2, 2],
            strides: vec![2, 1],
        }));
        let raw = [0u8; 20]; // 5 floats; the view needs indices 2..=5
        let storages: Storages =
            [("0".to_string(), (StorageKind::from_torch_name("FloatStorage").unwrap(), &raw[..]))].into();
        let err = materialize(&arena, tensor, &storages).unwrap_err();
        assert!(err.contains("reads element 5 of a storage with 5"), "{err}");
        let ok = pickle::TensorRef { storage, offset: 1, shape: vec![2, 2], strides: vec![2, 1] };
        arena.nodes[tensor] = Node::Tensor(ok);
        assert_eq!(materialize(&arena, tensor, &storages).unwrap().data, [0.0; 4]);
    }
}
