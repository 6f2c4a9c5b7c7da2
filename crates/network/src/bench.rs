//! The `infer` benchmark: the network's forward pass alone on an `N³` grid,
//! no gradient, as `shared/bench/torch_ff_ref.py --infer N` times it (one
//! warm-up, then timed passes).

use std::time::Instant;

use nst3d_core::gradcheck::pseudo_random;

use crate::feedforward::FeedForward;
use crate::volume::Volume;

/// Milliseconds of each of `iters` timed forward passes (after one warm-up)
/// of the density network of width `channels` on an `n³` grid. The work does
/// not depend on the values, so the input is uniform noise in `[0, 1]`.
pub fn infer(n: usize, channels: usize, iters: usize) -> Vec<f64> {
    let net = FeedForward::new(channels, 1, 0);
    let x = Volume::from_vec(1, [n; 3], pseudo_random(n * n * n, 1).iter().map(|v| 0.5 * (v + 1.0)).collect());
    (0..=iters)
        .map(|_| {
            let t0 = Instant::now();
            std::hint::black_box(net.infer(&x));
            t0.elapsed().as_secs_f64() * 1e3
        })
        .skip(1)
        .collect()
}
