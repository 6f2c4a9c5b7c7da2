//! Algorithm 1 on a synthetic moving smoke puff: the EMA makes the pattern
//! follow the smoke instead of flickering, at a small cost in style loss.

use nst3d_core::{Grid3, Image};
use nst3d_features::{Vgg19, VggFlavor};
use nst3d_render::Camera;
use nst3d_sequence::ema::{stylize_sequence, stylized_density, MemoryStore, SequenceError, SequenceParams, Simulation};
use nst3d_sequence::flicker::flicker;
use nst3d_stylize::{bench::synthetic_smoke, FrameParams, Limits, Mode, StyleSpec, ViewLoss, ViewSpec};

/// A puff drifting one voxel per frame along +x.
struct Drift {
    base: Grid3,
    frames: usize,
}

impl Simulation for Drift {
    fn len(&self) -> usize {
        self.frames
    }
    fn dims(&self) -> [usize; 3] {
        self.base.dims
    }
    fn density(&self, t: usize) -> Result<Grid3, SequenceError> {
        let u = vec![[t as f32, 0.0, 0.0]; self.base.len()];
        Ok(nst3d_transport::advect_linear(&self.base, &u.iter().map(|w| [-w[0], 0.0, 0.0]).collect::<Vec<_>>()))
    }
    fn velocity(&self, _t: usize) -> Result<Option<Vec<[f32; 3]>>, SequenceError> {
        Ok(Some(vec![[1.0, 0.0, 0.0]; self.base.len()]))
    }
}

fn stripes(n: usize) -> Image {
    let mut img = Image::zeros(3, n, n);
    for (i, v) in img.data.iter_mut().enumerate() {
        let (y, x) = ((i / n) % n, i % n);
        *v = if (x + 2 * y) % 8 < 4 { 0.9 } else { 0.1 };
    }
    img
}

#[test]
fn ema_cuts_flicker() {
    let mut base = synthetic_smoke(20, 3);
    // Leave room to drift: shrink the puff into the left part of the box.
    base = nst3d_transport::advect_linear(&base, &vec![[4.0, 0.0, 0.0]; base.len()]);
    let sim = Drift { base, frames: 6 };
    let vgg = Vgg19::random(VggFlavor::Torchvision, 4);
    let loss = ViewLoss::new(&vgg, &stripes(32), &StyleSpec::default()).unwrap();
    let view = ViewSpec { camera: Some(Camera::front(sim.dims())), gamma: 0.2, exposure: 0.2, equalize: false };
    let run = |alpha: f32| {
        let frame = FrameParams {
            mode: Mode::Velocity,
            octaves: 1,
            iterations: 12,
            learning_rate: 0.3,
            limits: Limits { vmax: 2.0, smin: 0.0, smax: 2.0 },
            view: view.clone(),
        };
        let mut store = MemoryStore::default();
        let params = SequenceParams { frame, alpha };
        stylize_sequence(&sim, &loss, &[view.clone()], &params, &mut store, &mut |_| {}).unwrap();
        let frames: Vec<Grid3> = (0..sim.len()).map(|t| stylized_density(&sim, &mut store, t).unwrap()).collect();
        let vels: Vec<_> = (0..sim.len()).map(|t| sim.velocity(t).unwrap()).collect();
        let f = flicker(&frames, &vels, |d| loss.image(d, &view).unwrap());
        let l: f32 = frames.iter().map(|d| loss.loss(d, &view).unwrap()).sum::<f32>() / frames.len() as f32;
        (f, l)
    };
    let (f0, l0) = run(0.0);
    let (f7, l7) = run(0.7);
    eprintln!("flicker: alpha 0 {f0:.5} (loss {l0:.3}), alpha 0.7 {f7:.5} (loss {l7:.3})");
    assert!(f7 < 0.8 * f0, "EMA did not reduce flicker: {f0} -> {f7}");
    assert!(l7 < 1.5 * l0, "EMA cost too much style: {l0} -> {l7}");
}
