//! The bf16 path of [`crate::gram`] and [`crate::gram_backward`]: the same
//! products on the bf16 block kernel of `nst3d_core::bf16` (operands rounded
//! to bf16, sums in fp32), taken when the precision in force is bf16.
//!
//! `G = F Fᵀ`: `F` is copied once into bf16 slices of 32 channels × 32
//! pixels (the kernel's A) and once into the kernel's packed B
//! (pixel pairs interleaved); only blocks on and above the diagonal are
//! multiplied, and the long pixel axis is cut into chunks fixed by the shape,
//! summed in order, so the result does not depend on the thread count.
//! `dF = F · sym`: `F` in bf16 rows of channels (pixel-major) against the
//! small `C x C` matrix packed once.

use nst3d_core::bf16::{self, Kernel, PackedB, KS, MB, NB};
use nst3d_core::FeatureView;
use rayon::prelude::*;

/// Most pixel chunks of one Gram.
const CHUNKS: usize = 8;
/// Fewest K-slices of 32 pixels a chunk holds (a task's fixed costs, the
/// tile set-up among them, amortise over them).
const MIN_CHUNK_STEPS: usize = 32;

/// `scale · F Fᵀ`, full `C x C` (both triangles), on `kernel`.
pub(crate) fn gram(kernel: Kernel, f: FeatureView<'_>, scale: f32) -> Vec<f32> {
    let (c, p) = (f.channels, f.pixels());
    let (row, col) = f.strides();
    let (cp, pp) = (c.div_ceil(MB) * MB, p.div_ceil(KS) * KS);
    let steps = pp / KS;
    let a = channel_blocks(f, cp, steps);
    // B: step s holds pixels 32 s .. 32 s + 32 of every channel.
    let b = PackedB::from_strided(p, c, f.data, (col, row));
    let blocks = cp / MB;
    let pairs: Vec<(usize, usize)> = (0..blocks).flat_map(|i| (i..blocks).map(move |j| (i, j))).collect();
    // Chunks of at least MIN_CHUNK_STEPS slices (a deep layer's few pixels
    // are one chunk): fixed by the shape, so sums do not depend on threads.
    let chunks = (steps / MIN_CHUNK_STEPS).clamp(1, CHUNKS);
    let chunk = steps.div_ceil(chunks);
    let offs: Vec<usize> = (0..steps).map(|s| s * MB * KS).collect();
    // One 32 x 32 partial block per (block pair, chunk), summed in chunk order.
    let partial: Vec<[f32; MB * NB]> = (0..pairs.len() * chunks)
        .into_par_iter()
        .map(|t| {
            let ((bi, bj), ch) = (pairs[t / chunks], t % chunks);
            let (s0, s1) = ((ch * chunk).min(steps), ((ch + 1) * chunk).min(steps));
            let mut blk = [0f32; MB * NB];
            if s0 < s1 {
                let a0 = a[bi * steps * MB * KS..].as_ptr();
                // SAFETY: channel block bi holds `steps` slices of 32 rows of
                // KS values; the pair holds `steps` steps; blk is 32 x 32.
                kernel.run(|ready| unsafe {
                    ready.block(
                        a0,
                        a0.add(16 * KS),
                        KS,
                        &offs[s0..s1],
                        b.pair(bj).as_ptr().add(s0 * bf16::B_STEP),
                        blk.as_mut_ptr(),
                        NB,
                    )
                });
            }
            blk
        })
        .collect();
    let mut g = vec![0.0f32; c * c];
    for (pi, &(bi, bj)) in pairs.iter().enumerate() {
        let mut sum = [0f32; MB * NB];
        for blk in &partial[pi * chunks..(pi + 1) * chunks] {
            sum.iter_mut().zip(blk).for_each(|(s, v)| *s += v);
        }
        let (rows, cols) = (MB.min(c - bi * MB), NB.min(c - bj * NB));
        // The block, then its mirror, each written along rows of g.
        for r in 0..rows {
            for j in 0..cols {
                g[(bi * MB + r) * c + bj * NB + j] = scale * sum[r * NB + j];
            }
        }
        for j in 0..cols {
            for r in 0..rows {
                g[(bj * NB + j) * c + bi * MB + r] = scale * sum[r * NB + j];
            }
        }
    }
    g
}

