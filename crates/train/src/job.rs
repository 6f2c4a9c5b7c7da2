//! `nst3d train`: one network for one painting, trained on the frames of
//! one or more simulations (Sec. 5.1), with a step budget and a wall-clock
//! budget, a loss log, and a checkpoint after every `checkpoint_every`
//! steps so a killed run resumes where it stopped. The checkpoint holds the
//! weights, Adam's moments, the step and the random generator's state, so a
//! resumed run continues exactly as an uninterrupted one on the same thread
//! count would have.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use nst3d_core::{math::SplitMix64, Grid3, Reporter};
use nst3d_features::Vgg19;
use nst3d_job::{expand_pattern, FrameSpec, JobId, Resume, StateFiles};
use nst3d_network::model::{TEXTURE, TEXTURE_PERIOD};
use nst3d_network::{FeedForward, Model, SolidTexture};
use nst3d_optim::OneCycle;
use nst3d_stylize::{StyleSpec, ViewLoss, ViewSpec};

use crate::absorption::Absorption;
use crate::axes::ViewAxes;
use crate::distributed::{self, Batch, Solo, Team};
use crate::step::{Stylization, TrainStep};

/// Everything `nst3d train` can be asked.
#[derive(Clone, Debug)]
pub struct TrainSettings {
    /// Density frames to cut patches from (already expanded from patterns).
    pub frames: Vec<PathBuf>,
    /// Name of the float grid in each frame.
    pub grid: String,
    /// The painting.
    pub style: PathBuf,
    /// Style image scale factor.
    pub style_scale: f32,
    /// VGG-19 weights (`None`: `$NST3D_VGG19`, else the user cache).
    pub weights: Option<PathBuf>,
    /// Density scale or velocity output.
    pub velocity: bool,
    /// Network width `C`.
    pub channels: usize,
    /// Patch side (a multiple of 4).
    pub patch: usize,
    /// Octaves of the loss (the paper's 2; see [`crate::step::octave_loss`]).
    pub octaves: usize,
    /// Steps of the OneCycle schedule (the run stops there). `None`:
    /// [`DEFAULT_STEPS`], or, when `minutes` is given, as many as the measured
    /// step time fits in the budget ([`sized_steps`]).
    pub steps: Option<u64>,
    /// Wall-clock budget in minutes (the run stops after the step that crosses it).
    pub minutes: Option<f64>,
    /// Rotation range about x, degrees (±).
    pub theta_deg: f32,
    /// Rotation range about y, degrees (±).
    pub phi_deg: f32,
    /// The patch axes each step renders along ([`crate::axes`]).
    pub view_axes: ViewAxes,
    /// The absorption each patch is rendered with ([`crate::absorption`]).
    pub absorption: Absorption,
    /// Period of a solid texture learned beside the network
    /// ([`nst3d_network::SolidTexture`]); `None`: the paper's network alone.
    pub texture: Option<usize>,
    /// Seed of the patch sampling and the initial weights.
    pub seed: u64,
    /// The model file written at the end (and with every checkpoint).
    pub out: PathBuf,
    /// Steps between checkpoints.
    pub checkpoint_every: u64,
    /// Patches a step, over all ranks of a distributed run: the step takes
    /// the mean of their gradients ([`crate::distributed`]).
    pub batch: usize,
}

impl TrainSettings {
    /// The command line's defaults (`nst3d train`) for training on `frames`
    /// with `style` into `out`.
    pub fn new(frames: Vec<PathBuf>, style: impl Into<PathBuf>, out: impl Into<PathBuf>) -> Self {
        Self {
            frames,
            grid: "density".into(),
            style: style.into(),
            style_scale: 0.5,
            weights: None,
            velocity: false,
            channels: 16,
            patch: 32,
            octaves: 2,
            steps: None,
            minutes: None,
            theta_deg: 180.0,
            phi_deg: 90.0,
            view_axes: ViewAxes::Random,
            absorption: Absorption::Patch,
            texture: None,
            seed: 0,
            out: out.into(),
            checkpoint_every: 50,
            batch: 1,
        }
    }
}

