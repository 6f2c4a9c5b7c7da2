//! A learned solid texture: a periodic `P³` field `T` in the frame's index
//! space whose scale `s_t = 1 + tanh T ∈ [0, 2]` multiplies the network's
//! stylized density. Not in the paper's Fig. 9: it gives the network a
//! source of variation where the smoke has none.
//!
//! Why: a convolution of a flat density is flat, so the paper's network
//! leaves dense, smooth cores untouched where the optimisation breaks them
//! into strokes; noise fed beside the density gets no first-order gradient
//! (a zero-mean texture moves a Gram matrix only to second order), while
//! `T` is in the picture the loss scores and is shaped by it directly
//! (docs/design/feedforward.md). The field is periodic and fixed in index
//! space, so tiles and frames agree and inference stays one multiply a voxel.

use nst3d_core::Grid3;
use rayon::prelude::*;

use crate::apply::CHUNK;

/// The periodic field `T`, `x` fastest, then `y`, then `z`.
#[derive(Clone, Debug, PartialEq)]
pub struct SolidTexture {
    /// The period `P` along every axis, in voxels.
    pub period: usize,
    /// `P³` values of `T` (the scale is `1 + tanh T`).
    pub values: Vec<f32>,
}

impl SolidTexture {
    /// A texture of period `period` starting near `s_t = 1` (`T` uniform in
    /// ±0.1 from `seed`), so a fresh texture leaves the network's result
    /// almost as it is and the loss decides what grows.
    pub fn new(period: usize, seed: u64) -> Self {
        let values =
            nst3d_core::gradcheck::pseudo_random(period.pow(3), seed ^ 0x7e47).iter().map(|v| 0.1 * v).collect();
        Self { period, values }
    }

    /// Index of the texel under the voxel `at` of the texture's space.
    pub fn index(&self, at: [i64; 3]) -> usize {
        let p = self.period as i64;
        let [x, y, z] = at.map(|c| c.rem_euclid(p) as usize);
        (z * self.period + y) * self.period + x
    }

    /// The scale `(1 + tanh T)^strength` at voxel `at` (strength 1: the
    /// trained texture; see [`crate::apply::apply_with_strength`]).
    pub fn scale(&self, at: [i64; 3], strength: f32) -> f32 {
        let s = 1.0 + self.values[self.index(at)].tanh();
        if strength == 1.0 {
            s
        } else {
            s.powf(strength)
        }
    }

    /// `d · s_t` over a box whose voxel `(0, 0, 0)` lies at `origin` of the
    /// texture's space.
    pub fn apply(&self, d: &Grid3, origin: [i64; 3]) -> Grid3 {
        let data =
            (0..d.len()).into_par_iter().with_min_len(CHUNK).map(|i| d.data[i] * self.scale(at(d, origin, i), 1.0));
        Grid3::from_vec(d.dims, data.collect())
    }

    /// Backward of [`SolidTexture::apply`]: from `grad = ∂L/∂(d · s_t)`,
    /// returns `∂L/∂d` and `∂L/∂T` (texels under several voxels sum them).
    pub fn apply_backward(&self, d: &Grid3, origin: [i64; 3], grad: &[f32]) -> (Vec<f32>, Vec<f32>) {
        let mut grad_d = vec![0.0f32; d.len()];
        let mut grad_t = vec![0.0f32; self.values.len()];
        // Serial: many voxels of a patch larger than the period share a
        // texel; the scatter is a small fraction of a step.
        for (i, g_d) in grad_d.iter_mut().enumerate() {
            let j = self.index(at(d, origin, i));
            let t = self.values[j].tanh();
            *g_d = grad[i] * (1.0 + t);
            grad_t[j] += grad[i] * d.data[i] * (1.0 - t * t);
        }
        (grad_d, grad_t)
    }
}

/// Where voxel `i` of `d` lies in the texture's space.
fn at(d: &Grid3, origin: [i64; 3], i: usize) -> [i64; 3] {
    let [nx, ny, _] = d.dims;
    let local = [i % nx, (i / nx) % ny, i / (nx * ny)];
    std::array::from_fn(|a| origin[a] + local[a] as i64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::{check_gradient, dot, pseudo_random};

    fn texture(period: usize, seed: u64) -> SolidTexture {
        SolidTexture { period, values: pseudo_random(period.pow(3), seed).iter().map(|v| 1.5 * v).collect() }
    }

    /// Both gradients of `d · (1 + tanh T)` against central differences, on
    /// a box larger than the period at a negative origin (texels under
    /// several voxels, the wrap on both sides).
    #[test]
    fn gradients_match_finite_differences() {
        let (dims, origin) = ([7, 5, 6], [-3, 2, -9]);
        let d = Grid3::from_vec(dims, pseudo_random(210, 1).iter().map(|v| v.abs()).collect());
        let w = pseudo_random(210, 2);
        let tex = texture(4, 3);
        let (gd, gt) = tex.apply_backward(&d, origin, &w);
        let by_d = |q: &[f32]| dot(&w, &tex.apply(&Grid3::from_vec(dims, q.to_vec()), origin).data);
        let r = check_gradient(&d.data, &gd, by_d, 1e-3, 210, 1e-4);
        assert!(r.max_rel_err < 1e-3, "∂/∂d {r:?}");
        let by_t = |q: &[f32]| {
            let t = SolidTexture { period: 4, values: q.to_vec() };
            dot(&w, &t.apply(&d, origin).data)
        };
        let r = check_gradient(&tex.values, &gt, by_t, 1e-2, 64, 1e-4);
        assert!(r.max_rel_err < 1e-3, "∂/∂T {r:?}");
    }

    /// The field is periodic and fixed in index space: a box applied at an
    /// origin shifted by whole periods, or cut from a larger box, gets the
    /// same scales (what keeps tiles and frames seamless).
    #[test]
    fn the_scale_depends_only_on_the_index_modulo_the_period() {
        let tex = texture(5, 4);
        let d = Grid3::from_vec([9, 8, 7], vec![1.0; 504]);
        let a = tex.apply(&d, [1, -2, 3]);
        assert_eq!(a.data, tex.apply(&d, [1 + 10, -2 - 5, 3 + 15]).data);
        let big = tex.apply(&Grid3::from_vec([12, 8, 7], vec![1.0; 672]), [-2, -2, 3]);
        for z in 0..7 {
            for y in 0..8 {
                for x in 0..9 {
                    assert_eq!(a.data[a.index(x, y, z)], big.data[big.index(x + 3, y, z)]);
                }
            }
        }
        assert_eq!(tex.scale([0, 0, 0], 2.0), tex.scale([5, 5, -5], 1.0).powi(2));
    }
}
