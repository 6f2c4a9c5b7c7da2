//! A whole simulation stylized with the EMA temporal coherence of
//! Algorithm 1 ([`nst3d_sequence::ema`]), as one job or as one farm chunk.
//!
//! All frames are densified into one common box (the union of their active
//! boxes plus the velocity margin) so fields can be carried from frame to
//! frame. Frames are read from disk when needed and every frame's field and
//! Adam moments live in a work folder ([`DiskStore`]), always, whatever the
//! sequence length: memory holds a few frames, and a killed run resumes from
//! its last completed sweep. Farm chunks optimise their frames plus a
//! warm-up overlap but derive the box, velocity scale and absorption from
//! the whole frame range, so every chunk solves the same problem.
//!
//! Frames whose grid is empty (a simulation's first frames often are) are
//! copied to the output unchanged and cut the EMA chain; frames without a
//! velocity grid are carried to their neighbour unmoved (identity advection),
//! so the EMA still couples them, only without following the flow.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use nst3d_core::{Grid3, Reporter};
use nst3d_io::vdb::{read_vdb, GridValues, Transform};
use nst3d_job::{default_work_dir, expand_pattern, settings_key, FrameSpec, JobId, Resume, StateFiles};
use nst3d_render::Camera;
use nst3d_sequence::ema::{stylize_sequence_with, Paintings, SequenceParams, Simulation, StateStore};
use nst3d_sequence::DiskStore;
use nst3d_stylize::{color_view_image, view_image, MapLoss, Mode, ViewLoss, ViewSpec};

use crate::cameras::Cameras;
use crate::look::{absorption_for, smallest_absorption, views_of};
use crate::output::write_stylized;
use crate::sequence_map::{FrameMaps, ShotBox};
use crate::settings::{SequenceSettings, VolumeSettings};
use crate::simulation::{VdbSimulation, VELOCITY_NAMES};
use crate::style::{load_paintings, load_style_and_vgg};
use crate::upsample::{refine_origin, refine_transform, Refined};

/// What a sequence job did.
#[derive(Clone, Debug)]
pub enum SequenceReport {
    /// Every frame of the chunk was already written (and `force` was off).
    NothingToDo {
        /// Frames in the chunk.
        frames: usize,
        /// The chunk's first frame number.
        start: i64,
        /// Its last.
        end: i64,
    },
    /// Frames were stylized and written.
    Done(SequenceSummary),
}

/// The figures of a finished sequence job.
#[derive(Clone, Debug)]
pub struct SequenceSummary {
    /// Frames stylized and written.
    pub stylized: usize,
    /// Empty frames copied through unchanged.
    pub unchanged: usize,
    /// The optimised quantity.
    pub mode: Mode,
    /// The EMA weight α.
    pub ema: f32,
    /// Cameras per frame.
    pub cameras: usize,
    /// Mean style loss of the written frames over their cameras.
    pub mean_loss: f32,
    /// Mean flicker of consecutive written frames ([`nst3d_sequence::flicker`]).
    pub flicker: f64,
    /// The output pattern.
    pub output: String,
}

/// The frames a run touches: the chunk's frames plus its warm-up, and which
/// of them it writes.
struct Plan {
    /// Every frame of the sequence (the chunk's context).
    all: Vec<i64>,
    /// Input file of each of `all`.
    paths: Vec<PathBuf>,
    /// Frames optimised by this run (chunk plus warm-up).
    run_frames: Vec<i64>,
    /// Output file of each of `run_frames`.
    outs: Vec<PathBuf>,
    /// Indices into `run_frames` still to be written.
    todo: Vec<usize>,
    /// The chunk's first and last frame.
    start: i64,
    end: i64,
    /// Frames of the chunk.
    written: usize,
}

