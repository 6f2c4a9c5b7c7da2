//! `train` end to end on real frames with the real VGG-19: a run killed
//! after its first step and started again ends with the same model file,
//! byte for byte, as an uninterrupted run; bad settings fail in one line.

use std::path::{Path, PathBuf};

use std::time::Instant;

use nst3d_core::{Reporter, Silent};
use nst3d_train::{job::checkpoint_path, train, TrainSettings};

fn shared(rel: &str) -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data").join(rel);
    assert!(p.exists(), "shared test data missing: {} (the repo expects ../shared beside it)", p.display());
    p
}

fn settings(out: &Path) -> TrainSettings {
    TrainSettings {
        frames: (20..=22).map(|f| shared(&format!("volumes/plume48/fluid_data_{f:04}.vdb"))).collect(),
        grid: "density".into(),
        style: shared("styles/starry_night.jpg"),
        style_scale: 0.25,
        weights: None,
        velocity: false,
        channels: 2,
        patch: 16,
        steps: Some(5),
        minutes: None,
        theta_deg: 180.0,
        phi_deg: 90.0,
        view_axes: nst3d_train::ViewAxes::Random,
        absorption: nst3d_train::Absorption::Patch,
        texture: None,
        seed: 3,
        out: out.to_path_buf(),
        checkpoint_every: 2,
        octaves: 2,
        batch: 1,
    }
}

#[test]
fn a_killed_run_resumes_to_the_same_model() {
    let dir = tempfile::tempdir().unwrap();
    let whole = dir.path().join("whole.safetensors");
    let r = train(&settings(&whole), &mut Silent).unwrap();
    assert_eq!((r.steps, r.resumed_at), (5, 0));
    assert!(r.loss_first.is_finite() && r.loss_last.is_finite());
    let log = std::fs::read_to_string(whole.with_extension("csv")).unwrap();
    assert_eq!(log.lines().count(), 6, "{log}");
    let curve = nst3d_train::job::curve_path(&whole);
    assert!(curve.ends_with("whole.loss.png") && curve.exists(), "no loss curve {}", curve.display());

    // A zero-minute budget stops after the first step, as a kill would.
    let parts = dir.path().join("parts.safetensors");
    let mut s = settings(&parts);
    s.minutes = Some(0.0);
    assert_eq!(train(&s, &mut Silent).unwrap().steps, 1);
    assert!(checkpoint_path(&parts).exists());
    s.minutes = None;
    let r = train(&s, &mut Silent).unwrap();
    assert_eq!((r.steps, r.resumed_at), (5, 1));
    assert_eq!(std::fs::read(&whole).unwrap(), std::fs::read(&parts).unwrap(), "resumed model differs");

    // The model file says what it is and loads back.
    let m = nst3d_network::Model::from_bytes(&std::fs::read(&whole).unwrap(), &whole).unwrap();
    assert_eq!(m.info.get("mode").map(String::as_str), Some("density"));
    assert_eq!(m.info.get("steps").map(String::as_str), Some("5"));

    // Other settings refuse the checkpoint instead of mixing runs.
    let mut other = settings(&parts);
    other.seed = 4;
    let e = train(&other, &mut Silent).unwrap_err().to_string();
    assert!(e.contains("different training run"), "{e}");
    let mut bad = settings(&dir.path().join("bad.safetensors"));
    bad.patch = 18;
    assert!(train(&bad, &mut Silent).unwrap_err().to_string().contains("--patch"));
}

/// A run with a solid texture checkpoints it with the network: stopped
/// after its first step and resumed, it ends with the same model file, and
/// the file carries the texture.
#[test]
fn a_textured_run_resumes_to_the_same_model() {
    let dir = tempfile::tempdir().unwrap();
    let textured = |name: &str| {
        let mut s = settings(&dir.path().join(name));
        s.texture = Some(8);
        s
    };
    let whole = textured("whole.safetensors");
    train(&whole, &mut Silent).unwrap();
    let mut parts = textured("parts.safetensors");
    parts.minutes = Some(0.0);
    assert_eq!(train(&parts, &mut Silent).unwrap().steps, 1);
    parts.minutes = None;
    assert_eq!(train(&parts, &mut Silent).unwrap().resumed_at, 1);
    let bytes = std::fs::read(&whole.out).unwrap();
    assert_eq!(bytes, std::fs::read(&parts.out).unwrap(), "resumed textured model differs");
    let m = nst3d_network::Model::from_bytes(&bytes, &whole.out).unwrap();
    assert_eq!(m.texture.map(|t| t.period), Some(8));
}

/// `frame` absorption sees each patch as its whole frame is drawn: the
/// same patches give another model than `patch`'s 8/P, and the file says
/// which rule trained it (a `patch` model keeps the earlier metadata).
#[test]
fn frame_absorption_trains_another_model_and_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let patch = settings(&dir.path().join("patch.safetensors"));
    let mut frame = settings(&dir.path().join("frame.safetensors"));
    frame.absorption = nst3d_train::Absorption::Frame;
    let first = |s: &TrainSettings| train(s, &mut Silent).unwrap().loss_first;
    assert_ne!(first(&patch), first(&frame), "the first step's loss should see another absorption");
    let model = |s: &TrainSettings| nst3d_network::Model::from_bytes(&std::fs::read(&s.out).unwrap(), &s.out).unwrap();
    assert_ne!(model(&patch).net, model(&frame).net);
    assert_eq!(model(&frame).info.get("absorption").map(String::as_str), Some("frame"));
    assert_eq!(model(&patch).info.get("absorption"), None);
}

