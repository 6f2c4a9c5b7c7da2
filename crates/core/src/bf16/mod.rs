//! bf16 operands with fp32 accumulation: the one micro-kernel every bf16
//! product of nst3d is built on (VGG-19 convolutions, the 3D network's
//! convolutions, Gram matrices, NNST matching), in three implementations
//! with one contract — AMX tiles ([`amx`]), AVX512-BF16 dot products, and
//! an emulation for CPUs with neither (AVX-512F FMAs on the bf16 values
//! widened exactly to f32, or scalar loops) — chosen by
//! `precision::Path`. The hardware kernels are checked against the
//! scalar one on this CPU before they are first used ([`self_check`]).
//!
//! The contract ([`Ready::block`]): a 32 × 32 fp32 block
//! `C = Σ_s A_s · B_s` over `steps` K-slices of 32, where
//! - `A_s` is two 16-row halves of bf16 rows, row `r` of half `h` at
//!   `a[h] + offs[s] + r * lda` (so a direct convolution's taps are just
//!   other offsets into the same padded activation: no im2col), and
//! - `B_s` is packed once (weights are frozen or reused): two 16-column
//!   tiles in the "VNNI" pair layout AMX and `vdpbf16ps` read, element
//!   `(k, n)` of a tile at row `k / 2`, position `2 n + k % 2`
//!   ([`PackedB`]).
//!
//! Every implementation multiplies the same bf16 values exactly and sums
//! in fp32; they differ only in summation order.
//!
//! A second shape, the tall block ([`Ready::block_tall`]: 64 rows from four
//! independent A pointers × 16 columns), serves products of at most 16
//! columns on AMX tiles (the 3D network's 16-channel layers), where the
//! 32 × 32 block would multiply zeros half the time.

pub mod amx;
mod matmul;

pub(crate) use matmul::matmul;

use rayon::prelude::*;

/// K (bf16 values) per step: one AMX tile row of 64 bytes.
pub const KS: usize = 32;
/// Rows of `C` per block (two A tiles of 16).
pub const MB: usize = 32;
/// Columns of `C` per block (two B tiles of 16).
pub const NB: usize = 32;
/// bf16 values in one packed B step (two 16 × 32 tiles).
pub const B_STEP: usize = 2 * 16 * KS;
/// Rows of `C` per tall block ([`Ready::block_tall`]: four A tiles).
pub const TALL_MB: usize = 64;
/// bf16 values in one B step of a tall block (one 16 × 32 tile).
pub const TALL_STEP: usize = 16 * KS;

/// Rounds to the nearest bf16, ties to even (NaN stays NaN).
#[inline(always)]
pub fn from_f32(x: f32) -> u16 {
    let b = x.to_bits();
    // Both results computed and one selected (no branch), so loops of
    // conversions vectorise.
    let rounded = b.wrapping_add(0x7fff + ((b >> 16) & 1)) >> 16;
    let quiet_nan = (b >> 16) | 0x40;
    (if b & 0x7fff_ffff > 0x7f80_0000 { quiet_nan } else { rounded }) as u16
}

/// The f32 a bf16 stands for (exact).
#[inline(always)]
pub fn to_f32(b: u16) -> f32 {
    f32::from_bits((b as u32) << 16)
}

/// `x` rounded through bf16 and back.
#[inline(always)]
pub fn round(x: f32) -> f32 {
    to_f32(from_f32(x))
}

/// Converts a slice (vectorised where AVX-512 is available).
pub fn convert(src: &[f32], dst: &mut [u16]) {
    assert_eq!(src.len(), dst.len(), "bf16 conversion lengths");
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx512f") {
        // SAFETY: the CPU has the enabled features.
        return unsafe { convert_avx512(src, dst) };
    }
    convert_plain(src, dst)
}

