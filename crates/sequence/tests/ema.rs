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
        let params = SequenceParams { frame, alpha, settle_first_sweep: false, color: false };
        stylize_sequence(&sim, &loss, std::slice::from_ref(&view), &params, &mut store, &mut |_| {}).unwrap();
        let frames: Vec<Grid3> = (0..sim.len()).map(|t| stylized_density(&sim, &mut store, t).unwrap()).collect();
        let vels: Vec<_> = (0..sim.len()).map(|t| sim.velocity(t).unwrap()).collect();
        let f = flicker(&frames, &vels, |d| loss.image(d, &view)).unwrap();
        let l: f32 = frames.iter().map(|d| loss.loss(d, &view).unwrap()).sum::<f32>() / frames.len() as f32;
        (f, l)
    };
    let (f0, l0) = run(0.0);
    let (f7, l7) = run(0.7);
    eprintln!("flicker: alpha 0 {f0:.5} (loss {l0:.3}), alpha 0.7 {f7:.5} (loss {l7:.3})");
    assert!(f7 < 0.8 * f0, "EMA did not reduce flicker: {f0} -> {f7}");
    assert!(l7 < 1.5 * l0, "EMA cost too much style: {l0} -> {l7}");
}

/// A simulation whose frame reads start failing after `budget` reads, as a
/// farm task killed mid-sweep.
struct Dying<'a> {
    sim: &'a Drift,
    budget: std::cell::Cell<usize>,
}

impl Simulation for Dying<'_> {
    fn len(&self) -> usize {
        self.sim.len()
    }
    fn dims(&self) -> [usize; 3] {
        self.sim.dims()
    }
    fn density(&self, t: usize) -> Result<Grid3, SequenceError> {
        if self.budget.get() == 0 {
            return Err(SequenceError::Frame { frame: t, message: "killed".into() });
        }
        self.budget.set(self.budget.get() - 1);
        self.sim.density(t)
    }
    fn velocity(&self, t: usize) -> Result<Option<Vec<[f32; 3]>>, SequenceError> {
        self.sim.velocity(t)
    }
}

