//! Algorithm 1 of the paper: velocity- (or density-) based stylisation of a
//! whole sequence with exponential-moving-average temporal coherence.
//!
//! Every iteration sweeps all frames; before frame `t` takes its optimiser
//! step its field is blended with the previous frame's field carried along
//! the simulation velocity, `v̂_t ← (1−α)v̂_t + α·T(v̂_{t−1}, u_{t−1})` (eq. 4),
//! then clipped (with `settle_first_sweep`, from each octave's second sweep on:
//! see the comment at the blend). The sweep direction flips after every iteration so each
//! frame is pulled by both neighbours. Octaves wrap the whole loop, coarse to
//! fine, as in the single-frame case.

use nst3d_core::Grid3;
use nst3d_optim::Adam;
use nst3d_stylize::guided::carried_regions;
use nst3d_stylize::{color, Field, FrameParams, MapLoss, ViewError, ViewLoss, ViewSpec};
use nst3d_transport as transport;

/// Why a sequence could not be stylised.
#[derive(Debug, thiserror::Error)]
pub enum SequenceError {
    /// A frame could not be loaded or saved (the message names it).
    #[error("frame {frame}: {message}")]
    Frame {
        /// Index of the frame in the sequence.
        frame: usize,
        /// What went wrong.
        message: String,
    },
    /// Scoring a view failed.
    #[error(transparent)]
    View(#[from] ViewError),
    /// The work folder's saved state cannot be used (the message says why).
    #[error("work folder: {0}")]
    Checkpoint(String),
    /// The caller asked the job to stop ([`nst3d_core::stop`]); every
    /// committed sweep stays on disk.
    #[error(transparent)]
    Interrupted(#[from] nst3d_core::stop::Interrupted),
}

/// The simulation, frame by frame, on one common dense domain.
pub trait Simulation {
    /// Number of frames.
    fn len(&self) -> usize;
    /// True when there are no frames.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Dims of the common domain every frame is densified into.
    fn dims(&self) -> [usize; 3];
    /// Density of frame `t` over the common domain.
    fn density(&self, t: usize) -> Result<Grid3, SequenceError>;
    /// Simulation velocity `u_t`, in voxels per frame at voxel centres of the
    /// common domain; `None` when the frame has none (no carrying then).
    fn velocity(&self, t: usize) -> Result<Option<Vec<[f32; 3]>>, SequenceError>;
    /// Whether frame `t` continues frame `t − 1`, so the EMA carries fields
    /// between them. False where the sequence has a break (e.g. an empty
    /// frame that is passed through unstylized was between them): nothing
    /// there moved one frame's smoke into the other's.
    fn linked(&self, _t: usize) -> bool {
        true
    }
}

/// Per-frame optimisation state: the field and its Adam moments.
#[derive(Clone, Debug)]
pub struct FrameState {
    /// The stylisation field `v̂_t` (or `ŝ_t`).
    pub field: Field,
    /// Adam first moments.
    pub m: Vec<f32>,
    /// Adam second moments.
    pub v: Vec<f32>,
    /// Adam step count (the colour's too: both step together).
    pub step: u64,
    /// With [`FrameParams::color`]: the colour's raw channels and moments.
    pub color: Option<ColorState>,
}

/// A frame's colour: the three raw channels of
/// [`nst3d_stylize::color`], carried and blended by the EMA exactly like
/// the field, and their Adam moments (channel after channel).
#[derive(Clone, Debug)]
pub struct ColorState {
    /// Raw channels R, G, B, each a scale field of one value per voxel.
    pub raw: Vec<Field>,
    /// Adam first moments, `3 × voxels`.
    pub m: Vec<f32>,
    /// Adam second moments, `3 × voxels`.
    pub v: Vec<f32>,
}

impl ColorState {
    /// White (raw 1), fresh moments.
    fn white(voxels: usize) -> Self {
        Self {
            raw: (0..3).map(|_| Field::identity(nst3d_stylize::Mode::Density, voxels)).collect(),
            m: vec![0.0; 3 * voxels],
            v: vec![0.0; 3 * voxels],
        }
    }

    /// Carried to a finer octave, fresh moments.
    fn resize(&self, from: [usize; 3], to: [usize; 3]) -> Self {
        let voxels = to.iter().product::<usize>();
        Self {
            raw: self.raw.iter().map(|f| f.resize(from, to)).collect(),
            m: vec![0.0; 3 * voxels],
            v: vec![0.0; 3 * voxels],
        }
    }

    /// The colour, one grid per channel of `dims`.
    pub fn color(&self, dims: [usize; 3]) -> Vec<Grid3> {
        color::chroma(&color::raw_of(&self.raw), dims, color::SMOOTH_PASSES).0
    }

    fn constrain(&mut self) {
        let (lo, hi) = color::RAW_RANGE;
        self.raw.iter_mut().for_each(|f| transport::clamp_scale(f.params_mut(), lo, hi));
    }
}

/// A point of Algorithm 1 at which every frame's state is consistent: the
/// end of sweep `sweeps_done` of octave `octave` (0 = coarsest); 0 sweeps done
/// means the octave's fields were just carried up from the coarser octave.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SweepMark {
    /// Octave, coarse first (0-based).
    pub octave: usize,
    /// Number of octaves of the run.
    pub octaves: usize,
    /// Sweeps of this octave completed.
    pub sweeps_done: usize,
}

/// Where per-frame state lives between sweeps: memory for short sequences,
/// disk when the sequence does not fit (memory then stays a few frames).
pub trait StateStore {
    /// The state of frame `t`, if any was saved.
    fn load(&mut self, t: usize) -> Result<Option<FrameState>, SequenceError>;
    /// Saves the state of frame `t`.
    fn save(&mut self, t: usize, state: FrameState) -> Result<(), SequenceError>;
    /// Called when every frame has been saved for `mark`: a persistent store
    /// makes those states the ones a restart resumes from. Memory does nothing.
    fn commit(&mut self, _mark: SweepMark) -> Result<(), SequenceError> {
        Ok(())
    }
    /// The last committed mark, where a restarted run picks up (`None`: start afresh).
    fn resume_point(&self) -> Option<SweepMark> {
        None
    }
}

/// All states in memory.
#[derive(Default)]
pub struct MemoryStore {
    states: Vec<Option<FrameState>>,
}

impl StateStore for MemoryStore {
    fn load(&mut self, t: usize) -> Result<Option<FrameState>, SequenceError> {
        Ok(self.states.get_mut(t).and_then(Option::take))
    }
    fn save(&mut self, t: usize, state: FrameState) -> Result<(), SequenceError> {
        if self.states.len() <= t {
            self.states.resize_with(t + 1, || None);
        }
        self.states[t] = Some(state);
        Ok(())
    }
}

/// Settings of a sequence stylisation.
#[derive(Clone, Debug)]
pub struct SequenceParams {
    /// Per-frame settings (mode, octaves, iterations = sweeps per octave, lr, limits).
    pub frame: FrameParams,
    /// EMA weight α of eq. 4 (0 = frames independent).
    pub alpha: f32,
    /// Skip the blend on each frame's first Adam step of an octave. Off,
    /// this is Algorithm 1 as printed; on, the run stops being chaotic in its
    /// first sweep, which farm chunks need to meet a single run at their seams
    /// (docs/guide/farm.md).
    pub settle_first_sweep: bool,
    /// Stylise an RGB colour per voxel with the density: the
    /// chroma layer's raw channels ([`nst3d_stylize::color`]) ride in every
    /// frame's state, are blended by the EMA like the field, and follow the
    /// RGB Gram loss of each frame's views (the painting given to the loss
    /// must be the colour one), which then drives the density too. A single
    /// frame colours in a stage of its own instead
    /// ([`nst3d_stylize::color_stage`]).
    pub color: bool,
}

/// Progress of the sweeps.
#[derive(Clone, Copy, Debug)]
pub struct SweepProgress {
    /// Octave, coarse first.
    pub octave: usize,
    /// Sweep (iteration of Algorithm 1) within the octave, 1-based.
    pub iteration: usize,
    /// Frame just updated.
    pub frame: usize,
    /// Its loss before the step.
    pub loss: f32,
}

/// Frame `t`'s region weights of a style map over the common domain at
/// full resolution, one grid per painting summing to 1 per voxel, given
/// the frame's density there (a label map checks its labels where there is
/// smoke).
pub type RegionsOf<'a> = dyn Fn(usize, &Grid3) -> Result<Vec<Grid3>, SequenceError> + 'a;

/// What every frame is stylized toward: one painting over the whole
/// picture (the paper's case), or a style map's paintings, each over its
/// region of the frame (guided Gram loss, [`nst3d_stylize::guided`]), the
/// regions read per frame.
#[derive(Clone, Copy)]
pub enum Paintings<'a> {
    /// One painting everywhere.
    One(&'a ViewLoss<'a>),
    /// Several paintings and where each goes, frame by frame (with
    /// [`SequenceParams::color`], the paintings in colour, each colouring
    /// its own region).
    Map(&'a MapLoss<'a>, &'a RegionsOf<'a>),
}