/// The settings' frames, chunk and warm-up turned into file lists.
fn plan(s: &VolumeSettings, seq: &SequenceSettings) -> Result<Plan> {
    let spec = FrameSpec::parse(&seq.frames)?;
    let input = s.input.to_string_lossy().to_string();
    let output = s.out.to_string_lossy().to_string();
    let all = spec.frames().to_vec();
    if seq.warmup < 0 {
        bail!("--warmup must be 0 or more frames, got {}", seq.warmup);
    }
    let (start, end) = match &seq.chunk {
        Some(c) => parse_chunk(c)?,
        None => (all[0], all[all.len() - 1]),
    };
    let written: Vec<i64> = spec.within(start, end);
    if written.is_empty() {
        bail!("--chunk {start}-{end} holds none of the frames {}", seq.frames);
    }
    // The chunk optimises its frames plus the warm-up on each side.
    let run_frames = spec.within(start.saturating_sub(seq.warmup), end.saturating_add(seq.warmup));
    let out_of = |f: i64| {
        expand_pattern(&output, f).map(PathBuf::from).context("--out must be a pattern too when --frames is given")
    };
    let paths: Vec<PathBuf> =
        all.iter().map(|&f| expand_pattern(&input, f).map(PathBuf::from)).collect::<Result<_, _>>()?;
    let outs: Vec<PathBuf> = run_frames.iter().map(|&f| out_of(f)).collect::<Result<_, _>>()?;
    let todo: Vec<usize> = (0..run_frames.len())
        .filter(|&i| (start..=end).contains(&run_frames[i]) && (seq.force || !outs[i].exists()))
        .collect();
    Ok(Plan { all, paths, run_frames, outs, todo, start, end, written: written.len() })
}

/// A farm chunk: `START-END` (frame numbers, inclusive).
pub(crate) fn parse_chunk(s: &str) -> Result<(i64, i64)> {
    let spec = FrameSpec::parse(s).with_context(|| format!("--chunk '{s}'"))?;
    let f = spec.frames();
    if f.len() != (f[f.len() - 1] - f[0] + 1) as usize {
        bail!("--chunk '{s}' must be one range START-END");
    }
    Ok((f[0], f[f.len() - 1]))
}

/// What one pass over every frame of the sequence found.
struct Survey {
    /// The transform of the first frame with smoke.
    transform: Transform,
    /// Lowest and highest active index over all frames.
    lo: [i32; 3],
    hi: [i32; 3],
    /// `empty[i]`: frame `all[i]`'s grid has no active voxel.
    empty: Vec<bool>,
    /// Grid names of each frame.
    grid_names: Vec<Vec<String>>,
}

/// One pass over ALL frames of the sequence, not just the chunk: the common
/// box, the velocity scale and the absorption must be the same in every
/// chunk or the chunks would not blend at their seams.
fn survey(s: &VolumeSettings, paths: &[PathBuf]) -> Result<Survey> {
    let mut transform: Option<Transform> = None;
    let mut lo = [i32::MAX; 3];
    let mut hi = [i32::MIN; 3];
    // Frames whose grid has no active voxel (a simulation's first frames
    // often do): nothing to stylize, so they are written unchanged and the
    // EMA chain is cut there rather than carried through emptiness.
    let mut empty = Vec::with_capacity(paths.len());
    let mut grid_names: Vec<Vec<String>> = Vec::with_capacity(paths.len());
    for p in paths {
        let file = read_vdb(p)?;
        let grid = file.grid(&s.grid).with_context(|| format!("{}: no grid named '{}'", p.display(), s.grid))?;
        if matches!(grid.values, GridValues::Unsupported { .. } | GridValues::Vec3(_)) {
            bail!("{}: grid '{}' is not a float grid", p.display(), s.grid);
        }
        if grid.has_non_finite() {
            bail!("{}: grid '{}' has non-finite values", p.display(), s.grid);
        }
        grid_names.push(file.grids.iter().map(|g| g.name.clone()).collect());
        let Some((a, b)) = grid.active_bbox() else {
            empty.push(true);
            continue;
        };
        empty.push(false);
        // The transform of an empty frame does not matter: it is copied as it is.
        match &transform {
            None => transform = Some(grid.transform.clone()),
            Some(t) if t.voxel_size != grid.transform.voxel_size => {
                bail!(
                    "{}: voxel size {:?} differs from the first frame's {:?}",
                    p.display(),
                    grid.transform.voxel_size,
                    t.voxel_size
                )
            }
            _ => {}
        }
        for k in 0..3 {
            lo[k] = lo[k].min(a[k]);
            hi[k] = hi[k].max(b[k]);
        }
    }
    let Some(transform) = transform else {
        bail!("every frame's grid '{}' is empty: nothing to stylize", s.grid);
    };
    Ok(Survey { transform, lo, hi, empty, grid_names })
}