/// The frame files of `nst3d train --input ... [--frames ...]` (and of the
/// Python `train`): each input is a file, or, with a frame list (one per
/// input, in order, as `--frames`), a `####` / `%04d` pattern expanded by the
/// sequence crate's parser.
pub fn training_frames(inputs: &[String], frame_lists: &[String]) -> Result<Vec<PathBuf>> {
    if !frame_lists.is_empty() && frame_lists.len() != inputs.len() {
        bail!("give one --frames per --input ({} inputs, {} frame lists)", inputs.len(), frame_lists.len());
    }
    if inputs.is_empty() {
        bail!("no training frames given");
    }
    let mut frames = Vec::new();
    for (i, input) in inputs.iter().enumerate() {
        match frame_lists.get(i) {
            Some(spec) => {
                for &f in FrameSpec::parse(spec)?.frames() {
                    frames.push(PathBuf::from(expand_pattern(input, f)?));
                }
            }
            None => frames.push(PathBuf::from(input)),
        }
    }
    Ok(frames)
}

/// The schedule's length when neither `steps` nor `minutes` is given.
pub const DEFAULT_STEPS: u64 = 2000;

/// Steps timed before a `--minutes` run sizes its schedule.
const CALIBRATION_STEPS: u64 = 8;

/// How many steps fit in `budget_s` seconds when `done` steps took
/// `elapsed_s`: the rest of the budget at the measured rate, 2 % kept back
/// for the checkpoints and the final write. Never fewer than `done + 1`.
pub fn sized_steps(done: u64, elapsed_s: f64, budget_s: f64) -> u64 {
    let per_step = elapsed_s / done.max(1) as f64;
    let more = ((budget_s - elapsed_s).max(0.0) * 0.98 / per_step.max(1e-9)).floor() as u64;
    done + more.max(1)
}

/// What a training run did.
#[derive(Clone, Debug)]
pub struct TrainReport {
    /// Steps done in total (including those of earlier, resumed runs).
    pub steps: u64,
    /// Step this run started at (0 unless resumed).
    pub resumed_at: u64,
    /// Length of the OneCycle schedule (given, default or sized to the budget).
    pub planned_steps: u64,
    /// Whether the schedule was sized from the measured step time and paced
    /// by the clock (in this call or, for a resumed run, the first).
    pub sized: bool,
    /// Whether the schedule ran to its end (not stopped by a budget or a signal).
    pub schedule_done: bool,
    /// Mean loss of the first and of the last 10 % of the steps.
    pub loss_first: f32,
    /// See `loss_first`.
    pub loss_last: f32,
    /// The model file.
    pub out: PathBuf,
}

/// The checkpoint beside the model: `<out>.ckpt`.
pub fn checkpoint_path(out: &Path) -> PathBuf {
    let mut p = out.as_os_str().to_owned();
    p.push(".ckpt");
    PathBuf::from(p)
}

/// The loss log beside the model: `<out>.csv` (step, loss, learning rate).
pub fn log_path(out: &Path) -> PathBuf {
    out.with_extension("csv")
}

/// The loss curve beside the model: `<out>.loss.png` (see [`crate::curve`]).
pub fn curve_path(out: &Path) -> PathBuf {
    out.with_extension("loss.png")
}

