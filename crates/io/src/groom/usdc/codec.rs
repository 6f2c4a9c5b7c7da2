//! The two compressions of crate files: LZ4 blocks in the chunked frame
//! USD calls "fast compression", and the integer coding USD puts under it
//! for index arrays and integer-valued arrays (deltas, a most common delta,
//! 2-bit width codes, then the deltas that are not the common one in 8, 16
//! or 32 bits, or 16, 32 or 64 bits for 64-bit integers).
//!
//! Decoding trusts nothing: every size is checked against the bytes there,
//! an output never grows past what the caller said it expects, and integer
//! arithmetic wraps as the format's own decoder's does.

use crate::bytes::corrupt;
use crate::ErrorKind;

/// LZ4's largest block input; longer buffers are split into chunks of this.
const MAX_CHUNK: usize = 0x7E00_0000;

/// How much an LZ4 block can expand: no sequence turns one byte into more
/// than 255 (a bound used to refuse absurd sizes before allocating).
const MAX_RATIO: usize = 256;

/// Decompresses a fast-compression buffer into at most `max_out` bytes.
pub(super) fn decompress(src: &[u8], max_out: usize) -> Result<Vec<u8>, ErrorKind> {
    let (&chunks, mut rest) = src.split_first().ok_or_else(|| corrupt("empty compressed buffer"))?;
    let bound = src.len().saturating_mul(MAX_RATIO);
    let mut out = vec![0u8; max_out.min(bound)];
    let bad = |e: lz4_flex::block::DecompressError| corrupt(format!("bad LZ4 block ({e})"));
    if chunks == 0 {
        let n = lz4_flex::block::decompress_into(rest, &mut out).map_err(bad)?;
        out.truncate(n);
        return Ok(out);
    }
    let mut done = 0;
    for _ in 0..chunks {
        if rest.len() < 4 {
            return Err(corrupt("compressed chunk header cut short"));
        }
        let size = i32::from_le_bytes([rest[0], rest[1], rest[2], rest[3]]);
        let size = usize::try_from(size).ok().filter(|&s| s <= rest.len() - 4);
        let size = size.ok_or_else(|| corrupt("compressed chunk size out of range"))?;
        let end = out.len().min(done + MAX_CHUNK);
        done += lz4_flex::block::decompress_into(&rest[4..4 + size], &mut out[done..end]).map_err(bad)?;
        rest = &rest[4 + size..];
    }
    out.truncate(done);
    Ok(out)
}

/// Compresses `src` in the fast-compression frame (one chunk below the
/// LZ4 block limit, else a chunk count and size-prefixed chunks).
pub(super) fn compress(src: &[u8]) -> Vec<u8> {
    if src.len() <= MAX_CHUNK {
        let mut out = vec![0u8];
        out.extend_from_slice(&lz4_flex::block::compress(src));
        return out;
    }
    let chunks = src.chunks(MAX_CHUNK);
    let mut out = vec![chunks.len() as u8];
    for c in chunks {
        let block = lz4_flex::block::compress(c);
        out.extend_from_slice(&(block.len() as i32).to_le_bytes());
        out.extend_from_slice(&block);
    }
    out
}

/// An integer width the integer coding works in: 32 or 64 bits.
pub(super) trait Coded: Copy {
    /// Bytes of the full-width integer.
    const BYTES: usize;
    fn to_i64(self) -> i64;
    fn from_i64(x: i64) -> Self;
}

impl Coded for i32 {
    const BYTES: usize = 4;
    fn to_i64(self) -> i64 {
        self as i64
    }
    fn from_i64(x: i64) -> Self {
        x as i32
    }
}

impl Coded for i64 {
    const BYTES: usize = 8;
    fn to_i64(self) -> i64 {
        self
    }
    fn from_i64(x: i64) -> Self {
        x
    }
}

/// Reads a little-endian signed integer of `n` bytes (1, 2, 4 or 8).
fn signed(b: &[u8], n: usize) -> i64 {
    match n {
        1 => b[0] as i8 as i64,
        2 => i16::from_le_bytes([b[0], b[1]]) as i64,
        4 => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as i64,
        _ => i64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]),
    }
}

/// Decodes `count` integers from an integer-coded buffer (after LZ4).
fn decode<T: Coded>(data: &[u8], count: usize) -> Result<Vec<T>, ErrorKind> {
    let short = || corrupt("integer-coded data cut short");
    let codes_len = count.div_ceil(4);
    if data.len() < T::BYTES + codes_len {
        return Err(short());
    }
    let common = signed(data, T::BYTES);
    let codes = &data[T::BYTES..T::BYTES + codes_len];
    let mut ints = &data[T::BYTES + codes_len..];
    // Small, medium and large widths in bytes for codes 1, 2, 3.
    let widths = if T::BYTES == 4 { [0, 1, 2, 4] } else { [0, 2, 4, 8] };
    let mut out = Vec::with_capacity(count);
    let mut prev: i64 = 0;
    for i in 0..count {
        let code = (codes[i / 4] >> (2 * (i % 4))) & 3;
        let delta = if code == 0 {
            common
        } else {
            let w = widths[code as usize];
            if ints.len() < w {
                return Err(short());
            }
            let d = signed(ints, w);
            ints = &ints[w..];
            d
        };
        // 32-bit streams wrap at 32 bits, as the format's decoder does.
        prev = T::from_i64(prev.wrapping_add(delta)).to_i64();
        out.push(T::from_i64(prev));
    }
    Ok(out)
}