/// Converts `src` where `mask` is positive and writes 0 elsewhere (a ReLU's
/// mask applied on the way), vectorised where AVX-512 is available.
pub fn convert_masked(src: &[f32], mask: &[f32], dst: &mut [u16]) {
    assert!(src.len() == dst.len() && mask.len() == dst.len(), "bf16 masked conversion lengths");
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx512f") {
        // SAFETY: the CPU has the enabled features.
        return unsafe { convert_masked_avx512(src, mask, dst) };
    }
    convert_masked_plain(src, mask, dst)
}

#[inline(always)]
fn convert_masked_plain(src: &[f32], mask: &[f32], dst: &mut [u16]) {
    for ((d, s), m) in dst.iter_mut().zip(src).zip(mask) {
        // from_f32(0.0) is 0: select the value, then convert (no branch).
        *d = from_f32(if *m > 0.0 { *s } else { 0.0 });
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx2")]
unsafe fn convert_masked_avx512(src: &[f32], mask: &[f32], dst: &mut [u16]) {
    convert_masked_plain(src, mask, dst)
}

#[inline(always)]
fn convert_plain(src: &[f32], dst: &mut [u16]) {
    for (d, s) in dst.iter_mut().zip(src) {
        *d = from_f32(*s);
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx2")]
unsafe fn convert_avx512(src: &[f32], dst: &mut [u16]) {
    convert_plain(src, dst)
}

/// Whether the CPU has AVX512-BF16 (`vdpbf16ps`).
pub fn avx512_bf16_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx512bf16") && std::arch::is_x86_feature_detected!("avx512f")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// B operands packed for [`Ready::block`]: `npairs` column pairs of 32
/// (columns past `n` are zero) × `steps` K-slices of 32, laid out
/// `[pair][step][tile][k / 2][2 n + k % 2]`, so one block's B streams
/// contiguously.
#[derive(Clone, Debug, PartialEq)]
pub struct PackedB {
    /// Column blocks of [`NB`].
    pub npairs: usize,
    /// K-slices of [`KS`] per column block.
    pub steps: usize,
    data: Vec<u16>,
}

impl PackedB {
    /// Packs `value(step, k, n)` for `k < KS` and `n < ncols`; `None` (or
    /// columns past `ncols`) is zero.
    pub fn new(steps: usize, ncols: usize, value: impl Fn(usize, usize, usize) -> f32 + Sync) -> Self {
        let npairs = ncols.div_ceil(NB);
        let mut data = vec![0u16; npairs * steps * B_STEP];
        data.par_chunks_mut(B_STEP).enumerate().for_each(|(i, out)| {
            let (pair, step) = (i / steps, i % steps);
            for tile in 0..2 {
                for k in 0..KS {
                    for j in 0..16 {
                        let n = pair * NB + tile * 16 + j;
                        if n < ncols {
                            out[tile * 16 * KS + (k / 2) * KS + 2 * j + k % 2] = from_f32(value(step, k, n));
                        }
                    }
                }
            }
        });
        Self { npairs, steps, data }
    }

    /// Packs a strided `k x n` matrix, `B[q][j] = data[q * rs + j * cs]`
    /// (zero past `k` and `n`): [`PackedB::new`] with fast paths for
    /// row-major (`cs == 1`) and column-major (`rs == 1`) operands, whose
    /// pairs of rows or of values are read as contiguous runs — the 3D
    /// network repacks an im2col matrix every call, so this is on its
    /// critical path.
    pub fn from_strided(k: usize, n: usize, data: &[f32], (rs, cs): (usize, usize)) -> Self {
        let steps = k.div_ceil(KS);
        let npairs = n.div_ceil(NB);
        let mut out = vec![0u16; npairs * steps * B_STEP];
        out.par_chunks_mut(B_STEP).enumerate().for_each(|(i, o)| {
            let (pair, step) = (i / steps, i % steps);
            for tile in 0..2 {
                let n0 = pair * NB + tile * 16;
                if n0 >= n {
                    break;
                }
                let nn = 16.min(n - n0);
                let ot = &mut o[tile * 16 * KS..(tile + 1) * 16 * KS];
                for kp in 0..KS / 2 {
                    let q = step * KS + 2 * kp;
                    if q >= k {
                        break;
                    }
                    let row = &mut ot[kp * KS..kp * KS + 2 * nn];
                    if cs == 1 {
                        let r0 = &data[q * rs + n0..q * rs + n0 + nn];
                        let r1 = (q + 1 < k).then(|| &data[(q + 1) * rs + n0..(q + 1) * rs + n0 + nn]);
                        interleave_rows(r0, r1, row);
                    } else if rs == 1 {
                        for (j, d) in row.chunks_exact_mut(2).enumerate() {
                            let at = (n0 + j) * cs + q;
                            d[0] = from_f32(data[at]);
                            if q + 1 < k {
                                d[1] = from_f32(data[at + 1]);
                            }
                        }
                    } else {
                        for (j, d) in row.chunks_exact_mut(2).enumerate() {
                            d[0] = from_f32(data[q * rs + (n0 + j) * cs]);
                            if q + 1 < k {
                                d[1] = from_f32(data[(q + 1) * rs + (n0 + j) * cs]);
                            }
                        }
                    }
                }
            }
        });
        Self { npairs, steps, data: out }
    }

    /// The B of column block `pair`: `steps * B_STEP` values.
    pub fn pair(&self, pair: usize) -> &[u16] {
        &self.data[pair * self.steps * B_STEP..(pair + 1) * self.steps * B_STEP]
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.data.len() * 2
    }
}

/// One implementation of the block product.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kernel {
    /// AMX tiles.
    Amx,
    /// AVX512-BF16.
    Avx512,
    /// Emulation on AVX-512F: bf16 widened to f32 (exact), fp32 FMAs.
    Emulated,
    /// The same emulation on AVX2 + FMA (CPUs without AVX-512).
    EmulatedAvx2,
    /// Scalar emulation: the reference.
    Portable,
}

impl Kernel {
    /// The kernel for bf16 without a bf16 unit: the AVX-512F emulation, or
    /// the scalar reference.
    pub fn without_unit() -> Self {
        if has_avx512f() {
            Kernel::Emulated
        } else if crate::microkernel::has_avx2() {
            Kernel::EmulatedAvx2
        } else {
            Kernel::Portable
        }
    }

    /// Every kernel this machine can run, the scalar reference first.
    pub fn all_here() -> Vec<Kernel> {
        let mut k = vec![Kernel::Portable];
        if crate::microkernel::has_avx2() {
            k.push(Kernel::EmulatedAvx2);
        }
        if has_avx512f() {
            k.push(Kernel::Emulated);
        }
        if avx512_bf16_available() {
            k.push(Kernel::Avx512);
        }
        if amx::available() {
            k.push(Kernel::Amx);
        }
        k
    }

    /// Runs `f` with this kernel ready on the calling thread (AMX: tiles
    /// configured before, released after). Call [`Ready::block`] only
    /// inside, with the [`Ready`] token, and start no rayon work inside.
    #[inline]
    pub fn run<R>(self, f: impl FnOnce(Ready) -> R) -> R {
        match self {
            Kernel::Amx => amx::with_tiles(|| f(Ready { kernel: self })),
            _ => f(Ready { kernel: self }),
        }
    }
}

/// Proof that the kernel is ready on this thread (see [`Kernel::run`]).
#[derive(Clone, Copy, Debug)]
pub struct Ready {
    kernel: Kernel,
}

impl Ready {
    /// `c[r * ldc + j] = Σ_s Σ_k A_s[r][k] · B_s[k][j]` for `r, j < 32`
    /// (see the module docs for the operands).
    ///
    /// # Safety
    /// For every step `s` and row `r < 16`, `a0 + offs[s] + r * lda` and
    /// `a1 + offs[s] + r * lda` must be valid for reading [`KS`] values; `b`
    /// must hold `offs.len() * B_STEP` values; `c` 32 rows of 32 floats at
    /// stride `ldc`.
    #[inline]
    #[allow(clippy::too_many_arguments)]
    pub unsafe fn block(
        self,
        a0: *const u16,
        a1: *const u16,
        lda: usize,
        offs: &[usize],
        b: *const u16,
        c: *mut f32,
        ldc: usize,
    ) {
        match self.kernel {
            #[cfg(target_arch = "x86_64")]
            Kernel::Amx => amx::block(a0, a1, lda, offs, b, c, ldc),
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx512 => block_avx512(a0, a1, lda, offs, b, c, ldc),
            #[cfg(target_arch = "x86_64")]
            Kernel::Emulated => block_emulated(a0, a1, lda, offs, b, c, ldc),
            #[cfg(target_arch = "x86_64")]
            Kernel::EmulatedAvx2 => block_emulated_avx2(a0, a1, lda, offs, b, c, ldc),
            _ => block_portable(a0, a1, lda, offs, b, c, ldc),
        }
    }

    /// The tall block, for products with at most 16 columns (a 32 × 32
    /// block would leave half its tiles zero):
    /// `c[r * ldc + j] = Σ_s Σ_k A_s[r][k] · B_s[k][j]` for `r < 64`,
    /// `j < 16`, row `r` of `A_s` at `a[r / 16] + offs[s] + (r % 16) * lda`,
    /// `B_s` one VNNI tile of [`TALL_STEP`] values per step (element
    /// `(k, n)` at `(k / 2) * 32 + 2 n + k % 2`). On AMX tiles; every other
    /// kernel runs the scalar reference (the convolutions that use it take
    /// it only where AMX is).
    ///
    /// # Safety
    /// As [`Ready::block`], for four A pointers, `offs.len() * TALL_STEP`
    /// values of `b` and 64 rows of 16 floats of `c`.
    #[inline]
    pub unsafe fn block_tall(
        self,
        a: [*const u16; 4],
        lda: usize,
        offs: &[usize],
        b: *const u16,
        c: *mut f32,
        ldc: usize,
    ) {
        match self.kernel {
            #[cfg(target_arch = "x86_64")]
            Kernel::Amx => amx::block_tall(a, lda, offs, b, c, ldc),
            _ => block_tall_portable(a, lda, offs, b, c, ldc),
        }
    }
}

/// Scalar [`Ready::block_tall`].
unsafe fn block_tall_portable(a: [*const u16; 4], lda: usize, offs: &[usize], b: *const u16, c: *mut f32, ldc: usize) {
    for r in 0..TALL_MB {
        let mut acc = [0f32; 16];
        for (s, &o) in offs.iter().enumerate() {
            let arow = a[r / 16].add(o + (r % 16) * lda);
            let bs = b.add(s * TALL_STEP);
            for k in 0..KS {
                let av = to_f32(*arow.add(k));
                for (j, x) in acc.iter_mut().enumerate() {
                    *x += av * to_f32(*bs.add((k / 2) * KS + 2 * j + k % 2));
                }
            }
        }
        std::ptr::copy_nonoverlapping(acc.as_ptr(), c.add(r * ldc), 16);
    }
}

/// Scalar [`Ready::block`]: the reference the fast kernels are tested against.
unsafe fn block_portable(
    a0: *const u16,
    a1: *const u16,
    lda: usize,
    offs: &[usize],
    b: *const u16,
    c: *mut f32,
    ldc: usize,
) {
    let mut acc = [[0f32; NB]; MB];
    for (s, &o) in offs.iter().enumerate() {
        let bs = b.add(s * B_STEP);
        for (r, acc_r) in acc.iter_mut().enumerate() {
            let arow = if r < 16 { a0.add(o + r * lda) } else { a1.add(o + (r - 16) * lda) };
            for k in 0..KS {
                let av = to_f32(*arow.add(k));
                for (j, x) in acc_r.iter_mut().enumerate() {
                    let bv = to_f32(*bs.add((j / 16) * 16 * KS + (k / 2) * KS + 2 * (j % 16) + k % 2));
                    *x += av * bv;
                }
            }
        }
    }
    for (r, acc_r) in acc.iter().enumerate() {
        std::ptr::copy_nonoverlapping(acc_r.as_ptr(), c.add(r * ldc), NB);
    }
}

/// [`Ready::block`] on `vdpbf16ps`: one 16 × 16 quarter at a time, 16
/// accumulator registers, each A pair broadcast against a B row of 16 pairs.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bf16")]
unsafe fn block_avx512(
    a0: *const u16,
    a1: *const u16,
    lda: usize,
    offs: &[usize],
    b: *const u16,
    c: *mut f32,
    ldc: usize,
) {
    use std::arch::x86_64::*;
    for (h, a) in [a0, a1].into_iter().enumerate() {
        for t in 0..2 {
            let mut acc = [_mm512_setzero_ps(); 16];
            for (s, &o) in offs.iter().enumerate() {
                let bt = b.add(s * B_STEP + t * 16 * KS);
                let arow = a.add(o);
                for kp in 0..16 {
                    let bv: __m512bh = std::mem::transmute(_mm512_loadu_si512(bt.add(kp * KS) as *const _));
                    for (r, x) in acc.iter_mut().enumerate() {
                        let pair = (arow.add(r * lda + 2 * kp) as *const i32).read_unaligned();
                        let av: __m512bh = std::mem::transmute(_mm512_set1_epi32(pair));
                        *x = _mm512_dpbf16_ps(*x, av, bv);
                    }
                }
            }
            for (r, x) in acc.iter().enumerate() {
                _mm512_storeu_ps(c.add((h * 16 + r) * ldc + t * 16), *x);
            }
        }
    }
}

/// [`Ready::block`] for AVX-512F CPUs without bf16 units: each B row of 16
/// pairs splits into its even-k and odd-k halves (a shift and a mask widen
/// bf16 to f32 exactly) and two fp32 FMAs do what one `vdpbf16ps` does.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn block_emulated(
    a0: *const u16,
    a1: *const u16,
    lda: usize,
    offs: &[usize],
    b: *const u16,
    c: *mut f32,
    ldc: usize,
) {
    use std::arch::x86_64::*;
    let hi = _mm512_set1_epi32(0xffff_0000u32 as i32);
    for (h, a) in [a0, a1].into_iter().enumerate() {
        for t in 0..2 {
            let mut acc = [_mm512_setzero_ps(); 16];
            for (s, &o) in offs.iter().enumerate() {
                let bt = b.add(s * B_STEP + t * 16 * KS);
                let arow = a.add(o);
                for kp in 0..16 {
                    let bv = _mm512_loadu_si512(bt.add(kp * KS) as *const _);
                    let be = _mm512_castsi512_ps(_mm512_slli_epi32::<16>(bv));
                    let bo = _mm512_castsi512_ps(_mm512_and_si512(bv, hi));
                    for (r, x) in acc.iter_mut().enumerate() {
                        let pair = (arow.add(r * lda + 2 * kp) as *const u32).read_unaligned();
                        let ae = _mm512_set1_ps(f32::from_bits(pair << 16));
                        let ao = _mm512_set1_ps(f32::from_bits(pair & 0xffff_0000));
                        *x = _mm512_fmadd_ps(ao, bo, _mm512_fmadd_ps(ae, be, *x));
                    }
                }
            }
            for (r, x) in acc.iter().enumerate() {
                _mm512_storeu_ps(c.add((h * 16 + r) * ldc + t * 16), *x);
            }
        }
    }
}

/// [`block_emulated`] on AVX2 + FMA: 16 registers of 8 lanes, so a 16 × 16
/// quarter runs four rows at a time (8 accumulators, a B row of 16 pairs
/// widened into four even/odd halves).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn block_emulated_avx2(
    a0: *const u16,
    a1: *const u16,
    lda: usize,
    offs: &[usize],
    b: *const u16,
    c: *mut f32,
    ldc: usize,
) {
    use std::arch::x86_64::*;
    const ROWS: usize = 4;
    let hi = _mm256_set1_epi32(0xffff_0000u32 as i32);
    for (h, a) in [a0, a1].into_iter().enumerate() {
        for t in 0..2 {
            for r0 in (0..16).step_by(ROWS) {
                let mut acc = [[_mm256_setzero_ps(); 2]; ROWS];
                for (s, &o) in offs.iter().enumerate() {
                    let bt = b.add(s * B_STEP + t * 16 * KS);
                    let arow = a.add(o + r0 * lda);
                    for kp in 0..16 {
                        let bp = bt.add(kp * KS);
                        let bv = [_mm256_loadu_si256(bp as *const _), _mm256_loadu_si256(bp.add(16) as *const _)];
                        let be = bv.map(|v| _mm256_castsi256_ps(_mm256_slli_epi32::<16>(v)));
                        let bo = bv.map(|v| _mm256_castsi256_ps(_mm256_and_si256(v, hi)));
                        for (r, x) in acc.iter_mut().enumerate() {
                            let pair = (arow.add(r * lda + 2 * kp) as *const u32).read_unaligned();
                            let ae = _mm256_set1_ps(f32::from_bits(pair << 16));
                            let ao = _mm256_set1_ps(f32::from_bits(pair & 0xffff_0000));
                            for q in 0..2 {
                                x[q] = _mm256_fmadd_ps(ao, bo[q], _mm256_fmadd_ps(ae, be[q], x[q]));
                            }
                        }
                    }
                }
                for (r, x) in acc.iter().enumerate() {
                    let dst = c.add((h * 16 + r0 + r) * ldc + t * 16);
                    _mm256_storeu_ps(dst, x[0]);
                    _mm256_storeu_ps(dst.add(8), x[1]);
                }
            }
        }
    }
}

/// `out[2 j] = bf16(r0[j])`, `out[2 j + 1] = bf16(r1[j])` (0 without `r1`):
/// two rows of B into one VNNI row, 16 lanes at a time with AVX-512.
fn interleave_rows(r0: &[f32], r1: Option<&[f32]>, out: &mut [u16]) {
    #[inline(always)]
    fn plain(r0: &[f32], r1: Option<&[f32]>, out: &mut [u16]) {
        for (j, d) in out.chunks_exact_mut(2).enumerate() {
            d[0] = from_f32(r0[j]);
            d[1] = r1.map_or(0, |r| from_f32(r[j]));
        }
    }
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512bw,avx2")]
    unsafe fn wide(r0: &[f32], r1: Option<&[f32]>, out: &mut [u16]) {
        if r0.len() == 16 && out.len() == 32 {
            let (mut lo, mut hi) = ([0u32; 16], [0u32; 16]);
            for j in 0..16 {
                lo[j] = from_f32(r0[j]) as u32;
            }
            if let Some(r1) = r1 {
                for j in 0..16 {
                    hi[j] = (from_f32(r1[j]) as u32) << 16;
                }
            }
            for j in 0..16 {
                let v = lo[j] | hi[j];
                out[2 * j] = v as u16;
                out[2 * j + 1] = (v >> 16) as u16;
            }
        } else {
            plain(r0, r1, out)
        }
    }
    #[cfg(target_arch = "x86_64")]
    if has_avx512f() {
        // SAFETY: the CPU has the enabled features.
        return unsafe { wide(r0, r1, out) };
    }
    plain(r0, r1, out)
}

/// Whether AVX-512F may be used (`NST3D_NO_AVX512` hides it, as for the
/// fp32 kernels).
pub fn has_avx512f() -> bool {
    crate::microkernel::has_avx512()
}

/// Runs `kernel` on a fixed block with awkward strides and offsets and
/// compares it with the scalar reference: a hardware path that disagrees
/// (a CPU or hypervisor that misreports, a kernel bug on hardware the tests
/// never ran on) is not used. Cost: microseconds, once per kernel.
pub fn self_check(kernel: Kernel) -> bool {
    let (lda, steps, ldc) = (80usize, 3usize, 40usize);
    let vals = |n: usize, seed: u32| -> Vec<f32> {
        (0..n)
            .map(|i| ((i as u32).wrapping_mul(2654435761).wrapping_add(seed) >> 8) as f32 / (1 << 24) as f32 - 0.5)
            .collect()
    };
    let a: Vec<u16> = vals(72 * lda + 64, 1).iter().map(|v| from_f32(*v)).collect();
    let bv = vals(steps * KS * NB, 2);
    let packed = PackedB::new(steps, NB, |s, k, n| bv[(s * KS + k) * NB + n]);
    let offs = [0usize, 33, 7];
    let run = |k: Kernel| {
        let mut c = vec![f32::NAN; MB * ldc];
        k.run(|ready| unsafe {
            ready.block(a.as_ptr(), a.as_ptr().add(20 * lda), lda, &offs, packed.pair(0).as_ptr(), c.as_mut_ptr(), ldc)
        });
        c
    };
    let (want, got) = (run(Kernel::Portable), run(kernel));
    (0..MB).all(|r| {
        (0..NB).all(|j| (got[r * ldc + j] - want[r * ldc + j]).abs() <= 1e-5 * (1.0 + want[r * ldc + j].abs()))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gradcheck::pseudo_random;

    #[test]
    fn rounding_is_nearest_even() {
        assert_eq!(round(1.0), 1.0);
        // 1 + 2^-8 lies halfway between 1 and 1 + 2^-7: ties to even (1).
        assert_eq!(round(1.0 + 1.0 / 256.0), 1.0);
        assert_eq!(round(1.0 + 3.0 / 256.0), 1.0 + 4.0 / 256.0);
        assert!(round(f32::NAN).is_nan());
        assert_eq!(round(f32::INFINITY), f32::INFINITY);
        assert_eq!(round(-0.0).to_bits(), (-0.0f32).to_bits());
        let mut out = [0u16; 3];
        convert(&[1.5, -2.0, 3.0e-3], &mut out);
        assert_eq!(out.map(to_f32), [1.5, -2.0, round(3.0e-3)]);
    }

    /// Every kernel this machine has against an f64 sum of the same bf16
    /// values: strided rows, per-step offsets, several steps.
    #[test]
    fn kernels_match_reference() {
        let (lda, steps, ldc) = (80usize, 3usize, 40usize);
        let rows = 16 + 16 + 40;
        let a: Vec<u16> = pseudo_random(rows * lda + 64, 1).iter().map(|v| from_f32(*v)).collect();
        let bv = pseudo_random(steps * KS * NB, 2);
        let packed = PackedB::new(steps, NB, |s, k, n| bv[(s * KS + k) * NB + n]);
        let offs = [0usize, 33, 7];
        let (a0, a1) = (0usize, 20 * lda);
        let mut want = vec![0f64; MB * NB];
        for r in 0..MB {
            let base = if r < 16 { a0 + r * lda } else { a1 + (r - 16) * lda };
            for j in 0..NB {
                want[r * NB + j] = (0..steps)
                    .flat_map(|s| (0..KS).map(move |k| (s, k)))
                    .map(|(s, k)| to_f32(a[base + offs[s] + k]) as f64 * round(bv[(s * KS + k) * NB + j]) as f64)
                    .sum();
            }
        }
        for k in Kernel::all_here() {
            assert!(self_check(k), "{k:?} fails its self-check");
            let mut c = vec![f32::NAN; MB * ldc];
            k.run(|ready| unsafe {
                ready.block(
                    a.as_ptr().add(a0),
                    a.as_ptr().add(a1),
                    lda,
                    &offs,
                    packed.pair(0).as_ptr(),
                    c.as_mut_ptr(),
                    ldc,
                )
            });
            for r in 0..MB {
                for j in 0..NB {
                    let (got, w) = (c[r * ldc + j] as f64, want[r * NB + j]);
                    assert!((got - w).abs() < 1e-5 * (1.0 + w.abs()), "{k:?} ({r}, {j}): {got} vs {w}");
                }
            }
        }
    }

    /// The tall block on every kernel here (AMX where the CPU has it, the
    /// scalar reference everywhere) against an f64 sum: four unrelated A
    /// pointers, per-step offsets, a wide `ldc`.
    #[test]
    fn tall_block_matches_reference() {
        let (lda, steps, ldc) = (70usize, 3usize, 24usize);
        let a: Vec<u16> = pseudo_random(90 * lda + 64, 5).iter().map(|v| from_f32(*v)).collect();
        let bv = pseudo_random(steps * KS * 16, 6);
        let mut packed = vec![0u16; steps * TALL_STEP];
        for s in 0..steps {
            for k in 0..KS {
                for j in 0..16 {
                    packed[s * TALL_STEP + (k / 2) * KS + 2 * j + k % 2] = from_f32(bv[(s * KS + k) * 16 + j]);
                }
            }
        }
        let starts = [0usize, 40 * lda, 17 * lda + 3, 70 * lda + 1];
        let offs = [5usize, 0, 41];
        for kernel in Kernel::all_here() {
            let mut c = vec![f32::NAN; TALL_MB * ldc];
            let ptrs = starts.map(|o| unsafe { a.as_ptr().add(o) });
            kernel.run(|ready| unsafe { ready.block_tall(ptrs, lda, &offs, packed.as_ptr(), c.as_mut_ptr(), ldc) });
            for r in 0..TALL_MB {
                for j in 0..16 {
                    let base = starts[r / 16] + (r % 16) * lda;
                    let want: f64 = (0..steps)
                        .flat_map(|s| (0..KS).map(move |k| (s, k)))
                        .map(|(s, k)| to_f32(a[base + offs[s] + k]) as f64 * round(bv[(s * KS + k) * 16 + j]) as f64)
                        .sum();
                    let got = c[r * ldc + j] as f64;
                    assert!((got - want).abs() < 1e-5 * (1.0 + want.abs()), "{kernel:?} ({r}, {j}): {got} vs {want}");
                }
            }
        }
    }

    /// The fast strided packers give exactly what the generic one gives.
    #[test]
    fn strided_packing_matches_generic() {
        let (k, n) = (45, 37);
        let v = pseudo_random(k * n, 9);
        let want =
            PackedB::new(k.div_ceil(KS), n, |s, kk, j| if s * KS + kk < k { v[(s * KS + kk) * n + j] } else { 0.0 });
        assert_eq!(PackedB::from_strided(k, n, &v, (n, 1)), want);
        let t: Vec<f32> = (0..n * k).map(|i| v[(i % k) * n + i / k]).collect(); // column-major copy
        assert_eq!(PackedB::from_strided(k, n, &t, (1, k)), want);
        let wide: Vec<f32> = (0..k * n * 2).map(|i| if i % 2 == 0 { v[i / 2] } else { f32::NAN }).collect();
        assert_eq!(PackedB::from_strided(k, n, &wide, (2 * n, 2)), want);
    }

    #[test]
    fn packing_zeroes_columns_past_the_end() {
        let p = PackedB::new(1, 20, |_, k, n| (k * 100 + n) as f32);
        assert_eq!(p.npairs, 1);
        let b = p.pair(0);
        // Tile 1 holds columns 16..32; column 19 (j = 3) is set, 20 (j = 4) is zero.
        assert_eq!(to_f32(b[16 * KS + (5 / 2) * KS + 2 * 3 + 1]), round(519.0));
        assert_eq!(b[16 * KS + 2 * 4], 0);
    }
}
