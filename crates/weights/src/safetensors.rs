//! The `.safetensors` format: a little-endian u64 header length, a JSON header mapping
//! each name to `{dtype, shape, data_offsets}`, then the raw little-endian data.

use crate::dtype::{gather, DType};
use crate::pickle::Problem;
use crate::{TensorData, TensorMap};

/// Header size limit of the reference implementation; larger is surely corrupt.
const MAX_HEADER: u64 = 100 << 20;

/// True if `bytes` starts like a safetensors file: a plausible header length followed by
/// a JSON object.
pub(crate) fn looks_like(bytes: &[u8]) -> bool {
    header_len(bytes).is_some_and(|n| bytes[8..8 + n].first() == Some(&b'{'))
}

fn header_len(bytes: &[u8]) -> Option<usize> {
    let n = u64::from_le_bytes(bytes.get(..8)?.try_into().ok()?);
    let n = usize::try_from(n).ok().filter(|&n| n as u64 <= MAX_HEADER)?;
    (n <= bytes.len() - 8).then_some(n)
}

/// The `__metadata__` string map of a safetensors file (empty if it has none).
pub(crate) fn metadata(bytes: &[u8]) -> Result<std::collections::BTreeMap<String, String>, Problem> {
    let n = header_len(bytes).ok_or("safetensors header length exceeds the file")?;
    let header: serde_json::Map<String, serde_json::Value> =
        serde_json::from_slice(&bytes[8..8 + n]).map_err(|e| format!("bad safetensors header: {e}"))?;
    let mut out = std::collections::BTreeMap::new();
    if let Some(meta) = header.get("__metadata__") {
        let meta = meta.as_object().ok_or("__metadata__ is not an object")?;
        for (k, v) in meta {
            let v = v.as_str().ok_or_else(|| format!("metadata {k} is not a string"))?;
            out.insert(k.clone(), v.to_string());
        }
    }
    Ok(out)
}

/// A safetensors file of F32 tensors (in `tensors`' order) with string
/// metadata, as the reference implementation lays it out: the header padded
/// with spaces to a multiple of 8 bytes, then the data.
pub(crate) fn write(
    tensors: &[(&str, &[usize], &[f32])],
    metadata: &std::collections::BTreeMap<String, String>,
) -> Vec<u8> {
    let mut header = serde_json::Map::new();
    if !metadata.is_empty() {
        let meta = metadata.iter().map(|(k, v)| (k.clone(), serde_json::Value::from(v.as_str()))).collect();
        header.insert("__metadata__".into(), serde_json::Value::Object(meta));
    }
    let mut offset = 0usize;
    for (name, shape, data) in tensors {
        let end = offset + 4 * data.len();
        header.insert(
            name.to_string(),
            serde_json::json!({"dtype": "F32", "shape": shape, "data_offsets": [offset, end]}),
        );
        offset = end;
    }
    let mut json = serde_json::to_vec(&serde_json::Value::Object(header)).expect("a JSON map serialises");
    while !json.len().is_multiple_of(8) {
        json.push(b' ');
    }
    let mut out = Vec::with_capacity(8 + json.len() + offset);
    out.extend_from_slice(&(json.len() as u64).to_le_bytes());
    out.extend_from_slice(&json);
    for (_, _, data) in tensors {
        data.iter().for_each(|v| out.extend_from_slice(&v.to_le_bytes()));
    }
    out
}

/// Reads every tensor of a safetensors file.
pub(crate) fn read(bytes: &[u8]) -> Result<TensorMap, Problem> {
    let n = header_len(bytes).ok_or("safetensors header length exceeds the file")?;
    let header: serde_json::Map<String, serde_json::Value> =
        serde_json::from_slice(&bytes[8..8 + n]).map_err(|e| format!("bad safetensors header: {e}"))?;
    let data = &bytes[8 + n..];
    let mut map = TensorMap::new();
    for (name, info) in &header {
        if name == "__metadata__" {
            continue;
        }
        let tensor = read_one(info, data).map_err(|e| format!("tensor {name}: {e}"))?;
        map.insert(name.clone(), tensor);
    }
    Ok(map)
}

fn read_one(info: &serde_json::Value, data: &[u8]) -> Result<TensorData, Problem> {
    let dtype_name = info.get("dtype").and_then(|d| d.as_str()).ok_or("no dtype")?;
    let dtype = DType::from_safetensors(dtype_name)
        .ok_or_else(|| format!("unsupported dtype {dtype_name} (only F32, F16, BF16 and F64 convert to f32)"))?;
    let usize_list = |key: &str| -> Result<Vec<usize>, Problem> {
        let list = info.get(key).and_then(|v| v.as_array()).ok_or_else(|| format!("no {key} list"))?;
        list.iter()
            .map(|v| v.as_u64().and_then(|u| usize::try_from(u).ok()).ok_or_else(|| format!("{key} holds a non-size")))
            .collect()
    };
    let shape = usize_list("shape")?;
    let offsets = usize_list("data_offsets")?;
    let [begin, end] = offsets[..] else {
        return Err("data_offsets is not a pair".into());
    };
    if begin > end || end > data.len() {
        return Err(format!("data_offsets [{begin}, {end}] outside the {} data bytes", data.len()));
    }
    let numel = shape.iter().try_fold(1usize, |acc, &n| acc.checked_mul(n)).ok_or("shape overflows")?;
    if numel.checked_mul(dtype.size()) != Some(end - begin) {
        return Err(format!(
            "shape {shape:?} of {dtype_name} needs {} bytes, data_offsets give {}",
            numel.saturating_mul(dtype.size()),
            end - begin
        ));
    }
    // Row-major strides: safetensors data is always contiguous.
    let mut strides = vec![1usize; shape.len()];
    for k in (0..shape.len().saturating_sub(1)).rev() {
        strides[k] = strides[k + 1].saturating_mul(shape[k + 1]);
    }
    Ok(TensorData { data: gather(dtype, &data[begin..end], 0, &shape, &strides), shape })
}
