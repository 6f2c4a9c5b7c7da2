//! Transport numerics against fixtures produced once with PyTorch
//! (tools/fixtures/transport_grid_sample.py documents the layouts).

use nst3d_core::Grid3;
use nst3d_transport::{advect_linear, advect_linear_backward, resize_grid};

use nst3d_core::fixture::{assert_close, split};

fn fixture(name: &str) -> Vec<f32> {
    nst3d_core::fixture::load_f32(env!("CARGO_MANIFEST_DIR"), name, "tools/fixtures/transport_grid_sample.py")
}

#[test]
fn advect_linear_matches_grid_sample() {
    let n = 120;
    let data = fixture("grid_sample.bin");
    let p = split(&data, &[n, 3 * n, n, n, 3 * n]);
    let d = Grid3::from_vec([5, 4, 6], p[0].to_vec());
    let v: Vec<[f32; 3]> = p[1].chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
    let out = advect_linear(&d, &v);
    assert_close(&out.data, p[3], 1e-5, "advected density");
    let mut gv = vec![[0f32; 3]; n];
    advect_linear_backward(&d, &v, p[2], &mut gv);
    let gflat: Vec<f32> = gv.iter().flatten().copied().collect();
    assert_close(&gflat, p[4], 1e-4, "velocity gradient");
}

#[test]
fn resize_grid_matches_interpolate() {
    let data = fixture("resize.bin");
    let p = split(&data, &[60, 140]);
    let src = Grid3::from_vec([5, 4, 3], p[0].to_vec());
    let out = resize_grid(&src, [4, 7, 5]);
    assert_close(&out.data, p[1], 1e-5, "resized grid");
}
