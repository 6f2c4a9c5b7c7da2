//! Gram, MSE and style loss against PyTorch (fixture from
//! tools/fixtures/loss_gram.py; layout documented there).

use nst3d_core::{FeatureView, Image};
use nst3d_loss::{gram, mse, mse_backward, style_loss, StyleTarget};

const SHAPES: [(usize, usize, usize); 2] = [(8, 6, 5), (16, 3, 4)];

/// Reads the fixture's floats in order.
struct Reader {
    data: Vec<f32>,
    pos: usize,
}

impl Reader {
    fn open() -> Self {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/loss_gram.bin");
        let bytes = std::fs::read(path)
            .unwrap_or_else(|e| panic!("missing fixture {path} ({e}); run tools/fixtures/loss_gram.py"));
        let data = bytes.chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect();
        Self { data, pos: 0 }
    }
    fn take(&mut self, n: usize) -> Vec<f32> {
        let v = self.data[self.pos..self.pos + n].to_vec();
        self.pos += n;
        v
    }
    fn images(&mut self) -> Vec<Image> {
        SHAPES.iter().map(|&(c, h, w)| Image::from_vec(c, h, w, self.take(c * h * w))).collect()
    }
}

fn assert_close(got: &[f32], want: &[f32], tol: f32, what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    for (i, (a, b)) in got.iter().zip(want).enumerate() {
        assert!((a - b).abs() <= tol * (1.0 + b.abs()), "{what}[{i}]: {a} vs torch {b}");
    }
}

#[test]
fn matches_pytorch() {
    nst3d_core::precision::fp32(|| {
        let mut r = Reader::open();
        let style = r.images();
        let feats = r.images();
        let weights = r.take(2);
        let grams: Vec<Vec<f32>> = SHAPES.iter().map(|&(c, ..)| r.take(c * c)).collect();
        let mses = r.take(2);
        let loss = r.take(1)[0];
        let dmse0 = r.take(SHAPES[0].0 * SHAPES[0].0);
        let grads = r.images();
        assert_eq!(r.pos, r.data.len(), "fixture has trailing data: layout changed?");

        let target = StyleTarget::from_features(&views(&style), &weights).unwrap();
        for l in 0..2 {
            let g = gram((&feats[l]).into());
            assert_close(&g, &grams[l], 1e-6, "gram");
            assert_close(&[mse(&g, target.gram(l))], &mses[l..l + 1], 1e-6, "mse");
        }
        assert_close(&mse_backward(&gram((&feats[0]).into()), target.gram(0)), &dmse0, 1e-6, "mse_backward");

        let (got_loss, got_grads) = style_loss(&views(&feats), &target).unwrap();
        assert_close(&[got_loss], &[loss], 1e-6, "style loss");
        for l in 0..2 {
            assert_close(&got_grads[l], &grads[l].data, 1e-6, "style loss gradient");
        }
    })
}

fn views(images: &[Image]) -> Vec<FeatureView<'_>> {
    images.iter().map(FeatureView::from).collect()
}
