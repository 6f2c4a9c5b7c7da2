//! The small fp32 dense product at the heart of the Winograd convolution
//! (`nst3d-features`) and of NNST matching (`nst3d-loss`):
//! `C[mr x nr] = A[mr x K] * B[K x nr]`, with `A` rows strided (transformed
//! tiles or hyper-columns, K contiguous) and `B` a pre-packed panel
//! (`K x nr` contiguous, prepared once because it is frozen or reused).
//!
//! An AVX-512 register-blocked kernel is chosen at run time, an AVX2 one
//! (6 rows x 16 columns a pass, the 12 accumulators AVX2's 16 registers
//! leave room for) on CPUs without AVX-512; a portable version with the
//! same contract serves other machines and is the reference in tests. (The
//! bf16 counterpart is [`crate::bf16`].)

/// Every block of rows is padded to a multiple of this many rows: a
/// multiple of each [`Blocking::mr`].
pub const ROW_ALIGN: usize = 12;
/// Narrowest panel.
pub const NR_MIN: usize = 32;

/// Register blocking of one kernel call: `mr` rows of `A` (tiles) times an
/// `nr`-wide panel of `B` (output channels), 24 accumulator registers either
/// way. Wide panels (6 x 64) need fewer loads per multiply-add and measured
/// ~10-40% faster than 12 x 32; the narrow one serves `cout = 32 (mod 64)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Blocking {
    /// Rows (tiles) per call.
    pub mr: usize,
    /// Panel width (output channels) per call.
    pub nr: usize,
}

impl Blocking {
    /// The fastest blocking that divides `cout` (a multiple of [`NR_MIN`]).
    pub fn for_cout(cout: usize) -> Self {
        if cout.is_multiple_of(64) {
            Self { mr: 6, nr: 64 }
        } else {
            Self { mr: 12, nr: 32 }
        }
    }
}

/// Whether the AVX-512 kernel may be used on this machine (checked once).
pub fn has_avx512() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        use std::sync::OnceLock;
        static HAS: OnceLock<bool> = OnceLock::new();
        *HAS.get_or_init(|| is_x86_feature_detected!("avx512f") && std::env::var_os("NST3D_NO_AVX512").is_none())
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Whether the AVX2 + FMA kernels may be used on this machine (checked
/// once; `NST3D_NO_AVX2` hides them, so the portable path can be run on any
/// machine).
pub fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        use std::sync::OnceLock;
        static HAS: OnceLock<bool> = OnceLock::new();
        *HAS.get_or_init(|| {
            is_x86_feature_detected!("avx2")
                && is_x86_feature_detected!("fma")
                && std::env::var_os("NST3D_NO_AVX2").is_none()
        })
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// `c[r * ldc + j] = sum_k a[r * lda + k] * b[k * nr + j]` for `r < mr`, `j < nr`.
///
/// # Safety
/// `a` must hold `bl.mr` rows of `k` values at stride `lda`, `b` `k * bl.nr`
/// values and `c` `bl.mr` rows of `bl.nr` values at stride `ldc`.
#[inline]
pub unsafe fn kernel(bl: Blocking, a: *const f32, lda: usize, b: *const f32, k: usize, c: *mut f32, ldc: usize) {
    #[cfg(target_arch = "x86_64")]
    if has_avx512() {
        return match bl.nr {
            64 => kernel_avx512::<6, 4>(a, lda, b, k, c, ldc),
            _ => kernel_avx512::<12, 2>(a, lda, b, k, c, ldc),
        };
    }
    #[cfg(target_arch = "x86_64")]
    if has_avx2() {
        return kernel_avx2(bl, a, lda, b, k, c, ldc);
    }
    kernel_portable(bl, a, lda, b, k, c, ldc)
}

/// Portable reference of [`kernel`] (same contract).
///
/// # Safety
/// As [`kernel`].
pub unsafe fn kernel_portable(
    bl: Blocking,
    a: *const f32,
    lda: usize,
    b: *const f32,
    k: usize,
    c: *mut f32,
    ldc: usize,
) {
    let mut acc = [[0f32; 64]; 12];
    for kk in 0..k {
        let brow = std::slice::from_raw_parts(b.add(kk * bl.nr), bl.nr);
        for (r, acc_r) in acc.iter_mut().enumerate().take(bl.mr) {
            let av = *a.add(r * lda + kk);
            for (x, bv) in acc_r.iter_mut().zip(brow) {
                *x += av * bv;
            }
        }
    }
    for (r, acc_r) in acc.iter().enumerate().take(bl.mr) {
        std::ptr::copy_nonoverlapping(acc_r.as_ptr(), c.add(r * ldc), bl.nr);
    }
}

/// AVX-512 version of [`kernel`] for `M` rows x `NV` 16-lane vectors, `A`
/// values broadcast straight from memory. One advancing `A` pointer with
/// constant row offsets keeps everything in registers (an array of row
/// pointers spilled and ran at a third of this speed).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn kernel_avx512<const M: usize, const NV: usize>(
    a: *const f32,
    lda: usize,
    b: *const f32,
    k: usize,
    c: *mut f32,
    ldc: usize,
) {
    use std::arch::x86_64::*;
    let mut acc = [[_mm512_setzero_ps(); NV]; M];
    let (mut ap, mut bp) = (a, b);
    for _ in 0..k {
        let mut bv = [_mm512_setzero_ps(); NV];
        for (v, x) in bv.iter_mut().enumerate() {
            *x = _mm512_loadu_ps(bp.add(16 * v));
        }
        bp = bp.add(16 * NV);
        for (r, acc_r) in acc.iter_mut().enumerate() {
            let av = _mm512_set1_ps(*ap.add(r * lda));
            for (x, bvv) in acc_r.iter_mut().zip(&bv) {
                *x = _mm512_fmadd_ps(av, *bvv, *x);
            }
        }
        ap = ap.add(1);
    }
    for (r, acc_r) in acc.iter().enumerate() {
        for (v, x) in acc_r.iter().enumerate() {
            _mm512_storeu_ps(c.add(r * ldc + 16 * v), *x);
        }
    }
}

