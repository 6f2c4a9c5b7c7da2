//! Decoder for Blosc1 frames (the `blosc_compress` output OpenVDB stores per
//! node buffer), with pure-Rust codecs: LZ4/LZ4HC (`lz4_flex`), zlib
//! (`flate2`) and BloscLZ (ported below), plus byte- and bit-unshuffle.
//! Snappy and Zstd frames are reported as unsupported.
//!
//! Frame layout (little-endian): `version u8, codec version u8, flags u8,
//! typesize u8, nbytes u32, blocksize u32, cbytes u32`, then one `u32` start
//! offset per block, then per block one or `typesize` split streams, each
//! `i32 length + data` (length == uncompressed size means stored raw).

use std::io::Read;

/// Frame header size.
const HEADER: usize = 16;
const DOSHUFFLE: u8 = 0x1;
const MEMCPYED: u8 = 0x2;
const DOBITSHUFFLE: u8 = 0x4;
const FUTURE_FLAGS: u8 = 0x8;
const DONT_SPLIT: u8 = 0x10;
/// Blosc splits a block per byte plane only for small types and big blocks.
const MAX_SPLITS: usize = 16;
const MIN_BUFFERSIZE: usize = 128;

/// Decompresses one Blosc frame that must expand to exactly `expected`
/// bytes. Errors are short reasons; the caller adds file and position.
pub fn decompress(src: &[u8], expected: usize) -> Result<Vec<u8>, String> {
    if src.len() < HEADER {
        return Err(format!("blosc frame of {} bytes is shorter than its header", src.len()));
    }
    let version = src[0];
    let flags = src[2];
    let typesize = src[3] as usize;
    let rd = |o: usize| u32::from_le_bytes([src[o], src[o + 1], src[o + 2], src[o + 3]]) as usize;
    let (nbytes, blocksize, cbytes) = (rd(4), rd(8), rd(12));
    if version == 0 || version > 2 {
        return Err(format!("blosc format version {version} is not supported"));
    }
    if flags & FUTURE_FLAGS != 0 {
        return Err("blosc frame uses unknown flags".into());
    }
    if nbytes != expected {
        return Err(format!("blosc frame holds {nbytes} bytes, expected {expected}"));
    }
    if cbytes > src.len() || cbytes < HEADER {
        return Err(format!("blosc frame claims {cbytes} bytes but {} are stored", src.len()));
    }
    let src = &src[..cbytes];
    let mut out = vec![0u8; nbytes];
    if nbytes == 0 {
        return Ok(out);
    }
    if flags & MEMCPYED != 0 {
        if cbytes != nbytes + HEADER {
            return Err("blosc memcpy frame has the wrong size".into());
        }
        out.copy_from_slice(&src[HEADER..]);
        return Ok(out);
    }
    if blocksize == 0 || typesize == 0 {
        return Err("blosc frame has zero block or type size".into());
    }
    let codec = Codec::from_flags(flags)?;
    let nblocks = nbytes.div_ceil(blocksize);
    if nblocks > (cbytes - HEADER) / 4 {
        return Err("blosc frame too small for its block table".into());
    }
    let mut tmp = vec![0u8; blocksize.min(nbytes)];
    for j in 0..nblocks {
        let start = j * blocksize;
        let bsize = blocksize.min(nbytes - start);
        let leftover = bsize < blocksize;
        let mut off = rd(HEADER + 4 * j);
        let shuffle = flags & DOSHUFFLE != 0 && typesize > 1;
        let bitshuffle = flags & DOBITSHUFFLE != 0 && bsize >= typesize;
        let nsplits =
            if flags & DONT_SPLIT == 0 && typesize <= MAX_SPLITS && bsize / typesize >= MIN_BUFFERSIZE && !leftover {
                typesize
            } else {
                1
            };
        let neblock = bsize / nsplits;
        let dest: &mut [u8] = if shuffle || bitshuffle { &mut tmp[..bsize] } else { &mut out[start..start + bsize] };
        for s in 0..nsplits {
            let part = &mut dest[s * neblock..(s + 1) * neblock];
            let len_end = off.checked_add(4).filter(|&e| e <= cbytes).ok_or("blosc split header out of bounds")?;
            let clen = i32::from_le_bytes(src[off..len_end].try_into().unwrap());
            let clen = usize::try_from(clen).map_err(|_| "negative blosc split length")?;
            let data = src.get(len_end..len_end + clen).ok_or("blosc split runs past the frame")?;
            if clen == neblock {
                part.copy_from_slice(data);
            } else {
                codec.decompress(data, part)?;
            }
            off = len_end + clen;
        }
        let dst = &mut out[start..start + bsize];
        if shuffle {
            unshuffle(typesize, &tmp[..bsize], dst);
        } else if bitshuffle {
            bitunshuffle(typesize, &tmp[..bsize], dst);
        }
    }
    Ok(out)
}