fn load_frames(s: &TrainSettings) -> Result<Vec<Grid3>> {
    let mut out = Vec::new();
    for path in &s.frames {
        let file = nst3d_io::vdb::read_vdb(path)?;
        let grid = file.grid(&s.grid).with_context(|| format!("{}: no grid named '{}'", path.display(), s.grid))?;
        if grid.active_voxel_count() == 0 {
            continue;
        }
        let (_, mut d) = grid.to_dense()?;
        // Densities normalised to [0, 1] going in (Sec. 5.1).
        let max = d.max();
        if max > 0.0 {
            d.data.iter_mut().for_each(|v| *v = (*v / max).clamp(0.0, 1.0));
        }
        // Frames smaller than a patch are padded with empty space.
        let dims = d.dims.map(|n| n.max(s.patch));
        if dims != d.dims {
            let mut p = Grid3::zeros(dims);
            for z in 0..d.dims[2] {
                for y in 0..d.dims[1] {
                    let (a, b) = (d.index(0, y, z), p.index(0, y, z));
                    p.data[b..b + d.dims[0]].copy_from_slice(&d.data[a..a + d.dims[0]]);
                }
            }
            d = p;
        }
        out.push(d);
    }
    if out.is_empty() {
        bail!("none of the {} training frames has smoke in grid '{}'", s.frames.len(), s.grid);
    }
    Ok(out)
}

/// What a training checkpoint says it is.
pub const STATE_KIND: &str = "training run";

/// What must match for a checkpoint to be resumed: every setting but the
/// budget, the output path and the checkpoint interval, the thread count
/// (a resumed run repeats an uninterrupted one bit for bit only on the
/// same count), the painting's contents and each frame's size and
/// modification time.
fn job_id(s: &TrainSettings) -> Result<JobId> {
    let mut a = s.clone();
    (a.minutes, a.out, a.checkpoint_every) = (None, PathBuf::new(), 0);
    let settings = nst3d_job::settings_key(&a, true);
    Ok(JobId::new(STATE_KIND, settings, std::slice::from_ref(&s.style), &s.frames)?)
}

struct Checkpoint {
    net: FeedForward,
    texture: Option<SolidTexture>,
    m: Vec<f32>,
    v: Vec<f32>,
    step: u64,
    planned_steps: u64,
    position: f64,
    rng: u64,
    losses: Vec<f32>,
    lrs: Vec<f32>,
    clock: Clock,
}

/// Where a run's clock stands, saved with each checkpoint: the budget
/// counts the run's training time over every call, so a paced run that is
/// killed and rerun with the same `--minutes` still ends with its budget.
#[derive(Clone, Copy, Debug)]
struct Clock {
    /// Seconds of training so far, earlier calls included.
    elapsed_s: f64,
    /// Whether the schedule is paced by the budget.
    paced: bool,
}

/// The checkpoint: a state file ([`nst3d_job::State`]) holding the
/// network (its tensors and metadata under `model.`), Adam's moments, the
/// losses and learning rates so far, and the step, schedule, random
/// generator and clock as metadata.
fn save_checkpoint(
    path: &Path,
    files: &StateFiles,
    t: &TrainStep,
    rng: &SplitMix64,
    (losses, lrs): (&[f32], &[f32]),
    clock: Clock,
) -> Result<()> {
    let (m, v, adam_step) = t.adam_state();
    let model = Model { net: t.net.clone(), texture: t.texture().cloned(), info: BTreeMap::new() };
    let mut st = files.fresh();
    for (name, shape, data) in model.tensors() {
        st.put_f32(&format!("model.{name}"), &shape, data);
    }
    for (key, value) in model.metadata() {
        st.set(&format!("model.{key}"), value);
    }
    st.put_f32("adam.m", &[m.len()], m);
    st.put_f32("adam.v", &[v.len()], v);
    st.put_f32("losses", &[losses.len()], losses);
    st.put_f32("lrs", &[lrs.len()], lrs);
    st.set("step", t.steps());
    st.set("planned_steps", t.schedule.total_steps);
    st.set("position", t.position());
    st.set("adam_step", adam_step);
    st.set("rng", rng.state());
    st.set("elapsed_s", clock.elapsed_s);
    st.set("paced", clock.paced);
    Ok(files.save(path, &st)?)
}

