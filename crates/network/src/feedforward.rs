//! The feed-forward stylization network of Fig. 9 (paper Sec. 4): an
//! encoder of two strided 3D convolutions (5³ then 3³, each halving the
//! resolution), four 3³ convolutions at a quarter of the resolution, a
//! decoder of two (trilinear ×2 upsample, 3³ convolution) steps and a final
//! 3³ convolution to the output channels, LeakyReLU 0.01 after all but the
//! last. The same network as `shared/bench/torch_ff_ref.py`'s `FeedForward`.
//!
//! The output is raw: density mode maps it to a scale `s = 1 + tanh(o)`,
//! velocity mode to `v = vmax · tanh(o)` (eq. 1, 3); those maps belong to the
//! trainer and to inference, which know the limits.

use nst3d_core::math::SplitMix64;

use crate::activation::{leaky_relu_backward, Act};
use crate::conv3d::{Conv3d, Conv3dGrads};
use crate::upsample::{upsample2, upsample2_backward};
use crate::volume::Volume;

/// Number of convolution layers.
pub const LAYERS: usize = 9;

/// The network's weights. Layer order: `e1, e2, m1..m4, d1, d2, last`.
#[derive(Clone, Debug, PartialEq)]
pub struct FeedForward {
    /// The convolutions in order.
    pub layers: Vec<Conv3d>,
}

/// What [`FeedForward::backward`] needs from the forward: each layer's input
/// and each activated output (kept apart only where it is not the next
/// layer's input: before an upsample).
pub struct Tape {
    inputs: Vec<Volume>,
    outputs: Vec<Option<Volume>>,
    /// The decoder's inputs before upsampling (for the upsample backward).
    before_up: [[usize; 3]; 2],
}

impl FeedForward {
    /// Width `c` (first level; `2c` at the low resolution) and `out` output
    /// channels (1 for density, 3 for velocity), initialised as PyTorch's
    /// `nn.Conv3d` does (weights and biases uniform in ±1/√fan_in) from `seed`.
    pub fn new(c: usize, out: usize, seed: u64) -> Self {
        let mut rng = SplitMix64::new(seed);
        let layers = Self::layer_shapes(c, out)
            .iter()
            .map(|&(cin, cout, k, s, p)| {
                let mut l = Conv3d::zeros(cin, cout, k, s, p);
                let bound = 1.0 / ((cin * k * k * k) as f32).sqrt();
                l.weight.iter_mut().chain(l.bias.iter_mut()).for_each(|w| *w = bound * (2.0 * rng.uniform_f32() - 1.0));
                l
            })
            .collect();
        Self { layers }
    }

    /// Fig. 9's layers for width `c` and `out` output channels, as
    /// `(in channels, out channels, kernel, stride, padding)`: what a model
    /// file's tensors are checked against before any network is allocated.
    pub fn layer_shapes(c: usize, out: usize) -> [(usize, usize, usize, usize, usize); LAYERS] {
        [
            (1, c, 5, 2, 2),
            (c, 2 * c, 3, 2, 1),
            (2 * c, 2 * c, 3, 1, 1),
            (2 * c, 2 * c, 3, 1, 1),
            (2 * c, 2 * c, 3, 1, 1),
            (2 * c, 2 * c, 3, 1, 1),
            (2 * c, c, 3, 1, 1),
            (c, c, 3, 1, 1),
            (c, out, 3, 1, 1),
        ]
    }

    /// All weights and biases as one vector, layer by layer (weights, then
    /// biases), the order [`FeedForward::flat_grads`] and
    /// [`FeedForward::set_flat`] use.
    pub fn flat(&self) -> Vec<f32> {
        self.layers.iter().flat_map(|l| l.weight.iter().chain(&l.bias)).copied().collect()
    }

    /// Loads a vector from [`FeedForward::flat`] back into the layers.
    ///
    /// # Panics
    /// If `values` does not hold exactly the network's parameter count.
    pub fn set_flat(&mut self, values: &[f32]) {
        let mut rest = values;
        for l in &mut self.layers {
            let (w, r) = rest.split_at(l.weight.len());
            l.weight.copy_from_slice(w);
            let (b, r) = r.split_at(l.bias.len());
            l.bias.copy_from_slice(b);
            rest = r;
        }
        assert!(rest.is_empty(), "set_flat: {} values too many", rest.len());
    }

    /// Gradients from [`FeedForward::backward`] in [`FeedForward::flat`]'s order.
    pub fn flat_grads(grads: &[Conv3dGrads]) -> Vec<f32> {
        grads.iter().flat_map(|g| g.weight.iter().chain(&g.bias)).copied().collect()
    }

    /// Input size the network maps back onto itself: every side a multiple of 4.
    pub fn fits(dims: [usize; 3]) -> bool {
        dims.iter().all(|&n| n > 0 && n % 4 == 0)
    }

    /// Output channels.
    pub fn out_channels(&self) -> usize {
        self.layers[LAYERS - 1].cout
    }

    /// Forward pass without keeping anything for a backward (inference).
    ///
    /// # Panics
    /// If `x` is not one channel whose sides are multiples of 4 ([`FeedForward::fits`]).
    pub fn infer(&self, x: &Volume) -> Volume {
        self.run(x, None)
    }

