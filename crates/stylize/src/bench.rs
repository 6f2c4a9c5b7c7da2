//! The `volume-iter` benchmark: exactly the per-iteration work of
//! `shared/bench/torch_ref.py` (see `shared/bench/README.md`), so the two
//! medians can be divided.

use std::time::Instant;

use nst3d_core::{gradcheck::pseudo_random, Grid3, Image};
use nst3d_features::{Vgg19, VggFlavor};
use nst3d_optim::Adam;
use nst3d_transport as transport;

use crate::field::{Field, Mode};
use crate::guided::{carried_regions, MapLoss};
use crate::view::{StyleSpec, ViewLoss, ViewSpec};

/// Median as Python's `statistics.median` computes it, so our figures and
/// the PyTorch peer's compare.
pub use nst3d_core::stats::median;

/// Timings of a benchmark run.
#[derive(Clone, Debug)]
pub struct BenchReport {
    /// Milliseconds of each timed iteration (the warm-up excluded).
    pub iteration_ms: Vec<f64>,
    /// Median of `iteration_ms`.
    pub median_ms: f64,
    /// Loss of the last iteration (a sanity value, not a result).
    pub last_loss: f32,
}

/// The peer's synthetic smoke: smooth noise (random at N/8, trilinearly
/// upsampled) inside a soft ball, clamped to `[0, 1]`.
pub fn synthetic_smoke(n: usize, seed: u64) -> Grid3 {
    let c = (n / 8).max(2);
    let coarse: Vec<f32> = pseudo_random(c * c * c, seed).iter().map(|v| 0.5 * (v + 1.0)).collect();
    let coarse = Grid3::from_vec([c; 3], coarse);
    let noise = transport::resize_grid(&coarse, [n; 3]);
    let mut d = Grid3::zeros([n; 3]);
    let h = 2.0 / (n as f32 - 1.0);
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                let p = [x, y, z].map(|i| -1.0 + h * i as f32);
                let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                let i = d.index(x, y, z);
                d.data[i] = (noise.data[i] * (1.0 - r).max(0.0) * 2.0).clamp(0.0, 1.0);
            }
        }
    }
    d
}

/// Runs `iters` timed iterations (after one warm-up) of the benchmark work
/// at resolution `n` in `mode`: transport, orthographic render along z with
/// γ = 8/N, 2x upsample, grey→RGB, ImageNet-normalised VGG-19 to relu4_1,
/// Gram MSE loss on relu1_1..relu4_1, backward to the field, one Adam step
/// (lr 0.01 in the peer's normalised units) and the density-mode clamp.
pub fn volume_iter(n: usize, mode: Mode, iters: usize) -> BenchReport {
    volume_iter_with(n, mode, iters, Look::Grey)
}

/// What a [`volume_iter_with`] iteration adds to the grey one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Look {
    /// The peer's iteration.
    Grey,
    /// `--color`: the view renders emission–absorption in RGB from the
    /// chroma layer ([`crate::color`]), VGG-19 sees the colour picture, and
    /// the backward also steps the three raw colour channels.
    Color,
    /// `--style-map`: two paintings, each over one half of the smoke (split
    /// at mid-height), scored by the guided Gram loss ([`crate::guided`])
    /// with the regions carried by the field.
    StyleMap,
}

/// [`volume_iter`] with what `look` adds to an iteration, to set against
/// the grey one.
pub fn volume_iter_with(n: usize, mode: Mode, iters: usize, look: Look) -> BenchReport {
    let d = synthetic_smoke(n, 0);
    // The peer uses a randomly initialised torchvision VGG: the work does not
    // depend on the weight values.
    let vgg = Vgg19::random(VggFlavor::Torchvision, 0);
    let style =
        Image::from_vec(3, 2 * n, 2 * n, pseudo_random(3 * 4 * n * n, 7).iter().map(|v| 0.5 * (v + 1.0)).collect());
    let loss = ViewLoss::new(&vgg, &style, &StyleSpec::default()).expect("default style layers are valid");
    let view = ViewSpec { camera: None, gamma: 8.0 / n as f32, exposure: 1.0, equalize: false };
    // Only a style-map run builds the second painting's target and the halves.
    let mapped = (look == Look::StyleMap).then(|| {
        let second = pseudo_random(3 * 4 * n * n, 8).iter().map(|v| 0.5 * (v + 1.0)).collect();
        let second = Image::from_vec(3, 2 * n, 2 * n, second);
        let loss = MapLoss::new(vec![
            ViewLoss::new(&vgg, &style, &StyleSpec::default()).expect("default style layers are valid"),
            ViewLoss::new(&vgg, &second, &StyleSpec::default()).expect("default style layers are valid"),
        ]);
        let upper = Grid3::from_vec(d.dims, (0..d.len()).map(|i| (i / (n * n) >= n / 2) as u8 as f32).collect());
        (loss, [Grid3::from_vec(d.dims, upper.data.iter().map(|u| 1.0 - u).collect()), upper])
    });
    let mut field = Field::identity(mode, d.len());
    // The peer's velocity lives in grid_sample's [-1, 1] coordinates; ours
    // is in voxels, so the same step is (N-1)/2 times larger here.
    let lr = match mode {
        Mode::Velocity => 0.01 * (n as f32 - 1.0) / 2.0,
        Mode::Density => 0.01,
    };
    let mut adam = Adam::new(field.len(), lr);
    let mut raw: Vec<Field> = (0..3).map(|_| Field::identity(Mode::Density, d.len())).collect();
    let mut color_adam: Vec<Adam> = (0..3).map(|_| Adam::new(d.len(), crate::color::LEARNING_RATE)).collect();
    let mut times = Vec::with_capacity(iters);
    let mut last_loss = 0.0;
    for it in 0..=iters {
        let t0 = Instant::now();
        let (dstar, tape) = field.forward(&d);
        let (l, grad_dstar) = if let Some((map_loss, regions)) = &mapped {
            let moved = carried_regions(&field, regions);
            map_loss.loss_and_grad(&dstar, &moved, &view).expect("the benchmark view renders")
        } else if look == Look::Color {
            let (c, tape) = crate::color::chroma(&crate::color::raw_of(&raw), d.dims, crate::color::SMOOTH_PASSES);
            let (l, g, gc) = loss.loss_and_grad_color(&dstar, &c, &view).expect("the benchmark view renders");
            let grad_raw = crate::color::chroma_backward(&tape, &gc);
            for ((f, a), g) in raw.iter_mut().zip(&mut color_adam).zip(grad_raw) {
                a.step(f.params_mut(), &g);
                transport::clamp_scale(f.params_mut(), crate::color::RAW_RANGE.0, crate::color::RAW_RANGE.1);
            }
            (l, g)
        } else {
            loss.loss_and_grad(&dstar, &view).expect("the benchmark view renders")
        };
        let grad = field.descent(field.backward(&d, &tape, &grad_dstar.data), d.dims);
        adam.step(field.params_mut(), &grad);
        if let Field::Scale(s) = &mut field {
            transport::clamp_scale(s, 0.0, 2.0);
        }
        last_loss = l;
        if it > 0 {
            times.push(t0.elapsed().as_secs_f64() * 1e3);
        }
    }
    let median_ms = median(&times);
    BenchReport { iteration_ms: times, median_ms, last_loss }
}