impl<'a> From<&'a ViewLoss<'a>> for Paintings<'a> {
    fn from(loss: &'a ViewLoss<'a>) -> Self {
        Paintings::One(loss)
    }
}

impl Paintings<'_> {
    /// Frame `t`'s regions at octave `level` as `field` carries them (the
    /// guides follow the smoke, as in a single frame); none for one
    /// painting. `full`: the frame's density at full resolution.
    fn regions_at(&self, t: usize, full: &Grid3, level: usize, field: &Field) -> Result<Vec<Grid3>, SequenceError> {
        let Paintings::Map(_, regions_of) = self else { return Ok(Vec::new()) };
        let here: Vec<Grid3> = regions_of(t, full)?.into_iter().map(|r| downsample(r, level)).collect();
        Ok(carried_regions(field, &here))
    }

    /// One view's loss of the transported density `dstar` and its gradient
    /// (`regions`: the frame's, carried by its field; unused by one painting).
    pub fn loss_and_grad(&self, dstar: &Grid3, regions: &[Grid3], view: &ViewSpec) -> Result<(f32, Grid3), ViewError> {
        match self {
            Paintings::One(loss) => loss.loss_and_grad(dstar, view),
            Paintings::Map(loss, _) => loss.loss_and_grad(dstar, regions, view),
        }
    }

    /// One view's loss of `d` without gradient (`regions` as in
    /// [`Paintings::loss_and_grad`]).
    pub fn loss(&self, d: &Grid3, regions: &[Grid3], view: &ViewSpec) -> Result<f32, ViewError> {
        match self {
            Paintings::One(loss) => loss.loss(d, view),
            Paintings::Map(loss, _) => loss.loss(d, regions, view),
        }
    }
}

