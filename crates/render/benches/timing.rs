//! Times the per-iteration transport and render work at N = 128 (2M voxels):
//! `cargo bench -p nst3d-render --bench timing -- [N]`. Prints wall
//! time and CPU time summed over threads (busy-waiting rayon workers inflate the latter).

use nst3d_core::{gradcheck::pseudo_random, Grid3, Image};
use nst3d_render::{
    march, march_backward, render, render_backward, upsample2x, upsample2x_backward, Camera, Projection,
};
use nst3d_transport::{advect_linear, advect_linear_backward};
use std::time::Instant;

/// CPU time of all threads of this process (Linux schedstat, ns): on a shared
/// machine wall time mostly measures the neighbours.
fn cpu_ns() -> u64 {
    std::fs::read_dir("/proc/self/task")
        .map(|dir| {
            dir.filter_map(|e| std::fs::read_to_string(e.ok()?.path().join("schedstat")).ok())
                .filter_map(|s| s.split_whitespace().next()?.parse::<u64>().ok())
                .sum()
        })
        .unwrap_or(0)
}

fn time<T>(label: &str, f: impl FnOnce() -> T) -> T {
    let (t, c) = (Instant::now(), cpu_ns());
    let out = f();
    let cpu = (cpu_ns() - c) as f64 * 1e-6;
    println!("{label:<48} wall {:8.2} ms   cpu {cpu:8.2} ms", t.elapsed().as_secs_f64() * 1e3);
    out
}

fn main() {
    let n: usize = std::env::args().nth(1).and_then(|s| s.parse().ok()).unwrap_or(128);
    let dims = [n; 3];
    let len = n * n * n;
    let d = Grid3::from_vec(dims, pseudo_random(len, 1).iter().map(|v| 0.5 * (v + 1.0)).collect());
    // Smooth velocities of up to 2 voxels, like an optimised stylisation field.
    let k = std::f32::consts::TAU / n as f32 * 3.0;
    let v: Vec<[f32; 3]> = (0..len)
        .map(|i| {
            let (x, y, z) = ((i % n) as f32, ((i / n) % n) as f32, (i / (n * n)) as f32);
            [2.0 * (k * y).sin(), 2.0 * (k * z).cos(), 2.0 * (k * x).sin()]
        })
        .collect();
    let gamma = 8.0 / n as f32;
    println!("N = {n}, {} threads", rayon::current_num_threads());
    let only_advect = std::env::args().nth(2).is_some_and(|a| a == "advect");
    for _ in 0..2 {
        if only_advect {
            let _ = time("advect_linear", || advect_linear(&d, &v));
            continue;
        }
        let ds = time("advect_linear", || advect_linear(&d, &v));
        let gout = pseudo_random(len, 3);
        let mut gv = vec![[0f32; 3]; len];
        time("advect_linear_backward", || advect_linear_backward(&d, &v, &gout, &mut gv));
        let img = time("march", || march(&ds, gamma));
        let gi = Image::from_vec(1, n, n, pseudo_random(n * n, 4));
        time("march_backward", || march_backward(&ds, gamma, &gi));
        let up = time("upsample2x", || upsample2x(&img));
        time("upsample2x_backward", || upsample2x_backward(&up));
        for (name, cam) in [
            ("front ortho", Camera::front(dims)),
            ("orbit(30,20) ortho", Camera::orbit(dims, 30.0, 20.0)),
            ("front perspective", Camera::front(dims).with_projection(Projection::Perspective)),
        ] {
            let (img, cache) = time(&format!("render {name}"), || render(&ds, &cam, gamma).unwrap());
            let gi = Image::from_vec(1, img.height, img.width, pseudo_random(img.data.len(), 5));
            time(&format!("render_backward {name} {:?}", cache.view.dims), || render_backward(&ds, &cache, &gi));
        }
        println!();
    }
}
