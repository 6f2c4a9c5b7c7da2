//! The bf16 path of [`crate::gram`] and [`crate::gram_backward`]: the same
//! products on the bf16 block kernel of `nst3d_core::bf16` (operands rounded
//! to bf16, sums in fp32), taken when the precision in force is bf16.
//!
//! `G = F Fᵀ`: `F` is copied once into bf16 rows (one per channel, the
//! pixels contiguous: the kernel's A) and once into the kernel's packed B
//! (pixel pairs interleaved); only blocks on and above the diagonal are
//! multiplied, and the long pixel axis is cut into a fixed number of chunks
//! summed in order, so the result does not depend on the thread count.
//! `dF = F · sym`: `F` in bf16 rows of channels (pixel-major) against the
//! small `C x C` matrix packed once.

use nst3d_core::bf16::{self, Kernel, PackedB, KS, MB, NB};
use nst3d_core::FeatureView;
use rayon::prelude::*;

/// Pixel chunks of one Gram (fixed, so sums do not depend on threads).
const CHUNKS: usize = 8;

/// `scale · F Fᵀ`, full `C x C` (both triangles), on `kernel`.
pub(crate) fn gram(kernel: Kernel, f: FeatureView<'_>, scale: f32) -> Vec<f32> {
    let (c, p) = (f.channels, f.pixels());
    let (row, col) = f.strides();
    let (cp, pp) = (c.div_ceil(MB) * MB, p.div_ceil(KS) * KS);
    let steps = pp / KS;
    // A: channel rows of bf16 pixels (zero past p and past c).
    let mut a = vec![0u16; cp * pp];
    a.par_chunks_mut(pp).take(c).enumerate().for_each(|(i, r)| {
        for (q, v) in r[..p].iter_mut().enumerate() {
            *v = bf16::from_f32(f.data[i * row + q * col]);
        }
    });
    // B: step s holds pixels 32 s .. 32 s + 32 of every channel.
    let b = PackedB::new(steps, c, |s, k, n| {
        let q = s * KS + k;
        if q < p {
            f.data[n * row + q * col]
        } else {
            0.0
        }
    });
    let blocks = cp / MB;
    let pairs: Vec<(usize, usize)> = (0..blocks).flat_map(|i| (i..blocks).map(move |j| (i, j))).collect();
    let chunk = steps.div_ceil(CHUNKS);
    let offs: Vec<usize> = (0..steps).map(|s| s * KS).collect();
    // One 32 x 32 partial block per (block pair, chunk), summed in chunk order.
    let partial: Vec<[f32; MB * NB]> = (0..pairs.len() * CHUNKS)
        .into_par_iter()
        .map(|t| {
            let ((bi, bj), ch) = (pairs[t / CHUNKS], t % CHUNKS);
            let (s0, s1) = ((ch * chunk).min(steps), ((ch + 1) * chunk).min(steps));
            let mut blk = [0f32; MB * NB];
            if s0 < s1 {
                let a0 = a[bi * MB * pp..].as_ptr();
                // SAFETY: rows bi*32 .. +32 of a hold pp values each; the
                // pair holds `steps` steps; blk is 32 x 32.
                kernel.run(|ready| unsafe {
                    ready.block(
                        a0,
                        a0.add(16 * pp),
                        pp,
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
        for blk in &partial[pi * CHUNKS..(pi + 1) * CHUNKS] {
            sum.iter_mut().zip(blk).for_each(|(s, v)| *s += v);
        }
        for r in 0..MB.min(c - bi * MB) {
            for j in 0..NB.min(c - bj * NB) {
                let v = scale * sum[r * NB + j];
                g[(bi * MB + r) * c + bj * NB + j] = v;
                g[(bj * NB + j) * c + bi * MB + r] = v;
            }
        }
    }
    g
}

/// `scale · Fᵀ sym` as `P x C` (pixel-major), on `kernel`; `sym` is `C x C`
/// and symmetric.
pub(crate) fn gram_backward_channels_last(kernel: Kernel, f: FeatureView<'_>, sym: &[f32], scale: f32) -> Vec<f32> {
    let (c, p) = (f.channels, f.pixels());
    let (row, col) = f.strides();
    let cp = c.div_ceil(KS) * KS;
    let steps = cp / KS;
    let b = PackedB::new(steps, c, |s, k, n| {
        let i = s * KS + k;
        if i < c {
            sym[i * c + n]
        } else {
            0.0
        }
    });
    let offs: Vec<usize> = (0..steps).map(|s| s * KS).collect();
    let mut out = vec![0.0f32; p * c];
    // Tasks of 32 pixels: their bf16 rows (channels contiguous) are made
    // on the spot, 32 + slack rows so the second A half stays in the buffer.
    out.par_chunks_mut(MB * c).enumerate().for_each(|(t, o)| {
        let q0 = t * MB;
        let nq = o.len() / c;
        let mut a = vec![0u16; MB * cp];
        for q in 0..nq {
            for i in 0..c {
                a[q * cp + i] = bf16::from_f32(f.data[i * row + (q0 + q) * col]);
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