/// `d` box-filtered down `level` octaves, as the single-frame pyramid is.
fn downsample(mut d: Grid3, level: usize) -> Grid3 {
    for _ in 0..level {
        d = transport::downsample2(&d);
    }
    d
}

/// A frame's simulation velocity at octave `level`, in voxels of that level.
fn velocity_at(sim: &dyn Simulation, t: usize, dims: [usize; 3]) -> Result<Option<Vec<[f32; 3]>>, SequenceError> {
    Ok(sim.velocity(t)?.map(|u| if dims == sim.dims() { u } else { transport::resize_velocity(&u, sim.dims(), dims) }))
}

/// Runs Algorithm 1; `views` is the camera set Θ (losses add up). Returns
/// nothing: the final fields are in `store`, one per frame, at full
/// resolution — [`stylized_density`] applies them.
pub fn stylize_sequence(
    sim: &dyn Simulation,
    loss: &ViewLoss,
    views: &[ViewSpec],
    params: &SequenceParams,
    store: &mut dyn StateStore,
    progress: &mut dyn FnMut(&SweepProgress),
) -> Result<(), SequenceError> {
    stylize_sequence_with(sim, loss, &|_| views.to_vec(), params, store, progress)
}

/// [`stylize_sequence`] with a camera set per frame (a camera path: `views(t)`
/// is Θ for frame `t`, full resolution), toward one painting or a style
/// map's ([`Paintings`]). If `store` has a
/// [`StateStore::resume_point`], the run picks up after it; every completed
/// sweep is [`StateStore::commit`]ted, so a killed run loses at most one sweep.
pub fn stylize_sequence_with<'a>(
    sim: &dyn Simulation,
    paintings: impl Into<Paintings<'a>>,
    views: &dyn Fn(usize) -> Vec<ViewSpec>,
    params: &SequenceParams,
    store: &mut dyn StateStore,
    progress: &mut dyn FnMut(&SweepProgress),
) -> Result<(), SequenceError> {
    let paintings = paintings.into();
    let n = sim.len();
    let fp = &params.frame;
    let dims = octave_dims(sim.dims(), fp.octaves);
    let octaves = dims.len();
    let resume = store.resume_point();
    check_resume(resume, octaves, fp.iterations)?;
    for (k, level) in (0..octaves).rev().enumerate() {
        // Octaves wholly before the checkpoint are done.
        let first_sweep = match resume {
            Some(r) if k < r.octave => continue,
            Some(r) if k == r.octave => Some(r.sweeps_done),
            _ => None,
        };
        let here = dims[level];
        let factor = (1usize << level) as f32;
        let level_views =
            |t: usize| -> Vec<ViewSpec> { views(t).iter().map(|v| nst3d_stylize::frame::view_at(v, factor)).collect() };
        let vmax_here = fp.limits.vmax / factor;
        if first_sweep.is_none() {
            start_octave(store, params, n, (here, dims.get(level + 1).copied()))?;
            store.commit(SweepMark { octave: k, octaves, sweeps_done: 0 })?;
        }
        for it in first_sweep.unwrap_or(0)..fp.iterations {
            let forward = it % 2 == 0;
            let order: Vec<usize> = if forward { (0..n).collect() } else { (0..n).rev().collect() };
            // The previous frame's updated field (and colour), already carried to this frame's time.
            let mut carried: Option<Carried> = None;
            for &t in &order {
                let full = sim.density(t)?;
                let u = velocity_at(sim, t, here)?;
                let mut st = load_sized(store, t, here)?
                    .ok_or_else(|| SequenceError::Frame { frame: t, message: "lost its optimisation state".into() })?;
                // Optionally no blend on a frame's first Adam step of the octave: that step is
                // lr·sign(g) per voxel, so any tiny difference in the blended
                // field flips signs and grows frame after frame along the first
                // sweep, making the whole run chaotic (a 1e-5 change of α moved
                // frames by 40% of their stylization) and a farm chunk's cold
                // start diverge from the single run however long its warm-up.
                if let (Some((c, cc)), true) = (&carried, st.step > 0 || !params.settle_first_sweep) {
                    st.field.blend(c, params.alpha);
                    st.field.constrain(&fp.limits, vmax_here);
                    if let (Some(own), Some(cc)) = (&mut st.color, cc) {
                        own.raw.iter_mut().zip(cc).for_each(|(a, b)| a.blend(b, params.alpha));
                        own.constrain();
                    }
                }
                // The style map's regions, read for this frame and carried
                // by its field before the step, as the single frame does.
                let regions = paintings.regions_at(t, &full, level, &st.field)?;
                let d = downsample(full, level);
                let (dstar, tape) = st.field.forward(&d);
                let mut grad_dstar = vec![0.0f32; d.len()];
                let views = level_views(t);
                let total = match &mut st.color {
                    None => grey_step(&paintings, &regions, (&dstar, &mut grad_dstar), &views)?,
                    Some(cs) => {
                        color_step((&paintings, &regions), cs, (t, st.step), (&dstar, &mut grad_dstar), &views)?
                    }
                };
                // The transport's backward is linear in ∂L/∂d*: one pass for all views.
                let grad = st.field.descent(st.field.backward(&d, &tape, &grad_dstar), d.dims);
                let mut adam = Adam::new(st.field.len(), fp.learning_rate);
                adam.set_state(&st.m, &st.v, st.step)
                    .map_err(|e| SequenceError::Frame { frame: t, message: e.to_string() })?;
                adam.step(st.field.params_mut(), &grad);
                st.field.constrain(&fp.limits, vmax_here);
                let (m, v, step) = adam.state();
                st.m.copy_from_slice(m);
                st.v.copy_from_slice(v);
                st.step = step;
                progress(&SweepProgress { octave: k, iteration: it + 1, frame: t, loss: total });
                nst3d_core::stop::check()?;
                // Forward sweeps carry v̂_t along u_t to t+1; backward sweeps
                // carry v̂_t back to t-1 along −u_{t−1}.
                carried = match params.alpha > 0.0 {
                    true => carry(sim, &st, t, forward, u, here)?,
                    false => None,
                };
                store.save(t, st)?;
            }
            store.commit(SweepMark { octave: k, octaves, sweeps_done: it + 1 })?;
        }
    }
    Ok(())
}

