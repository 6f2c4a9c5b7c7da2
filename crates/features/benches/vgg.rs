//! Forward + backward of VGG-19 to relu4_1 on a 3x256x256 image with 2 threads:
//! the per-iteration network work of the style-transfer benchmark
//! (shared/bench/torch_ref.py). Prints the median over 7 timed runs.
//!
//! `cargo bench -p nst3d-features --bench vgg [-- <size> <runs>]`

use std::time::Instant;

use nst3d_core::{gradcheck::pseudo_random, FeatureView, Image};
use nst3d_features::{Vgg19, VggFlavor, VggLayer};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).filter(|a| !a.starts_with('-')).collect();
    let size: usize = args.first().and_then(|s| s.parse().ok()).unwrap_or(256);
    let runs: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(7);
    let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().expect("thread pool");
    let net = Vgg19::random(VggFlavor::Torchvision, 0);
    let taps = [VggLayer::Relu1_1, VggLayer::Relu2_1, VggLayer::Relu3_1, VggLayer::Relu4_1];
    let img = Image::from_vec(3, size, size, pseudo_random(3 * size * size, 1).iter().map(|v| 0.5 + 0.5 * v).collect());
    pool.install(|| {
        net.prepare(VggLayer::Relu4_1);
        let step = || {
            let t0 = Instant::now();
            let f = net.forward(&img, &taps, true);
            let t1 = Instant::now();
            // d(sum of squares)/d tap = 2 * tap, like the PyTorch script's loss.
            let grads: Vec<Vec<f32>> = f.features().iter().map(|t| t.data.iter().map(|v| 2.0 * v).collect()).collect();
            let views: Vec<FeatureView> =
                f.features().iter().zip(&grads).map(|(t, g)| FeatureView { data: g, ..*t }).collect();
            let g = net.backward(&f, &views);
            let t2 = Instant::now();
            std::hint::black_box(g);
            ((t1 - t0).as_secs_f64() * 1e3, (t2 - t1).as_secs_f64() * 1e3)
        };
        step();
        let mut times: Vec<(f64, f64)> = (0..runs).map(|_| step()).collect();
        times.sort_by(|a, b| (a.0 + a.1).total_cmp(&(b.0 + b.1)));
        let (f, b) = times[times.len() / 2];
        // The minimum as well: on a shared machine it is the least disturbed run.
        let (fm, bm) = times[0];
        println!(
            "vgg19_relu4_1 3x{size}x{size} threads 2: forward {f:.1} ms, backward {b:.1} ms, total {:.1} ms (median of {runs}; min total {:.1} = {fm:.1} + {bm:.1})",
            f + b,
            fm + bm
        );
    });
}
