//! Animated grooms: Alg. 1 run frame after frame with the temporal
//! coherency of Sec. 3.3, and a flicker measure for the result.
//!
//! [`SequenceStylizer`] is fed one frame at a time (a farm reads, stylizes
//! and writes frame by frame, so only the previous frame's state is kept):
//!
//! 1. **Topology.** Every frame's groom must have the strands of the first
//!    frame with the same point counts ([`check_topology`]); the animation
//!    velocity `u` is the difference of consecutive frames' control points,
//!    which needs that correspondence.
//! 2. **Same cameras.** Each frame gets its own [`StrandScene`] (guides,
//!    proxies grown with the same seed, field on the frame's guides), but
//!    the view frame, eye distance, field of view and strand width are
//!    locked to the first frame's. Otherwise the camera would follow the
//!    wind (a fur ball's "front" falls back to the groom's bounding-box
//!    offset) and every frame would be seen from a different place. With
//!    the same seed, the Poisson view angles are the same every frame; the
//!    matches cannot be (they are made on each frame's undeformed render).
//! 3. **EMA (eq. 8, Alg. 1 line 7).** Before every iteration the current
//!    velocities are blended towards the previous frame's optimized field
//!    `v̂ₜ₋₁` transported to this frame, `T(v̂ₜ₋₁, uₜ₋₁)`, with the decaying
//!    weight `f(m; ν, σ)` ([`ema_blend_factor`]); `m` is the fraction of the
//!    current scale's iterations done, as Alg. 1's inner loop counts it
//!    ([`EmaClock`]). The transport moves the previous samples by `uₜ₋₁` and
//!    re-interpolates at this frame's samples with the *inverse-distance*
//!    kernel, whatever the field's kernel: it interpolates, so a field
//!    carried along its own samples (the groom's animation, where moved old
//!    samples land exactly on the new ones) comes back unchanged, while the
//!    field's cubic kernel would blur it a little more every frame.
//! 4. **1€ filter (eq. 9–10, Alg. 1 line 19)** on the optimized control
//!    points, guides and proxies, with the animation speed `‖uₜ‖` (units per
//!    second) opening the cutoff. It filters the stylization *deformation*
//!    `pₜ − xₜ` (optimized minus undeformed points) rather than the raw
//!    positions: the paper's `OneEuro(pₜ, p̂ₜ₋₁, uₜ, uₜ₋₁)` blends with the
//!    previous output, and blending raw positions would drag every point
//!    back to where the animation *was* (at the Table 1 cutoffs, `γ ≈ 0.7`
//!    at 24 fps, a lag of ~0.4 frames of motion). Filtering `p − x` is the
//!    same blend with `p̂ₜ₋₁` first carried along the animation. The
//!    filtered groom is then put back through the scene's constraints
//!    (lengths, collisions), since a blend of two valid grooms is slightly
//!    short.
//!
//! With a user *style flow* ([`Flow::Style`], Alg. 1 line 2) `u` is that
//! flow instead of the animation, for both the transport and the 1€ speed.
//!
//! **Flicker** ([`FrameFlicker`]): from one fixed camera (the first frame's
//! front camera), the mean absolute pixel difference between this frame's
//! output and the previous frame's *stylization carried along the
//! animation* — the previous deformation `p̂ₜ₋₁ − xₜ₋₁` added to this frame's
//! undeformed groom `xₜ`: `mean |R(p̂ₜ) − R(xₜ + p̂ₜ₋₁ − xₜ₋₁)|`. The wind's own
//! motion scores 0 by construction (the unstylized input has no deformation
//! to carry), and so does a stylization that rides along with the groom;
//! patterns that jump from frame to frame score high. The plain difference
//! of consecutive renders, `|R(p̂ₜ) − R(p̂ₜ₋₁)|`, is also reported with the
//! same for the input: it is dominated by the wind (thin strands sweeping
//! across pixels), so its excess over the input's is a noisy second opinion.
//! A stylization that does nothing also scores 0, so flicker is only
//! meaningful next to the NNST loss the frames reach.

use nst3d_core::groom::Groom;
use nst3d_core::mesh::TriMesh;
use nst3d_core::Image;
use nst3d_features::Vgg19;
use nst3d_loss::nnst::{nnst_loss, nnst_loss_matched};
use nst3d_splat::{SplatCamera, StrandStyle};