/// The velocity grid the EMA follows: the one asked for, else the first of
/// [`VELOCITY_NAMES`] some frame with smoke has; notes what it cannot follow.
fn velocity_grid(
    seq: &SequenceSettings,
    sv: &Survey,
    all: &[i64],
    reporter: &mut dyn Reporter,
) -> Result<Option<String>> {
    let has = |i: usize, name: &str| sv.grid_names[i].iter().any(|g| g == name);
    let live_all: Vec<usize> = (0..sv.empty.len()).filter(|&i| !sv.empty[i]).collect();
    let velocity_grid = match &seq.velocity_grid {
        Some(v) if !live_all.iter().any(|&i| has(i, v)) => {
            bail!("no frame with smoke has a velocity grid '{v}' (grids: {})", sv.grid_names[live_all[0]].join(", "))
        }
        Some(v) => Some(v.clone()),
        None => VELOCITY_NAMES.iter().find(|n| live_all.iter().any(|&i| has(i, n))).map(|n| n.to_string()),
    };
    match &velocity_grid {
        None => reporter.note(&format!(
            "no velocity grid (looked for {}): the EMA carries each frame's field to the next unmoved (no advection)",
            VELOCITY_NAMES.join(", ")
        )),
        Some(v) => {
            let missing: Vec<i64> = live_all.iter().filter(|&&i| !has(i, v)).map(|&i| all[i]).collect();
            if !missing.is_empty() {
                reporter.note(&format!(
                    "frames {missing:?} have no grid '{v}': the EMA carries their fields to the next frame unmoved"
                ));
            }
        }
    }
    Ok(velocity_grid)
}

/// Where a shot is stylized: one refinement `k` for the whole shot, the
/// common box of every frame (plus the margin vmax needs) in fine voxels,
/// and the simulation read in that box at the files' resolution.
struct Shot {
    k: usize,
    vmax: f32,
    dims: [usize; 3],
    origin: [i32; 3],
    transform: Transform,
    full: VdbSimulation,
    /// The frames' smoke (the union of their active boxes) inside the box:
    /// offset and size in fine voxels.
    inner: ([usize; 3], [usize; 3]),
}

fn shot(
    s: &VolumeSettings,
    seq: &SequenceSettings,
    sv: &Survey,
    velocity_grid: Option<String>,
    paths: &[PathBuf],
    reporter: &mut dyn Reporter,
) -> Result<Shot> {
    let (lo, hi) = (sv.lo, sv.hi);
    let active: [usize; 3] = std::array::from_fn(|a| (hi[a] - lo[a] + 1) as usize);
    // One refinement for the whole shot, from the common box (crate::upsample).
    let k = s.upsample.factor(active);
    let vmax = s.vmax_for(active.iter().max().unwrap_or(&1) * k);
    // The margin is counted in the file's voxels, enough for vmax fine voxels.
    let margin = s.margin(vmax).div_ceil(k) as i32;
    let coarse_origin = lo.map(|v| v - margin);
    let coarse_dims: [usize; 3] = std::array::from_fn(|a| active[a] + 2 * margin as usize);
    let dims = coarse_dims.map(|n| n * k);
    if dims.iter().product::<usize>() > (1 << 28) {
        bail!("the frames' common box {dims:?} is too large to stylize densely");
    }
    VolumeSettings::check_memory(dims, true)?;
    let origin = refine_origin(coarse_origin, k)?;
    let transform = refine_transform(&sv.transform, k);
    if k > 1 {
        reporter.note(&format!(
            "the frames' common box is {}x{}x{} voxels, too few for strokes; they are stylized and written {k}x finer ({}x{}x{}; --upsample 1 keeps the files' resolution)",
            active[0], active[1], active[2], active[0] * k, active[1] * k, active[2] * k
        ));
    }
    let mut full = VdbSimulation {
        paths: paths.to_vec(),
        grid: s.grid.clone(),
        velocity_grid,
        velocity_scale: 1.0,
        origin: coarse_origin,
        dims: coarse_dims,
        linked: Vec::new(),
    };
    if full.velocity_grid.is_some() {
        full.velocity_scale = match seq.velocity_scale {
            Some(v) if v.is_finite() && v >= 0.0 => v,
            Some(v) => bail!("--velocity-scale must be a non-negative number, got {v}"),
            None => full.calibrate()?,
        };
    }
    let inner = ([margin as usize * k; 3], active.map(|n| n * k));
    Ok(Shot { k, vmax, dims, origin, transform, full, inner })
}

