//! NNST matches, loss and gradient against PyTorch (fixture from
//! tools/fixtures/loss_nnst.py; layout documented there).

use nst3d_core::fixture::{assert_close, load_f32, split};
use nst3d_core::Image;
use nst3d_loss::nnst::{nnst_loss, LayerWeight, NnstParams, NnstTarget};

const STYLE: [(usize, usize, usize); 3] = [(4, 12, 14), (6, 6, 7), (8, 3, 3)];
const CONTENT: [(usize, usize, usize); 3] = [(4, 16, 12), (6, 8, 6), (8, 4, 3)];
/// Content hyper-column count: (16 / 2) x (12 / 2).
const NC: usize = 48;

fn images(parts: &[&[f32]], shapes: &[(usize, usize, usize)]) -> Vec<Image> {
    parts.iter().zip(shapes).map(|(p, &(c, h, w))| Image::from_vec(c, h, w, p.to_vec())).collect()
}

#[test]
fn matches_pytorch() {
    check("loss_nnst.bin", LayerWeight::InverseChannels);
}

#[test]
fn matches_pytorch_with_square_root_layer_weights() {
    check("loss_nnst_sqrt.bin", LayerWeight::InverseSqrtChannels);
}

fn check(file: &str, layer_weight: LayerWeight) {
    let data = load_f32(env!("CARGO_MANIFEST_DIR"), file, "tools/fixtures/loss_nnst.py");
    let size = |s: &[(usize, usize, usize)]| s.iter().map(|&(c, h, w)| c * h * w).collect::<Vec<_>>();
    let lens: Vec<usize> = [size(&STYLE), size(&CONTENT), vec![NC, 1], size(&CONTENT)].concat();
    let parts = split(&data, &lens);
    let style = images(&parts[0..3], &STYLE);
    let content = images(&parts[3..6], &CONTENT);
    let (want_idx, want_loss) = (parts[6], parts[7][0]);
    let want_grads = &parts[8..11];

    let target = NnstTarget::from_style_features(&style, &NnstParams { grid_divisor: 2, layer_weight }).unwrap();
    let matched = target.match_content(&content).unwrap();
    let idx: Vec<f32> = matched.indices().iter().map(|&i| i as f32).collect();
    assert_eq!(idx, want_idx, "nearest style columns");

    let (loss, grads) = nnst_loss(&content, &target).unwrap();
    assert_close(&[loss], &[want_loss], 1e-5, "loss");
    for (l, (g, w)) in grads.iter().zip(want_grads).enumerate() {
        assert_close(&g.data, w, 1e-5, &format!("dloss/dcontent[{l}]"));
    }
}
