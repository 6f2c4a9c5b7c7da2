use nst3d_stylize::bench::synthetic_smoke;
use std::time::Instant;
fn main() {
    rayon::ThreadPoolBuilder::new().num_threads(2).build_global().unwrap();
    let n = 128;
    let d = synthetic_smoke(n, 0);
    let v: Vec<[f32; 3]> = (0..d.len())
        .map(|i| {
            let f = (i % 97) as f32 * 0.01;
            [f, -f, 0.5 * f]
        })
        .collect();
    let g: Vec<f32> = (0..d.len()).map(|i| ((i % 13) as f32) * 0.1).collect();
    for _ in 0..3 {
        let t = Instant::now();
        let sv = nst3d_transport::tent_smooth(&v, d.dims);
        let t1 = t.elapsed();
        let out = nst3d_transport::advect_linear(&d, &sv);
        let t2 = t.elapsed();
        let mut gv = vec![[0.0f32; 3]; v.len()];
        nst3d_transport::advect_linear_backward(&d, &sv, &g, &mut gv);
        let t3 = t.elapsed();
        let r = nst3d_transport::tent_smooth(&gv, d.dims).into_flattened();
        let t4 = t.elapsed();
        eprintln!(
            "smooth {:?} advect {:?} advect_bwd {:?} smooth {:?} ({})",
            t1,
            t2 - t1,
            t3 - t2,
            t4 - t3,
            out.data[5] + r[7]
        );
    }
}
