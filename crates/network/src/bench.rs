//! The `infer` benchmark: the network's forward pass alone on an `N³` grid,
//! no gradient, as `shared/bench/torch_ff_ref.py --infer N` times it (one
//! warm-up, then timed passes); and `conv3d`, each layer's products on
//! each kernel, the table the kernel routing was read from.

use std::time::Instant;

use nst3d_core::gradcheck::pseudo_random;

use crate::conv3d::{Conv3d, Conv3dProduct, Kernel3d};
use crate::feedforward::FeedForward;
use crate::volume::Volume;

/// Milliseconds of each of `iters` timed forward passes (after one warm-up)
/// of the density network of width `channels` on an `n³` grid. The work does
/// not depend on the values, so the input is uniform noise in `[0, 1]`.
pub fn infer(n: usize, channels: usize, iters: usize) -> Vec<f64> {
    let net = FeedForward::new(channels, 1, 0);
    let x = Volume::from_vec(1, [n; 3], pseudo_random(n * n * n, 1).iter().map(|v| 0.5 * (v + 1.0)).collect());
    (0..=iters)
        .map(|_| {
            let t0 = Instant::now();
            std::hint::black_box(net.infer(&x));
            t0.elapsed().as_secs_f64() * 1e3
        })
        .skip(1)
        .collect()
}

/// One row of [`conv3d_table`]: a layer, one of its products, the median
/// milliseconds on each of [`Kernel3d::ALL`] (`None` where it did not run)
/// and the kernel the precision in force picks.
#[derive(Clone, Debug)]
pub struct KernelRow {
    /// The layer, as `name cin->cout kK sS at N³`.
    pub layer: String,
    /// Which product.
    pub product: Conv3dProduct,
    /// Median ms per kernel, in [`Kernel3d::ALL`]'s order.
    pub ms: [Option<f64>; 3],
    /// The kernel the routing rule picks here.
    pub chosen: Option<Kernel3d>,
}

/// Every distinct layer of the width-`channels` network (density and
/// velocity heads) at a `p³` patch, each product timed on each kernel this
/// machine has: `iters` runs after a warm-up, the median.
pub fn conv3d_table(p: usize, channels: usize, iters: usize) -> Vec<KernelRow> {
    let names = ["first", "encoder", "middle", "middle", "middle", "middle", "decoder 1", "decoder 2", "last"];
    let sizes = [p, p / 2, p / 4, p / 4, p / 4, p / 4, p / 2, p, p];
    let mut layers: Vec<(String, Conv3d, usize)> = Vec::new();
    for out in [1, 3] {
        for (i, (cin, cout, k, s, pad)) in FeedForward::layer_shapes(channels, out).into_iter().enumerate() {
            let name = format!("{} {cin}->{cout} k{k} s{s} at {}³", names[i], sizes[i]);
            if !layers.iter().any(|(n, _, _)| *n == name) {
                let mut l = Conv3d::zeros(cin, cout, k, s, pad);
                l.weight = pseudo_random(l.weight.len(), 1);
                layers.push((name, l, sizes[i]));
            }
        }
    }
    let mut rows = Vec::new();
    for (name, l, n) in layers {
        let x = Volume::from_vec(l.cin, [n; 3], pseudo_random(l.cin * n * n * n, 2));
        let out = l.out_dims(x.dims);
        let g = Volume::from_vec(l.cout, out, pseudo_random(l.cout * out.iter().product::<usize>(), 3));
        for product in [Conv3dProduct::Forward, Conv3dProduct::WeightGrad, Conv3dProduct::InputGrad] {
            let ms = Kernel3d::ALL.map(|k| {
                if !l.run_on(k, product, &x, &g) {
                    return None;
                }
                let mut t: Vec<f64> = (0..iters.max(1))
                    .map(|_| {
                        let t0 = Instant::now();
                        l.run_on(k, product, &x, &g);
                        t0.elapsed().as_secs_f64() * 1e3
                    })
                    .collect();
                t.sort_by(f64::total_cmp);
                Some(t[t.len() / 2])
            });
            if ms.iter().any(Option::is_some) {
                rows.push(KernelRow { layer: name.clone(), product, ms, chosen: l.chosen_kernel(product) });
            }
        }
    }
    rows
}