/// AVX2 version of [`kernel`]: the block in passes of 6 rows x 16 columns
/// (two 8-lane vectors), each over all of `k` with its 12 accumulators in
/// registers; `A` rows stay in L1 between the passes over the panel.
///
/// # Safety
/// As [`kernel`], and the CPU must have AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
pub unsafe fn kernel_avx2(bl: Blocking, a: *const f32, lda: usize, b: *const f32, k: usize, c: *mut f32, ldc: usize) {
    const M: usize = 6;
    for r0 in (0..bl.mr).step_by(M) {
        for j0 in (0..bl.nr).step_by(16) {
            pass_avx2::<M>(a.add(r0 * lda), lda, b.add(j0), bl.nr, k, c.add(r0 * ldc + j0), ldc);
        }
    }
}

/// One `M x 16` pass of [`kernel_avx2`]: `b` is the pass's first column of
/// a panel `ldb` wide.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
unsafe fn pass_avx2<const M: usize>(
    a: *const f32,
    lda: usize,
    b: *const f32,
    ldb: usize,
    k: usize,
    c: *mut f32,
    ldc: usize,
) {
    use std::arch::x86_64::*;
    let mut acc = [[_mm256_setzero_ps(); 2]; M];
    let (mut ap, mut bp) = (a, b);
    for _ in 0..k {
        let bv = [_mm256_loadu_ps(bp), _mm256_loadu_ps(bp.add(8))];
        for (r, acc_r) in acc.iter_mut().enumerate() {
            let av = _mm256_broadcast_ss(&*ap.add(r * lda));
            acc_r[0] = _mm256_fmadd_ps(av, bv[0], acc_r[0]);
            acc_r[1] = _mm256_fmadd_ps(av, bv[1], acc_r[1]);
        }
        ap = ap.add(1);
        bp = bp.add(ldb);
    }
    for (r, acc_r) in acc.iter().enumerate() {
        _mm256_storeu_ps(c.add(r * ldc), acc_r[0]);
        _mm256_storeu_ps(c.add(r * ldc + 8), acc_r[1]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gradcheck::pseudo_random;

    #[test]
    fn fast_kernel_matches_portable() {
        for cout in [32, 64] {
            let bl = Blocking::for_cout(cout);
            let (k, lda, ldc) = (37, 41, 72);
            let a = pseudo_random(bl.mr * lda, 1);
            let b = pseudo_random(k * bl.nr, 2);
            let mut c1 = vec![0.0; bl.mr * ldc];
            let mut c2 = vec![0.0; bl.mr * ldc];
            unsafe {
                kernel(bl, a.as_ptr(), lda, b.as_ptr(), k, c1.as_mut_ptr(), ldc);
                kernel_portable(bl, a.as_ptr(), lda, b.as_ptr(), k, c2.as_mut_ptr(), ldc);
            }
            for (x, y) in c1.iter().zip(&c2) {
                assert!((x - y).abs() < 1e-4, "{x} vs {y}");
            }
        }
    }

    /// The AVX2 kernel (run wherever the CPU has AVX2, AVX-512 machines
    /// included) against the portable reference, both blockings.
    #[test]
    fn avx2_kernel_matches_portable() {
        #[cfg(target_arch = "x86_64")]
        {
            if !(is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")) {
                eprintln!("no AVX2 here: nothing to compare");
                return;
            }
            for cout in [32, 64] {
                let bl = Blocking::for_cout(cout);
                let (k, lda, ldc) = (37, 41, 72);
                let a = pseudo_random(bl.mr * lda, 3);
                let b = pseudo_random(k * bl.nr, 4);
                let mut c1 = vec![0.0; bl.mr * ldc];
                let mut c2 = vec![0.0; bl.mr * ldc];
                // SAFETY: the CPU has AVX2 and FMA; the operands hold what the contract reads.
                unsafe {
                    kernel_avx2(bl, a.as_ptr(), lda, b.as_ptr(), k, c1.as_mut_ptr(), ldc);
                    kernel_portable(bl, a.as_ptr(), lda, b.as_ptr(), k, c2.as_mut_ptr(), ldc);
                }
                for (x, y) in c1.iter().zip(&c2) {
                    assert!((x - y).abs() < 1e-4, "{x} vs {y}");
                }
            }
        }
    }
}