fn load_checkpoint(path: &Path, files: &StateFiles) -> Result<Option<Checkpoint>> {
    let Some(mut st) = files.load(path)? else {
        return Ok(None);
    };
    let mut tensors = nst3d_weights::TensorMap::new();
    for name in nst3d_network::model::LAYER_NAMES.iter().flat_map(|n| [format!("{n}.weight"), format!("{n}.bias")]) {
        let (shape, data) = st.take_f32s(&format!("model.{name}")).map_err(|p| files.unusable(path, p))?;
        tensors.insert(name, nst3d_weights::TensorData { shape, data });
    }
    if st.metadata().contains_key(&format!("model.{TEXTURE_PERIOD}")) {
        let (shape, data) = st.take_f32s(&format!("model.{TEXTURE}")).map_err(|p| files.unusable(path, p))?;
        tensors.insert(TEXTURE.to_string(), nst3d_weights::TensorData { shape, data });
    }
    let info = st.metadata().iter().filter_map(|(k, v)| Some((k.strip_prefix("model.")?.to_string(), v.clone())));
    let model = Model::from_parts(&tensors, info.collect(), path)?;
    let checkpoint = |st: &mut nst3d_job::State<'_>| -> Result<Checkpoint, nst3d_job::state::Problem> {
        Ok(Checkpoint {
            net: model.net,
            texture: model.texture,
            m: st.take_f32s("adam.m")?.1,
            v: st.take_f32s("adam.v")?.1,
            step: st.get("step")?,
            planned_steps: st.get("planned_steps")?,
            position: st.get("position")?,
            rng: st.get("rng")?,
            losses: st.take_f32s("losses")?.1,
            lrs: st.take_f32s("lrs")?.1,
            clock: Clock { elapsed_s: st.get("elapsed_s")?, paced: st.get("paced")? },
        })
    };
    Ok(Some(checkpoint(&mut st).map_err(|p| files.unusable(path, p))?))
}

/// Writes the model file and the loss log.
fn write_outputs(
    s: &TrainSettings,
    t: &TrainStep,
    (losses, lrs): (&[f32], &[f32]),
    style_sha: &str,
    style_size: [usize; 2],
) -> Result<()> {
    let mut info = BTreeMap::new();
    info.insert("mode".to_string(), if s.velocity { "velocity" } else { "density" }.to_string());
    if let Stylization::Velocity { vmax } = t.stylization {
        info.insert("vmax_fraction".to_string(), (vmax / s.patch as f32).to_string());
    }
    info.insert("style_sha256".to_string(), style_sha.to_string());
    info.insert("style_size".to_string(), format!("{}x{}", style_size[0], style_size[1]));
    info.insert("style_scale".to_string(), s.style_scale.to_string());
    info.insert("theta_deg".to_string(), s.theta_deg.to_string());
    info.insert("phi_deg".to_string(), s.phi_deg.to_string());
    info.insert("patch".to_string(), s.patch.to_string());
    info.insert("octaves".to_string(), s.octaves.to_string());
    info.insert("view_axes".to_string(), s.view_axes.name().to_string());
    // Only where it is not the rule every earlier model was trained with.
    if s.absorption != Absorption::Patch {
        info.insert("absorption".to_string(), s.absorption.name().to_string());
    }
    info.insert("mass".to_string(), if s.velocity { "conserved" } else { crate::step::MASS_PINNED }.to_string());
    info.insert("steps".to_string(), t.steps().to_string());
    // Only where it is not the one patch every model was trained with, so
    // an unbatched model keeps its bytes.
    if s.batch != 1 {
        info.insert("batch".to_string(), s.batch.to_string());
    }
    info.insert("nst3d_version".to_string(), env!("CARGO_PKG_VERSION").to_string());
    let bytes = Model { net: t.net.clone(), texture: t.texture().cloned(), info }.to_bytes();
    nst3d_io::atomic::write_atomic(&s.out, |w| w.write_all(&bytes))
        .with_context(|| format!("cannot write the model {}", s.out.display()))?;
    let log = log_path(&s.out);
    nst3d_io::atomic::write_atomic(&log, |w| {
        writeln!(w, "step,loss,lr")?;
        for (i, (l, lr)) in losses.iter().zip(lrs).enumerate() {
            writeln!(w, "{},{l},{lr}", i + 1)?;
        }
        Ok(())
    })
    .with_context(|| format!("cannot write the loss log {}", log.display()))?;
    let curve = curve_path(&s.out);
    nst3d_io::image::write_png(&curve, &crate::curve::loss_curve(losses))
        .with_context(|| format!("cannot write the loss curve {}", curve.display()))
}