/// The densest frame and view of the whole sequence set the absorption
/// for all, so brightness does not pump and chunks agree.
fn shot_absorption(
    s: &VolumeSettings,
    full: &impl Simulation,
    live_all: &[usize],
    cams_at: &dyn Fn(usize) -> Vec<Camera>,
) -> Result<f32> {
    Ok(match s.absorption {
        Some(_) => absorption_for(s.absorption, std::iter::empty())?,
        None => {
            let mut best = f32::INFINITY;
            for &t in live_all {
                let d = full.density(t)?;
                let cams = cams_at(t);
                if let Some(g) = smallest_absorption(cams.iter().map(|c| (&d, c)))? {
                    best = best.min(g);
                }
            }
            if !best.is_finite() {
                bail!("the density is zero everywhere in view: nothing to stylize");
            }
            best
        }
    })
}

/// The flicker of the written frames `s.out` of the sequence
/// `s.input` / `s.sequence`, by the metric optimised sequences report
/// (docs/design/volumes.md) with the box, velocity and first camera such a run
/// would use at the files' resolution (`--upsample 1`): so a feed-forward
/// sequence and an optimised one are scored alike. Pairs of consecutive
/// frames of the run with smoke in both count; `None` if there are none.
pub fn flicker_of_outputs(s: &VolumeSettings, reporter: &mut dyn Reporter) -> Result<Option<f64>> {
    let s = &VolumeSettings { upsample: crate::Upsample::Factor(1), ..s.clone() };
    let seq = s.sequence.as_ref().context("the job has no frames (set the sequence settings)")?;
    let Plan { all, paths, run_frames, outs, .. } = plan(s, seq)?;
    let sv = survey(s, &paths)?;
    let velocity_grid = velocity_grid(seq, &sv, &all, &mut nst3d_core::Silent)?;
    let Shot { dims, origin, transform, full, .. } = shot(s, seq, &sv, velocity_grid, &paths, reporter)?;
    let cameras = Cameras::of(s)?;
    let live_all: Vec<usize> = (0..all.len()).filter(|&i| !sv.empty[i]).collect();
    let gamma = shot_absorption(s, &full, &live_all, &|t| cameras.at(all[t] as f64, dims, &transform, origin))?;
    let written = VdbSimulation { paths: outs.clone(), ..full.clone() };
    let at = |f: i64| all.iter().position(|&a| a == f).with_context(|| format!("frame {f} is not in --frames"));
    let (mut sum, mut pairs) = (0.0f64, 0usize);
    for i in 1..run_frames.len() {
        let (t0, t1) = (at(run_frames[i - 1])?, at(run_frames[i])?);
        if t1 != t0 + 1 || sv.empty[t0] || sv.empty[t1] || !outs[i - 1].exists() || !outs[i].exists() {
            continue;
        }
        let view = views_of(&cameras.at(run_frames[i] as f64, dims, &transform, origin), gamma, s.equalize).remove(0);
        let render = |g: &Grid3| view_image(g, &view);
        let frames = [written.density(i - 1)?, written.density(i)?];
        sum += nst3d_sequence::flicker::flicker(&frames, &[full.velocity(t0)?, None], render)? as f64;
        pairs += 1;
    }
    Ok((pairs > 0).then(|| sum / pairs as f64))
}

/// What a volume sequence's state files say they are.
pub const STATE_KIND: &str = "volume sequence";

/// Everything the optimised states depend on, so a work folder is only
/// reused by the same job: settings, the style image and camera file
/// contents, and each input frame's size and modification time.
fn job_id(s: &VolumeSettings, run_paths: &[PathBuf]) -> Result<JobId> {
    // Not what the states depend on: previews, held-out scoring, where the
    // states go, --force; the painting and the camera file count by their
    // contents below, not their paths.
    let mut a = s.clone();
    (a.preview, a.eval_cameras, a.model, a.style, a.camera_file) = (None, None, None, PathBuf::new(), None);
    if let Some(q) = &mut a.sequence {
        (q.force, q.work_dir) = (false, None);
    }
    let settings = settings_key(&a, false);
    let mut read = vec![s.style.clone()];
    read.extend(s.camera_file.clone());
    read.extend(s.more_styles.iter().cloned());
    Ok(JobId::new(STATE_KIND, settings, &read, run_paths)?)
}