/// `F` as the block kernel's A, one 32-channel × 32-pixel slice after
/// another: `[channel block][step][row][32]` (zero past the pixels and the
/// channels). A tile's 16 rows are then 64 bytes apart, where rows of whole
/// pixel runs put them tens of kilobytes apart, in the same cache sets; and
/// a channels-last map is read one pixel's 32 channels at a time.
fn channel_blocks(f: FeatureView<'_>, cp: usize, steps: usize) -> Vec<u16> {
    let (c, p) = (f.channels, f.pixels());
    let (row, col) = f.strides();
    let len = cp * steps * KS;
    let mut a = Vec::with_capacity(len);
    a.spare_capacity_mut()[..len].par_chunks_mut(MB * KS).enumerate().for_each_init(
        || vec![0u16; KS * MB],
        |pixels, (t, slice)| {
            let (i0, s) = (t / steps * MB, t % steps);
            let (n, nk) = (MB.min(c.saturating_sub(i0)), KS.min(p.saturating_sub(s * KS)));
            // The slice pixel by pixel first (`pixels[kk][r]`, zero past the
            // pixels and channels), then transposed into place: a
            // channels-last map converts 32 contiguous channels at a time.
            pixels.fill(0);
            for kk in 0..nk {
                let (q, dst) = (s * KS + kk, &mut pixels[kk * MB..][..n]);
                if row == 1 {
                    bf16::convert(&f.data[q * col + i0..][..n], dst);
                } else {
                    dst.iter_mut().enumerate().for_each(|(r, d)| *d = bf16::from_f32(f.data[(i0 + r) * row + q * col]));
                }
            }
            for (r, out) in slice.chunks_exact_mut(KS).enumerate() {
                out.iter_mut().enumerate().for_each(|(kk, o)| *o = std::mem::MaybeUninit::new(pixels[kk * MB + r]));
            }
        },
    );
    // SAFETY: every slice was written whole just above.
    unsafe { a.set_len(len) };
    a
}

/// `scale · Fᵀ sym` as `P x C` (pixel-major), on `kernel`; `sym` is `C x C`
/// and symmetric.
pub(crate) fn gram_backward_channels_last(kernel: Kernel, f: FeatureView<'_>, sym: &[f32], scale: f32) -> Vec<f32> {
    let (c, p) = (f.channels, f.pixels());
    let (row, col) = f.strides();
    let cp = c.div_ceil(KS) * KS;
    let steps = cp / KS;
    let b = PackedB::from_strided(c, c, sym, (c, 1));
    let offs: Vec<usize> = (0..steps).map(|s| s * KS).collect();
    let mut out = vec![0.0f32; p * c];
    // Tasks of 32 pixels: their bf16 rows (channels contiguous) are made
    // on the spot, 32 + slack rows so the second A half stays in the buffer.
    out.par_chunks_mut(MB * c).enumerate().for_each(|(t, o)| {
        let q0 = t * MB;
        let nq = o.len() / c;
        let mut a = vec![0u16; MB * cp];
        for q in 0..nq {
            if row == 1 {
                bf16::convert(&f.data[(q0 + q) * col..][..c], &mut a[q * cp..][..c]);
            } else {
                for i in 0..c {
                    a[q * cp + i] = bf16::from_f32(f.data[i * row + (q0 + q) * col]);
                }
            }
        }
        let mut blk = [0f32; MB * NB];
        kernel.run(|ready| {
            for pair in 0..b.npairs {
                // SAFETY: a holds 32 rows of cp values; the pair holds
                // `steps` steps; blk is 32 x 32.
                unsafe {
                    ready.block(
                        a.as_ptr(),
                        a.as_ptr().add(16 * cp),
                        cp,
                        &offs,
                        b.pair(pair).as_ptr(),
                        blk.as_mut_ptr(),
                        NB,
                    )
                };
                for q in 0..nq {
                    for j in 0..NB.min(c - pair * NB) {
                        o[q * c + pair * NB + j] = scale * blk[q * NB + j];
                    }
                }
            }
        });
    });
    out
}
