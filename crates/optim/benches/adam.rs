//! Times one Adam step on a `128³ x 3` velocity field, the benchmark's
//! parameter count. Run: `cargo bench -p nst3d-optim`.

use nst3d_optim::Adam;
use std::time::Instant;

fn main() {
    let n = 128 * 128 * 128 * 3;
    let mut params = vec![0.0f32; n];
    let grads: Vec<f32> = (0..n).map(|i| ((i * 7919 % 1000) as f32 - 500.0) * 1e-3).collect();
    let mut adam = Adam::new(n, 0.01);
    adam.step(&mut params, &grads);
    let mut t: Vec<f64> = (0..11)
        .map(|_| {
            let s = Instant::now();
            adam.step(&mut params, &grads);
            s.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    t.sort_by(f64::total_cmp);
    println!("rayon threads: {}", rayon::current_num_threads());
    println!("adam step, {n} params: {:.2} ms (median of 11)", t[5]);
}