/// Stylizes the frames `s.sequence` names, or one chunk of them with its
/// warm-up overlap (docs/guide/farm.md); frames already written are kept unless
/// `force`. A killed run started again with the same settings resumes.
pub fn stylize_sequence_files(s: &VolumeSettings, reporter: &mut dyn Reporter) -> Result<SequenceReport> {
    s.check()?;
    let seq = s.sequence.as_ref().context("the job has no frames to stylize (set the sequence settings)")?;
    let Plan { all, paths, run_frames, outs, todo, start, end, written } = plan(s, seq)?;
    let existing = written - todo.len();
    if todo.is_empty() {
        return Ok(SequenceReport::NothingToDo { frames: written, start, end });
    }
    if existing > 0 {
        reporter.status(&format!("{existing} of {written} frames already exist and are kept (--force redoes them)"));
    }

    let sv = survey(s, &paths)?;
    let velocity_grid = velocity_grid(seq, &sv, &all, reporter)?;
    let is_empty = |f: i64| all.iter().position(|&a| a == f).is_some_and(|i| sv.empty[i]);
    let passed: Vec<i64> = todo.iter().map(|&i| run_frames[i]).filter(|&f| is_empty(f)).collect();
    note_empty_frames(&passed, &s.grid, reporter);
    let Shot { k, vmax, dims, origin, transform, full, inner } = shot(s, seq, &sv, velocity_grid, &paths, reporter)?;
    let (run_index, sim) = live_frames(s, &run_frames, &is_empty, &full)?;
    let live: Vec<i64> = run_index.iter().map(|&i| run_frames[i]).collect();
    let sim_of = |i: usize| run_index.iter().position(|&r| r == i);
    let (full, sim) = (Refined { inner: full, k }, Refined { inner: sim, k });
    let warmup = run_frames.iter().filter(|&&f| !(start..=end).contains(&f)).count();
    reporter.status(&run_status(run_frames.len(), todo.len(), warmup, &sim, dims, origin));
    let frame_files = live.iter().copied().zip(sim.inner.paths.iter().cloned()).collect();
    let at = ShotBox { dims, origin, transform: transform.clone(), inner };
    let maps = FrameMaps::checked(s, frame_files, at, &sim)?;

    let id = job_id(s, &sim.inner.paths)?;
    let work = seq.work_dir.clone().unwrap_or_else(|| default_work_dir(&s.out, id.hash));
    let restart = format!("rerun with --force (or delete {}) to start over", work.display());
    // Held until the job ends: a second blade on the same job exits here,
    // before the weights and the painting's features are loaded (seconds on
    // a blade the first one keeps busy).
    let job = Resume::begin(&work, StateFiles::new(id, restart)).map_err(anyhow::Error::msg)?;
    let (style, vgg) = load_style_and_vgg(s)?;
    let cameras = Cameras::of(s)?;
    let cams_at = |f: i64| cameras.at(f as f64, dims, &transform, origin);
    let live_all: Vec<usize> = (0..all.len()).filter(|&i| !sv.empty[i]).collect();
    let gamma = shot_absorption(s, &full, &live_all, &|t| cams_at(all[t]))?;
    let views: Vec<Vec<ViewSpec>> = live.iter().map(|&f| views_of(&cams_at(f), gamma, s.equalize)).collect();
    let loss = ViewLoss::new(&vgg, &style, &s.style_spec())?;
    let map_loss = maps.as_ref().map(|_| load_paintings(s, &vgg, s.color).map(|(_, l)| MapLoss::new(l))).transpose()?;
    let regions_of = |t: usize, d: &Grid3| maps.as_ref().map_or(Ok(Vec::new()), |m| m.sweep_regions(t, d));
    let paintings = match &map_loss {
        Some(m) => Paintings::Map(m, &regions_of),
        None => Paintings::One(&loss),
    };
    // Unused by the sweeps (each frame has its views); any view of the run will do.
    let first_view = match views.first() {
        Some(v) => v[0].clone(),
        None => views_of(&cams_at(all[live_all[0]]), gamma, s.equalize).remove(0),
    };
    let params = SequenceParams {
        frame: s.frame_params(vmax, &first_view),
        alpha: seq.ema,
        settle_first_sweep: seq.ema_settle,
        color: s.color,
    };

    if seq.force {
        DiskStore::remove(&work).with_context(|| format!("cannot clear the work folder {}", work.display()))?;
    }
    // A chunk of empty frames only has nothing to optimise.
    let mut store = if sim.is_empty() { None } else { Some(DiskStore::open(&work, job.files().clone())?) };
    if let Some(store) = &mut store {
        optimise(s, &work, &sim, paintings, &views, &live, &params, store, reporter)?;
    }

    let sources = todo
        .iter()
        .map(|&i| all.iter().position(|&a| a == run_frames[i]).map(|p| paths[p].clone()))
        .collect::<Option<Vec<PathBuf>>>()
        .context("a frame of the run is not in --frames")?;
    let frames = RunFrames {
        todo: &todo,
        run_frames: &run_frames,
        outs: &outs,
        sources: &sources,
        sim_index: (0..run_frames.len()).map(sim_of).collect(),
    };
    let Tally { stylized, unchanged, losses, flicker_sum, pairs } =
        write_frames(s, &frames, &sim, store.as_mut(), paintings, &views, (&transform, origin), reporter)?;
    // Every frame landed: the states are no longer needed (they are large).
    // Only the store's own files go: the work folder may hold other things.
    let _ = DiskStore::remove(&work);
    Ok(SequenceReport::Done(SequenceSummary {
        stylized,
        unchanged,
        mode: s.mode,
        ema: seq.ema,
        cameras: views.first().map_or(0, |v| v.len()),
        mean_loss: losses / stylized.max(1) as f32,
        flicker: if pairs > 0 { flicker_sum / pairs as f64 } else { 0.0 },
        output: s.out.to_string_lossy().to_string(),
    }))
}