/// A checkpoint an older nst3d wrote (its model, then a second
/// safetensors part, behind a length) is refused in one line that says how
/// to start over, and so is a cut one; deleting it starts afresh.
#[test]
fn an_older_or_cut_checkpoint_is_refused_in_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("old.safetensors");
    let model =
        nst3d_network::Model { net: nst3d_network::FeedForward::new(2, 1, 3), texture: None, info: Default::default() };
    let model = model.to_bytes();
    let mut old = (model.len() as u64).to_le_bytes().to_vec();
    old.extend(&model);
    old.extend(nst3d_weights::safetensors_bytes(&[("adam.m", &[1], &[0.0])], &Default::default()));
    std::fs::write(checkpoint_path(&out), &old).unwrap();
    let mut s = settings(&out);
    s.steps = Some(2);
    let e = train(&s, &mut Silent).unwrap_err().to_string();
    assert!(
        e.contains("old.safetensors.ckpt") && e.contains("older nst3d") && e.ends_with("delete it to start over"),
        "{e}"
    );
    assert_eq!(e.lines().count(), 1, "{e}");

    std::fs::remove_file(checkpoint_path(&out)).unwrap();
    assert_eq!(train(&s, &mut Silent).unwrap().steps, 2);
    let ckpt = std::fs::read(checkpoint_path(&out)).unwrap();
    std::fs::write(checkpoint_path(&out), &ckpt[..ckpt.len() - 100]).unwrap();
    let e = train(&s, &mut Silent).unwrap_err().to_string();
    assert!(e.contains("truncated or corrupt") && e.ends_with("delete it to start over"), "{e}");
}

/// Given only `minutes`, the schedule is sized from the measured step time
/// and the run ends with it, near the budget.
#[test]
fn a_minutes_budget_sizes_the_schedule() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("sized.safetensors");
    let mut s = settings(&out);
    s.steps = None;
    s.minutes = Some(0.1);
    s.checkpoint_every = 1000;
    let t0 = std::time::Instant::now();
    // fp32: the emulated bf16 pass of CI takes most of a 6 s budget for the
    // 8 timed steps alone; what is tested here is the clock, not the arithmetic.
    let r = nst3d_core::precision::fp32(|| train(&s, &mut Silent)).unwrap();
    let secs = t0.elapsed().as_secs_f64();
    assert!(r.sized && r.planned_steps > 8 && r.steps >= 9, "{r:?}");
    // Paced by the clock, the schedule ends with the budget.
    assert!(r.schedule_done, "{r:?}");
    // 6 s of budget, set-up (weights, painting) not counted: within a second.
    assert!(secs > 4.5 && secs < 14.0, "ran {secs:.1} s for a 6 s budget");
    let m = nst3d_network::Model::from_bytes(&std::fs::read(&out).unwrap(), &out).unwrap();
    assert_eq!(m.info.get("steps").map(String::as_str), Some(r.steps.to_string().as_str()));
}

/// Times a run's training loop, from the progress bar's first `begin`
/// (after the set-up: weights, painting, frames) to its return, and asks
/// it to stop (as Ctrl-C does) once `stop_after_s` of that have passed.
struct LoopClock {
    began: Option<Instant>,
    stop_after_s: f64,
    said: Vec<String>,
}

impl Reporter for LoopClock {
    fn begin(&mut self, _: u64) {
        self.began.get_or_insert_with(Instant::now);
    }
    fn step(&mut self, _: &str) {
        if self.began.is_some_and(|t| t.elapsed().as_secs_f64() > self.stop_after_s) {
            nst3d_core::stop::request();
        }
    }
    fn status(&mut self, line: &str) {
        self.said.push(line.to_string());
    }
}

/// A `--minutes` budget is the run's, not the call's: a paced run stopped
/// part way and started again with the same budget goes on being paced by
/// what is left of it and ends with it. (A stop request is this thread's.)
#[test]
fn a_stopped_paced_run_ends_with_its_budget() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("paced.safetensors");
    let mut s = settings(&out);
    (s.steps, s.minutes, s.checkpoint_every) = (None, Some(0.2), 1000);
    // fp32: the clock is tested here, not the arithmetic (see train.rs).
    // Stopped after 7 of its 12 s of training (the 8 timed steps that size
    // the schedule take well under a second).
    let mut first = LoopClock { began: None, stop_after_s: 7.0, said: Vec::new() };
    let r = nst3d_core::precision::fp32(|| train(&s, &mut first));
    assert!(r.is_err(), "the first call should have been stopped: {r:?}");
    nst3d_core::stop::clear();
    let mut second = LoopClock { began: None, stop_after_s: f64::INFINITY, said: Vec::new() };
    let r = nst3d_core::precision::fp32(|| train(&s, &mut second)).unwrap();
    let secs = second.began.expect("the resumed run trained").elapsed().as_secs_f64();
    assert!(r.resumed_at > 8 && r.schedule_done && r.sized, "{r:?}");
    // About 5 of the 12 s were left; a fresh budget would have taken 12 s.
    assert!(secs > 2.0 && secs < 9.5, "the resumed call trained {secs:.1} s with about 5 s of its 12 s budget left");
    // Its steps and its schedule's position differ, and it says both.
    let said = second.said.iter().find(|l| l.starts_with("resuming")).expect("the resumed run said so");
    assert!(said.contains("resuming after ") && said.contains(" steps, the schedule at "), "{said}");
}
