//! Trilinear ×2 upsampling, the decoder's "upsample then convolve" step of
//! Fig. 9, as PyTorch's `F.interpolate(scale_factor=2, mode="trilinear",
//! align_corners=False)` computes it.
//!
//! With a factor of 2 the weights are fixed: fine sample `2i` is
//! `3/4 x[i] + 1/4 x[i−1]` and `2i+1` is `3/4 x[i] + 1/4 x[i+1]`, the
//! neighbour clamped at the border. The filter is separable, so one 1D
//! kernel runs along each axis in turn, and the backward runs its transpose
//! along the axes in the opposite order.

use rayon::prelude::*;

use crate::volume::Volume;

/// Strides and sizes of `axis` in a `(C, z, y, x)` layout: (length along
/// the axis, stride of the axis, number of contiguous elements below it).
fn axis_layout(dims: [usize; 3], axis: usize) -> (usize, usize) {
    let n = dims[axis];
    let inner: usize = dims[..axis].iter().product();
    (n, inner)
}

/// One axis ×2: `src` has `n` samples along `axis`, the result `2n`.
fn up_axis(src: &[f32], dims: [usize; 3], axis: usize) -> Vec<f32> {
    let (n, inner) = axis_layout(dims, axis);
    let outer_len = n * inner;
    let mut out = vec![0.0f32; src.len() * 2];
    out.par_chunks_mut(2 * outer_len).zip(src.par_chunks(outer_len)).for_each(|(o, s)| {
        for i in 0..n {
            let (lo, hi) = (i.saturating_sub(1), (i + 1).min(n - 1));
            let (c, l, h) = (&s[i * inner..][..inner], &s[lo * inner..][..inner], &s[hi * inner..][..inner]);
            let (even, odd) = o[2 * i * inner..][..2 * inner].split_at_mut(inner);
            for j in 0..inner {
                even[j] = 0.75 * c[j] + 0.25 * l[j];
                odd[j] = 0.75 * c[j] + 0.25 * h[j];
            }
        }
    });
    out
}

/// Transpose of [`up_axis`]: `grad` has `2n` samples along `axis`, the result `n`.
fn up_axis_backward(grad: &[f32], dims: [usize; 3], axis: usize) -> Vec<f32> {
    let (n, inner) = axis_layout(dims, axis);
    let outer_len = n * inner;
    let mut out = vec![0.0f32; grad.len() / 2];
    out.par_chunks_mut(outer_len).zip(grad.par_chunks(2 * outer_len)).for_each(|(o, g)| {
        for i in 0..n {
            let (lo, hi) = (i.saturating_sub(1), (i + 1).min(n - 1));
            let (even, odd) = g[2 * i * inner..][..2 * inner].split_at(inner);
            for j in 0..inner {
                o[i * inner + j] += 0.75 * (even[j] + odd[j]);
                o[lo * inner + j] += 0.25 * even[j];
                o[hi * inner + j] += 0.25 * odd[j];
            }
        }
    });
    out
}

/// `x` upsampled ×2 along x, y and z (trilinear, `align_corners=False`).
pub fn upsample2(x: &Volume) -> Volume {
    let mut dims = x.dims;
    let mut data = x.data.clone();
    for axis in 0..3 {
        // The per-channel blocks are contiguous, so the outer loop of
        // `up_axis` runs over channels and the axes above `axis` together.
        data = up_axis(&data, dims, axis);
        dims[axis] *= 2;
    }
    Volume::from_vec(x.channels, dims, data)
}

/// Backward of [`upsample2`]: the gradient w.r.t. its input (of `dims`)
/// from the gradient w.r.t. its output.
///
/// # Panics
/// If `grad` is not twice `dims` along every axis.
pub fn upsample2_backward(grad: &Volume, dims: [usize; 3]) -> Volume {
    assert_eq!(grad.dims, dims.map(|n| 2 * n), "upsample2_backward: gradient size");
    let mut d = grad.dims;
    let mut data = grad.data.clone();
    for axis in (0..3).rev() {
        d[axis] /= 2;
        data = up_axis_backward(&data, d, axis);
    }
    Volume::from_vec(grad.channels, dims, data)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::{check_gradient, dot, pseudo_random};

    #[test]
    fn upsample_gradient_matches_finite_differences() {
        let dims = [3, 4, 2];
        let x = Volume::from_vec(2, dims, pseudo_random(48, 3));
        let w = pseudo_random(48 * 8, 4);
        let g = upsample2_backward(&Volume::from_vec(2, dims.map(|n| 2 * n), w.clone()), dims);
        let r = check_gradient(
            &x.data,
            &g.data,
            |p| dot(&w, &upsample2(&Volume::from_vec(2, dims, p.to_vec())).data),
            1e-2,
            100,
            1e-3,
        );
        assert!(r.max_rel_err < 1e-3, "{r:?}");
    }

    #[test]
    fn constants_stay_constant() {
        let x = Volume::from_vec(1, [2, 3, 1], vec![0.5; 6]);
        assert!(upsample2(&x).data.iter().all(|v| (v - 0.5).abs() < 1e-7));
    }
}