/// The per-split compressor named in the flags' top three bits.
#[derive(Clone, Copy)]
enum Codec {
    BloscLz,
    Lz4,
    Zlib,
}

impl Codec {
    fn from_flags(flags: u8) -> Result<Self, String> {
        match flags >> 5 {
            0 => Ok(Codec::BloscLz),
            1 => Ok(Codec::Lz4),
            3 => Ok(Codec::Zlib),
            2 => Err("blosc codec snappy is not supported".into()),
            4 => Err("blosc codec zstd is not supported".into()),
            c => Err(format!("unknown blosc codec {c}")),
        }
    }

    /// Fills `out` exactly from one compressed split.
    fn decompress(self, src: &[u8], out: &mut [u8]) -> Result<(), String> {
        let n = match self {
            Codec::Lz4 => lz4_flex::block::decompress_into(src, out).map_err(|e| format!("lz4: {e}"))?,
            Codec::Zlib => {
                let mut d = flate2::read::ZlibDecoder::new(src);
                let mut filled = 0;
                while filled < out.len() {
                    match d.read(&mut out[filled..]) {
                        Ok(0) => break,
                        Ok(k) => filled += k,
                        Err(e) => return Err(format!("zlib: {e}")),
                    }
                }
                filled
            }
            Codec::BloscLz => blosclz_decompress(src, out)?,
        };
        if n != out.len() {
            return Err(format!("blosc split decoded to {n} bytes, expected {}", out.len()));
        }
        Ok(())
    }
}

/// Undoes byte shuffling: the frame stores byte 0 of every element, then
/// byte 1, ...; trailing bytes that do not fill an element stay in place.
fn unshuffle(typesize: usize, src: &[u8], dst: &mut [u8]) {
    let n = src.len() / typesize;
    for j in 0..typesize {
        let plane = &src[j * n..(j + 1) * n];
        for (i, &b) in plane.iter().enumerate() {
            dst[i * typesize + j] = b;
        }
    }
    let tail = n * typesize;
    dst[tail..].copy_from_slice(&src[tail..]);
}

/// Undoes bit shuffling: bit row `j * 8 + b` holds bit `b` of byte `j` of
/// every element. Blosc only bit-shuffles whole groups of 8 elements; other
/// block sizes are stored as they are.
fn bitunshuffle(typesize: usize, src: &[u8], dst: &mut [u8]) {
    let n = src.len() / typesize;
    if !n.is_multiple_of(8) {
        dst.copy_from_slice(src);
        return;
    }
    let row = n / 8;
    dst[..n * typesize].fill(0);
    for j in 0..typesize {
        for b in 0..8 {
            let bits = &src[(j * 8 + b) * row..(j * 8 + b + 1) * row];
            for (g, &byte) in bits.iter().enumerate() {
                if byte == 0 {
                    continue;
                }
                for k in 0..8 {
                    if byte >> k & 1 == 1 {
                        dst[(g * 8 + k) * typesize + j] |= 1 << b;
                    }
                }
            }
        }
    }
    let tail = n * typesize;
    dst[tail..].copy_from_slice(&src[tail..]);
}