/// Algorithm 1 on disk, killed in the middle of a sweep of the second
/// octave and restarted, ends bit-identical to an uninterrupted in-memory run.
#[test]
fn disk_store_resumes_exactly() {
    use nst3d_sequence::ema::{stylize_sequence_with, StateStore};
    use nst3d_sequence::DiskStore;
    let sim = Drift { base: synthetic_smoke(16, 5), frames: 4 };
    let vgg = Vgg19::random(VggFlavor::Torchvision, 4);
    let loss = ViewLoss::new(&vgg, &stripes(24), &StyleSpec::default()).unwrap();
    let view = ViewSpec { camera: Some(Camera::front(sim.dims())), gamma: 0.2, exposure: 0.2, equalize: false };
    let frame = FrameParams {
        mode: Mode::Velocity,
        octaves: 2,
        iterations: 3,
        learning_rate: 0.3,
        limits: Limits { vmax: 2.0, smin: 0.0, smax: 2.0 },
        view: view.clone(),
    };
    let params = SequenceParams { frame, alpha: 0.7, settle_first_sweep: true, color: false };
    // Two views per frame, the second a turntable step that moves with the frame (a camera path).
    let views = |t: usize| {
        vec![
            view.clone(),
            ViewSpec { camera: Some(Camera::orbit(sim.dims(), 30.0 + 10.0 * t as f32, 10.0)), ..view.clone() },
        ]
    };
    let mut mem = MemoryStore::default();
    stylize_sequence_with(&sim, &loss, &views, &params, &mut mem, &mut |_| {}).unwrap();

    let dir = std::env::temp_dir().join(format!("nst3d-resume-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    // Octave 1: 3 sweeps x 4 frames = 12 reads; octave 2's first sweep 4 more; die 2 frames into its sweep 2.
    let dying = Dying { sim: &sim, budget: std::cell::Cell::new(12 + 4 + 2) };
    let id = nst3d_job::JobId { kind: "volume sequence".into(), hash: 42, settings: String::new() };
    let files = nst3d_job::StateFiles::new(id, "rerun with --force");
    let mut disk = DiskStore::open(&dir, files.clone()).unwrap();
    assert!(stylize_sequence_with(&dying, &loss, &views, &params, &mut disk, &mut |_| {}).is_err());
    drop(disk);
    let mut disk = DiskStore::open(&dir, files).unwrap();
    let mark = disk.resume_point().expect("a checkpoint");
    assert_eq!((mark.octave, mark.sweeps_done), (1, 1), "{mark:?}");
    let mut sweeps = Vec::new();
    stylize_sequence_with(&sim, &loss, &views, &params, &mut disk, &mut |p| sweeps.push((p.octave, p.iteration)))
        .unwrap();
    assert_eq!(sweeps.first(), Some(&(1, 2)), "resumed at octave 2 sweep 2");
    for t in 0..sim.len() {
        let a = mem.load(t).unwrap().unwrap();
        let b = disk.load(t).unwrap().unwrap();
        assert_eq!(a.field.params(), b.field.params(), "frame {t}");
        assert_eq!((a.m, a.v, a.step), (b.m, b.v, b.step), "frame {t}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// [`Drift`] with a break before frame `cut`: as if an empty frame that is
/// passed through unstylized had been taken out there.
struct Broken {
    sim: Drift,
    cut: usize,
}

impl Simulation for Broken {
    fn len(&self) -> usize {
        self.sim.len()
    }
    fn dims(&self) -> [usize; 3] {
        self.sim.dims()
    }
    fn density(&self, t: usize) -> Result<Grid3, SequenceError> {
        self.sim.density(t)
    }
    fn velocity(&self, t: usize) -> Result<Option<Vec<[f32; 3]>>, SequenceError> {
        self.sim.velocity(t)
    }
    fn linked(&self, t: usize) -> bool {
        t != self.cut
    }
}

/// The frames of [`Drift`] from `from` on, as a sequence of their own.
struct Tail {
    sim: Drift,
    from: usize,
}

impl Simulation for Tail {
    fn len(&self) -> usize {
        self.sim.len() - self.from
    }
    fn dims(&self) -> [usize; 3] {
        self.sim.dims()
    }
    fn density(&self, t: usize) -> Result<Grid3, SequenceError> {
        self.sim.density(t + self.from)
    }
    fn velocity(&self, t: usize) -> Result<Option<Vec<[f32; 3]>>, SequenceError> {
        self.sim.velocity(t + self.from)
    }
}

/// A break in the sequence stops the EMA in both sweep directions: the
/// frames after it end exactly as if they had been stylized on their own.
#[test]
fn a_break_splits_the_ema_chain() {
    let vgg = Vgg19::random(VggFlavor::Torchvision, 4);
    let loss = ViewLoss::new(&vgg, &stripes(24), &StyleSpec::default()).unwrap();
    let base = synthetic_smoke(12, 7);
    let view = ViewSpec { camera: Some(Camera::front(base.dims)), gamma: 0.2, exposure: 0.2, equalize: false };
    let frame = FrameParams {
        mode: Mode::Velocity,
        octaves: 1,
        iterations: 3,
        learning_rate: 0.3,
        limits: Limits { vmax: 2.0, smin: 0.0, smax: 2.0 },
        view: view.clone(),
    };
    let params = SequenceParams { frame, alpha: 0.7, settle_first_sweep: false, color: false };
    let run = |sim: &dyn Simulation| {
        let mut store = MemoryStore::default();
        stylize_sequence(sim, &loss, std::slice::from_ref(&view), &params, &mut store, &mut |_| {}).unwrap();
        (0..sim.len()).map(|t| stylized_density(sim, &mut store, t).unwrap()).collect::<Vec<_>>()
    };
    let linked = run(&Drift { base: base.clone(), frames: 4 });
    let broken = run(&Broken { sim: Drift { base: base.clone(), frames: 4 }, cut: 2 });
    let alone = run(&Tail { sim: Drift { base, frames: 4 }, from: 2 });
    for (t, a) in [(2, &alone[0]), (3, &alone[1])] {
        assert_eq!(broken[t].data, a.data, "frame {t} still felt the frames before the break");
    }
    assert_ne!(broken[1].data, linked[1].data, "the break changed nothing");
}