use crate::field::Kernel;
use crate::pipeline::{
    match_view, style_target, stylize_mapped, stylize_with, FrameHooks, IterationClock, IterationReport, MapKind,
    NnstTarget, PipelineError, StrandScene, StrandShares, StylizeParams, StylizeResult, ViewFrame, NNST_LAYERS,
};
use crate::preset::TemporalParams;
use crate::strands::FlatStrands;
use crate::temporal::{ema_blend, ema_blend_factor, transport_velocities, OneEuroFilter};
use nst3d_core::math::{add, scale, sub, V3};

mod state;

pub use state::SavedState;

/// Neighbours of the inverse-distance interpolation that carries the
/// previous frame's field (a sample that lands on a new one dominates its
/// weights by ~10⁸, so the count only matters for a style flow).
const TRANSPORT_NEIGHBOURS: usize = 8;

/// Why a sequence could not be stylized; one line naming the frame.
#[derive(Debug, thiserror::Error)]
pub enum SequenceError {
    /// A frame's strands do not correspond to the first frame's.
    #[error("frame {frame}: {reason} (an animated groom needs the same strands, with the same point counts, in every frame)")]
    Topology {
        /// Frame number.
        frame: i64,
        /// What differs.
        reason: String,
    },
    /// A setting outside its valid range.
    #[error("bad parameter: {0}")]
    Parameter(String),
    /// A saved sequence state could not be read back.
    #[error("{0}")]
    State(String),
    /// The frame's stylization failed.
    #[error("frame {frame}: {source}")]
    Frame {
        /// Frame number.
        frame: i64,
        /// What failed.
        source: PipelineError,
    },
}

/// How the iteration count `m` of eq. 8's `f(m; ν, σ)` is read (as a
/// fraction, see [`ema_blend_factor`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EmaClock {
    /// Fraction of the current scale's iterations, Alg. 1's inner loop
    /// counter `m` as printed: every scale starts from the previous frame's
    /// field again and only its last `1 − ν` runs free. The default:
    /// measured on the wind-blown fur ball (docs/design/strands.md) it halves the
    /// per-frame flicker at a lower NNST loss, where [`EmaClock::Frame`]
    /// flickers more than per-frame stylization.
    Scale,
    /// Fraction of the frame's iterations over all scales (the reading
    /// suggested in [`crate::temporal`]): the EMA fades out during the
    /// coarse scales and the last `1 − ν` of the frame, all at the finest
    /// scale, runs free, so the field drifts further from the previous
    /// frame's every frame.
    Frame,
}

nst3d_core::named_enum!(EmaClock, "an EMA clock", { Scale => "scale", Frame => "frame" });

/// What carries the previous frame's field and drives the 1€ speed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Flow {
    /// The groom's own animation: consecutive frames' control points.
    Animation,
    /// A user style flow `s*` (Alg. 1 line 2): one world-space velocity,
    /// scene units per frame, for every point.
    Style([f32; 3]),
}

/// Settings of a sequence.
#[derive(Clone, Debug, PartialEq)]
pub struct SequenceParams {
    /// One frame's stylization (the same for every frame).
    pub stylize: StylizeParams,
    /// σ, ν of the EMA and α, β, f_min, FPS of the 1€ filter.
    pub temporal: TemporalParams,
    /// Blend towards the previous frame's field (eq. 8).
    pub ema: bool,
    /// 1€-filter the optimized points (eq. 9–10).
    pub one_euro: bool,
    /// Reading of the EMA's `m`.
    pub ema_clock: EmaClock,
    /// What `u` is.
    pub flow: Flow,
    /// Square size of the flicker renders.
    pub flicker_size: usize,
}

impl SequenceParams {
    /// EMA (scale clock) and 1€ on, the groom's own animation, flicker at
    /// the render size.
    pub fn new(stylize: StylizeParams, temporal: TemporalParams) -> Self {
        let flicker_size = stylize.render_size;
        SequenceParams {
            stylize,
            temporal,
            ema: true,
            one_euro: true,
            ema_clock: EmaClock::Scale,
            flow: Flow::Animation,
            flicker_size,
        }
    }
}

