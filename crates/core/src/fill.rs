//! Large buffers filled on every thread. `vec![0; n]` of a block the
//! allocator reuses is one memset on the calling thread; at a 64³ training
//! step's sizes (8–16 MB a buffer, several a step) those serial memsets took
//! about a tenth of the step while the other threads waited.

use std::mem::MaybeUninit;

use rayon::prelude::*;

/// Values one filling task takes at least (256 KB of `f32`).
const CHUNK: usize = 1 << 16;

/// `buf` emptied and refilled with `n` copies of `value` on every thread,
/// reusing its allocation where it is large enough.
pub fn filled_into<T: Copy + Send + Sync>(mut buf: Vec<T>, n: usize, value: T) -> Vec<T> {
    buf.clear();
    buf.reserve(n);
    buf.spare_capacity_mut()[..n].par_chunks_mut(CHUNK).for_each(|c| c.fill(MaybeUninit::new(value)));
    // SAFETY: the first n values were all written just above.
    unsafe { buf.set_len(n) };
    buf
}

/// `n` copies of `value`, written on every thread.
pub fn filled<T: Copy + Send + Sync>(n: usize, value: T) -> Vec<T> {
    filled_into(Vec::new(), n, value)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fills_every_value_whatever_the_length() {
        for n in [0, 1, CHUNK - 1, CHUNK, CHUNK + 1, 3 * CHUNK + 7] {
            assert_eq!(filled(n, 7u16), vec![7u16; n]);
        }
    }

    #[test]
    fn reuses_and_overwrites_a_buffer() {
        let buf = vec![1.5f32; 2 * CHUNK];
        let ptr = buf.as_ptr();
        let out = filled_into(buf, CHUNK + 3, 0.0);
        assert_eq!(out, vec![0.0; CHUNK + 3]);
        assert_eq!(out.as_ptr(), ptr, "a buffer large enough is kept");
        assert_eq!(filled_into(out, 3 * CHUNK, 2.0), vec![2.0; 3 * CHUNK]);
    }
}