/// Reads `count` integer-coded, LZ4-compressed integers from `src`: their
/// compressed size (`u64`), then that many bytes. Returns the integers and
/// the bytes consumed.
pub(super) fn read_ints<T: Coded>(src: &[u8], count: usize) -> Result<(Vec<T>, usize), ErrorKind> {
    let size = src.get(..8).ok_or_else(|| corrupt("compressed integers: size cut short"))?;
    let size = u64::from_le_bytes(size.try_into().expect("8 bytes"));
    let size = usize::try_from(size).ok().filter(|&s| s <= src.len() - 8);
    let size = size.ok_or_else(|| corrupt("compressed integers: size past the end"))?;
    if count == 0 {
        return Ok((Vec::new(), 8 + size));
    }
    // Each integer takes at least 2 bits before compression.
    if count / 4 > size.saturating_mul(MAX_RATIO) {
        return Err(corrupt(format!("{count} compressed integers cannot fit in {size} bytes")));
    }
    let max = T::BYTES + count.div_ceil(4) + count * T::BYTES;
    let data = decompress(&src[8..8 + size], max)?;
    Ok((decode(&data, count)?, 8 + size))
}

/// Integer-codes `ints` (without compressing).
fn encode<T: Coded>(ints: &[T]) -> Vec<u8> {
    let mut deltas = Vec::with_capacity(ints.len());
    let mut prev: i64 = 0;
    for &x in ints {
        let v = x.to_i64();
        deltas.push(T::from_i64(v.wrapping_sub(prev)).to_i64());
        prev = v;
    }
    // The most common delta, the largest on ties.
    let mut sorted = deltas.clone();
    sorted.sort_unstable();
    let (mut common, mut best, mut run) = (0i64, 0usize, 0usize);
    for (i, &d) in sorted.iter().enumerate() {
        run = if i > 0 && sorted[i - 1] == d { run + 1 } else { 1 };
        if run >= best {
            (common, best) = (d, run);
        }
    }
    let mut out = common.to_le_bytes()[..T::BYTES].to_vec();
    let codes_at = out.len();
    out.resize(codes_at + ints.len().div_ceil(4), 0);
    let (small, medium): (u32, u32) = if T::BYTES == 4 { (8, 16) } else { (16, 32) };
    let fits = |d: i64, bits: u32| d >= -(1i64 << (bits - 1)) && d < (1i64 << (bits - 1));
    for (i, &d) in deltas.iter().enumerate() {
        let (code, width) = if d == common {
            (0u8, 0)
        } else if fits(d, small) {
            (1, small as usize / 8)
        } else if fits(d, medium) {
            (2, medium as usize / 8)
        } else {
            (3, T::BYTES)
        };
        out[codes_at + i / 4] |= code << (2 * (i % 4));
        out.extend_from_slice(&d.to_le_bytes()[..width]);
    }
    out
}

/// Appends `ints` integer-coded and compressed, after their compressed
/// size (`u64`): what [`read_ints`] reads.
pub(super) fn write_ints<T: Coded>(out: &mut Vec<u8>, ints: &[T]) {
    let packed = compress(&encode(ints));
    out.extend_from_slice(&(packed.len() as u64).to_le_bytes());
    out.extend_from_slice(&packed);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integer_coding_round_trips_every_width() {
        let ints: Vec<i32> = vec![123, 124, 125, 100125, 100125, 100126, 100126, -5, i32::MIN, i32::MAX, 0, 7];
        let mut buf = Vec::new();
        write_ints(&mut buf, &ints);
        assert_eq!(read_ints::<i32>(&buf, ints.len()).unwrap(), (ints, buf.len()));
        let big: Vec<i64> = vec![1, 1 << 40, -(1 << 50), i64::MAX, i64::MIN, 3, 3, 3, 40000, 40001];
        let mut buf = Vec::new();
        write_ints(&mut buf, &big);
        assert_eq!(read_ints::<i64>(&buf, big.len()).unwrap().0, big);
    }

    /// The worked example of the format's own documentation: deltas
    /// [123, 1, 1, 100000, 0, 1, 0], most common 1.
    #[test]
    fn encoding_matches_the_documented_example() {
        let e = encode(&[123i32, 124, 125, 100125, 100125, 100126, 100126]);
        let mut expect = 1i32.to_le_bytes().to_vec();
        expect.extend_from_slice(&[0b11_00_00_01, 0b00_01_00_01]);
        expect.push(123);
        expect.extend_from_slice(&100000i32.to_le_bytes());
        expect.extend_from_slice(&[0, 0]);
        assert_eq!(e, expect);
    }

    #[test]
    fn bad_buffers_are_errors() {
        assert!(read_ints::<i32>(&[], 3).is_err());
        assert!(read_ints::<i32>(&[200, 0, 0, 0, 0, 0, 0, 0, 0], 3).is_err());
        let mut buf = Vec::new();
        write_ints(&mut buf, &[1i32, 2, 3, 4, 5]);
        assert!(read_ints::<i32>(&buf, 500).is_err(), "more integers than coded");
        assert!(decompress(&[3, 255, 255, 255, 127], 10).is_err());
        assert_eq!(decompress(&compress(b"hello hello hello"), 100).unwrap(), b"hello hello hello");
    }
}
