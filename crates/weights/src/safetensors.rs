//! The `.safetensors` format: a little-endian u64 header length, a JSON header mapping
//! each name to `{dtype, shape, data_offsets}`, then the raw little-endian data.
//!
//! Reading goes through the `safetensors` crate, so every file passes the
//! reference implementation's checks (header size, offsets that tile the data
//! exactly, sizes that cannot overflow) before a byte of it is used.
//!
//! Writing is ours, because the crate's writer cannot give the same bytes
//! twice: it writes `__metadata__` in the order of a randomly seeded hash map
//! (it differs from process to process), it orders the data by dtype and then
//! by name rather than as given, and it writes a tensor's keys as
//! `dtype, shape, data_offsets`. Here the data follows the caller's order and
//! every JSON object has sorted keys, so the same tensors and metadata always
//! give the same file, and model files keep the bytes they had before the
//! crate was used for reading. Both pad the header with spaces to a multiple
//! of 8 bytes.

use std::borrow::Cow;
use std::collections::BTreeMap;
use std::io::{self, Write};

use ::safetensors::{Dtype, SafeTensors};

use crate::dtype::{gather, DType};
use crate::pickle::Problem;
use crate::{TensorData, TensorMap};

/// Header size limit of the reference implementation; larger is surely corrupt.
const MAX_HEADER: u64 = 100_000_000;

/// The values of one stored tensor, in one of the element types nst3d
/// writes, without conversion.
#[derive(Clone, Debug, PartialEq)]
pub enum Values<'a> {
    /// `F32`.
    F32(Cow<'a, [f32]>),
    /// `F64`.
    F64(Cow<'a, [f64]>),
    /// `U64`.
    U64(Cow<'a, [u64]>),
}

impl Values<'_> {
    /// Number of elements.
    pub fn len(&self) -> usize {
        match self {
            Values::F32(v) => v.len(),
            Values::F64(v) => v.len(),
            Values::U64(v) => v.len(),
        }
    }

    /// True without elements.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The safetensors spelling of the element type.
    pub fn dtype(&self) -> &'static str {
        match self {
            Values::F32(_) => "F32",
            Values::F64(_) => "F64",
            Values::U64(_) => "U64",
        }
    }

    fn elem_size(&self) -> usize {
        match self {
            Values::F32(_) => 4,
            Values::F64(_) | Values::U64(_) => 8,
        }
    }

    /// The little-endian bytes, a block at a time.
    fn write_le(&self, w: &mut dyn Write) -> io::Result<()> {
        const BLOCK: usize = 8192;
        let mut buf = Vec::with_capacity(8 * BLOCK);
        macro_rules! blocks {
            ($v:expr) => {
                for block in $v.chunks(BLOCK) {
                    buf.clear();
                    block.iter().for_each(|x| buf.extend_from_slice(&x.to_le_bytes()));
                    w.write_all(&buf)?;
                }
            };
        }
        match self {
            Values::F32(v) => blocks!(v),
            Values::F64(v) => blocks!(v),
            Values::U64(v) => blocks!(v),
        }
        Ok(())
    }
}

/// A tensor as a safetensors file stores it: its shape and its values.
#[derive(Clone, Debug, PartialEq)]
pub struct Tensor<'a> {
    /// Dimensions, outermost first.
    pub shape: Vec<usize>,
    /// `shape.iter().product()` values, row-major.
    pub values: Values<'a>,
}

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

/// Writes a safetensors file of `tensors`, their data in this order, and the
/// string `metadata` (its `__metadata__`, left out when empty).
///
/// # Panics
/// If a tensor's values do not fill its shape (a programming error).
pub(crate) fn write(
    w: &mut dyn Write,
    tensors: &[(&str, &Tensor<'_>)],
    metadata: &BTreeMap<String, String>,
) -> io::Result<()> {
    let mut header = serde_json::Map::new();
    if !metadata.is_empty() {
        let meta = metadata.iter().map(|(k, v)| (k.clone(), serde_json::Value::from(v.as_str()))).collect();
        header.insert("__metadata__".into(), serde_json::Value::Object(meta));
    }
    let mut offset = 0usize;
    for (name, t) in tensors {
        assert_eq!(t.shape.iter().product::<usize>(), t.values.len(), "tensor {name}: shape vs values");
        let end = offset + t.values.elem_size() * t.values.len();
        header.insert(
            name.to_string(),
            serde_json::json!({"dtype": t.values.dtype(), "shape": t.shape, "data_offsets": [offset, end]}),
        );
        offset = end;
    }
    let mut json = serde_json::to_vec(&serde_json::Value::Object(header)).expect("a JSON map serialises");
    while !json.len().is_multiple_of(8) {
        json.push(b' ');
    }
    w.write_all(&(json.len() as u64).to_le_bytes())?;
    w.write_all(&json)?;
    for (_, t) in tensors {
        t.values.write_le(w)?;
    }
    Ok(())
}

/// The header and data of a file the crate accepted: every tensor's dtype,
/// shape and bytes, and the `__metadata__` strings.
type Checked<'b> = (Vec<(String, Dtype, Vec<usize>, &'b [u8])>, BTreeMap<String, String>);

