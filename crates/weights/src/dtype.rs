//! Element types of stored tensors and their conversion to `f32`.

/// A floating-point element type we can convert to `f32` (little-endian on disk).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum DType {
    F32,
    F64,
    F16,
    BF16,
}

impl DType {
    /// The safetensors spelling (`"F32"`, ...).
    pub fn from_safetensors(name: &str) -> Option<DType> {
        Some(match name {
            "F32" => DType::F32,
            "F64" => DType::F64,
            "F16" => DType::F16,
            "BF16" => DType::BF16,
            _ => return None,
        })
    }
}

/// A torch storage class (`torch.FloatStorage`, ...): its element size is needed even
/// for types we cannot convert, because legacy files lay storages back to back.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct StorageKind {
    /// Class name without the `torch.` prefix, for messages.
    pub name: String,
    pub elem_size: usize,
    /// `None` for integer, boolean, complex and quantized storages.
    pub dtype: Option<DType>,
}

impl StorageKind {
    /// Maps a class name in module `torch` to its element layout.
    pub fn from_torch_name(name: &str) -> Option<StorageKind> {
        let (elem_size, dtype) = match name {
            "FloatStorage" => (4, Some(DType::F32)),
            "DoubleStorage" => (8, Some(DType::F64)),
            "HalfStorage" => (2, Some(DType::F16)),
            "BFloat16Storage" => (2, Some(DType::BF16)),
            "LongStorage" => (8, None),
            "IntStorage" => (4, None),
            "ShortStorage" => (2, None),
            "CharStorage" | "ByteStorage" | "BoolStorage" => (1, None),
            "ComplexFloatStorage" => (8, None),
            "ComplexDoubleStorage" => (16, None),
            "QInt8Storage" | "QUInt8Storage" | "QUInt4x2Storage" | "QUInt2x4Storage" => (1, None),
            "QInt32Storage" => (4, None),
            _ => return None,
        };
        Some(StorageKind { name: name.to_string(), elem_size, dtype })
    }
}

/// IEEE binary16 bits to f32 (exact: every half value is representable).
pub(crate) fn f16_to_f32(h: u16) -> f32 {
    let sign = u32::from(h >> 15) << 31;
    let exp = u32::from((h >> 10) & 0x1f);
    let man = u32::from(h & 0x3ff);
    let magnitude = match exp {
        // Subnormal halves are man * 2^-24, normal in f32.
        0 => (man as f32 * (1.0 / 16_777_216.0)).to_bits(),
        0x1f => 0x7f80_0000 | (man << 13),
        _ => ((exp + 127 - 15) << 23) | (man << 13),
    };
    f32::from_bits(sign | magnitude)
}

/// Reads a strided view `storage[offset + sum(i_k * strides[k])]` of `dtype` elements in
/// row-major order of `shape`, converted to f32. The caller has checked that every
/// addressed element lies inside `storage`.
pub(crate) fn gather(dtype: DType, storage: &[u8], offset: usize, shape: &[usize], strides: &[usize]) -> Vec<f32> {
    // The dtype is resolved here, once, so that each instance of the kernel below has a
    // fixed element width and a decode the compiler can vectorize.
    match dtype {
        DType::F32 => gather_as(storage, offset, shape, strides, f32::from_le_bytes),
        DType::F64 => gather_as(storage, offset, shape, strides, |b| f64::from_le_bytes(b) as f32),
        DType::F16 => gather_as(storage, offset, shape, strides, |b| f16_to_f32(u16::from_le_bytes(b))),
        DType::BF16 => {
            gather_as(storage, offset, shape, strides, |b| f32::from_bits(u32::from(u16::from_le_bytes(b)) << 16))
        }
    }
}

/// [`gather`] for elements of `N` bytes decoded by `decode`.
#[inline(always)]
fn gather_as<const N: usize>(
    storage: &[u8],
    offset: usize,
    shape: &[usize],
    strides: &[usize],
    decode: impl Fn([u8; N]) -> f32,
) -> Vec<f32> {
    let numel: usize = shape.iter().product();
    let mut out = Vec::with_capacity(numel);
    if numel == 0 {
        return out;
    }
    let elements = storage.as_chunks::<N>().0;
    // A size-1 dim's stride is never used for addressing, and the caller's bounds check
    // cannot constrain it, so zero it before the odometer below adds it up.
    let strides: Vec<usize> = shape.iter().zip(strides).map(|(&n, &s)| if n == 1 { 0 } else { s }).collect();
    // Row-major contiguity (ignoring size-1 dims) makes the whole tensor one run: the
    // common case, converted without index arithmetic.
    let mut expect = 1usize;
    let contiguous = shape.iter().zip(&strides).rev().all(|(&n, &s)| {
        let ok = n == 1 || s == expect;
        expect *= n;
        ok
    });
    if contiguous {
        out.extend(elements[offset..offset + numel].iter().map(|&e| decode(e)));
        return out;
    }
    let (inner_n, inner_s) = (shape[shape.len() - 1], strides[strides.len() - 1]);
    let outer = &shape[..shape.len() - 1];
    let mut index = vec![0usize; outer.len()];
    let mut base = offset;
    loop {
        if inner_s == 1 {
            out.extend(elements[base..base + inner_n].iter().map(|&e| decode(e)));
        } else {
            out.extend((0..inner_n).map(|i| decode(elements[base + i * inner_s])));
        }
        // Odometer over the outer dims.
        let mut k = outer.len();
        loop {
            if k == 0 {
                return out;
            }
            k -= 1;
            index[k] += 1;
            base += strides[k];
            if index[k] < outer[k] {
                break;
            }
            base -= strides[k] * outer[k];
            index[k] = 0;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn half_conversion_covers_special_values() {
        assert_eq!(f16_to_f32(0x3c00), 1.0);
        assert_eq!(f16_to_f32(0xc000), -2.0);
        assert_eq!(f16_to_f32(0x7bff), 65504.0);
        assert_eq!(f16_to_f32(0x0001), 2f32.powi(-24));
        assert_eq!(f16_to_f32(0x03ff), 1023.0 * 2f32.powi(-24));
        assert_eq!(f16_to_f32(0x0400), 2f32.powi(-14));
        assert_eq!(f16_to_f32(0x8000).to_bits(), (-0.0f32).to_bits());
        assert_eq!(f16_to_f32(0x7c00), f32::INFINITY);
        assert_eq!(f16_to_f32(0xfc00), f32::NEG_INFINITY);
        assert!(f16_to_f32(0x7e00).is_nan());
    }

    #[test]
    fn gather_matches_index_formula() {
        // 3x4 storage of f32 0..12, read as the transpose (4x3) from offset 0, and a
        // 2x2 window with offset 5.
        let storage: Vec<u8> = (0..12).flat_map(|i| (i as f32).to_le_bytes()).collect();
        let t = gather(DType::F32, &storage, 0, &[4, 3], &[1, 4]);
        assert_eq!(t, vec![0., 4., 8., 1., 5., 9., 2., 6., 10., 3., 7., 11.]);
        let w = gather(DType::F32, &storage, 5, &[2, 2], &[4, 1]);
        assert_eq!(w, vec![5., 6., 9., 10.]);
        let s = gather(DType::F32, &storage, 7, &[], &[]);
        assert_eq!(s, vec![7.]);
        let e = gather(DType::F32, &storage, 0, &[3, 0], &[1, 1]);
        assert!(e.is_empty());
    }
}