/// Octave dims from the common domain, as the single-frame pyramid does:
/// halved (rounded up) until a side would drop under 4 voxels.
fn octave_dims(full: [usize; 3], octaves: usize) -> Vec<[usize; 3]> {
    let mut dims = vec![full];
    for _ in 1..octaves.max(1) {
        let [x, y, z] = *dims.last().unwrap();
        let next = [x.div_ceil(2), y.div_ceil(2), z.div_ceil(2)];
        if next.iter().any(|&k| k < 4) {
            break;
        }
        dims.push(next);
    }
    dims
}

/// A checkpoint must fit the run: the same octaves, and no more sweeps done
/// than the run makes.
fn check_resume(resume: Option<SweepMark>, octaves: usize, iterations: usize) -> Result<(), SequenceError> {
    if let Some(r) = resume {
        if r.octaves != octaves || r.octave >= octaves || r.sweeps_done > iterations {
            return Err(SequenceError::Checkpoint(format!(
                "checkpoint at octave {}/{} sweep {} does not fit a run of {} octaves x {} sweeps",
                r.octave + 1,
                r.octaves,
                r.sweeps_done,
                octaves,
                iterations
            )));
        }
    }
    Ok(())
}

/// The start of an octave of dims `here`: every frame's field (and colour)
/// carried up from the coarser octave's (`coarser`; none at the coarsest,
/// whose frames start afresh), with fresh Adam moments.
fn start_octave(
    store: &mut dyn StateStore,
    params: &SequenceParams,
    n: usize,
    (here, coarser): ([usize; 3], Option<[usize; 3]>),
) -> Result<(), SequenceError> {
    let fp = &params.frame;
    for t in 0..n {
        let saved = match coarser {
            Some(coarser) => load_sized(store, t, coarser)?.map(|s| (s, coarser)),
            None => None,
        };
        let voxels = here.iter().product();
        let (field, color) = match saved {
            None => (Field::initial(fp.mode, voxels), params.color.then(|| ColorState::white(voxels))),
            Some((s, coarser)) => (
                s.field.resize(coarser, here),
                s.color.map(|c| c.resize(coarser, here)).or_else(|| params.color.then(|| ColorState::white(voxels))),
            ),
        };
        let len = field.len();
        store.save(t, FrameState { field, m: vec![0.0; len], v: vec![0.0; len], step: 0, color })?;
    }
    Ok(())
}

