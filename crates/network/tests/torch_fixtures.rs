//! The network's ops against PyTorch (`tools/fixtures/network_ops.py`):
//! `F.conv3d` forward and its input, weight and bias gradients for the
//! network's three layer shapes, `F.interpolate` (trilinear ×2,
//! `align_corners=False`) and `F.leaky_relu(0.01)`.

use nst3d_core::fixture::{assert_close, load_f32, split};
use nst3d_network::{leaky_relu, leaky_relu_backward, upsample2, upsample2_backward, Conv3d, Volume};

const SCRIPT: &str = "tools/fixtures/network_ops.py";

fn fixture(name: &str) -> Vec<f32> {
    load_f32(env!("CARGO_MANIFEST_DIR"), name, SCRIPT)
}

#[test]
fn conv3d_matches_torch() {
    nst3d_core::precision::fp32(|| {
        // (cin, cout, k, stride, pad, [x, y, z])
        let shapes = [(1, 3, 5, 2, 2, [5, 6, 7]), (2, 3, 3, 2, 1, [4, 5, 6]), (3, 2, 3, 1, 1, [4, 5, 6])];
        for (i, (cin, cout, k, s, p, dims)) in shapes.into_iter().enumerate() {
            let mut c = Conv3d::zeros(cin, cout, k, s, p);
            let out = c.out_dims(dims);
            let (nin, nout): (usize, usize) =
                (cin * dims.iter().product::<usize>(), cout * out.iter().product::<usize>());
            let data = fixture(&format!("conv3d_{i}.bin"));
            let f = split(&data, &[nin, c.weight.len(), cout, nout, nout, nin, c.weight.len(), cout]);
            c.weight = f[1].to_vec();
            c.bias = f[2].to_vec();
            let x = Volume::from_vec(cin, dims, f[0].to_vec());
            let y = c.forward(&x);
            assert_close(&y.data, f[4], 1e-5, &format!("conv3d_{i} forward"));
            let (dx, g) = c.backward(&x, &Volume::from_vec(cout, out, f[3].to_vec()), true);
            assert_close(&dx.unwrap().data, f[5], 1e-5, &format!("conv3d_{i} dx"));
            assert_close(&g.weight, f[6], 1e-5, &format!("conv3d_{i} dweight"));
            assert_close(&g.bias, f[7], 1e-5, &format!("conv3d_{i} dbias"));
        }
    })
}

#[test]
fn upsample_matches_torch() {
    let dims = [5, 4, 3];
    let n = 2 * 60;
    let data = fixture("upsample.bin");
    let f = split(&data, &[n, 8 * n, 8 * n, n]);
    let x = Volume::from_vec(2, dims, f[0].to_vec());
    assert_close(&upsample2(&x).data, f[2], 1e-6, "upsample forward");
    let dx = upsample2_backward(&Volume::from_vec(2, dims.map(|v| 2 * v), f[1].to_vec()), dims);
    assert_close(&dx.data, f[3], 1e-5, "upsample backward");
}

#[test]
fn leaky_relu_matches_torch() {
    let data = fixture("leaky.bin");
    let f = split(&data, &[200, 200, 200, 200]);
    let mut y = f[0].to_vec();
    leaky_relu(&mut y);
    assert_close(&y, f[2], 1e-7, "leaky_relu forward");
    let mut g = f[1].to_vec();
    leaky_relu_backward(&y, &mut g);
    assert_close(&g, f[3], 1e-7, "leaky_relu backward");
}