/// Frame-to-frame change of one frame against the previous one (see the
/// module notes), mean absolute difference per pixel and channel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameFlicker {
    /// `|R(p̂ₜ) − R(xₜ + p̂ₜ₋₁ − xₜ₋₁)|`: stylization flicker, the animation
    /// compensated.
    pub compensated: f32,
    /// `|R(p̂ₜ) − R(p̂ₜ₋₁)|`: plain difference of the output renders.
    pub raw: f32,
    /// `|R(xₜ) − R(xₜ₋₁)|`: the same for the unstylized input.
    pub input_raw: f32,
}

/// One stylized frame.
pub struct FrameResult {
    /// Frame number.
    pub frame: i64,
    /// The frame's scene (view locked to the first frame's).
    pub scene: StrandScene,
    /// The optimization (before the 1€ filter).
    pub optimized: StylizeResult,
    /// Output strands, guides then proxies (after the 1€ filter when on).
    pub strands: FlatStrands,
    /// Output guides (the groom to write).
    pub guides: FlatStrands,
    /// Mean NNST loss of the undeformed frame over the evaluation views.
    pub eval_before: f32,
    /// Mean NNST loss of the output against the same targets.
    pub eval_output: f32,
    /// Mean NNST loss of the output re-matched on its own renders.
    pub eval_output_rematched: f32,
    /// Change from the previous frame (`None` on the first).
    pub flicker: Option<FrameFlicker>,
}

/// Means over a sequence.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SequenceReport {
    /// Frames stylized.
    pub frames: usize,
    /// Mean NNST loss of the undeformed frames.
    pub eval_before: f32,
    /// Mean NNST loss of the optimized frames (before the 1€ filter).
    pub eval_optimized: f32,
    /// Mean NNST loss of the output frames.
    pub eval_output: f32,
    /// Mean re-matched NNST loss of the output frames.
    pub eval_output_rematched: f32,
    /// Mean [`FrameFlicker::compensated`] over consecutive pairs.
    pub flicker: f32,
    /// Mean [`FrameFlicker::raw`].
    pub flicker_raw: f32,
    /// Mean [`FrameFlicker::input_raw`].
    pub flicker_input_raw: f32,
}

/// The first frame's camera setup, imposed on every later frame.
#[derive(Clone, Copy)]
struct LockedView {
    frame: ViewFrame,
    distance: f32,
    fov_deg: f32,
    style: StrandStyle,
}

/// What the next frame needs of this one.
struct Previous {
    samples: Vec<V3>,
    velocities: Vec<V3>,
    undeformed: FlatStrands,
    output: FlatStrands,
    render_output: Image,
    render_input: Image,
}

/// A style map over an animation: every frame's strands take the
/// paintings by the same values (strands keep their identity from frame to
/// frame), so the regions move with the hair.
pub struct SequenceMap<'a> {
    /// The paintings, in the map's order.
    pub paintings: Vec<&'a Image>,
    /// One value per guide strand.
    pub values: Vec<f32>,
    /// How the values pick the paintings.
    pub kind: MapKind,
}

/// Stylizes an animated groom frame by frame (see the module notes).
pub struct SequenceStylizer<'a> {
    vgg: &'a Vgg19,
    style: &'a Image,
    map: Option<SequenceMap<'a>>,
    params: SequenceParams,
    eval_target: NnstTarget,
    topology: Option<Vec<usize>>,
    view: Option<LockedView>,
    previous: Option<Previous>,
    filter: OneEuroFilter,
    sums: [f64; 4],
    flicker_sums: [f64; 3],
    frames: usize,
    pairs: usize,
}

/// Checks that `groom` (frame `frame`) has the strands and per-strand point
/// counts of `first`.
pub fn check_topology(first: &Groom, frame: i64, groom: &Groom) -> Result<(), SequenceError> {
    check_counts(&point_counts(first), frame, groom)
}

fn point_counts(g: &Groom) -> Vec<usize> {
    g.strands.iter().map(|s| s.points.len()).collect()
}

fn check_counts(first: &[usize], frame: i64, groom: &Groom) -> Result<(), SequenceError> {
    let bad = |reason: String| Err(SequenceError::Topology { frame, reason });
    if groom.strands.len() != first.len() {
        return bad(format!("{} strands, the first frame has {}", groom.strands.len(), first.len()));
    }
    if let Some((i, (s, &n))) = groom.strands.iter().zip(first).enumerate().find(|(_, (s, &n))| s.points.len() != n) {
        return bad(format!("strand {i} has {} points, {n} in the first frame", s.points.len()));
    }
    Ok(())
}