/// The grey loss of the transported density `dstar` over `views`, its
/// gradient added to `grad_dstar`: one painting's, or each painting's over
/// its region (`regions`, carried by the frame's field). Returns the loss.
fn grey_step(
    paintings: &Paintings,
    regions: &[Grid3],
    (dstar, grad_dstar): (&Grid3, &mut [f32]),
    views: &[ViewSpec],
) -> Result<f32, SequenceError> {
    let mut total = 0.0;
    for view in views {
        let (l, g) = paintings.loss_and_grad(dstar, regions, view)?;
        total += l;
        grad_dstar.iter_mut().zip(&g.data).for_each(|(a, b)| *a += b);
    }
    Ok(total)
}

/// One sweep's step of a frame's colour: the colour loss over `views` of
/// the transported density `dstar` (with a style map, each painting's over
/// its carried region of `regions`), its density gradient added to
/// `grad_dstar`, and an Adam step (at frame `t`'s `step`) on the colour's
/// raw channels through the luma-divided chroma. Returns the loss.
fn color_step(
    (paintings, regions): (&Paintings, &[Grid3]),
    cs: &mut ColorState,
    (t, step): (usize, u64),
    (dstar, grad_dstar): (&Grid3, &mut [f32]),
    views: &[ViewSpec],
) -> Result<f32, SequenceError> {
    let dims = dstar.dims;
    let (grids, chroma_tape) = color::chroma(&color::raw_of(&cs.raw), dims, color::SMOOTH_PASSES);
    let mut grad_color: Vec<Grid3> = (0..3).map(|_| Grid3::zeros(dims)).collect();
    let mut total = 0.0;
    for view in views {
        let (l, g, gc) = match paintings {
            Paintings::One(loss) => loss.loss_and_grad_color(dstar, &grids, view)?,
            Paintings::Map(loss, _) => {
                let (l, _, g, gc) = loss.loss_and_grad_color_guarded(dstar, &grids, regions, view, 0.0, None)?;
                (l, g, gc)
            }
        };
        total += l;
        grad_dstar.iter_mut().zip(&g.data).for_each(|(a, b)| *a += b);
        for (acc, g) in grad_color.iter_mut().zip(&gc) {
            acc.data.iter_mut().zip(&g.data).for_each(|(a, b)| *a += b);
        }
    }
    let grad_raw = color::chroma_backward(&chroma_tape, &grad_color).concat();
    let mut raw: Vec<f32> = cs.raw.iter().flat_map(|f| f.params().to_vec()).collect();
    let mut adam = Adam::new(raw.len(), color::LEARNING_RATE);
    adam.set_state(&cs.m, &cs.v, step).map_err(|e| SequenceError::Frame { frame: t, message: e.to_string() })?;
    adam.step(&mut raw, &grad_raw);
    let (m, v, _) = adam.state();
    cs.m.copy_from_slice(m);
    cs.v.copy_from_slice(v);
    for (f, chunk) in cs.raw.iter_mut().zip(raw.chunks_exact(dstar.len())) {
        f.params_mut().copy_from_slice(chunk);
    }
    cs.constrain();
    Ok(total)
}

