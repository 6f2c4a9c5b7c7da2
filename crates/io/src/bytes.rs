//! The one byte reader of the binary formats (OpenVDB, cyHair, HairSalon,
//! Alembic Ogawa, binary PLY). Every count read from a file is untrusted: it
//! is checked against the bytes that remain before anything is allocated, so
//! random bytes give a `Truncated`/`Corrupt` [`ErrorKind`] instead of a panic
//! or a huge allocation. Errors carry no file name; the format's entry point
//! attaches it once ([`crate::Error`]).

use std::path::Path;

use crate::{Error, ErrorKind};

/// Reads a whole file, naming it in the error.
pub(crate) fn read_file(path: &Path) -> Result<Vec<u8>, Error> {
    std::fs::read(path).map_err(|e| Error::new(path, ErrorKind::Open(e)))
}

/// Shorthand for a corrupt-data error that names no offset.
pub(crate) fn corrupt(reason: impl Into<String>) -> ErrorKind {
    ErrorKind::Corrupt { offset: None, reason: reason.into() }
}

/// Shorthand for valid data using a feature the reader does not implement.
pub(crate) fn unsupported(reason: impl Into<String>) -> ErrorKind {
    ErrorKind::Unsupported { reason: reason.into() }
}

/// Little-endian cursor over a byte slice; every read is bounds-checked.
pub(crate) struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    /// Starts reading `bytes` at offset `pos`.
    pub(crate) fn new(bytes: &'a [u8], pos: usize) -> Self {
        Self { bytes, pos }
    }

    /// Current byte offset.
    pub(crate) fn pos(&self) -> usize {
        self.pos
    }

    /// Moves the cursor to `pos`; callers check it against [`Reader::len`]
    /// (a later read past the end fails as truncated either way).
    pub(crate) fn seek(&mut self, pos: usize) {
        self.pos = pos;
    }

    /// Length of the whole slice.
    pub(crate) fn len(&self) -> usize {
        self.bytes.len()
    }

    /// Bytes left after the cursor.
    pub(crate) fn remaining(&self) -> usize {
        self.bytes.len().saturating_sub(self.pos)
    }

    /// Takes the next `n` bytes; a short read reports the bytes missing.
    pub(crate) fn take(&mut self, n: usize, what: &'static str) -> Result<&'a [u8], ErrorKind> {
        if n > self.remaining() {
            return Err(ErrorKind::Truncated { what, offset: self.pos, needed: n - self.remaining() });
        }
        let s = &self.bytes[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    /// Fails unless `count` records of `record_size` bytes fit in what is
    /// left, so an absurd count is refused before allocating for it.
    pub(crate) fn ensure(&self, count: u64, record_size: u64, what: &'static str) -> Result<(), ErrorKind> {
        let need = count.saturating_mul(record_size);
        if need > self.remaining() as u64 {
            return Err(ErrorKind::Truncated {
                what,
                offset: self.pos,
                needed: usize::try_from(need - self.remaining() as u64).unwrap_or(usize::MAX),
            });
        }
        Ok(())
    }

    /// Reads an `N`-byte array.
    pub(crate) fn array<const N: usize>(&mut self, what: &'static str) -> Result<[u8; N], ErrorKind> {
        let s = self.take(N, what)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }

    /// Reads one byte.
    pub(crate) fn u8(&mut self, what: &'static str) -> Result<u8, ErrorKind> {
        Ok(self.take(1, what)?[0])
    }

    /// Reads a little-endian `u16`.
    pub(crate) fn u16(&mut self, what: &'static str) -> Result<u16, ErrorKind> {
        Ok(u16::from_le_bytes(self.array(what)?))
    }

    /// Reads a little-endian `u32`.
    pub(crate) fn u32(&mut self, what: &'static str) -> Result<u32, ErrorKind> {
        Ok(u32::from_le_bytes(self.array(what)?))
    }

    /// Reads a little-endian `i32`.
    pub(crate) fn i32(&mut self, what: &'static str) -> Result<i32, ErrorKind> {
        Ok(i32::from_le_bytes(self.array(what)?))
    }

    /// Reads a little-endian `u64`.
    pub(crate) fn u64(&mut self, what: &'static str) -> Result<u64, ErrorKind> {
        Ok(u64::from_le_bytes(self.array(what)?))
    }

    /// Reads a little-endian `i64`.
    pub(crate) fn i64(&mut self, what: &'static str) -> Result<i64, ErrorKind> {
        Ok(i64::from_le_bytes(self.array(what)?))
    }

    /// Reads a little-endian `f32`.
    pub(crate) fn f32(&mut self, what: &'static str) -> Result<f32, ErrorKind> {
        Ok(f32::from_le_bytes(self.array(what)?))
    }

    /// Reads a little-endian `f64`.
    pub(crate) fn f64(&mut self, what: &'static str) -> Result<f64, ErrorKind> {
        Ok(f64::from_le_bytes(self.array(what)?))
    }

    /// Reads three little-endian `f32`s.
    pub(crate) fn vec3(&mut self, what: &'static str) -> Result<[f32; 3], ErrorKind> {
        Ok([self.f32(what)?, self.f32(what)?, self.f32(what)?])
    }

    /// Reads three little-endian `i32`s.
    pub(crate) fn vec3i(&mut self, what: &'static str) -> Result<[i32; 3], ErrorKind> {
        Ok([self.i32(what)?, self.i32(what)?, self.i32(what)?])
    }

    /// Reads three little-endian `f64`s.
    pub(crate) fn vec3d(&mut self, what: &'static str) -> Result<[f64; 3], ErrorKind> {
        Ok([self.f64(what)?, self.f64(what)?, self.f64(what)?])
    }
}
