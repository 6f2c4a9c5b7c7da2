//! A general strided product on the block kernel: both operands packed per
//! call (A into bf16 rows, B into [`PackedB`]), for operands that change
//! every call. Called through `linalg::matmul_into_precision`.

use rayon::prelude::*;

use super::{from_f32, Kernel, PackedB, KS, MB, NB};

/// `dst[i * ldd + j] (+)= beta · Σ_k lhs(i, k) · rhs(k, j)` with
/// `lhs(i, k) = lhs[i * r + k * c]` for strides `(r, c)` (likewise `rhs`);
/// bounds checked by the caller. Output blocks in parallel when `parallel`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn matmul(
    kernel: Kernel,
    (m, n, k): (usize, usize, usize),
    dst: &mut [f32],
    ldd: usize,
    accumulate: bool,
    (lhs, (lr, lc)): (&[f32], (usize, usize)),
    (rhs, (rr, rc)): (&[f32], (usize, usize)),
    beta: f32,
    parallel: bool,
) {
    let (mp, kp) = (m.div_ceil(MB) * MB, k.div_ceil(KS) * KS);
    let steps = kp / KS;
    let mut a = vec![0u16; mp * kp];
    let fill = |(i, row): (usize, &mut [u16])| {
        if i < m {
            if lc == 1 {
                super::convert(&lhs[i * lr..i * lr + k], &mut row[..k]);
            } else {
                for (q, v) in row[..k].iter_mut().enumerate() {
                    *v = from_f32(lhs[i * lr + q * lc]);
                }
            }
        }
    };
    if parallel {
        a.par_chunks_mut(kp).enumerate().for_each(fill);
    } else {
        a.chunks_mut(kp).enumerate().for_each(fill);
    }
    let b = PackedB::from_strided(k, n, rhs, (rr, rc));
    let offs: Vec<usize> = (0..steps).map(|s| s * KS).collect();
    // One task per band of 32 output rows; each writes only its own rows.
    let band = |(bi, rows): (usize, &mut [f32])| {
        let a0 = a[bi * MB * kp..].as_ptr();
        let mut blk = [0f32; MB * NB];
        let nr = MB.min(m - bi * MB);
        kernel.run(|ready| {
            for pair in 0..b.npairs {
                // SAFETY: a holds mp rows of kp values; the pair holds
                // `steps` steps; blk is 32 x 32.
                unsafe { ready.block(a0, a0.add(16 * kp), kp, &offs, b.pair(pair).as_ptr(), blk.as_mut_ptr(), NB) };
                let (j0, nj) = (pair * NB, NB.min(n - pair * NB));
                for r in 0..nr {
                    let d = &mut rows[r * ldd + j0..r * ldd + j0 + nj];
                    let s = &blk[r * NB..r * NB + nj];
                    if accumulate {
                        d.iter_mut().zip(s).for_each(|(d, v)| *d += beta * v);
                    } else {
                        d.iter_mut().zip(s).for_each(|(d, v)| *d = beta * v);
                    }
                }
            }
        });
    };
    // Bands of 32 rows of dst (the last one may be short: it ends at the
    // last row's n values).
    let used = (m - 1) * ldd + n;
    if parallel {
        dst[..used].par_chunks_mut(MB * ldd).enumerate().for_each(band);
    } else {
        dst[..used].chunks_mut(MB * ldd).enumerate().for_each(band);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gradcheck::pseudo_random;

    /// Strided operands (a transposed rhs), accumulation, a band stride
    /// wider than n, sizes off every block: within bf16's tolerance of f64.
    #[test]
    fn strided_product_matches_reference() {
        let (m, n, k, ldd) = (37, 45, 70, 50);
        let lhs = pseudo_random(m * k, 1);
        let rhs = pseudo_random(n * k, 2); // stored n x k: rhs(q, j) = rhs[j * k + q]
        let base = pseudo_random(m * ldd, 3);
        for kernel in Kernel::all_here() {
            for parallel in [false, true] {
                let mut dst = base.clone();
                matmul(kernel, (m, n, k), &mut dst, ldd, true, (&lhs, (k, 1)), (&rhs, (1, k)), 0.5, parallel);
                for i in 0..m {
                    for j in 0..ldd {
                        let want = if j < n {
                            base[i * ldd + j] as f64
                                + 0.5 * (0..k).map(|q| lhs[i * k + q] as f64 * rhs[j * k + q] as f64).sum::<f64>()
                        } else {
                            base[i * ldd + j] as f64
                        };
                        let got = dst[i * ldd + j] as f64;
                        assert!((got - want).abs() < 2e-2, "{kernel:?} ({i}, {j}): {got} vs {want}");
                    }
                }
            }
        }
    }
}
