//! Forward + backward time of a groom-sized render: 100 guide + 2000 proxy
//! strands of 32 segments on a unit fur ball, 600x600, median of several runs.
//! Run with `RAYON_NUM_THREADS=2 cargo bench -p nst3d-splat`.

use nst3d_core::stats::median;
use nst3d_core::{gradcheck::pseudo_random, Image};
use nst3d_splat::{render, render_backward, SplatCamera, StrandStyle, Strands};
use std::time::Instant;

/// Strands growing from a unit sphere along its normal, with some curl.
fn fur_ball(n_strands: usize, segments: usize, seed: u64) -> (Vec<[f32; 3]>, Vec<usize>, Vec<[f32; 3]>) {
    let r = pseudo_random(n_strands * 4, seed);
    let mut points = Vec::new();
    let mut offsets = vec![0];
    let mut normals = Vec::new();
    for i in 0..n_strands {
        // Uniform on the sphere from two uniforms.
        let z = r[4 * i];
        let phi = std::f32::consts::PI * r[4 * i + 1];
        let s = (1.0 - z * z).sqrt();
        let n = [s * phi.cos(), s * phi.sin(), z];
        let curl = 0.05 + 0.05 * r[4 * i + 2].abs();
        let len = 0.35 + 0.1 * r[4 * i + 3];
        // A tangent to curl around.
        let t = if n[2].abs() < 0.9 { [-n[1], n[0], 0.0] } else { [0.0, -n[2], n[1]] };
        let tn = (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt();
        let t = t.map(|v| v / tn);
        for k in 0..=segments {
            let u = k as f32 / segments as f32;
            let w = curl * (6.0 * u).sin() * u;
            points.push(std::array::from_fn(|a| n[a] * (1.0 + len * u) + t[a] * w));
        }
        offsets.push(points.len());
        normals.push(n);
    }
    (points, offsets, normals)
}

fn main() {
    let (points, offsets, normals) = fur_ball(2100, 32, 3);
    let cam = SplatCamera::look_at([0.0, 0.8, 3.4], [0.0; 3], [0.0, 1.0, 0.0], 45.0, 600, 600).unwrap();
    let style = StrandStyle { width: 0.004, visibility_threshold: -0.2, ..StrandStyle::default() };
    let grad = Image::from_vec(3, 600, 600, pseudo_random(3 * 600 * 600, 9));
    for (label, root_normals) in [("all strands", None), ("culled (eps -0.2)", Some(normals.as_slice()))] {
        let strands = Strands { points: &points, offsets: &offsets, colors: None, root_normals };
        let (mut fwd, mut bwd) = (Vec::new(), Vec::new());
        let mut splats = 0;
        for _ in 0..9 {
            let t0 = Instant::now();
            let (img, cache) = render(&strands, &cam, &style).unwrap();
            let t1 = Instant::now();
            let g = render_backward(&strands, &cam, &style, &cache, &grad).unwrap();
            let t2 = Instant::now();
            std::hint::black_box((img, g));
            splats = cache.splat_count();
            fwd.push((t1 - t0).as_secs_f64() * 1e3);
            bwd.push((t2 - t1).as_secs_f64() * 1e3);
        }
        let total: Vec<f64> = fwd.iter().zip(&bwd).map(|(a, b)| a + b).collect();
        println!(
            "splat 2100 strands x 32 seg, 600x600, {label} ({splats} splats, {} threads): \
             forward {:.1} ms, backward {:.1} ms, forward+backward {:.1} ms (median of 9)",
            rayon::current_num_threads(),
            median(&fwd),
            median(&bwd),
            median(&total)
        );
    }
}