/// The settings' limits, checked before anything is loaded.
fn check_settings(s: &TrainSettings) -> Result<()> {
    if !s.patch.is_multiple_of(4) || !(16..=256).contains(&s.patch) {
        bail!("--patch must be a multiple of 4 from 16 to 256, got {}", s.patch);
    }
    if !(1..=128).contains(&s.channels) || s.steps == Some(0) || s.checkpoint_every == 0 {
        bail!("--channels must be 1..=128 and --steps and --checkpoint-every at least 1");
    }
    if s.minutes.is_some_and(|m| !(m >= 0.0 && m.is_finite())) {
        bail!("--minutes must be a number of minutes, 0 or more");
    }
    if s.texture.is_some_and(|p| !(2..=256).contains(&p)) {
        bail!("--texture must be a period from 2 to 256 voxels");
    }
    if !(1..=3).contains(&s.octaves) || s.patch >> (s.octaves - 1) < 8 {
        bail!(
            "--octaves must be 1 to 3, with the patch at least 8 voxels at the coarsest ({} at {})",
            s.patch,
            s.octaves
        );
    }
    Ok(())
}

/// What a resumed run takes from its checkpoint besides the trainer's state.
struct Resumed {
    rng: SplitMix64,
    losses: Vec<f32>,
    lrs: Vec<f32>,
    /// Whether the schedule goes on being paced by the clock.
    paced: bool,
    /// Training time of earlier calls.
    elapsed_before: f64,
}

/// Resume: the checkpoint's network, Adam moments, schedule and position
/// set in `trainer`, and the rest of its state; `None` without one.
fn resume(
    trainer: &mut TrainStep,
    (ckpt, files): (&Path, &StateFiles),
    s: &TrainSettings,
    reporter: &mut dyn Reporter,
) -> Result<Option<Resumed>> {
    let Some(c) = load_checkpoint(ckpt, files)? else {
        return Ok(None);
    };
    trainer.net = c.net;
    if let Some(t) = c.texture {
        trainer.set_texture(t);
    }
    trainer.set_adam_state(&c.m, &c.v, c.step)?;
    trainer.set_position(c.position);
    // A resumed run keeps the schedule it was planned with, and a
    // paced one goes on being paced by what is left of its budget.
    trainer.schedule = OneCycle::new(1e-4, c.planned_steps, 20.0);
    let paced = c.clock.paced && s.minutes.is_some();
    let elapsed_before = c.clock.elapsed_s;
    let left = match s.minutes {
        Some(m) if elapsed_before > 0.0 => {
            format!(", {:.1} of its {m} minutes left", (m - elapsed_before / 60.0).max(0.0))
        }
        _ => String::new(),
    };
    // A paced run's steps and its schedule's position part ways (the
    // clock moves the schedule), so it says both.
    let at = if paced {
        format!("after {} steps, the schedule at {:.0} of {}", c.step, c.position, c.planned_steps)
    } else {
        format!("at step {} of {}", c.step + 1, c.planned_steps)
    };
    reporter.status(&format!("resuming {at} from {}{left}", ckpt.display()));
    Ok(Some(Resumed { rng: SplitMix64::new(c.rng), losses: c.losses, lrs: c.lrs, paced, elapsed_before }))
}

