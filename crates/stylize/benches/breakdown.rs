//! Where one `volume-iter` iteration spends its time, stage by stage
//! (profiling aid for docs/design/performance.md). `cargo bench -p
//! nst3d-stylize --bench breakdown -- [N]`.

use std::time::Instant;

use nst3d_core::{gradcheck::pseudo_random, FeatureView, Image};
use nst3d_features::{Vgg19, VggFlavor, VggLayer};
use nst3d_loss::{style_loss, StyleTarget};
use nst3d_optim::Adam;
use nst3d_render as render;
use nst3d_stylize::{bench::synthetic_smoke, view::grey_to_rgb, Field, Mode};

fn main() {
    let n: usize = std::env::args().nth(1).and_then(|s| s.parse().ok()).unwrap_or(128);
    rayon::ThreadPoolBuilder::new().num_threads(2).build_global().unwrap();
    let d = synthetic_smoke(n, 0);
    let vgg = Vgg19::random(VggFlavor::Torchvision, 0);
    let layers = [VggLayer::Relu1_1, VggLayer::Relu2_1, VggLayer::Relu3_1, VggLayer::Relu4_1];
    let style =
        Image::from_vec(3, 2 * n, 2 * n, pseudo_random(12 * n * n, 7).iter().map(|v| 0.5 * (v + 1.0)).collect());
    let target = StyleTarget::from_features(&vgg.forward(&style, &layers, false).features(), &[]).unwrap();
    for mode in [Mode::Velocity, Mode::Density] {
        let mut field = Field::identity(mode, d.len());
        let mut adam = Adam::new(field.len(), 0.1);
        for rep in 0..3 {
            let mut t = Instant::now();
            let mut lap = |name: &str| {
                if rep == 2 {
                    eprintln!("{mode:?} {name:>22}: {:7.1} ms", t.elapsed().as_secs_f64() * 1e3);
                }
                t = Instant::now();
            };
            let (ds, tape) = field.forward(&d);
            lap("transport");
            let img = render::march(&ds, 8.0 / n as f32);
            let rgb = grey_to_rgb(&render::upsample2x(&img));
            lap("render+upsample");
            let fwd = vgg.forward(&rgb, &layers, true);
            lap("vgg forward");
            let feats = fwd.features();
            let (_, g) = style_loss(&feats, &target).unwrap();
            let g: Vec<FeatureView> = feats.iter().zip(&g).map(|(f, g)| FeatureView { data: g, ..*f }).collect();
            lap("gram loss+backward");
            let grgb = vgg.backward(&fwd, &g);
            lap("vgg backward");
            let gi = render::upsample2x_backward(&nst3d_stylize::view::rgb_to_grey_backward(&grgb));
            let gd = render::march_backward(&ds, 8.0 / n as f32, &gi);
            lap("render backward");
            let gp = field.descent(field.backward(&d, &tape, &gd.data), d.dims);
            lap("transport backward");
            adam.step(field.params_mut(), &gp);
            lap("adam");
            drop(fwd);
            lap("free");
        }
    }
}