/// The frames a run optimises: those of `run_frames` with smoke, as a
/// simulation of their own (`full`'s box and velocity), two frames linked
/// when adjacent in the run; and each one's place in `run_frames`.
fn live_frames(
    s: &VolumeSettings,
    run_frames: &[i64],
    is_empty: &dyn Fn(i64) -> bool,
    full: &VdbSimulation,
) -> Result<(Vec<usize>, VdbSimulation)> {
    let run_index: Vec<usize> = (0..run_frames.len()).filter(|&i| !is_empty(run_frames[i])).collect();
    let input = s.input.to_string_lossy().to_string();
    let sim = VdbSimulation {
        paths: run_index
            .iter()
            .map(|&i| expand_pattern(&input, run_frames[i]).map(PathBuf::from))
            .collect::<Result<_, _>>()?,
        linked: (0..run_index.len()).map(|k| k == 0 || run_index[k] == run_index[k - 1] + 1).collect(),
        ..full.clone()
    };
    Ok((run_index, sim))
}

/// Says which frames to write have an empty grid (they are copied, not stylized).
fn note_empty_frames(passed: &[i64], grid: &str, reporter: &mut dyn Reporter) {
    if !passed.is_empty() {
        reporter
            .note(&format!("frames {passed:?} have an empty grid '{grid}'; they are written unchanged (not stylized)"));
    }
}

/// The status line of a run: its frames, the box they share and the
/// velocity grid the EMA follows.
fn run_status(
    frames: usize,
    to_write: usize,
    warmup: usize,
    sim: &Refined<VdbSimulation>,
    dims: [usize; 3],
    origin: [i32; 3],
) -> String {
    format!(
        "{} frames ({} to write, {} warm-up, {} empty), common box {}x{}x{} at {:?}, velocity grid {} (x{:.4} voxels/frame)",
        frames,
        to_write,
        warmup,
        frames - sim.len(),
        dims[0],
        dims[1],
        dims[2],
        origin,
        sim.inner.velocity_grid.as_deref().unwrap_or("none"),
        sim.inner.velocity_scale
    )
}

/// The style loss of a written frame, mean over its views: of the grey
/// render (with a style map, each painting's over the frame's `regions`
/// as its field carried them), or with colour of the colour render.
fn frame_loss(
    paintings: Paintings,
    d: &Grid3,
    color: Option<&Vec<Grid3>>,
    regions: &[Grid3],
    views: &[ViewSpec],
) -> Result<f32> {
    let mut sum = 0.0;
    for v in views {
        sum += match (color, paintings) {
            (Some(c), Paintings::One(loss)) => loss.loss_color(d, c, v)?,
            (Some(c), Paintings::Map(loss, _)) => loss.loss_color(d, c, regions, v)?,
            _ => paintings.loss(d, regions, v)?,
        };
    }
    Ok(sum / views.len().max(1) as f32)
}

/// Where each frame of a run comes from and goes to.
struct RunFrames<'a> {
    /// Places in `run_frames` of the frames to write.
    todo: &'a [usize],
    /// Frame numbers of the run (warm-up included).
    run_frames: &'a [i64],
    /// Output file of each run frame.
    outs: &'a [PathBuf],
    /// Input file of each frame to write (`todo` order).
    sources: &'a [PathBuf],
    /// Each run frame's place among the optimised frames (`None`: empty).
    sim_index: Vec<Option<usize>>,
}

