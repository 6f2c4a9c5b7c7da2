//! The bf16 path of a 3x3 convolution: a direct convolution on the bf16
//! block kernel of `nst3d_core::bf16` (AMX tiles, AVX512-BF16 or the
//! portable emulation), fp32 accumulation.
//!
//! No Winograd here: its transforms amplify bf16's rounding (8-bit
//! mantissas, ~0.4 % per value) into errors of several percent, while a
//! direct sum of bf16 products keeps the error of the roundings alone. On
//! AMX the 4x more multiplies cost less than the transforms did. And no
//! im2col either: the source is copied once into a padded bf16 map, channels
//! fastest, and each of the 9 taps is just another offset into it — 16
//! consecutive output pixels read 16 consecutive padded pixels, one tile
//! row each (`nst3d_core::bf16` module docs).

use nst3d_core::bf16::{self, Kernel, PackedB, KS, MB, NB};
use rayon::prelude::*;

use crate::tensor::{take_buffer, FeatureMap, Source};

/// Whether the bf16 path takes a layer with these channel counts (the RGB
/// layer and its gradient stay fp32: 3 channels would waste a tile's 32).
pub(crate) fn supports(cin: usize, cout: usize) -> bool {
    cin >= 16 && cout >= 16
}

/// Frozen weights packed for the block kernel: step `tap * kslices + kb`
/// multiplies input channels `32 kb ..` of tap `tap` (`ky * 3 + kx`).
pub(crate) struct Bf16Conv {
    cin: usize,
    cout: usize,
    /// `cin` rounded up to [`KS`]: the padded map's channel stride.
    cinp: usize,
    w: PackedB,
}

impl Bf16Conv {
    /// From PyTorch-layout `[cout][cin][3][3]` weights (correlation).
    pub(crate) fn new(w: &[f32], cin: usize, cout: usize) -> Self {
        let cinp = cin.div_ceil(KS) * KS;
        let kslices = cinp / KS;
        let packed = PackedB::new(9 * kslices, cout, |step, k, n| {
            let (tap, ci) = (step / kslices, (step % kslices) * KS + k);
            if ci < cin {
                w[(n * cin + ci) * 9 + tap]
            } else {
                0.0
            }
        });
        Self { cin, cout, cinp, w: packed }
    }

    /// Convolves `src` to `out_h x out_w` ("valid" over the padded source),
    /// adding `bias` and applying ReLU when asked, with `kernel`.
    pub(crate) fn run(
        &self,
        kernel: Kernel,
        src: Source<'_>,
        out_h: usize,
        out_w: usize,
        bias: Option<&[f32]>,
        relu: bool,
    ) -> FeatureMap {
        assert_eq!(src.map.channels, self.cin);
        let (cinp, cout) = (self.cinp, self.cout);
        let (ph, pw) = (out_h + 2, out_w + 2);
        let mut padded = PADDED.lock().map(|mut s| std::mem::take(&mut *s)).unwrap_or_default();
        fill_padded(&mut padded, src, ph, pw, cinp);
        let kslices = cinp / KS;
        let offs: Vec<usize> = (0..9 * kslices)
            .map(|s| ((s / kslices / 3) * pw + (s / kslices) % 3) * cinp + (s % kslices) * KS)
            .collect();

        // Every output value is written once below: no zeroing.
        let mut data = take_buffer(out_h * out_w * cout);
        // SAFETY: f32 has no invalid bit patterns; each value is written by
        // the epilogue before the map is returned.
        unsafe { data.set_len(out_h * out_w * cout) };
        let band = out_h.div_ceil(8).clamp(1, 16);
        let zero = vec![0.0f32; cout];
        let bias = bias.unwrap_or(&zero);
        let pad_ref = &padded;
        data.par_chunks_mut(band * out_w * cout).enumerate().for_each(|(bi, rows)| {
            let y0 = bi * band;
            let nrows = rows.len() / (out_w * cout);
            kernel.run(|ready| {
                let mut c = [0f32; MB * NB];
                for pair in 0..self.w.npairs {
                    let b = self.w.pair(pair).as_ptr();
                    let (n0, nn) = (pair * NB, NB.min(cout - pair * NB));
                    for dy in 0..nrows {
                        for x0 in (0..out_w).step_by(MB) {
                            let a0 = ((y0 + dy) * pw + x0) * cinp;
                            // SAFETY: fill_padded leaves MB + 2 pixels of slack
                            // after the map, so the rows of a block past the
                            // right edge (discarded below) stay in the buffer.
                            unsafe {
                                ready.block(
                                    pad_ref.as_ptr().add(a0),
                                    pad_ref.as_ptr().add(a0 + 16 * cinp),
                                    cinp,
                                    &offs,
                                    b,
                                    c.as_mut_ptr(),
                                    NB,
                                );
                            }
                            let npx = MB.min(out_w - x0);
                            epilogue(
                                &c,
                                npx,
                                nn,
                                &bias[n0..n0 + nn],
                                relu,
                                &mut rows[(dy * out_w + x0) * cout + n0..],
                                cout,
                            );
                        }
                    }
                }
            })
        });
        if let Ok(mut s) = PADDED.lock() {
            *s = padded;
        }
        FeatureMap::from_vec(out_h, out_w, cout, data)
    }

