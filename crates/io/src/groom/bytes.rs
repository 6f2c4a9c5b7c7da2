//! Bounds-checked little helpers shared by the binary readers (groom and mesh
//! formats). Every count read from a file is untrusted: it is checked against
//! the bytes that remain before anything is allocated, so random bytes give a
//! `Truncated`/`Corrupt` error instead of a panic or a huge allocation.

/// A format-level problem, before the caller attaches the file name.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum FormatError {
    /// The data ends before the structure it announces.
    Truncated {
        /// What was being decoded.
        what: &'static str,
        /// Byte offset where the read started.
        offset: usize,
        /// Bytes requested.
        needed: usize,
    },
    /// A value is inconsistent (bad count, bad index, bad token, ...).
    Corrupt(String),
    /// Valid data that uses a feature this reader does not implement.
    Unsupported(String),
}

/// Shorthand for a corrupt-data error.
pub(crate) fn corrupt(reason: impl Into<String>) -> FormatError {
    FormatError::Corrupt(reason.into())
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

    /// Bytes left after the cursor.
    pub(crate) fn remaining(&self) -> usize {
        self.bytes.len().saturating_sub(self.pos)
    }

    /// Takes the next `n` bytes.
    pub(crate) fn take(&mut self, n: usize, what: &'static str) -> Result<&'a [u8], FormatError> {
        if n > self.remaining() {
            return Err(FormatError::Truncated { what, offset: self.pos, needed: n - self.remaining() });
        }
        let s = &self.bytes[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    /// Fails unless `count` records of `record_size` bytes fit in what is
    /// left, so an absurd count is refused before allocating for it.
    pub(crate) fn ensure(&self, count: u64, record_size: u64, what: &'static str) -> Result<(), FormatError> {
        let need = count.saturating_mul(record_size);
        if need > self.remaining() as u64 {
            return Err(FormatError::Truncated {
                what,
                offset: self.pos,
                needed: usize::try_from(need - self.remaining() as u64).unwrap_or(usize::MAX),
            });
        }
        Ok(())
    }

    /// Reads an `N`-byte array.
    pub(crate) fn array<const N: usize>(&mut self, what: &'static str) -> Result<[u8; N], FormatError> {
        let s = self.take(N, what)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }

    /// Reads a little-endian `u16`.
    pub(crate) fn u16(&mut self, what: &'static str) -> Result<u16, FormatError> {
        Ok(u16::from_le_bytes(self.array(what)?))
    }

    /// Reads a little-endian `u32`.
    pub(crate) fn u32(&mut self, what: &'static str) -> Result<u32, FormatError> {
        Ok(u32::from_le_bytes(self.array(what)?))
    }

    /// Reads a little-endian `i32`.
    pub(crate) fn i32(&mut self, what: &'static str) -> Result<i32, FormatError> {
        Ok(i32::from_le_bytes(self.array(what)?))
    }

    /// Reads a little-endian `u64`.
    pub(crate) fn u64(&mut self, what: &'static str) -> Result<u64, FormatError> {
        Ok(u64::from_le_bytes(self.array(what)?))
    }

    /// Reads a little-endian `f32`.
    pub(crate) fn f32(&mut self, what: &'static str) -> Result<f32, FormatError> {
        Ok(f32::from_le_bytes(self.array(what)?))
    }

    /// Reads three little-endian `f32`s.
    pub(crate) fn vec3(&mut self, what: &'static str) -> Result<[f32; 3], FormatError> {
        Ok([self.f32(what)?, self.f32(what)?, self.f32(what)?])
    }
}