/// How the schedule follows the clock.
struct Pacing {
    /// Given only a budget, until the calibration steps are timed.
    sizing: bool,
    /// The schedule is paced by the clock (after sizing, or resumed so).
    paced: bool,
    /// Seconds a step at the recent rate.
    step_s: f64,
}

impl Pacing {
    /// Given only a budget: after the calibration steps the schedule is
    /// sized to the steps the measured rate fits in it; from then on the
    /// schedule is paced by the clock (each step advances it by what is
    /// left of it over the steps the recent rate still fits), so it ends
    /// with the budget however busy the machine gets. `done`: steps of this
    /// call, `elapsed`: its seconds, `dt`: the last step's.
    fn after_step(
        &mut self,
        trainer: &mut TrainStep,
        s: &TrainSettings,
        (done, elapsed, dt): (u64, f64, f64),
        elapsed_before: f64,
        reporter: &mut dyn Reporter,
    ) {
        let budget_s = 60.0 * s.minutes.unwrap_or_default();
        if self.sizing {
            if done == CALIBRATION_STEPS {
                let total = sized_steps(trainer.steps(), elapsed, budget_s);
                trainer.schedule = OneCycle::new(1e-4, total, 20.0);
                reporter.status(&format!(
                    "{:.0} ms a step over the first {done}: the OneCycle schedule is sized to {total} steps \
                     for {} min and paced by the clock",
                    1e3 * elapsed / done as f64,
                    s.minutes.unwrap_or_default()
                ));
                reporter.end();
                reporter.begin(total.saturating_sub(trainer.position().floor() as u64));
                self.step_s = elapsed / done as f64;
                (self.sizing, self.paced) = (false, true);
            }
        } else if self.paced {
            // The recent rate: a machine that got busier is seen within ~20
            // steps (a resumed run starts from its first step's time).
            self.step_s = if self.step_s == 0.0 { dt } else { 0.9 * self.step_s + 0.1 * dt };
            // 2 % kept back for the checkpoints and the final write, as in sizing.
            let steps_left = ((0.98 * budget_s - elapsed_before - elapsed) / self.step_s.max(1e-9)).max(1.0);
            let left = trainer.schedule.total_steps as f64 - trainer.position();
            trainer.pace = (left / steps_left).clamp(0.0, 8.0);
        }
    }
}

/// What every rank reads before training: the frames, the painting and
/// the VGG-19 weights.
struct Inputs {
    frames: Vec<Grid3>,
    style_img: nst3d_core::Image,
    style_sha: String,
    vgg: Vgg19,
}

fn load_inputs(s: &TrainSettings, team: &dyn Team) -> Result<Inputs> {
    let inputs: Vec<&Path> = s.frames.iter().map(PathBuf::as_path).collect();
    nst3d_io::atomic::check_output("--out", &s.out, &[], &inputs).map_err(anyhow::Error::msg)?;
    check_settings(s)?;
    distributed::check_batch(team, s.batch)?;
    let frames = load_frames(s)?;
    let style_img = nst3d_io::image::luminance_rgb(&nst3d_io::image::load_style(&s.style, s.style_scale)?);
    let style_sha = nst3d_weights::sha256_file(&s.style)?;
    Ok(Inputs { frames, style_img, style_sha, vgg: Vgg19::load(s.weights.as_deref())? })
}

/// Trains (or resumes training) the network `s` describes, in this process.
pub fn train(s: &TrainSettings, reporter: &mut dyn Reporter) -> Result<TrainReport> {
    train_on(&Solo, s, reporter)
}

/// What each step draws ([`distributed::batch_step`]).
fn batch_of(s: &TrainSettings) -> Batch {
    Batch {
        size: s.batch,
        patch: s.patch,
        theta_deg: s.theta_deg,
        phi_deg: s.phi_deg,
        view_axes: s.view_axes,
        texture_period: s.texture,
    }
}

