//! Transport numerics against fixtures produced once with PyTorch
//! (tools/fixtures/transport_grid_sample.py documents the layouts).

use nst3d_core::Grid3;
use nst3d_transport::{advect_linear, advect_linear_backward, resize_grid};

/// Reads a committed fixture as f32 values; panics loudly if it is missing.
fn fixture(name: &str) -> Vec<f32> {
    let path = format!("{}/tests/fixtures/{name}", env!("CARGO_MANIFEST_DIR"));
    let bytes = std::fs::read(&path)
        .unwrap_or_else(|e| panic!("missing fixture {path} ({e}); run tools/fixtures/transport_grid_sample.py"));
    bytes.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect()
}

/// Splits `data` into consecutive arrays of the given lengths.
fn split<'a>(mut data: &'a [f32], lens: &[usize]) -> Vec<&'a [f32]> {
    assert_eq!(data.len(), lens.iter().sum::<usize>(), "fixture size");
    lens.iter()
        .map(|&n| {
            let (a, b) = data.split_at(n);
            data = b;
            a
        })
        .collect()
}

fn assert_close(got: &[f32], want: &[f32], tol: f32, what: &str) {
    assert_eq!(got.len(), want.len());
    for (i, (a, b)) in got.iter().zip(want).enumerate() {
        assert!((a - b).abs() <= tol * (1.0 + b.abs()), "{what}[{i}]: {a} vs torch {b}");
    }
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