fn open(bytes: &[u8]) -> Result<Checked<'_>, Problem> {
    let (n, header) = SafeTensors::read_metadata(bytes).map_err(|e| format!("bad safetensors file: {e}"))?;
    let data = &bytes[8 + n..];
    let mut tensors: Vec<_> = header
        .tensors()
        .into_iter()
        .map(|(name, info)| {
            let (begin, end) = info.data_offsets;
            (name, info.dtype, info.shape.clone(), &data[begin..end])
        })
        .collect();
    tensors.sort_by(|a, b| a.0.cmp(&b.0));
    let meta = header.metadata().iter().flatten().map(|(k, v)| (k.clone(), v.clone())).collect();
    Ok((tensors, meta))
}

/// Reads every tensor of a safetensors file, converted to f32, and its metadata.
pub(crate) fn read(bytes: &[u8]) -> Result<(TensorMap, BTreeMap<String, String>), Problem> {
    let (tensors, meta) = open(bytes)?;
    let mut map = TensorMap::new();
    for (name, dtype, shape, data) in tensors {
        let dtype = DType::from_safetensors(&dtype.to_string()).ok_or_else(|| {
            format!("tensor {name}: unsupported dtype {dtype} (only F32, F16, BF16 and F64 convert to f32)")
        })?;
        // Row-major strides: safetensors data is always contiguous.
        let mut strides = vec![1usize; shape.len()];
        for k in (0..shape.len().saturating_sub(1)).rev() {
            strides[k] = strides[k + 1].saturating_mul(shape[k + 1]);
        }
        let tensor = TensorData { data: gather(dtype, data, 0, &shape, &strides), shape };
        map.insert(name, tensor);
    }
    Ok((map, meta))
}

/// Every tensor of a safetensors file by name, as stored, and its metadata.
pub type Exact = (BTreeMap<String, Tensor<'static>>, BTreeMap<String, String>);

/// Reads every tensor of a safetensors file as stored (F32, F64 or U64; any
/// other element type is refused), and its metadata.
pub(crate) fn read_exact(bytes: &[u8]) -> Result<Exact, Problem> {
    fn le<const N: usize, T>(data: &[u8], from: fn([u8; N]) -> T) -> Vec<T> {
        data.chunks_exact(N).map(|c| from(c.try_into().expect("N bytes"))).collect()
    }
    let (tensors, meta) = open(bytes)?;
    let mut map = BTreeMap::new();
    for (name, dtype, shape, data) in tensors {
        let values = match dtype {
            Dtype::F32 => Values::F32(le(data, f32::from_le_bytes).into()),
            Dtype::F64 => Values::F64(le(data, f64::from_le_bytes).into()),
            Dtype::U64 => Values::U64(le(data, u64::from_le_bytes).into()),
            other => return Err(format!("tensor {name}: dtype {other}, expected F32, F64 or U64")),
        };
        map.insert(name, Tensor { shape, values });
    }
    Ok((map, meta))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn file(tensors: &[(&str, &Tensor<'_>)], meta: &BTreeMap<String, String>) -> Vec<u8> {
        let mut out = Vec::new();
        write(&mut out, tensors, meta).unwrap();
        out
    }

    /// What we write, the crate reads back bit for bit, in every element
    /// type we write; the data is in the order given, the keys sorted.
    #[test]
    fn the_crate_reads_what_we_write_exactly() {
        let w = Tensor { shape: vec![2, 2], values: Values::F32(vec![1.0, -0.0, f32::MIN_POSITIVE, 3.5].into()) };
        let d = Tensor { shape: vec![3], values: Values::F64(vec![0.1, f64::MAX, -2.0].into()) };
        let n = Tensor { shape: vec![2], values: Values::U64(vec![u64::MAX, 7].into()) };
        let e = Tensor { shape: vec![0], values: Values::F32(Vec::new().into()) };
        let meta = BTreeMap::from([("b".to_string(), "2".to_string()), ("a".to_string(), "1".to_string())]);
        let bytes = file(&[("z", &w), ("y", &d), ("x", &n), ("empty", &e)], &meta);
        let header_len = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
        assert_eq!(header_len % 8, 0, "header padded to 8 bytes");
        let header = std::str::from_utf8(&bytes[8..8 + header_len]).unwrap();
        assert!(header.starts_with(r#"{"__metadata__":{"a":"1","b":"2"},"empty":"#), "{header}");
        assert!(header.contains(r#""z":{"data_offsets":[0,16],"dtype":"F32","shape":[2,2]}"#), "{header}");
        let (back, meta_back) = read_exact(&bytes).unwrap();
        assert_eq!(meta_back, meta);
        assert_eq!(back.len(), 4);
        assert_eq!((&back["z"], &back["y"], &back["x"], &back["empty"]), (&w, &d, &n, &e));
        // The same input gives the same bytes.
        assert_eq!(file(&[("z", &w), ("y", &d), ("x", &n), ("empty", &e)], &meta), bytes);
    }

    /// Every cut of a file, and a file with a byte flipped anywhere, is an
    /// error or a file of the right sizes, never a panic.
    #[test]
    fn cut_and_flipped_files_are_errors_not_panics() {
        let w = Tensor { shape: vec![3], values: Values::U64(vec![1, 2, 3].into()) };
        let bytes = file(&[("w", &w)], &BTreeMap::from([("k".to_string(), "v".to_string())]));
        for len in 0..bytes.len() {
            assert!(read_exact(&bytes[..len]).is_err(), "cut to {len} bytes read");
        }
        for at in 0..bytes.len() {
            let mut b = bytes.clone();
            b[at] ^= 0x5a;
            if let Ok((t, _)) = read_exact(&b) {
                assert!(t.values().all(|t| t.shape.iter().product::<usize>() == t.values.len()));
            }
        }
    }
}
