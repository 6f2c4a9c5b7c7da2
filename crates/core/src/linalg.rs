//! Dense matrix products for nst3d's own kernels (Gram matrices, 3D
//! convolutions as im2col products), on the `gemm` crate's runtime-dispatched
//! AVX-512 / AVX2 kernels.

use gemm::gemm;
pub use gemm::Parallelism;

/// Below this many multiply-adds a product runs on the calling thread: waking
/// the rayon pool costs more than it saves on the small Grams of tests and of
/// deep layers of tiny renders.
const PARALLEL_MIN_FLOPS: usize = 1 << 20;

/// Threads for an `m x n x k` product: the caller's rayon pool above
/// [`PARALLEL_MIN_FLOPS`], the calling thread below.
pub fn parallelism(m: usize, n: usize, k: usize) -> Parallelism {
    if m * n * k < PARALLEL_MIN_FLOPS {
        Parallelism::None
    } else {
        // 0 = the size of the current rayon pool, so callers control threads
        // with `ThreadPool::install`.
        Parallelism::Rayon(0)
    }
}

/// `dst (m x n) = beta · lhs (m x k) · rhs (k x n)`, all described by
/// (row stride, column stride) pairs so transposes cost nothing.
///
/// Accumulation is in `f32`, as PyTorch's CPU `matmul` (a BLAS `sgemm`) does,
/// so results agree with the reference to float rounding.
#[allow(clippy::too_many_arguments)]
pub fn matmul(
    m: usize,
    n: usize,
    k: usize,
    dst: &mut [f32],
    lhs: &[f32],
    lhs_strides: (usize, usize),
    rhs: &[f32],
    rhs_strides: (usize, usize),
    beta: f32,
    parallelism: Parallelism,
) {
    assert_eq!(dst.len(), m * n, "matmul destination size");
    matmul_into(m, n, k, dst, n, false, lhs, lhs_strides, rhs, rhs_strides, beta, parallelism);
}

/// [`matmul`] into rows `dst_row_stride` apart (a band of a larger
/// row-major matrix), overwriting them, or adding to them when `accumulate`.
///
/// # Panics
/// If an operand's strides reach outside its slice.
#[allow(clippy::too_many_arguments)]
pub fn matmul_into(
    m: usize,
    n: usize,
    k: usize,
    dst: &mut [f32],
    dst_row_stride: usize,
    accumulate: bool,
    lhs: &[f32],
    lhs_strides: (usize, usize),
    rhs: &[f32],
    rhs_strides: (usize, usize),
    beta: f32,
    parallelism: Parallelism,
) {
    if m == 0 || n == 0 {
        return;
    }
    assert!(n <= dst_row_stride && (m - 1) * dst_row_stride + n <= dst.len(), "matmul destination bounds");
    if k == 0 {
        if !accumulate {
            dst.chunks_mut(dst_row_stride).take(m).for_each(|r| r[..n].fill(0.0));
        }
        return;
    }
    // The last element each operand's strides reach must be in bounds; this
    // is what makes the raw-pointer call below sound.
    assert!((m - 1) * lhs_strides.0 + (k - 1) * lhs_strides.1 < lhs.len(), "matmul lhs bounds");
    assert!((k - 1) * rhs_strides.0 + (n - 1) * rhs_strides.1 < rhs.len(), "matmul rhs bounds");
    // SAFETY: the bounds were checked above and dst is exclusively borrowed;
    // with read_dst = false its old contents are ignored, else dst += product.
    unsafe {
        gemm(
            m,
            n,
            k,
            dst.as_mut_ptr(),
            1,
            dst_row_stride as isize,
            accumulate,
            lhs.as_ptr(),
            lhs_strides.1 as isize,
            lhs_strides.0 as isize,
            rhs.as_ptr(),
            rhs_strides.1 as isize,
            rhs_strides.0 as isize,
            1.0,
            beta,
            false,
            false,
            false,
            parallelism,
        );
    }
}

/// [`matmul_into`] in the arithmetic of `path` (a
/// [`crate::precision::path`] the caller resolved on its own thread, so a
/// scoped choice holds inside its parallel tasks too): this module's fp32
/// product, or the block kernel of [`crate::bf16`] (operands rounded to bf16
/// once, sums in fp32, each output block's sum in one fixed order). For
/// products whose operands change every call (the 3D network's im2col
/// matrices), so both are packed here.
#[allow(clippy::too_many_arguments)]
pub fn matmul_into_precision(
    path: crate::precision::Path,
    m: usize,
    n: usize,
    k: usize,
    dst: &mut [f32],
    dst_row_stride: usize,
    accumulate: bool,
    lhs: &[f32],
    lhs_strides: (usize, usize),
    rhs: &[f32],
    rhs_strides: (usize, usize),
    beta: f32,
    parallelism: Parallelism,
) {
    match path.kernel() {
        Some(kernel) if m > 0 && n > 0 && k > 0 => {
            assert!(n <= dst_row_stride && (m - 1) * dst_row_stride + n <= dst.len(), "matmul destination bounds");
            assert!((m - 1) * lhs_strides.0 + (k - 1) * lhs_strides.1 < lhs.len(), "matmul lhs bounds");
            assert!((k - 1) * rhs_strides.0 + (n - 1) * rhs_strides.1 < rhs.len(), "matmul rhs bounds");
            let parallel = !matches!(parallelism, Parallelism::None);
            crate::bf16::matmul(
                kernel,
                (m, n, k),
                dst,
                dst_row_stride,
                accumulate,
                (lhs, lhs_strides),
                (rhs, rhs_strides),
                beta,
                parallel,
            );
        }
        _ => {
            matmul_into(m, n, k, dst, dst_row_stride, accumulate, lhs, lhs_strides, rhs, rhs_strides, beta, parallelism)
        }
    }
}

/// [`matmul`] in the arithmetic of `path` (see [`matmul_into_precision`]).
#[allow(clippy::too_many_arguments)]
pub fn matmul_precision(
    path: crate::precision::Path,
    m: usize,
    n: usize,
    k: usize,
    dst: &mut [f32],
    lhs: &[f32],
    lhs_strides: (usize, usize),
    rhs: &[f32],
    rhs_strides: (usize, usize),
    beta: f32,
    parallelism: Parallelism,
) {
    assert_eq!(dst.len(), m * n, "matmul destination size");
    matmul_into_precision(path, m, n, k, dst, n, false, lhs, lhs_strides, rhs, rhs_strides, beta, parallelism);
}
