//! LeakyReLU, the network's activation after every convolution but the
//! last (Fig. 9).

use rayon::prelude::*;

/// The negative slope the paper's network uses.
pub const LEAKY_SLOPE: f32 = 0.01;

/// Elements a task takes: the activations of a 64³ patch's last layers are
/// millions of values, a pass over them worth splitting over threads.
const CHUNK: usize = 1 << 16;

/// `max(x, 0) + slope · min(x, 0)` of one value.
#[inline(always)]
pub fn leaky(x: f32) -> f32 {
    x * if x < 0.0 { LEAKY_SLOPE } else { 1.0 }
}

/// [`leaky`], in place.
pub fn leaky_relu(x: &mut [f32]) {
    x.par_chunks_mut(CHUNK).for_each(|c| c.iter_mut().for_each(|v| *v = leaky(*v)));
}

/// What a convolution applies to each output as it stores it, so an
/// activation costs no second pass over a layer's output (16 MB for the
/// decoder's last layers at 64³).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Act {
    /// The output as computed (the network's last layer, input gradients).
    Identity,
    /// [`leaky`] (every layer but the last, Fig. 9).
    LeakyRelu,
}

impl Act {
    /// `v` through the activation.
    #[inline(always)]
    pub fn apply(self, v: f32) -> f32 {
        match self {
            Act::Identity => v,
            Act::LeakyRelu => leaky(v),
        }
    }
}

/// Backward of [`leaky_relu`]: scales `grad` in place where the activation's
/// output `y` (or its input: the sign is the same) is negative.
pub fn leaky_relu_backward(y: &[f32], grad: &mut [f32]) {
    assert_eq!(y.len(), grad.len(), "leaky_relu_backward lengths");
    grad.par_chunks_mut(CHUNK)
        .zip(y.par_chunks(CHUNK))
        .for_each(|(g, y)| g.iter_mut().zip(y).for_each(|(g, y)| *g *= if *y < 0.0 { LEAKY_SLOPE } else { 1.0 }));
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::{check_gradient, dot, pseudo_random};

    #[test]
    fn leaky_relu_gradient_matches_finite_differences() {
        // Away from the kink at 0.
        let x: Vec<f32> = pseudo_random(200, 1).iter().map(|v| if v.abs() < 0.05 { v + 0.1 } else { *v }).collect();
        let w = pseudo_random(200, 2);
        let mut y = x.clone();
        leaky_relu(&mut y);
        let mut g = w.clone();
        leaky_relu_backward(&y, &mut g);
        let r = check_gradient(
            &x,
            &g,
            |p| {
                let mut q = p.to_vec();
                leaky_relu(&mut q);
                dot(&w, &q)
            },
            1e-3,
            200,
            1e-3,
        );
        assert!(r.max_rel_err < 1e-3, "{r:?}");
    }
}