/// A fresh network and its optimiser on the provisional schedule.
fn new_trainer(s: &TrainSettings) -> TrainStep {
    let stylization =
        if s.velocity { Stylization::Velocity { vmax: 0.04 * s.patch as f32 } } else { Stylization::Density };
    let net = FeedForward::new(s.channels, stylization.channels(), s.seed);
    let planned = s.steps.unwrap_or(DEFAULT_STEPS);
    let mut trainer = TrainStep::new(net, stylization, OneCycle::new(1e-4, planned, 20.0));
    if let Some(p) = s.texture {
        trainer = trainer.with_texture(SolidTexture::new(p, s.seed));
    }
    trainer.octaves = s.octaves;
    trainer
}

/// Rank 0 takes the job's lock (two blades training one model would
/// interleave their checkpoints; rank 0 alone writes them) and resumes the
/// checkpoint it finds; the other ranks hold neither.
fn begin_job(
    team: &dyn Team,
    s: &TrainSettings,
    ckpt: &Path,
    trainer: &mut TrainStep,
    reporter: &mut dyn Reporter,
) -> Result<(Option<Resume>, Option<Resumed>)> {
    let job = distributed::on_rank0(team, || {
        Resume::begin(ckpt, StateFiles::new(job_id(s)?, "delete it to start over")).map_err(anyhow::Error::msg)
    })?;
    let resumed = distributed::on_rank0(team, || match &job {
        Some(job) => resume(trainer, (ckpt, job.files()), s, reporter),
        None => Ok(None),
    })?;
    Ok((job, resumed.flatten()))
}