fn mean_abs_diff(a: &Image, b: &Image) -> f32 {
    let s: f64 = a.data.iter().zip(&b.data).map(|(x, y)| (x - y).abs() as f64).sum();
    (s / a.data.len().max(1) as f64) as f32
}

impl<'a> SequenceStylizer<'a> {
    /// A stylizer that has seen no frame; `style` is the painting (RGB in
    /// `[0, 1]`, its luminance is matched).
    pub fn new(vgg: &'a Vgg19, style: &'a Image, params: SequenceParams) -> Result<Self, SequenceError> {
        let t = params.temporal;
        ema_blend_factor(0.0, t.ema_nu, t.ema_sigma).map_err(|e| SequenceError::Parameter(e.to_string()))?;
        let filter = OneEuroFilter::new(t.one_euro()).map_err(|e| SequenceError::Parameter(e.to_string()))?;
        if params.flicker_size < 16 || params.flicker_size > 4096 {
            return Err(SequenceError::Parameter(format!(
                "flicker render size {} must be 16..=4096",
                params.flicker_size
            )));
        }
        if style.channels != 3 || style.height < 16 || style.width < 16 {
            return Err(SequenceError::Parameter(format!(
                "style image is {}x{}x{}, need 3 channels and at least 16x16",
                style.channels, style.height, style.width
            )));
        }
        let eval_target = style_target(vgg, style, params.stylize.style_height(2))
            .map_err(|e| SequenceError::Parameter(format!("style: {e}")))?;
        Ok(SequenceStylizer {
            vgg,
            style,
            map: None,
            params,
            eval_target,
            topology: None,
            view: None,
            previous: None,
            filter,
            sums: [0.0; 4],
            flicker_sums: [0.0; 3],
            frames: 0,
            pairs: 0,
        })
    }

    /// The stylizer with a style map: every frame toward `map`'s
    /// paintings; the evaluation and flicker renders stay as they are.
    pub fn with_map(mut self, map: SequenceMap<'a>) -> Self {
        self.map = Some(map);
        self
    }

    /// The settings.
    pub fn params(&self) -> &SequenceParams {
        &self.params
    }