/// A frame's field and colour channels carried to the next frame's time.
type Carried = (Field, Option<Vec<Field>>);

/// Frame `t`'s updated field (and colour) carried to the next frame of the
/// sweep: forward sweeps carry v̂_t along u_t (`u`) to t+1; backward sweeps
/// carry v̂_t back to t-1 along −u_{t−1}. None at the sweep's end or where
/// the next frame is not linked to this one.
fn carry(
    sim: &dyn Simulation,
    st: &FrameState,
    t: usize,
    forward: bool,
    u: Option<Vec<[f32; 3]>>,
    here: [usize; 3],
) -> Result<Option<Carried>, SequenceError> {
    let next = if forward { t + 1 } else { t.wrapping_sub(1) };
    if !(next < sim.len() && sim.linked(if forward { next } else { t })) {
        return Ok(None);
    }
    let disp = if forward { u } else { velocity_at(sim, next, here)?.map(|w| negate(&w)) };
    let raw = st.color.as_ref().map(|c| &c.raw);
    Ok(Some(match disp {
        Some(w) => (st.field.carried(here, &w), raw.map(|r| r.iter().map(|f| f.carried(here, &w)).collect())),
        None => (st.field.clone(), raw.cloned()),
    }))
}

/// Frame `t`'s state, checked to hold one value (scale) or vector (velocity)
/// per voxel of `dims` and Adam moments of the same length: a state file
/// that decodes but belongs to another grid is an error here rather than an
/// out-of-bounds index in the transport.
fn load_sized(store: &mut dyn StateStore, t: usize, dims: [usize; 3]) -> Result<Option<FrameState>, SequenceError> {
    let Some(st) = store.load(t)? else { return Ok(None) };
    let per_voxel = if matches!(st.field, Field::Velocity(_)) { 3 } else { 1 };
    let len = per_voxel * dims.iter().product::<usize>();
    let color_fits = st.color.as_ref().is_none_or(|c| {
        let n = dims.iter().product::<usize>();
        c.raw.len() == 3 && c.raw.iter().all(|f| f.len() == n) && c.m.len() == 3 * n && c.v.len() == 3 * n
    });
    if st.field.len() != len || st.m.len() != len || st.v.len() != len || !color_fits {
        return Err(SequenceError::Checkpoint(format!(
            "frame {t}: saved state does not match the grid {dims:?} (delete the work folder to start afresh)"
        )));
    }
    Ok(Some(st))
}

