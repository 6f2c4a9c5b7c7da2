//! Render numerics against fixtures produced once with PyTorch
//! (tools/fixtures/render_torch.py documents the layouts).

use nst3d_core::{Grid3, Image};
use nst3d_render::{march, march_backward, upsample2x, upsample2x_backward};

use nst3d_core::fixture::{assert_close, split};

fn fixture(name: &str) -> Vec<f32> {
    nst3d_core::fixture::load_f32(env!("CARGO_MANIFEST_DIR"), name, "tools/fixtures/render_torch.py")
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