    /// Forward pass keeping what [`FeedForward::backward`] needs.
    pub fn forward(&self, x: &Volume) -> (Volume, Tape) {
        let mut tape =
            Tape { inputs: Vec::with_capacity(LAYERS), outputs: Vec::with_capacity(LAYERS), before_up: [[0; 3]; 2] };
        let y = self.run(x, Some(&mut tape));
        (y, tape)
    }

    fn run(&self, x: &Volume, mut tape: Option<&mut Tape>) -> Volume {
        assert!(
            x.channels == 1 && Self::fits(x.dims),
            "the network takes one channel with sides a multiple of 4, got {:?}",
            x.dims
        );
        let mut h = x.clone();
        for (i, layer) in self.layers.iter().enumerate() {
            if i == 6 || i == 7 {
                if let Some(t) = tape.as_deref_mut() {
                    t.before_up[i - 6] = h.dims;
                }
                h = upsample2(&h);
            }
            // LeakyReLU after every layer but the last, applied in the layer's store.
            let y = layer.forward_then(&h, if i + 1 < LAYERS { Act::LeakyRelu } else { Act::Identity });
            if let Some(t) = tape.as_deref_mut() {
                t.inputs.push(h);
                t.outputs.push((i == 5 || i == 6).then(|| y.clone()));
            }
            h = y;
        }
        h
    }

    /// Gradients of every layer's parameters from the gradient w.r.t. the
    /// network's output (the network's input needs none: it is data).
    pub fn backward(&self, tape: &Tape, grad_out: &Volume) -> Vec<Conv3dGrads> {
        let mut grads = Vec::with_capacity(LAYERS);
        let mut g = grad_out.clone();
        for i in (0..LAYERS).rev() {
            if i + 1 < LAYERS {
                let y = tape.outputs[i].as_ref().unwrap_or(&tape.inputs[i + 1]);
                leaky_relu_backward(&y.data, &mut g.data);
            }
            let (dx, dw) = self.layers[i].backward(&tape.inputs[i], &g, i > 0);
            grads.push(dw);
            if let Some(dx) = dx {
                g = if i == 6 || i == 7 { upsample2_backward(&dx, tape.before_up[i - 6]) } else { dx };
            }
        }
        grads.reverse();
        grads
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::{directional, dot, pseudo_random};

    #[test]
    fn output_has_the_input_size() {
        let net = FeedForward::new(2, 3, 1);
        let x = Volume::from_vec(1, [8, 4, 12], pseudo_random(384, 2));
        let y = net.infer(&x);
        assert_eq!((y.channels, y.dims), (3, [8, 4, 12]));
        assert_eq!(net.forward(&x).0, y);
    }

    /// The whole network's weight gradients against finite differences,
    /// layer by layer.
    ///
    /// Why it is set up so: at PyTorch's initialisation on an 8³ input the
    /// first layers' gradients were 10⁻⁴–10⁻⁶ of the last layer's (the
    /// biases drown the signal layer by layer, and a quarter-resolution
    /// 2³ is mostly padding), below what a weight's step can move the f32
    /// loss by, so a per-weight check with an absolute floor passed whatever
    /// they were. Here the weights carry a variance-keeping gain, the
    /// biases are small, the input is 16³, and each layer moves along a
    /// direction by 0.1 % of its weights' size: every layer's `g · v` is
    /// checked at once, far above the loss's rounding.
    #[test]
    fn weight_gradients_match_finite_differences() {
        nst3d_core::precision::fp32(weight_gradients_check)
    }

    fn weight_gradients_check() {
        let mut net = FeedForward::new(2, 1, 3);
        for l in &mut net.layers {
            l.weight.iter_mut().for_each(|w| *w *= 2.45);
            l.bias.iter_mut().for_each(|b| *b *= 0.1);
        }
        // 16³: at 8³ the quarter-resolution layers would see mostly padding.
        let x = Volume::from_vec(1, [16; 3], pseudo_random(4096, 4).iter().map(|v| v.abs()).collect());
        let (y, tape) = net.forward(&x);
        let w = pseudo_random(y.data.len(), 5);
        let grads = net.backward(&tape, &Volume::from_vec(1, y.dims, w.clone()));
        for l in 0..LAYERS {
            let g = &grads[l].weight;
            let random = pseudo_random(g.len(), 6 + l as u64);
            // A random direction, and one with the gradient's signs (never
            // nearly orthogonal to it, where a relative error means little).
            let along: Vec<f32> = random.iter().zip(g).map(|(r, g)| r.abs() * g.signum()).collect();
            for v in [random, along] {
                let err = directional_error(&net, &x, &w, (l, &v), g);
                // LeakyReLU kinks crossed by the step and f32 rounding: up to
                // 3e-2 measured; a gradient 20 % off scores 0.17.
                assert!(err < 5e-2, "layer {l}: {err}");
            }
        }
    }

    /// [`directional`]'s error for the loss `⟨w, net(x)⟩` moved along `v` in
    /// layer `l`'s weights by 0.1 % of their size.
    fn directional_error(net: &FeedForward, x: &Volume, w: &[f32], (l, v): (usize, &[f32]), g: &[f32]) -> f64 {
        let weights = &net.layers[l].weight;
        let step = 1e-3 * weights.iter().map(|w| w.abs()).sum::<f32>() / weights.len() as f32;
        directional(g, v, step, |t| {
            let mut probe = net.clone();
            probe.layers[l].weight.iter_mut().zip(v).for_each(|(p, v)| *p += t * v);
            dot(w, &probe.infer(x).data)
        })
    }
}
