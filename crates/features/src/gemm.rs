//! The small dense product at the heart of every Winograd convolution:
//! `C[MR x NR] = A[MR x K] * B[K x NR]`, with `A` rows strided (transformed
//! tiles, channels contiguous) and `B` a pre-packed panel (`K x NR`
//! contiguous, prepared once because the network weights are frozen).
//!
//! An AVX-512 register-blocked kernel is chosen at run time; a portable
//! version with the same blocking serves other machines and is the reference
//! in tests.

/// Rows of `A` handled per kernel call (tiles).
pub(crate) const MR: usize = 8;
/// Columns of `B` per packed panel (output channels): two 16-lane registers.
pub(crate) const NR: usize = 32;

/// Whether the AVX-512 kernel may be used on this machine (checked once).
pub(crate) fn has_avx512() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        use std::sync::OnceLock;
        static HAS: OnceLock<bool> = OnceLock::new();
        *HAS.get_or_init(|| {
            is_x86_feature_detected!("avx512f")
                && std::env::var_os("NST3D_NO_AVX512").is_none()
        })
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// `c[r * ldc + j] = sum_k a[r * lda + k] * b[k * NR + j]` for `r < MR`, `j < NR`.
///
/// # Safety
/// `a` must hold `MR` rows of `k` values at stride `lda`, `b` `k * NR`
/// values and `c` `MR` rows of `NR` values at stride `ldc`.
#[inline]
pub(crate) unsafe fn kernel(a: *const f32, lda: usize, b: *const f32, k: usize, c: *mut f32, ldc: usize) {
    #[cfg(target_arch = "x86_64")]
    if has_avx512() {
        return kernel_avx512(a, lda, b, k, c, ldc);
    }
    kernel_portable(a, lda, b, k, c, ldc)
}

/// Portable reference of [`kernel`] (same contract).
pub(crate) unsafe fn kernel_portable(a: *const f32, lda: usize, b: *const f32, k: usize, c: *mut f32, ldc: usize) {
    let mut acc = [[0f32; NR]; MR];
    for kk in 0..k {
        let brow = std::slice::from_raw_parts(b.add(kk * NR), NR);
        for (r, acc_r) in acc.iter_mut().enumerate() {
            let av = *a.add(r * lda + kk);
            for (x, bv) in acc_r.iter_mut().zip(brow) {
                *x += av * bv;
            }
        }
    }
    for (r, acc_r) in acc.iter().enumerate() {
        std::ptr::copy_nonoverlapping(acc_r.as_ptr(), c.add(r * ldc), NR);
    }
}

/// AVX-512 version of [`kernel`]: 16 accumulators (MR rows x 2 registers),
/// `A` values broadcast straight from memory.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn kernel_avx512(a: *const f32, lda: usize, b: *const f32, k: usize, c: *mut f32, ldc: usize) {
    use std::arch::x86_64::*;
    let mut acc0 = [_mm512_setzero_ps(); MR];
    let mut acc1 = [_mm512_setzero_ps(); MR];
    let mut rows = [a; MR];
    for (r, p) in rows.iter_mut().enumerate() {
        *p = a.add(r * lda);
    }
    let mut bp = b;
    for kk in 0..k {
        let b0 = _mm512_loadu_ps(bp);
        let b1 = _mm512_loadu_ps(bp.add(16));
        bp = bp.add(NR);
        for r in 0..MR {
            let av = _mm512_set1_ps(*rows[r].add(kk));
            acc0[r] = _mm512_fmadd_ps(av, b0, acc0[r]);
            acc1[r] = _mm512_fmadd_ps(av, b1, acc1[r]);
        }
    }
    for r in 0..MR {
        _mm512_storeu_ps(c.add(r * ldc), acc0[r]);
        _mm512_storeu_ps(c.add(r * ldc + 16), acc1[r]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::pseudo_random;

    #[test]
    fn fast_kernel_matches_portable() {
        let (k, lda, ldc) = (37, 41, 40);
        let a = pseudo_random(MR * lda, 1);
        let b = pseudo_random(k * NR, 2);
        let mut c1 = vec![0.0; MR * ldc];
        let mut c2 = vec![0.0; MR * ldc];
        unsafe {
            kernel(a.as_ptr(), lda, b.as_ptr(), k, c1.as_mut_ptr(), ldc);
            kernel_portable(a.as_ptr(), lda, b.as_ptr(), k, c2.as_mut_ptr(), ldc);
        }
        for (x, y) in c1.iter().zip(&c2) {
            assert!((x - y).abs() < 1e-4, "{x} vs {y}");
        }
    }
}