    /// Stylizes the next frame `frame` of the animation: `groom` growing
    /// from `mesh` (if it has one), reporting every iteration to `progress`.
    pub fn stylize_frame(
        &mut self,
        frame: i64,
        groom: &Groom,
        mesh: Option<&TriMesh>,
        progress: &mut dyn FnMut(&IterationReport),
    ) -> Result<FrameResult, SequenceError> {
        let wrap = |source: PipelineError| SequenceError::Frame { frame, source };
        match &self.topology {
            Some(first) => check_counts(first, frame, groom)?,
            None => self.topology = Some(point_counts(groom)),
        }
        let mut scene = StrandScene::new(groom, mesh, &self.params.stylize).map_err(wrap)?;
        self.lock_view(&mut scene);
        self.check_proxies(frame, &scene)?;

        // T(v̂ₜ₋₁, uₜ₋₁): the previous field carried to this frame's samples.
        let transported = self.transported(&scene).map_err(wrap)?;
        let (temporal, clock) = (self.params.temporal, self.params.ema_clock);
        let mut ema = |c: IterationClock, v: &mut [[f32; 3]]| -> Result<(), PipelineError> {
            let Some(prev) = &transported else { return Ok(()) };
            let m = match clock {
                EmaClock::Frame => c.done as f32 / c.total.max(1) as f32,
                EmaClock::Scale => c.iteration as f32 / c.iterations.max(1) as f32,
            };
            let f = ema_blend_factor(m, temporal.ema_nu, temporal.ema_sigma)?;
            if f > 0.0 {
                let blended = ema_blend(v, prev, f)?;
                v.copy_from_slice(&blended);
            }
            Ok(())
        };
        let hooks = FrameHooks { initial: None, before_iteration: Some(&mut ema) };
        let optimized = match &self.map {
            Some(m) => {
                let shares = StrandShares::from_guides(&scene, &m.values, m.kind, m.paintings.len()).map_err(wrap)?;
                stylize_mapped(&scene, &m.paintings, &shares, self.vgg, &self.params.stylize, hooks, progress)
            }
            None => stylize_with(&scene, self.style, self.vgg, &self.params.stylize, hooks, progress),
        }
        .map_err(wrap)?;

        let strands = if self.params.one_euro {
            self.one_euro(&scene, &optimized.strands).map_err(wrap)?
        } else {
            optimized.strands.clone()
        };
        let (eval_output, eval_output_rematched) = if self.params.one_euro {
            self.evaluate(&scene, &strands, &optimized.eval_angles).map_err(wrap)?
        } else {
            (optimized.eval_after, optimized.eval_after_rematched)
        };

        let cam = scene.front_camera(self.params.flicker_size).map_err(wrap)?;
        let render_output = scene.render(&strands, &cam).map_err(wrap)?;
        let render_input = scene.render(&scene.undeformed, &cam).map_err(wrap)?;
        let flicker = self.flicker(&scene, &cam, (&render_output, &render_input)).map_err(wrap)?;

        self.frames += 1;
        for (s, x) in
            self.sums.iter_mut().zip([optimized.eval_before, optimized.eval_after, eval_output, eval_output_rematched])
        {
            *s += x as f64;
        }
        if let Some(f) = flicker {
            self.pairs += 1;
            for (s, x) in self.flicker_sums.iter_mut().zip([f.compensated, f.raw, f.input_raw]) {
                *s += x as f64;
            }
        }
        self.previous = Some(Previous {
            samples: scene.field.samples().to_vec(),
            // Alg. 1 line 18: v̂ₜ is the optimized field, before the 1€ filter.
            velocities: optimized.velocities.clone(),
            undeformed: scene.undeformed.clone(),
            output: strands.clone(),
            render_output,
            render_input,
        });
        let g = scene.guide_count;
        let split = strands.offsets[g];
        let guides = FlatStrands { points: strands.points[..split].to_vec(), offsets: strands.offsets[..=g].to_vec() };
        Ok(FrameResult {
            frame,
            eval_before: optimized.eval_before,
            eval_output,
            eval_output_rematched,
            scene,
            optimized,
            strands,
            guides,
            flicker,
        })
    }

    /// Every frame is seen through the first frame's camera frame, distance,
    /// lens and look, so the sequence does not jump with its box.
    fn lock_view(&mut self, scene: &mut StrandScene) {
        match self.view {
            Some(v) => {
                scene.frame = v.frame;
                scene.distance = v.distance;
                scene.fov_deg = v.fov_deg;
                scene.style = v.style;
            }
            None => {
                self.view = Some(LockedView {
                    frame: scene.frame,
                    distance: scene.distance,
                    fov_deg: scene.fov_deg,
                    style: scene.style,
                })
            }
        }
    }

    /// Same input topology but a different mesh can still grow a different
    /// number of proxies: a frame's field must match the previous one's.
    fn check_proxies(&self, frame: i64, scene: &StrandScene) -> Result<(), SequenceError> {
        if let Some(prev) = &self.previous {
            if prev.undeformed.offsets != scene.undeformed.offsets || prev.samples.len() != scene.field.sample_count() {
                return Err(SequenceError::Topology {
                    frame,
                    reason: format!(
                        "{} strands × {} points and {} velocity samples after densification, {} × {} and {} before \
                     (did the mesh change?)",
                        scene.undeformed.strand_count(),
                        scene.undeformed.points.len(),
                        scene.field.sample_count(),
                        prev.undeformed.strand_count(),
                        prev.undeformed.points.len(),
                        prev.samples.len()
                    ),
                });
            }
        }
        Ok(())
    }

    /// T(v̂ₜ₋₁, uₜ₋₁): the previous frame's optimized field carried to
    /// this frame's samples (none for the first frame or without the EMA).
    fn transported(&self, scene: &StrandScene) -> Result<Option<Vec<V3>>, PipelineError> {
        Ok(match (&self.previous, self.params.ema) {
            (Some(prev), true) => {
                let motion: Vec<V3> = match self.params.flow {
                    Flow::Animation => {
                        scene.field.samples().iter().zip(&prev.samples).map(|(&o, &q)| sub(o, q)).collect()
                    }
                    Flow::Style(s) => vec![s; prev.samples.len()],
                };
                let t = transport_velocities(
                    &prev.samples,
                    &prev.velocities,
                    &motion,
                    scene.field.samples(),
                    Kernel::InverseDistance,
                    TRANSPORT_NEIGHBOURS,
                )
                .map_err(PipelineError::from)?;
                Some(t)
            }
            _ => None,
        })
    }

