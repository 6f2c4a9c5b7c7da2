//! The `train-step` benchmark: one training step as
//! `shared/bench/torch_ff_ref.py` times it (its README defines the work):
//! a `P³` patch cut at a random place of a `(2P)³` synthetic smoke, rotated
//! (x: ±180°, y: ±90°) and mirrored at random, the width-`C` network,
//! density or velocity stylization (`vmax = 0.04 P`), orthographic render
//! along z with γ = 8/P, 2x upsample, VGG-19 Gram loss to a random image,
//! backward to the weights, clipping at 1.0, Adam with OneCycle.

use std::time::Instant;

use nst3d_core::{gradcheck::pseudo_random, math::SplitMix64, Image};
use nst3d_features::{Vgg19, VggFlavor};
use nst3d_network::FeedForward;
use nst3d_optim::OneCycle;
use nst3d_stylize::{bench::synthetic_smoke, StyleSpec, ViewLoss, ViewSpec};

use crate::patch::{rotated_patch, Rotation};
use crate::step::{Stylization, TrainStep};

/// Milliseconds of each of `steps` timed training steps (after one warm-up)
/// on `p³` patches with a width-`channels` network, and the last loss.
pub fn train_step(p: usize, velocity: bool, channels: usize, steps: usize) -> (Vec<f64>, f32) {
    let volume = synthetic_smoke(2 * p, 0);
    // The peer's VGG is randomly initialised: the work does not depend on the weights.
    let vgg = Vgg19::random(VggFlavor::Torchvision, 0);
    let style =
        Image::from_vec(3, 2 * p, 2 * p, pseudo_random(12 * p * p, 7).iter().map(|v| 0.5 * (v + 1.0)).collect());
    let loss = ViewLoss::new(&vgg, &style, &StyleSpec::default()).expect("default style layers are valid");
    let view = ViewSpec { camera: None, gamma: 8.0 / p as f32, exposure: 1.0, equalize: false };
    let stylization = if velocity { Stylization::Velocity { vmax: 0.04 * p as f32 } } else { Stylization::Density };
    let net = FeedForward::new(channels, stylization.channels(), 0);
    let mut trainer = TrainStep::new(net, stylization, OneCycle::new(1e-4, steps as u64 + 1, 20.0));
    // The peer scores one octave.
    trainer.octaves = 1;
    let mut rng = SplitMix64::new(1);
    let mut times = Vec::with_capacity(steps);
    let mut last = 0.0;
    for it in 0..=steps {
        let t0 = Instant::now();
        let origin = [0; 3].map(|_: usize| (rng.next_u64() % (p as u64 + 1)) as usize);
        let rot = Rotation {
            theta: (2.0 * rng.uniform_f32() - 1.0) * std::f32::consts::PI,
            phi: (rng.uniform_f32() - 0.5) * std::f32::consts::PI,
            mirror: rng.uniform_f32() < 0.5,
        };
        let patch = rotated_patch(&volume, origin, p, &rot);
        last = trainer
            .step(&patch, [0; 3], &loss, &view, &[crate::axes::Sight::Along(crate::axes::Axis::Z)])
            .expect("the benchmark view renders");
        if it > 0 {
            times.push(t0.elapsed().as_secs_f64() * 1e3);
        }
    }
    (times, last)
}
