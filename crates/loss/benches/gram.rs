//! Times `gram` and `gram_backward` at the shapes of the volume-iter benchmark
//! (256x256 render: relu1_1 is 64 x 256², relu4_1 is 512 x 32²).
//! Run: `cargo bench -p nst3d-loss` (threads: RAYON_NUM_THREADS, default all cores).

use nst3d_core::{gradcheck::pseudo_random, FeatureView, Layout};
use nst3d_loss::{gram, gram_backward, style_loss, StyleTarget};
use std::time::Instant;

/// CPU time of all threads of this process in ns (Linux schedstat): on a
/// shared, oversubscribed machine it shows the work done where wall time
/// mostly shows the neighbours.
fn cpu_ns() -> u64 {
    let Ok(dir) = std::fs::read_dir("/proc/self/task") else {
        return 0;
    };
    dir.filter_map(|e| std::fs::read_to_string(e.ok()?.path().join("schedstat")).ok())
        .filter_map(|s| s.split_whitespace().next()?.parse::<u64>().ok())
        .sum()
}

/// Median wall and CPU time of `f` in milliseconds over `reps` runs after one warm-up.
fn median_ms(reps: usize, mut f: impl FnMut()) -> (f64, f64) {
    f();
    let mut t: Vec<(f64, f64)> = (0..reps)
        .map(|_| {
            let (s, c) = (Instant::now(), cpu_ns());
            f();
            (s.elapsed().as_secs_f64() * 1e3, (cpu_ns() - c) as f64 * 1e-6)
        })
        .collect();
    t.sort_by(|a, b| a.0.total_cmp(&b.0));
    t[reps / 2]
}

type Layer = (usize, usize, usize, Vec<f32>);

fn view(f: &Layer, layout: Layout) -> FeatureView<'_> {
    let (channels, height, width, ref data) = *f;
    FeatureView { channels, height, width, layout, data }
}

fn main() {
    println!("rayon threads: {}", rayon::current_num_threads());
    let shapes = [(64, 256, 256), (128, 128, 128), (256, 64, 64), (512, 32, 32)];
    // The network's own layout (what the volume pipeline passes) and planar.
    let feats: Vec<Layer> =
        shapes.iter().enumerate().map(|(i, &(c, h, w))| (c, h, w, pseudo_random(c * h * w, i as u64 + 1))).collect();
    for layout in [Layout::ChannelsLast, Layout::Planar] {
        for f in &feats {
            let v = view(f, layout);
            let g = gram(v);
            let fwd = median_ms(15, || drop(std::hint::black_box(gram(v))));
            let bwd = median_ms(15, || drop(std::hint::black_box(gram_backward(v, &g))));
            println!(
                "{layout:?} {:>3} x {:>5}: gram {:6.2} ms (cpu {:6.2})   gram_backward {:6.2} ms (cpu {:6.2})",
                v.channels,
                v.pixels(),
                fwd.0,
                fwd.1,
                bwd.0,
                bwd.1
            );
        }
    }
    let style: Vec<_> = feats.iter().map(|(c, h, w, d)| (*c, *h, *w, d.iter().map(|v| v * 0.5).collect())).collect();
    let target =
        StyleTarget::from_features(&style.iter().map(|f| view(f, Layout::ChannelsLast)).collect::<Vec<_>>(), &[])
            .unwrap();
    let views: Vec<_> = feats.iter().map(|f| view(f, Layout::ChannelsLast)).collect();
    let all = median_ms(9, || drop(std::hint::black_box(style_loss(&views, &target).unwrap())));
    println!("style_loss, 4 layers (relu1_1..relu4_1 at 256², channels-last): {:6.2} ms (cpu {:6.2})", all.0, all.1);
}