    /// The flicker of this frame's front render against the previous
    /// frame's: motion-compensated, raw, and the input's raw.
    fn flicker(
        &self,
        scene: &StrandScene,
        cam: &SplatCamera,
        (render_output, render_input): (&Image, &Image),
    ) -> Result<Option<FrameFlicker>, PipelineError> {
        Ok(match &self.previous {
            Some(prev) => {
                let carried: Vec<V3> = scene
                    .undeformed
                    .points
                    .iter()
                    .zip(prev.output.points.iter().zip(&prev.undeformed.points))
                    .map(|(&x, (&p, &q))| add(x, sub(p, q)))
                    .collect();
                let carried = scene.undeformed.with_points(carried).map_err(PipelineError::from)?;
                let render_carried = scene.render(&carried, cam)?;
                Some(FrameFlicker {
                    compensated: mean_abs_diff(render_output, &render_carried),
                    raw: mean_abs_diff(render_output, &prev.render_output),
                    input_raw: mean_abs_diff(render_input, &prev.render_input),
                })
            }
            None => None,
        })
    }

    /// Eq. 9–10 on the deformation `p − x`, then the scene's constraints.
    fn one_euro(&mut self, scene: &StrandScene, optimized: &FlatStrands) -> Result<FlatStrands, PipelineError> {
        let x = &scene.undeformed.points;
        let d: Vec<V3> = optimized.points.iter().zip(x).map(|(&p, &q)| sub(p, q)).collect();
        let fps = self.params.temporal.fps;
        let u: Vec<V3> = match (&self.previous, self.params.flow) {
            (_, Flow::Style(s)) => vec![scale(s, fps); d.len()],
            (Some(prev), Flow::Animation) => {
                x.iter().zip(&prev.undeformed.points).map(|(&a, &b)| scale(sub(a, b), fps)).collect()
            }
            (None, Flow::Animation) => vec![[0.0; 3]; d.len()],
        };
        let filtered = self.filter.filter_with_velocity(&d, &u)?;
        let mut out = scene.undeformed.with_points(x.iter().zip(&filtered).map(|(&q, &e)| add(q, e)).collect())?;
        scene.constrain(&mut out)?;
        Ok(out)
    }

    /// Mean NNST loss of `strands` over the views `angles`, against targets
    /// matched on the undeformed frame (the optimized objective) and
    /// re-matched on the strands' own renders.
    fn evaluate(
        &self,
        scene: &StrandScene,
        strands: &FlatStrands,
        angles: &[(f32, f32)],
    ) -> Result<(f32, f32), PipelineError> {
        let (mut after, mut rematched) = (0.0f64, 0.0f64);
        for &(psi, delta) in angles {
            let cam = scene.camera(psi, delta)?;
            let (matched, _) = match_view(scene, self.vgg, &self.eval_target, &cam)?;
            let img = scene.render(strands, &cam)?;
            let feats = self.vgg.forward(&img, &NNST_LAYERS, false);
            after += nnst_loss_matched(feats.taps(), &matched)?.0 as f64;
            rematched += nnst_loss(feats.taps(), &self.eval_target)?.0 as f64;
        }
        let k = angles.len().max(1) as f64;
        Ok(((after / k) as f32, (rematched / k) as f32))
    }

