//! Doubling the render's resolution before the network (paper Sec. 5.1): small
//! renders give poor stylisation gradients, and doubling also halves the size
//! of the generated patterns relative to the voxels.
//!
//! Exactly PyTorch's `F.interpolate(scale_factor=2, mode="bilinear",
//! align_corners=False)`, per channel.

use nst3d_core::Image;
use rayon::prelude::*;

/// For each output index of a doubled axis of `n` samples: the two source
/// taps and the weight of the second (`align_corners=False`, source index
/// clamped at 0 and the upper tap at `n - 1`, as PyTorch does).
fn taps(n: usize) -> Vec<(usize, usize, f32)> {
    (0..2 * n)
        .map(|o| {
            let src = ((o as f32 + 0.5) * 0.5 - 0.5).max(0.0);
            let i0 = (src as usize).min(n - 1);
            (i0, (i0 + 1).min(n - 1), src - i0 as f32)
        })
        .collect()
}

/// The transpose of [`taps`]: for each source index, the output indices it
/// feeds and with which weight (at most four for a doubling).
fn adjoint_taps(n: usize) -> Vec<Vec<(usize, f32)>> {
    let mut adj = vec![Vec::with_capacity(4); n];
    for (o, (i0, i1, l)) in taps(n).into_iter().enumerate() {
        adj[i0].push((o, 1.0 - l));
        adj[i1].push((o, l));
    }
    adj
}

/// 2x bilinear upsampling (`C x H x W` to `C x 2H x 2W`).
pub fn upsample2x(img: &Image) -> Image {
    let (h, w) = (img.height, img.width);
    let mut out = Image::zeros(img.channels, 2 * h, 2 * w);
    if out.data.is_empty() {
        return out;
    }
    let (ty, tx) = (taps(h), taps(w));
    out.data.par_chunks_mut(2 * w).enumerate().for_each(|(row, dst)| {
        let (c, oy) = (row / (2 * h), row % (2 * h));
        let (y0, y1, ly) = ty[oy];
        let plane = img.channel(c);
        let (r0, r1) = (&plane[y0 * w..][..w], &plane[y1 * w..][..w]);
        for (d, &(x0, x1, lx)) in dst.iter_mut().zip(&tx) {
            let top = r0[x0] + lx * (r0[x1] - r0[x0]);
            let bottom = r1[x0] + lx * (r1[x1] - r1[x0]);
            *d = (1.0 - ly) * top + ly * bottom;
        }
    });
    out
}

/// Backward of [`upsample2x`]: `∂L/∂img` for `grad_out = ∂L/∂out`, as a
/// gather over the transposed taps so every input pixel is written once.
///
/// # Panics
/// If `grad_out` is not `C x 2H x 2W` for some `C x H x W` image.
pub fn upsample2x_backward(grad_out: &Image) -> Image {
    assert!(
        grad_out.height.is_multiple_of(2) && grad_out.width.is_multiple_of(2),
        "upsample2x_backward: gradient must have even height and width"
    );
    let (h, w) = (grad_out.height / 2, grad_out.width / 2);
    let mut out = Image::zeros(grad_out.channels, h, w);
    if out.data.is_empty() {
        return out;
    }
    let (ay, ax) = (adjoint_taps(h), adjoint_taps(w));
    out.data.par_chunks_mut(w).enumerate().for_each(|(row, dst)| {
        let (c, y) = (row / h, row % h);
        let plane = grad_out.channel(c);
        for &(oy, wy) in &ay[y] {
            let src = &plane[oy * 2 * w..][..2 * w];
            for (d, taps) in dst.iter_mut().zip(&ax) {
                *d += wy * taps.iter().map(|&(ox, wx)| wx * src[ox]).sum::<f32>();
            }
        }
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::{check_gradient, dot, pseudo_random};

    #[test]
    fn constant_stays_constant() {
        let img = Image::from_vec(1, 3, 2, vec![0.7; 6]);
        assert!(upsample2x(&img).data.iter().all(|v| (v - 0.7).abs() < 1e-6));
    }

    #[test]
    fn upsample_gradient_check() {
        let img = Image::from_vec(2, 3, 5, pseudo_random(30, 21));
        let w = pseudo_random(120, 22);
        let grad = upsample2x_backward(&Image::from_vec(2, 6, 10, w.clone()));
        let r = check_gradient(
            &img.data,
            &grad.data,
            |x| dot(&w, &upsample2x(&Image::from_vec(2, 3, 5, x.to_vec())).data),
            0.1,
            30,
            1e-2,
        );
        assert!(r.max_rel_err < 1e-3, "{r:?}");
    }
}