/// What writing a run's frames gave.
#[derive(Default)]
struct Tally {
    stylized: usize,
    unchanged: usize,
    /// Sum of the stylized frames' mean style loss.
    losses: f32,
    /// Sum of the flicker of consecutive written frames, over `pairs`.
    flicker_sum: f64,
    pairs: usize,
}

/// A written frame: its density, its colour (with colour), the input's
/// grids not copied, its style loss.
type Written = (Grid3, Option<Vec<Grid3>>, Vec<String>, f32);

/// Writes the frames of `frames.todo`: an optimised frame transported by
/// its stored field (every other grid of its file kept), an empty one
/// copied byte for byte; scores what it wrote.
#[allow(clippy::too_many_arguments)]
fn write_frames(
    s: &VolumeSettings,
    frames: &RunFrames<'_>,
    sim: &Refined<VdbSimulation>,
    store: Option<&mut DiskStore>,
    paintings: Paintings,
    views: &[Vec<ViewSpec>],
    placement: (&Transform, [i32; 3]),
    reporter: &mut dyn Reporter,
) -> Result<Tally> {
    // Every frame we can is written; one that fails is reported and the others still land.
    let RunFrames { todo, run_frames, outs, sources, sim_index } = frames;
    let (transform, origin) = placement;
    let mut failures = Vec::new();
    let mut tally = Tally::default();
    let mut prev: Option<(usize, Grid3, Option<Vec<Grid3>>)> = None;
    let mut dropped_noted = false;
    let mut store = store;
    for (n, &i) in todo.iter().enumerate() {
        let Some(t) = sim_index[i] else {
            // An empty frame: the input file byte for byte, so every grid is as it was.
            let src = &sources[n];
            let copied =
                std::fs::read(src).and_then(|bytes| nst3d_io::atomic::write_atomic(&outs[i], |w| w.write_all(&bytes)));
            match copied {
                Ok(()) => tally.unchanged += 1,
                Err(e) => {
                    reporter.warn(&format!("frame {} failed: {}: {e}", run_frames[i], outs[i].display()));
                    failures.push(run_frames[i]);
                }
            }
            continue;
        };
        let result = (|| -> Result<Written> {
            let store = store.as_deref_mut().context("frames with smoke were not optimised")?;
            let regions = match paintings {
                Paintings::Map(_, regions_of) => regions_of(t, &sim.density(t)?)?,
                Paintings::One(_) => Vec::new(),
            };
            let (d, color, regions) = nst3d_sequence::ema::stylized_frame_carrying(sim, store, t, &regions)?;
            if d.data.iter().any(|v| !v.is_finite()) {
                bail!("stylization produced non-finite densities (try a smaller --lr)");
            }
            let file = read_vdb(&sim.inner.paths[t])?;
            file.grid(&s.grid).context("the grid vanished")?;
            let color_name =
                s.color_grid.clone().unwrap_or_else(|| crate::output::color_grid_name(&file, s.up).to_string());
            let named = color.as_ref().map(|c| (color_name.as_str(), &c[..]));
            let dropped = write_stylized(&outs[i], &file, &s.grid, transform, origin, &d, named)?;
            let loss = frame_loss(paintings, &d, color.as_ref(), &regions, &views[t])?;
            Ok((d, color, dropped, loss))
        })();
        match result {
            Ok((d, color, dropped, loss)) => {
                // Said once: every frame of a simulation has the same grids.
                if !dropped.is_empty() && !dropped_noted {
                    reporter.note(&format!("{} not copied to the outputs", dropped.join(", ")));
                    dropped_noted = true;
                }
                tally.stylized += 1;
                tally.losses += loss;
                // Flicker of consecutive written frames, computed pairwise so
                // memory holds two frames.
                if let Some((tp, dp, cp)) = &prev {
                    if *tp + 1 == t && sim.linked(t) {
                        let vel = sim.velocity(*tp)?;
                        tally.flicker_sum += pair_flicker((dp, cp.as_ref()), (&d, color.as_ref()), vel, &views[t][0])?;
                        tally.pairs += 1;
                    }
                }
                prev = Some((t, d, color));
            }
            Err(e) => {
                reporter.warn(&format!("frame {} failed: {e:#}", run_frames[i]));
                failures.push(run_frames[i]);
            }
        }
    }
    if !failures.is_empty() {
        bail!(
            "{} of {} frames failed: {:?} (rerun to retry them; finished frames are kept)",
            failures.len(),
            todo.len(),
            failures
        );
    }
    Ok(tally)
}

