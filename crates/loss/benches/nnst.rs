//! Timing of the NNST loss at benchmark sizes: a 600x600 render (VGG-19 taps
//! relu1_1..relu4_1 at 600², 300², 150², 75²) against a 512² style image.
//! A benchmark, not a test: `cargo bench -p nst3d-loss --bench nnst`
//! (2 threads).

use nst3d_core::gradcheck::pseudo_random;
use nst3d_core::Image;
use nst3d_loss::nnst::{nnst_loss_matched, NnstParams, NnstTarget};
use std::time::Instant;

/// ReLU-like (non-negative) VGG taps of a `size²` image.
fn taps(size: usize, seed: u64) -> Vec<Image> {
    [(64, 1), (128, 2), (256, 4), (512, 8)]
        .iter()
        .enumerate()
        .map(|(i, &(c, down))| {
            let s = size / down;
            let data = pseudo_random(c * s * s, seed + i as u64).into_iter().map(|v| v.max(0.0)).collect();
            Image::from_vec(c, s, s, data)
        })
        .collect()
}

fn best_ms(reps: usize, mut f: impl FnMut()) -> f64 {
    (0..reps)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64() * 1e3
        })
        .fold(f64::INFINITY, f64::min)
}

fn main() {
    rayon::ThreadPoolBuilder::new().num_threads(2).build_global().expect("thread pool");
    let style = taps(512, 1);
    let content = taps(600, 10);
    let params = NnstParams::default();
    let mut target = None;
    let t_style = best_ms(2, || target = Some(NnstTarget::from_style_features(&style, &params).unwrap()));
    let target = target.unwrap();
    let mut matched = None;
    let t_match = best_ms(1, || matched = Some(target.match_content(&content).unwrap()));
    let matched = matched.unwrap();
    let t_loss = best_ms(3, || {
        nnst_loss_matched(&content, &matched).unwrap();
    });
    println!(
        "threads {}: style target {t_style:.1} ms, match (N_c {} x N_s {} x D {}) {t_match:.1} ms, \
         loss+grad vs fixed targets {t_loss:.1} ms",
        rayon::current_num_threads(),
        matched.indices().len(),
        target.columns().plane(),
        target.depth(),
    );
}
