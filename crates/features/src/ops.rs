//! ReLU and 2x2/2 max-pooling on channels-last maps, forward and backward.

use rayon::prelude::*;

use crate::tensor::FeatureMap;

/// `max(x, 0)`.
pub fn relu(x: &FeatureMap) -> FeatureMap {
    FeatureMap::from_vec(x.height, x.width, x.channels, x.data.iter().map(|v| v.max(0.0)).collect())
}

/// Gradient of [`relu`] from its output: passes `grad` where `out > 0`.
pub fn relu_backward(grad: &FeatureMap, out: &FeatureMap) -> FeatureMap {
    let data = grad.data.iter().zip(&out.data).map(|(g, o)| if *o > 0.0 { *g } else { 0.0 }).collect();
    FeatureMap::from_vec(grad.height, grad.width, grad.channels, data)
}

/// 2x2 max-pool with stride 2 (`nn.MaxPool2d(2, 2)`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MaxPool2x2 {
    /// Output size `ceil(n / 2)` with a clipped last window (the Gatys VGG's
    /// `ceil_mode=True`) instead of `floor(n / 2)`.
    pub ceil_mode: bool,
}

/// Where each pooled value came from: what [`MaxPool2x2::backward`] needs.
#[derive(Clone, Debug)]
pub struct PoolArgmax {
    in_height: usize,
    in_width: usize,
    /// Flat input index of the winner of every output value.
    index: Vec<u32>,
}

impl MaxPool2x2 {
    /// Output size along an axis of `n`.
    pub fn out_size(&self, n: usize) -> usize {
        if self.ceil_mode {
            n.div_ceil(2)
        } else {
            n / 2
        }
    }

    /// Pools `x`; ties go to the first maximum in row-major window order, like PyTorch.
    pub fn forward(&self, x: &FeatureMap) -> (FeatureMap, PoolArgmax) {
        let (h, w, c) = (x.height, x.width, x.channels);
        let (oh, ow) = (self.out_size(h), self.out_size(w));
        let mut out = FeatureMap::pooled_zeros(oh, ow, c);
        let mut index = vec![0u32; oh * ow * c];
        out.data.par_chunks_mut((ow * c).max(1)).zip(index.par_chunks_mut((ow * c).max(1))).enumerate().for_each(
            |(oy, (orow, irow))| {
                for ox in 0..ow {
                    let (ov, oi) = (&mut orow[ox * c..(ox + 1) * c], &mut irow[ox * c..(ox + 1) * c]);
                    // Window in PyTorch's scan order; the first candidate seeds the maximum.
                    let mut first = true;
                    for (dy, dx) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                        let (y, xx) = (2 * oy + dy, 2 * ox + dx);
                        if y >= h || xx >= w {
                            continue;
                        }
                        let base = (y * w + xx) * c;
                        let src = &x.data[base..base + c];
                        for (ch, ((o, i), v)) in ov.iter_mut().zip(oi.iter_mut()).zip(src).enumerate() {
                            // Strictly greater keeps the first maximum; NaN wins like PyTorch.
                            if first || *v > *o || v.is_nan() {
                                *o = *v;
                                *i = (base + ch) as u32;
                            }
                        }
                        first = false;
                    }
                }
            },
        );
        (out, PoolArgmax { in_height: h, in_width: w, index })
    }

    /// Routes each output gradient to its window's maximum.
    pub fn backward(&self, grad: &FeatureMap, arg: &PoolArgmax) -> FeatureMap {
        let c = grad.channels;
        let (h, w) = (arg.in_height, arg.in_width);
        let mut gx = FeatureMap::pooled_zeros(h, w, c);
        let orow = grad.width * c;
        // Windows never overlap, so every input receives at most one value;
        // output row oy only reaches input rows 2oy and 2oy + 1, so pairs of
        // input rows fill in parallel.
        gx.data.par_chunks_mut((2 * w * c).max(1)).enumerate().for_each(|(oy, rows)| {
            if oy >= grad.height {
                return;
            }
            let base = oy * 2 * w * c;
            let span = oy * orow..(oy + 1) * orow;
            for (g, i) in grad.data[span.clone()].iter().zip(&arg.index[span]) {
                rows[*i as usize - base] = *g;
            }
        });
        gx
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::{check_gradient, dot, pseudo_random};

    #[test]
    fn relu_gradient() {
        let x = FeatureMap::from_vec(3, 4, 5, pseudo_random(60, 1));
        let probe = pseudo_random(60, 2);
        let y = relu(&x);
        let g = relu_backward(&FeatureMap::from_vec(3, 4, 5, probe.clone()), &y);
        let loss = |p: &[f32]| dot(&probe, &relu(&FeatureMap::from_vec(3, 4, 5, p.to_vec())).data);
        assert!(check_gradient(&x.data, &g.data, loss, 1e-4, 60, 1e-3).max_rel_err < 1e-3);
    }

    #[test]
    fn pool_gradient_and_shapes() {
        for ceil_mode in [false, true] {
            let pool = MaxPool2x2 { ceil_mode };
            let (h, w, c) = (5, 7, 3);
            let x = FeatureMap::from_vec(h, w, c, pseudo_random(h * w * c, 3));
            let (y, arg) = pool.forward(&x);
            assert_eq!((y.height, y.width), if ceil_mode { (3, 4) } else { (2, 3) });
            let probe = pseudo_random(y.data.len(), 4);
            let g = pool.backward(&FeatureMap::from_vec(y.height, y.width, c, probe.clone()), &arg);
            let loss = |p: &[f32]| dot(&probe, &pool.forward(&FeatureMap::from_vec(h, w, c, p.to_vec())).0.data);
            assert!(check_gradient(&x.data, &g.data, loss, 1e-4, 200, 1e-3).max_rel_err < 1e-3);
        }
    }

    #[test]
    fn pool_ties_pick_first_maximum() {
        let x = FeatureMap::from_vec(2, 2, 1, vec![1.0, 2.0, 2.0, 0.0]);
        let pool = MaxPool2x2 { ceil_mode: false };
        let (y, arg) = pool.forward(&x);
        assert_eq!(y.data, vec![2.0]);
        let g = pool.backward(&FeatureMap::from_vec(1, 1, 1, vec![1.0]), &arg);
        assert_eq!(g.data, vec![0.0, 1.0, 0.0, 0.0]);
    }
}