    /// Means over the frames so far.
    pub fn report(&self) -> SequenceReport {
        let f = |s: f64| (s / self.frames.max(1) as f64) as f32;
        let p = |s: f64| (s / self.pairs.max(1) as f64) as f32;
        SequenceReport {
            frames: self.frames,
            eval_before: f(self.sums[0]),
            eval_optimized: f(self.sums[1]),
            eval_output: f(self.sums[2]),
            eval_output_rematched: f(self.sums[3]),
            flicker: p(self.flicker_sums[0]),
            flicker_raw: p(self.flicker_sums[1]),
            flicker_input_raw: p(self.flicker_sums[2]),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::generators::{fur_ball, FurBallParams, Wind};
    use crate::preset::Preset;
    use nst3d_features::VggFlavor;

    /// Four frames of a 40-strand fur ball in a strong wind.
    fn animation() -> (Vec<Groom>, TriMesh) {
        let (rest, mesh) =
            fur_ball(&FurBallParams { strands: 40, points: 5, length: 0.4, radius: 1.0, seed: 2 }).unwrap();
        let wind = Wind { strength: 1.2, ..Wind::default() };
        let frames = (1..=4).map(|f| wind.frame(&rest, f, 24.0).unwrap().to_groom()).collect();
        (frames, mesh)
    }

    fn stripes() -> Image {
        let (h, w) = (32, 32);
        let plane: Vec<f32> = (0..h * w).map(|i| if ((i / w) + (i % w)) % 8 < 4 { 0.9 } else { 0.1 }).collect();
        Image::from_vec(3, h, w, [plane.as_slice(); 3].concat())
    }

    fn params(ema: bool, one_euro: bool) -> SequenceParams {
        let preset = Preset::FurBall.params();
        let mut sp = StylizeParams::from_preset(preset, 40);
        sp.render_size = 48;
        sp.iterations = [1, 1, 4];
        sp.proxies = 40;
        sp.views_per_scale = 2;
        sp.lr_scale = 1.0;
        let mut p = SequenceParams::new(sp, preset.temporal.unwrap());
        p.ema = ema;
        p.one_euro = one_euro;
        p
    }

    fn run(vgg: &Vgg19, style: &Image, params: SequenceParams) -> (SequenceReport, Vec<FrameResult>) {
        let (frames, mesh) = animation();
        let mut s = SequenceStylizer::new(vgg, style, params).unwrap();
        let out = frames
            .iter()
            .enumerate()
            .map(|(i, g)| s.stylize_frame(i as i64 + 1, g, Some(&mesh), &mut |_| {}).unwrap())
            .collect();
        (s.report(), out)
    }

    #[test]
    fn temporal_filtering_reduces_frame_to_frame_change() {
        let vgg = Vgg19::random(VggFlavor::Gatys, 7);
        let style = stripes();
        let (plain, plain_frames) = run(&vgg, &style, params(false, false));
        assert_eq!(plain.frames, 4);
        assert!(plain_frames[0].flicker.is_none() && plain_frames[1].flicker.is_some());
        // Same cameras every frame: the evaluation views do not move.
        for f in &plain_frames {
            assert_eq!(f.optimized.eval_angles, plain_frames[0].optimized.eval_angles);
            assert_eq!(f.scene.frame, plain_frames[0].scene.frame);
        }
        // Without the filter the output is the optimization's own.
        assert_eq!(plain_frames[2].strands, plain_frames[2].optimized.strands);
        assert_eq!(plain.eval_output, plain.eval_optimized);
        let deformed = |f: &FrameResult| f.strands.points.iter().zip(&f.scene.undeformed.points).any(|(a, b)| a != b);
        assert!(deformed(&plain_frames[3]) && plain.flicker > 0.0);

        // The 1€ filter low-passes the deformation: less change per frame.
        let (euro, euro_frames) = run(&vgg, &style, params(false, true));
        assert!(euro.flicker < 0.9 * plain.flicker, "1€ {} vs per frame {}", euro.flicker, plain.flicker);
        assert_eq!(euro_frames[0].strands.points.len(), plain_frames[0].strands.points.len());
        // An EMA that never decays (ν ≫ 1) holds each frame's field at the
        // previous one carried along: the stylization rides with the wind.
        let mut hold = params(true, false);
        hold.temporal.ema_nu = 20.0;
        let (held, held_frames) = run(&vgg, &style, hold);
        // (Not to zero: the same field moves a bent strand a little
        // differently, and the constraints are re-applied.)
        assert!(held.flicker < 0.7 * plain.flicker, "held EMA {} vs per frame {}", held.flicker, plain.flicker);
        assert!(deformed(&held_frames[3]));
        // The preset's EMA + 1€ runs through (how much it helps at real
        // sizes is measured in docs/design/strands.md).
        let (paper, _) = run(&vgg, &style, params(true, true));
        assert!(paper.flicker.is_finite() && paper.eval_output.is_finite());
        // The wind moves the same in every run.
        for r in [&euro, &held, &paper] {
            assert!((r.flicker_input_raw - plain.flicker_input_raw).abs() < 1e-6);
        }
        assert!(plain.flicker_input_raw > 0.0);
    }

    #[test]
    fn mismatched_topology_is_a_clear_error() {
        let (mut frames, mesh) = animation();
        let mut fewer = frames[1].clone();
        fewer.strands.pop();
        let e = check_topology(&frames[0], 2, &fewer).unwrap_err().to_string();
        assert!(e.contains("frame 2") && e.contains("39 strands, the first frame has 40"), "{e}");
        let mut shorter = frames[1].clone();
        shorter.strands[5].points.pop();
        let e = check_topology(&frames[0], 7, &shorter).unwrap_err().to_string();
        assert!(e.contains("frame 7: strand 5 has 4 points, 5 in the first frame"), "{e}");
        assert!(check_topology(&frames[0], 2, &frames[1]).is_ok());

        // The stylizer refuses it before any work on the frame.
        let vgg = Vgg19::random(VggFlavor::Gatys, 7);
        let style = stripes();
        let mut p = params(true, true);
        p.stylize.iterations = [0, 0, 1];
        let mut s = SequenceStylizer::new(&vgg, &style, p).unwrap();
        s.stylize_frame(1, &frames[0], Some(&mesh), &mut |_| {}).unwrap();
        frames[1].strands.truncate(30);
        let e = s.stylize_frame(2, &frames[1], Some(&mesh), &mut |_| {}).err().unwrap();
        assert!(matches!(e, SequenceError::Topology { frame: 2, .. }), "{e}");
    }

    #[test]
    fn a_restored_state_continues_exactly_as_the_uninterrupted_run() {
        let vgg = Vgg19::random(VggFlavor::Gatys, 7);
        let style = stripes();
        let (frames, mesh) = animation();
        let (whole, whole_frames) = run(&vgg, &style, params(true, true));

        // Frames 1-2, saved; a fresh stylizer (a new process) restores and
        // runs frames 3-4.
        let mut first = SequenceStylizer::new(&vgg, &style, params(true, true)).unwrap();
        for (i, g) in frames[..2].iter().enumerate() {
            first.stylize_frame(i as i64 + 1, g, Some(&mesh), &mut |_| {}).unwrap();
        }
        let id = nst3d_job::JobId { kind: "groom sequence".into(), hash: 1, settings: String::new() };
        let mut saved = nst3d_job::State::new(&id);
        first.save_state(&mut saved);
        let bytes = saved.to_bytes();
        let mut second = SequenceStylizer::new(&vgg, &style, params(true, true)).unwrap();
        second.restore_state(&nst3d_job::State::from_bytes(&bytes).unwrap()).unwrap();
        for (i, g) in frames.iter().enumerate().skip(2) {
            let r = second.stylize_frame(i as i64 + 1, g, Some(&mesh), &mut |_| {}).unwrap();
            assert_eq!(r.strands, whole_frames[i].strands, "frame {}", i + 1);
            assert_eq!(r.flicker, whole_frames[i].flicker);
        }
        assert_eq!(second.report(), whole);

        // A state lacking a part, or whose parts disagree, is refused and
        // changes nothing.
        let mut third = SequenceStylizer::new(&vgg, &style, params(true, true)).unwrap();
        let full = nst3d_job::State::from_bytes(&bytes).unwrap();
        let mut no_velocities = full.clone();
        no_velocities.take_f32s("previous.velocities").unwrap();
        let mut short_history = full.clone();
        short_history.put_f32("one_euro.d", &[1, 3], vec![0.0; 3]);
        for bad in [no_velocities, short_history, nst3d_job::State::new(&id)] {
            let e = third.restore_state(&bad).unwrap_err().to_string();
            assert!(e.contains("state"), "{e}");
        }
        assert!(third.previous.is_none() && third.frames == 0);
    }

    #[test]
    fn bad_temporal_parameters_are_refused() {
        let vgg = Vgg19::random(VggFlavor::Gatys, 7);
        let style = stripes();
        let mut p = params(true, true);
        p.temporal.ema_nu = 0.0;
        assert!(SequenceStylizer::new(&vgg, &style, p.clone()).is_err());
        p.temporal.ema_nu = 0.6;
        p.temporal.fps = -1.0;
        assert!(SequenceStylizer::new(&vgg, &style, p).is_err());
    }
}
