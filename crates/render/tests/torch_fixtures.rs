//! Render numerics against fixtures produced once with PyTorch
//! (tools/fixtures/render_torch.py documents the layouts).

use nst3d_core::{Grid3, Image};
use nst3d_render::{march, march_backward, upsample2x, upsample2x_backward};

/// Reads a committed fixture as f32 values; panics loudly if it is missing.
fn fixture(name: &str) -> Vec<f32> {
    let path = format!("{}/tests/fixtures/{name}", env!("CARGO_MANIFEST_DIR"));
    let bytes =
        std::fs::read(&path).unwrap_or_else(|e| panic!("missing fixture {path} ({e}); run tools/fixtures/render_torch.py"));
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
fn march_matches_torch_reference_render() {
    let data = fixture("march.bin");
    let p = split(&data, &[210, 30, 30, 210]);
    let d = Grid3::from_vec([6, 5, 7], p[0].to_vec());
    let img = march(&d, 0.35);
    assert_eq!((img.channels, img.height, img.width), (1, 5, 6));
    assert_close(&img.data, p[2], 1e-5, "image");
    let grad = march_backward(&d, 0.35, &Image::from_vec(1, 5, 6, p[1].to_vec()));
    assert_close(&grad.data, p[3], 1e-5, "density gradient");
}

#[test]
fn upsample2x_matches_interpolate() {
    let data = fixture("upsample.bin");
    let p = split(&data, &[30, 120, 120, 30]);
    let out = upsample2x(&Image::from_vec(2, 3, 5, p[0].to_vec()));
    assert_eq!((out.channels, out.height, out.width), (2, 6, 10));
    assert_close(&out.data, p[2], 1e-6, "upsampled");
    let grad = upsample2x_backward(&Image::from_vec(2, 6, 10, p[1].to_vec()));
    assert_close(&grad.data, p[3], 1e-5, "image gradient");
}