/// [`train`] as one rank of `team` (every rank calls it with the same
/// settings; rank 0 reports and writes, see [`crate::distributed`]).
pub fn train_on(team: &dyn Team, s: &TrainSettings, reporter: &mut dyn Reporter) -> Result<TrainReport> {
    let Inputs { frames, style_img, style_sha, vgg } = distributed::agree(team, load_inputs(s, team))?;
    let loss = distributed::agree(team, ViewLoss::new(&vgg, &style_img, &StyleSpec::default()).map_err(Into::into))?;
    // Given only a budget, the schedule is sized after the first steps are
    // timed; until then it is provisionally the default one (the first steps
    // of any OneCycle sit at its initial rate, so the switch is seamless).
    let mut pacing = Pacing { sizing: s.steps.is_none() && s.minutes.is_some(), paced: false, step_s: 0.0 };
    let mut trainer = new_trainer(s);
    let mut rng = SplitMix64::new(s.seed ^ 0x7261_696e);
    let (mut losses, mut lrs) = (Vec::new(), Vec::new());
    let ckpt = checkpoint_path(&s.out);
    let (job, resumed) = begin_job(team, s, &ckpt, &mut trainer, reporter)?;
    // Training time of earlier calls; the budget is the run's, not the call's.
    let mut elapsed_before = 0.0f64;
    if let Some(r) = resumed {
        (rng, losses, lrs, elapsed_before) = (r.rng, r.losses, r.lrs, r.elapsed_before);
        (pacing.sizing, pacing.paced) = (false, r.paced);
    }
    distributed::share_start(team, &mut trainer, &mut rng)?;
    let batch = batch_of(s);
    let resumed_at = trainer.steps();
    // γ by the settings' rule (crate::absorption). Exposure γ, as every
    // picture the optimisation, the previews and the judges draw:
    // grey = γ Σ d τ ≈ the ray's opacity, in [0, 1) like the painting.
    // (Exposure 1, the benchmark's, drew dense smoke up to 1/γ = P/8 times
    // too bright for VGG — 4 at the default patch — and the network learned
    // its look on pictures nobody sees.)
    let views: Vec<ViewSpec> = s
        .absorption
        .gammas(&frames, s.patch)
        .into_iter()
        .map(|gamma| ViewSpec { camera: None, gamma, exposure: gamma, equalize: false })
        .collect();
    let t0 = Instant::now();
    let mut last_step = Instant::now();
    reporter.begin(trainer.schedule.total_steps.saturating_sub(trainer.position().floor() as u64));
    while !trainer.schedule_done() {
        let before = trainer.position().floor() as u64;
        let l = distributed::batch_step(team, &mut trainer, &mut rng, &frames, &batch, (&loss, &views))?;
        // The bar counts the schedule's steps: a paced run takes more or
        // fewer training steps than its schedule has, as the clock says.
        for _ in before..trainer.position().floor() as u64 {
            reporter.step(&format!(
                "step {}/{} loss {l:.4e} k {:.3}",
                trainer.position().floor() as u64,
                trainer.schedule.total_steps,
                trainer.last_mass_ratio()
            ));
        }
        if !l.is_finite() {
            let e = anyhow::anyhow!("the loss became {l} at step {} (try a smaller learning rate)", trainer.steps());
            return Err(distributed::everywhere(team, e));
        }
        losses.push(l);
        lrs.push(trainer.last_lr());
        let now = Instant::now();
        let dt = (now - last_step).as_secs_f64();
        last_step = now;
        let done = trainer.steps() - resumed_at;
        if team.rank() == 0 {
            pacing.after_step(&mut trainer, s, (done, t0.elapsed().as_secs_f64(), dt), elapsed_before, reporter);
        }
        let clock = Clock { elapsed_s: elapsed_before + t0.elapsed().as_secs_f64(), paced: pacing.paced };
        let mut out_of_time = s.minutes.is_some_and(|m| clock.elapsed_s >= 60.0 * m);
        // Rank 0's pacing and clock hold for every rank; a stop asked of
        // any rank stops all. A stopped run checkpoints first, so rerunning
        // it resumes at this step.
        let stop = distributed::follow_rank0(team, &mut trainer, &mut out_of_time);
        let last = trainer.schedule_done();
        if trainer.steps().is_multiple_of(s.checkpoint_every) || last || out_of_time || stop {
            distributed::on_rank0(team, || {
                if let Some(job) = &job {
                    save_checkpoint(&ckpt, job.files(), &trainer, &rng, (&losses, &lrs), clock)?;
                }
                write_outputs(s, &trainer, (&losses, &lrs), &style_sha, [style_img.width, style_img.height])
            })?;
        }
        // The stop the ranks agreed on: a signal arriving after it is taken
        // at the next step by every rank alike.
        if stop {
            return Err(nst3d_core::stop::Interrupted.into());
        }
        if out_of_time {
            break;
        }
    }
    reporter.end();
    let tenth = (losses.len() / 10).max(1);
    let mean = |v: &[f32]| v.iter().sum::<f32>() / v.len().max(1) as f32;
    Ok(TrainReport {
        steps: trainer.steps(),
        resumed_at,
        planned_steps: trainer.schedule.total_steps,
        schedule_done: trainer.schedule_done(),
        sized: pacing.paced,
        loss_first: mean(&losses[..tenth.min(losses.len())]),
        loss_last: mean(&losses[losses.len().saturating_sub(tenth)..]),
        out: s.out.clone(),
    })
}

#[cfg(test)]
mod tests {
    use super::sized_steps;

    #[test]
    fn sized_steps_fill_the_rest_of_the_budget() {
        // 8 steps in 4 s (0.5 s each), 60 s budget: 56 s left, 98 % of it = 109 more.
        assert_eq!(sized_steps(8, 4.0, 60.0), 8 + 109);
        // Over budget already: one more step, never zero.
        assert_eq!(sized_steps(8, 70.0, 60.0), 9);
        // An hour at 0.8 s a step.
        assert_eq!(sized_steps(8, 6.4, 3600.0), 8 + ((3600.0 - 6.4) * 0.98 / 0.8f64).floor() as u64);
    }
}