    /// Bytes of packed weights.
    pub(crate) fn bytes(&self) -> usize {
        self.w.bytes()
    }
}

/// Bias, ReLU and the store of one block's `npx x nn` valid values.
#[inline(always)]
fn epilogue(c: &[f32; MB * NB], npx: usize, nn: usize, bias: &[f32], relu: bool, out: &mut [f32], cout: usize) {
    for r in 0..npx {
        let dst = &mut out[r * cout..r * cout + nn];
        for ((d, v), b) in dst.iter_mut().zip(&c[r * NB..r * NB + nn]).zip(bias) {
            let x = v + b;
            *d = if relu { x.max(0.0) } else { x };
        }
    }
}

/// The padded bf16 copy of `src`: `ph x pw` pixels of `cinp` channels
/// (zeros past the source's channels, at zero-padding and where the ReLU
/// mask is off), then `MB + 2` pixels of zero slack. Every value is written
/// once — no clearing pass over the whole buffer — and each run of
/// consecutive source pixels of a row is converted in one call (the
/// interior of a row is one run when the channels need no padding).
fn fill_padded(buf: &mut Vec<u16>, src: Source<'_>, ph: usize, pw: usize, cinp: usize) {
    let (map, mask) = (src.map, src.mask);
    let c = map.channels;
    buf.resize((ph * pw + MB + 2) * cinp, 0);
    let (body, slack) = buf.split_at_mut(ph * pw * cinp);
    slack.fill(0);
    let (ys, xs) = (src.axis_map(ph, map.height), src.axis_map(pw, map.width));
    let runs = column_runs(&xs);
    body.par_chunks_mut(pw * cinp).zip(&ys).for_each(|(row, sy)| {
        let Some(sy) = *sy else {
            row.fill(0);
            return;
        };
        for &(px, sx, n) in &runs {
            let dst = &mut row[px * cinp..(px + n) * cinp];
            let Some(sx) = sx else {
                dst.fill(0);
                continue;
            };
            let s = (sy * map.width + sx) * c;
            if cinp == c {
                let (from, to) = (&map.data[s..s + n * c], dst);
                match mask {
                    None => bf16::convert(from, to),
                    Some(m) => bf16::convert_masked(from, &m.data[s..s + n * c], to),
                }
                continue;
            }
            for (k, px_dst) in dst.chunks_exact_mut(cinp).enumerate() {
                let (from, (to, tail)) = (&map.data[s + k * c..s + (k + 1) * c], px_dst.split_at_mut(c));
                match mask {
                    None => bf16::convert(from, to),
                    Some(m) => bf16::convert_masked(from, &m.data[s + k * c..s + (k + 1) * c], to),
                }
                tail.fill(0);
            }
        }
    });
}

/// The padded columns `xs` (source column of each, `None` for zero
/// padding) as runs `(first padded column, first source column, length)`
/// of consecutive source columns, or of zero columns.
fn column_runs(xs: &[Option<usize>]) -> Vec<(usize, Option<usize>, usize)> {
    let mut runs: Vec<(usize, Option<usize>, usize)> = Vec::new();
    for (px, &sx) in xs.iter().enumerate() {
        if let Some((_, start, n)) = runs.last_mut() {
            let extends = match (*start, sx) {
                (None, None) => true,
                (Some(a), Some(b)) => b == a + *n,
                _ => false,
            };
            if extends {
                *n += 1;
                continue;
            }
        }
        runs.push((px, sx, 1));
    }
    runs
}

/// The padded map of the last finished convolution, handed to the next one
/// (a fresh multi-MB buffer per layer costs page faults).
static PADDED: std::sync::Mutex<Vec<u16>> = std::sync::Mutex::new(Vec::new());

#[cfg(test)]
mod tests {
    use super::column_runs;

    #[test]
    fn column_runs_split_at_jumps_and_padding() {
        // Zero padding: a zero column, the row, a zero column.
        assert_eq!(
            column_runs(&[None, Some(0), Some(1), Some(2), None]),
            [(0, None, 1), (1, Some(0), 3), (4, None, 1)]
        );
        // Reflection: 1 | 0 1 2 | 1.
        assert_eq!(
            column_runs(&[Some(1), Some(0), Some(1), Some(2), Some(1)]),
            [(0, Some(1), 1), (1, Some(0), 3), (4, Some(1), 1)]
        );
        assert!(column_runs(&[]).is_empty());
    }
}