/// The flicker of a frame against the one before it (`prev`, carried along
/// `vel`), seen from `view`: of the grey picture, or with colour of the
/// colour picture.
fn pair_flicker(
    (dp, cp): (&Grid3, Option<&Vec<Grid3>>),
    (d, c): (&Grid3, Option<&Vec<Grid3>>),
    vel: Option<Vec<[f32; 3]>>,
    view: &ViewSpec,
) -> Result<f64> {
    Ok(match (cp, c) {
        (Some(cp), Some(c)) => {
            let render = |f: &(Grid3, Vec<Grid3>)| color_view_image(&f.0, &f.1, view);
            let pair = [(dp.clone(), cp.clone()), (d.clone(), c.clone())];
            nst3d_sequence::flicker::flicker_color(&pair, &[vel, None], render)? as f64
        }
        _ => nst3d_sequence::flicker::flicker(&[dp.clone(), d.clone()], &[vel, None], |g| view_image(g, view))? as f64,
    })
}

/// Runs Algorithm 1 over the frames with smoke (`sim`), each state saved
/// in `store`, or resumes it where a killed run stopped; the progress bar
/// counts only the steps left.
#[allow(clippy::too_many_arguments)]
fn optimise(
    s: &VolumeSettings,
    work: &Path,
    sim: &Refined<VdbSimulation>,
    paintings: Paintings,
    views: &[Vec<ViewSpec>],
    live: &[i64],
    params: &SequenceParams,
    store: &mut DiskStore,
    reporter: &mut dyn Reporter,
) -> Result<()> {
    let n = sim.len();
    let per_octave = s.iterations() * n;
    let mut done_steps = 0;
    if let Some(r) = store.resume_point() {
        done_steps = (r.octave * s.iterations() + r.sweeps_done) * n;
        if r.octave + 1 == r.octaves && r.sweeps_done == s.iterations() {
            reporter
                .status(&format!("optimisation already complete in {}; writing the missing frames", work.display()));
        } else {
            reporter.status(&format!(
                "resuming at octave {} sweep {} from {}",
                r.octave + 1,
                r.sweeps_done + 1,
                work.display()
            ));
        }
    }
    // A resumed run counts only the steps left.
    reporter.begin((s.octaves() * per_octave).saturating_sub(done_steps) as u64);
    stylize_sequence_with(sim, paintings, &|t| views[t].clone(), params, store, &mut |p| {
        reporter.step(&format!(
            "octave {} sweep {}/{} frame {} loss {:.4e}",
            p.octave + 1,
            p.iteration,
            s.iterations(),
            live[p.frame],
            p.loss
        ))
    })?;
    reporter.end();
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The work folder's hash follows every setting that changes the
    /// states and none of those that do not (a hand-kept list of 30
    /// fields drifted from the settings).
    #[test]
    fn the_job_hash_follows_the_settings_that_matter() {
        let dir = tempfile::tempdir().unwrap();
        let style = dir.path().join("p.png");
        std::fs::write(&style, b"painting").unwrap();
        let mut s = VolumeSettings::new("in_####.vdb", &style, "out_####.vdb");
        s.sequence = Some(SequenceSettings { frames: "1-3".into(), ..SequenceSettings::default() });
        let h = |s: &VolumeSettings| job_id(s, &[]).unwrap().hash;
        let base = h(&s);
        let mut same = s.clone();
        same.preview = Some("p_####.png".into());
        same.eval_cameras = Some("ring:8:30".into());
        let q = same.sequence.as_mut().unwrap();
        (q.force, q.work_dir) = (true, Some("w".into()));
        assert_eq!(h(&same), base);
        // The painting counts by its contents, not its path.
        let copy = dir.path().join("copy.png");
        std::fs::copy(&style, &copy).unwrap();
        assert_eq!(h(&VolumeSettings { style: copy.clone(), ..s.clone() }), base);
        std::fs::write(&copy, b"another painting").unwrap();
        assert_ne!(h(&VolumeSettings { style: copy, ..s.clone() }), base);
        let mut other = s.clone();
        other.sequence.as_mut().unwrap().ema = 0.5;
        assert_ne!(h(&other), base);
        assert_ne!(h(&VolumeSettings { fov: 40.0, ..s.clone() }), base);
        assert_ne!(h(&VolumeSettings { strength: 2.0, ..s }), base);
    }
}