/// BloscLZ (a FastLZ derivative): a control byte < 32 starts a literal run
/// of `ctrl + 1` bytes; otherwise the top 3 bits give the match length and
/// the low 5 bits plus the next byte the distance (with a 16-bit far form).
fn blosclz_decompress(src: &[u8], out: &mut [u8]) -> Result<usize, String> {
    const MAX_DISTANCE: usize = 8191;
    let bad = || "corrupt blosclz stream".to_string();
    if src.is_empty() {
        return Ok(0);
    }
    let mut ip = 0usize;
    let mut op = 0usize;
    let mut ctrl = (src[ip] & 31) as usize;
    ip += 1;
    loop {
        if ctrl >= 32 {
            let mut len = (ctrl >> 5) - 1;
            let ofs = (ctrl & 31) << 8;
            if len == 6 {
                loop {
                    let code = *src.get(ip).ok_or_else(bad)?;
                    ip += 1;
                    len += code as usize;
                    if code != 255 {
                        break;
                    }
                }
            }
            let code = *src.get(ip).ok_or_else(bad)? as usize;
            ip += 1;
            len += 3;
            let mut dist = ofs + code + 1;
            if code == 255 && ofs == 31 << 8 {
                let hi = *src.get(ip).ok_or_else(bad)? as usize;
                let lo = *src.get(ip + 1).ok_or_else(bad)? as usize;
                ip += 2;
                dist = (hi << 8) + lo + MAX_DISTANCE + 1;
            }
            if op + len > out.len() || dist > op {
                return Err(bad());
            }
            for k in 0..len {
                out[op + k] = out[op + k - dist];
            }
            op += len;
        } else {
            let run = ctrl + 1;
            if op + run > out.len() || ip + run > src.len() {
                return Err(bad());
            }
            out[op..op + run].copy_from_slice(&src[ip..ip + run]);
            op += run;
            ip += run;
        }
        if ip >= src.len() {
            break;
        }
        ctrl = src[ip] as usize;
        ip += 1;
    }
    Ok(op)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unshuffle_inverts_byte_planes() {
        let src = [1, 3, 2, 4, 9];
        let mut dst = [0; 5];
        unshuffle(2, &src, &mut dst);
        assert_eq!(dst, [1, 2, 3, 4, 9]);
    }

    #[test]
    fn memcpy_frame() {
        let mut f = vec![2, 1, MEMCPYED | DOSHUFFLE, 4];
        for v in [8u32, 8, 24] {
            f.extend_from_slice(&v.to_le_bytes());
        }
        f.extend_from_slice(&[1, 2, 3, 4, 5, 6, 7, 8]);
        assert_eq!(decompress(&f, 8).unwrap(), vec![1, 2, 3, 4, 5, 6, 7, 8]);
        assert!(decompress(&f, 9).is_err());
        assert!(decompress(&f[..20], 8).is_err());
    }

    /// Frames made by the C library (tools/fixtures/io_blosc.py) decode to
    /// the original bytes for every codec and shuffle mode; zstd/snappy are
    /// refused by name.
    #[test]
    fn c_library_frames() {
        let dir = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures"));
        let input = std::fs::read(dir.join("blosc_input.bin")).expect("fixture blosc_input.bin");
        let noise = std::fs::read(dir.join("blosc_noise.bin")).expect("fixture blosc_noise.bin");
        let mut seen = 0;
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            let name = path.file_name().unwrap().to_string_lossy().to_string();
            let want = if name.starts_with("blosc_input_") {
                &input
            } else if name.starts_with("blosc_noise_") {
                &noise
            } else {
                continue;
            };
            let frame = std::fs::read(&path).unwrap();
            let got = decompress(&frame, want.len()).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert!(got == *want, "{name}: decoded bytes differ");
            // Every strict prefix is an error, never a panic.
            for cut in [0, 5, 16, frame.len() / 2, frame.len() - 1] {
                assert!(decompress(&frame[..cut], want.len()).is_err(), "{name} cut at {cut}");
            }
            seen += 1;
        }
        assert_eq!(seen, 10, "expected 10 fixture frames in {}", dir.display());
        let mut zstd = std::fs::read(dir.join("blosc_input_lz4_sh1_ts4_bs0.bin")).unwrap();
        zstd[2] = (zstd[2] & 0x1f) | (4 << 5);
        assert!(decompress(&zstd, input.len()).unwrap_err().contains("zstd"));
    }
}