fn negate(u: &[[f32; 3]]) -> Vec<[f32; 3]> {
    u.iter().map(|w| [-w[0], -w[1], -w[2]]).collect()
}

/// `d*_t = T(d_t, v̂_t)` for a frame whose field is in `store`.
pub fn stylized_density(sim: &dyn Simulation, store: &mut dyn StateStore, t: usize) -> Result<Grid3, SequenceError> {
    Ok(stylized_frame(sim, store, t)?.0)
}

/// [`stylized_density`] and, for a run with colour, the frame's colour.
pub fn stylized_frame(
    sim: &dyn Simulation,
    store: &mut dyn StateStore,
    t: usize,
) -> Result<(Grid3, Option<Vec<Grid3>>), SequenceError> {
    let (d, color, _) = stylized_frame_carrying(sim, store, t, &[])?;
    Ok((d, color))
}

/// A stylized frame: its density, its colour (in a run with colour), and
/// the grids carried with it.
pub type CarriedFrame = (Grid3, Option<Vec<Grid3>>, Vec<Grid3>);

/// [`stylized_frame`] and `grids` (a style map's regions, full resolution)
/// as the frame's field carries them: moved with the smoke in velocity
/// mode, unchanged by a density scale, so the written frame is scored over
/// the regions its smoke holds.
pub fn stylized_frame_carrying(
    sim: &dyn Simulation,
    store: &mut dyn StateStore,
    t: usize,
    grids: &[Grid3],
) -> Result<CarriedFrame, SequenceError> {
    let d = sim.density(t)?;
    let st = load_sized(store, t, d.dims)?
        .ok_or_else(|| SequenceError::Frame { frame: t, message: "was never stylized".into() })?;
    let out = st.field.transport(&d);
    let color = st.color.as_ref().map(|c| c.color(d.dims));
    let carried = carried_regions(&st.field, grids);
    store.save(t, st)?;
    Ok((out, color, carried))
}
