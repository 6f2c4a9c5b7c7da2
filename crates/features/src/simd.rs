//! Runs a closure compiled for AVX-512 when the machine has it, else for
//! AVX2 + FMA.
//!
//! Kernels are written as plain loops over 16-lane arrays; inlining them into
//! a `#[target_feature]` function lets the compiler emit 512-bit code there,
//! while the same source stays the portable fallback.

/// Calls `f`, inside an AVX-512-enabled frame when available. Mark `f` and
/// the helpers it calls `#[inline(always)]` so they inherit the features.
#[inline(always)]
pub(crate) fn dispatch<R>(f: impl FnOnce() -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    if crate::gemm::has_avx512() {
        // SAFETY: the CPU was checked to support the enabled features.
        return unsafe { with_avx512(f) };
    }
    #[cfg(target_arch = "x86_64")]
    if crate::gemm::has_avx2() {
        // SAFETY: as above.
        return unsafe { with_avx2(f) };
    }
    f()
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn with_avx2<R>(f: impl FnOnce() -> R) -> R {
    f()
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2,fma")]
unsafe fn with_avx512<R>(f: impl FnOnce() -> R) -> R {
    f()
}
