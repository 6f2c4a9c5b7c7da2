//! One stylization of a static groom (Alg. 1 without its temporal lines):
//! guides → proxies → deformation field → per iteration a camera, transport,
//! constraints, splat render, VGG-19, NNST loss, and the whole chain backward
//! to the velocities `v`, stepped with AdamW over the preset's three scales.
//!
//! Setup ([`StrandScene::new`]):
//! - guides are the groom's strands, each re-sampled as a natural cubic
//!   spline ([`StrandSpline`]) to the preset's points per strand at even arc
//!   length; proxies come from [`densify`] on the head mesh with the same
//!   point count; both are the `p` of eq. 5 and the field's samples `o` sit
//!   on the guides at the preset's density `ρ`.
//! - The view frame: centre and radius `R` of the rest strands' bounding
//!   box (centre) and enclosing sphere (radius). *Front* is the direction the
//!   groom faces, the mean of the head's pseudo-normals at the guide roots
//!   (falling back to the mesh-centre → groom-centre direction, then +Z, when
//!   the normals cancel, as on a fur ball). *Up* is +Y (the groom formats we
//!   read are Y-up), or +Z when the front is nearly vertical.
//! - Units: the paper's assets are about one unit across, ours can be
//!   hundreds (the Bangs head is ~240 units). The preset's camera distance
//!   `r` and learning rates `η` are therefore read in units of `R`: the eye
//!   sits `r·R` from the centre, a step of AdamW moves a velocity by about
//!   `η·R`. The field of view is fitted so the enclosing sphere fills the
//!   frame; strands are drawn [`StylizeParams::strand_width_px`] pixels wide
//!   (σ of the cross-section at the centre's depth).
//! - Rendering: grey strands on black (root dark, tip bright, opaque roots,
//!   translucent tips: [`StrandStyle::default`]'s heuristics), culled by the
//!   head normal at the root with the preset's threshold `ϵ`; the grey image
//!   is fed to VGG-19 as three equal channels, and the painting is matched by
//!   its luminance (a grey render cannot reach colour statistics).
//!
//! Cameras: directions on the shell within the polar `ψ` / azimuth `δ`
//! ranges around the front, spread by best-candidate sampling (Mitchell's
//! Poisson-disk approximation: each new direction is the farthest, in angle,
//! of 16 seeded random candidates from those already taken), so every prefix
//! of the sequence covers the ranges evenly and a seed fixes it.
//!
//! Loss: eq. 2–3 as the paper states them. The targets `T` of a view are
//! matched on the *undeformed* render `R_θ(x₀)` against the style image
//! resized for the scale; the loss is `‖Φ(R_θ(x)) − T‖²` averaged over
//! hyper-columns (relu1_1, relu2_1, relu3_1, relu4_1, NNST's grid of a
//! quarter resolution). Gradients flow NNST → VGG backward → splat backward →
//! back through every constraint projection of the iterate (the recorded
//! [`ConstraintTape`], as autograd would in the paper's PyTorch pipeline) →
//! `Wᵀ` of the field.
//!
//! Matching cost: each view's targets need one match (`N_c × N_s × D`)
//! per scale. Views are *cached*: each scale draws
//! [`StylizeParams::views_per_scale`] cameras, matches each once on `x₀`
//! and cycles its iterations through them; `views_per_scale = 0` restores
//! the paper's new camera every iteration. Measured on the Bangs groom (100
//! guides × 100 points + 565 proxies, 256² render, styles 68–128 px as the
//! preset's sizes scaled to 256, 2 cores): 12 iterations take 16.0 s with 3
//! matches and 18.0 s with 12, so a match costs ~0.2 s against ~1.1 s for
//! an iteration (render, VGG forward/backward, splat backward, constraints).
//! At these sizes per-iteration matching is affordable (+20 %); the cache
//! matters at the preset's full 600² render against 300² styles, where a
//! match approaches the cost of an iteration. The default stays at 8 cached
//! views per scale.
//!
//! Step size: the preset's `η` read as `η·R` (see Units) times
//! [`StylizeParams::lr_scale`], 0.3 by default. Measured on the Bangs groom
//! at a 160² render with the preset's 100 iterations (NNST loss from the
//! optimized views, targets matched on the rest groom): lr-scale 0.1 →
//! −10.0 %, 0.3 → −12.6 %, 1.0 → −7.5 % (re-matched −16 %: large steps
//! find another stylization rather than the one matched on `x₀`). Before the
//! constraints' backward existed (they were passed through as identity) the
//! loss *rose* at any step size above ~0.1 px; a single view at the finest
//! scale now falls 29 % in 30 steps at lr-scale 1, against 7 % before.
//!
//! Evaluation: the optimized views — the finest scale's cached cameras (or,
//! with a new camera per iteration, [`StylizeParams::eval_views`] fixed
//! cameras from the same distribution, separately seeded) — matched on the
//! undeformed groom against the finest scale's style. The initial loss is the NNST loss
//! of the rest groom, the final one the same objective on the stylized
//! groom; the loss re-matched on the final render is reported too.

use std::collections::HashMap;
use std::time::{Duration, Instant};

use nst3d_core::Image;
use nst3d_features::{Vgg19, VggLayer};
use nst3d_io::groom::{Groom, GroomError, StrandSpline};
use nst3d_io::mesh::TriMesh;
use nst3d_loss::nnst::{nnst_loss, nnst_loss_matched, NnstError, NnstParams};
use nst3d_splat::{render, render_backward, SplatError, SplatOutput, StrandStyle, Strands};

// Re-exported so callers of [`iteration`] (the `strands-iter` benchmark)
// can hold its inputs without depending on every stage crate.
pub use nst3d_loss::nnst::{NnstMatch, NnstTarget};
pub use nst3d_optim::Adam;
pub use nst3d_splat::SplatCamera;

use crate::bvh::MeshBvh;
use crate::constraints::{CollisionParams, CollisionStats, ConstraintTape, Constraints};
use crate::densify::{densify, DensifyParams};
use crate::field::DeformationField;
use crate::preset::PresetParams;
use crate::strand_rng;
use crate::strands::FlatStrands;
use crate::StrandError;
use nst3d_core::math::{add, cross, dot, norm, normalize, scale, sub, V3};

/// VGG-19 taps of the NNST hyper-columns.
pub const NNST_LAYERS: [VggLayer; 4] = [VggLayer::Relu1_1, VggLayer::Relu2_1, VggLayer::Relu3_1, VggLayer::Relu4_1];

/// Why a stylization could not run; one line naming the problem.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// A groom stage failed (bad geometry or parameter).
    #[error(transparent)]
    Strands(#[from] StrandError),
    /// A strand could not be re-sampled as a spline.
    #[error("groom: {0}")]
    Groom(#[from] GroomError),
    /// The renderer refused its input.
    #[error("render: {0}")]
    Render(#[from] SplatError),
    /// The style loss refused its input.
    #[error(transparent)]
    Loss(#[from] NnstError),
    /// A setting outside its valid range.
    #[error("bad parameter: {0}")]
    Parameter(String),
    /// The optimization diverged.
    #[error("stylization diverged: {0}")]
    Diverged(String),
}

/// Settings of one stylization: the Table 1 preset plus the knobs the
/// command line exposes.
#[derive(Clone, Debug, PartialEq)]
pub struct StylizeParams {
    /// The preset (Table 1).
    pub preset: PresetParams,
    /// Square render size `w_c = h_c`; the preset's style sizes are scaled
    /// by `render_size / preset render width` so patterns keep their size
    /// relative to the picture.
    pub render_size: usize,
    /// Iterations per scale (the preset's, or scaled by the caller).
    pub iterations: [u32; 3],
    /// Proxy strands `M` to grow.
    pub proxies: usize,
    /// Seed of densification and camera sampling.
    pub seed: u64,
    /// Multiplier on the preset's learning rates.
    pub lr_scale: f32,
    /// AdamW decoupled weight decay (PyTorch's default 0.01): pulls unused
    /// velocities back towards the rest groom.
    pub weight_decay: f32,
    /// Cameras (cached matches) per scale; 0 draws a new camera for every
    /// iteration as the paper does (see the module notes).
    pub views_per_scale: usize,
    /// Evaluation cameras when `views_per_scale` is 0 (otherwise the finest
    /// scale's views are the evaluation views).
    pub eval_views: usize,
    /// Strand cross-section σ in pixels at the groom centre's depth.
    pub strand_width_px: f32,
}

impl StylizeParams {
    /// The preset's settings at its own render size, with proxies scaled to
    /// keep Table 1's proxy/guide ratio for `guides` guide strands.
    pub fn from_preset(preset: PresetParams, guides: usize) -> Self {
        let ratio = preset.densified_strands as f64 / preset.guide_strands.max(1) as f64;
        StylizeParams {
            preset,
            render_size: preset.render_size.0 as usize,
            iterations: preset.iterations,
            proxies: (ratio * guides as f64).round() as usize,
            seed: 0,
            lr_scale: 0.3,
            weight_decay: 0.01,
            views_per_scale: 8,
            eval_views: 4,
            strand_width_px: 0.5,
        }
    }

    /// Iterations per scale rescaled to about `total` in all, keeping the
    /// preset's proportions (each scale at least one).
    pub fn with_total_iterations(mut self, total: u32) -> Self {
        let sum: u32 = self.preset.iterations.iter().sum::<u32>().max(1);
        self.iterations =
            self.preset.iterations.map(|n| ((n as f64 * total as f64 / sum as f64).round() as u32).max(1));
        self
    }

    /// Style image height of scale `l` at this render size.
    pub fn style_height(&self, l: usize) -> usize {
        let s = self.render_size as f64 / self.preset.render_size.1.max(1) as f64;
        ((self.preset.style_sizes[l].1 as f64 * s).round() as usize).max(16)
    }

    fn validate(&self) -> Result<(), PipelineError> {
        let bad = |m: String| Err(PipelineError::Parameter(m));
        if self.render_size < 32 || self.render_size > 4096 {
            return bad(format!("render size {} must be 32..=4096 pixels", self.render_size));
        }
        if self.iterations.iter().all(|&n| n == 0) {
            return bad("no iterations".into());
        }
        if !(self.lr_scale.is_finite() && self.lr_scale > 0.0) {
            return bad(format!("learning-rate scale {} must be positive", self.lr_scale));
        }
        if !(self.strand_width_px.is_finite() && self.strand_width_px > 0.0) {
            return bad(format!("strand width {} px must be positive", self.strand_width_px));
        }
        if !(self.preset.camera_distance > 1.0) {
            return bad(format!("camera distance r = {} must exceed 1 groom radius", self.preset.camera_distance));
        }
        if self.eval_views == 0 {
            return bad("need at least one evaluation view".into());
        }
        Ok(())
    }
}

/// Where the cameras live: the groom's centre, enclosing radius and the
/// front/up/side axes the angle ranges are measured from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ViewFrame {
    /// Look-at point (bounding-box centre of the rest strands).
    pub centre: [f32; 3],
    /// Radius of the sphere about `centre` enclosing every rest point.
    pub radius: f32,
    /// Unit direction the groom faces (azimuth 0, polar 0).
    pub front: [f32; 3],
    /// Unit up, orthogonal to `front` (positive polar angles tilt towards it).
    pub up: [f32; 3],
    /// Unit `front × up` (positive azimuths turn towards it).
    pub side: [f32; 3],
}

impl ViewFrame {
    /// Unit direction from the centre to the eye at polar `ψ` (elevation
    /// towards `up`) and azimuth `δ` (about `up`), degrees.
    pub fn direction(&self, polar_deg: f32, azimuth_deg: f32) -> [f32; 3] {
        let (p, a) = (polar_deg.to_radians(), azimuth_deg.to_radians());
        let h = add(scale(self.front, a.cos()), scale(self.side, a.sin()));
        add(scale(h, p.cos()), scale(self.up, p.sin()))
    }
}

/// Everything fixed during one stylization: rest strands (guides then
/// proxies), the deformation field, constraints, root normals and cameras.
#[derive(Clone, Debug)]
pub struct StrandScene {
    /// Rest guides followed by rest proxies.
    pub rest: FlatStrands,
    /// The undeformed groom `x₀`: [`StrandScene::deform`] at `v = 0` (the
    /// rest strands after one constraint step), what the targets are matched
    /// on and the loss starts from.
    pub undeformed: FlatStrands,
    /// How many leading strands of `rest` are guides.
    pub guide_count: usize,
    /// The field of eq. 5 on the guides, acting on every rest point.
    pub field: DeformationField,
    /// Length preservation and collision against the head.
    pub constraints: Constraints,
    /// Head normal at every strand root (visibility culling).
    pub root_normals: Vec<[f32; 3]>,
    /// The cameras' frame.
    pub frame: ViewFrame,
    /// Look of the strands.
    pub style: StrandStyle,
    /// Eye distance from the centre (`r · R`).
    pub distance: f32,
    /// Vertical field of view, degrees.
    pub fov_deg: f32,
    /// Square render size.
    pub render_size: usize,
    /// How far outside the mesh strands with a root inside are lifted
    /// (`10⁻⁴` of the mesh diagonal; see [`resolve_rest`]).
    pub lift_margin: f32,
}

impl StrandScene {
    /// Builds guides, proxies, field, constraints and view frame from a
    /// groom and the mesh it grows from.
    pub fn new(groom: &Groom, head: &TriMesh, params: &StylizeParams) -> Result<Self, PipelineError> {
        params.validate()?;
        let p = params.preset;
        if groom.strands.is_empty() {
            return Err(StrandError::Invalid("the groom has no strands".into()).into());
        }
        let n = p.points_per_strand.max(2);
        let guides = FlatStrands::from_strands(
            groom
                .strands
                .iter()
                .enumerate()
                .map(|(i, s)| {
                    StrandSpline::new(&s.points)
                        .map(|sp| sp.resample(n))
                        .map_err(|e| PipelineError::Parameter(format!("strand {i}: {e}")))
                })
                .collect::<Result<Vec<_>, _>>()?,
        )?;
        let bvh = MeshBvh::new(head)?;
        let mut raw = guides.clone();
        if params.proxies > 0 {
            let dp = DensifyParams {
                count: params.proxies,
                points_per_strand: Some(n),
                seed: params.seed,
                ..Default::default()
            };
            raw.append(&densify(&guides, head, &dp)?);
        }
        let (lo, hi) = head.bbox().ok_or_else(|| StrandError::Invalid("the head mesh has no vertices".into()))?;
        let diag = norm(sub(hi, lo));
        let collision = p.collision(diag);
        let rest = resolve_rest(&raw, &bvh, collision, diag)?;
        let guide_count = guides.strand_count();
        let rest_guides = FlatStrands {
            points: rest.points[..rest.offsets[guide_count]].to_vec(),
            offsets: rest.offsets[..=guide_count].to_vec(),
        };
        let field = DeformationField::on_guides(&rest_guides, &rest, p.sample_density(), p.kernel, p.neighbors)?;
        let root_normals: Vec<V3> = rest.roots().iter().map(|&r| bvh.closest_point(r).normal).collect();

        let frame = view_frame(&rest, &root_normals[..guide_count], head)?;
        let constraints = Constraints { rest: rest.clone(), collider: Some(bvh), collision };

        let distance = p.camera_distance * frame.radius;
        // Fit the enclosing sphere with 5 % margin.
        let half = (1.0 / p.camera_distance).asin() * 1.05;
        let fov_deg = (2.0 * half).to_degrees().min(120.0);
        let pixel = 2.0 * distance * (0.5 * fov_deg.to_radians()).tan() / params.render_size as f32;
        let style = StrandStyle {
            width: params.strand_width_px * pixel,
            visibility_threshold: p.visibility_threshold,
            output: SplatOutput::Rgb,
            ..StrandStyle::default()
        };
        let mut scene = StrandScene {
            undeformed: rest.clone(),
            rest,
            guide_count,
            field,
            constraints,
            root_normals,
            frame,
            style,
            distance,
            fov_deg,
            render_size: params.render_size,
            lift_margin: lift_margin(diag),
        };
        scene.undeformed = scene.deform(&vec![[0.0; 3]; scene.field.sample_count()])?.0;
        Ok(scene)
    }

    /// The camera at polar `ψ` / azimuth `δ` (degrees) on the shell.
    pub fn camera(&self, polar_deg: f32, azimuth_deg: f32) -> Result<SplatCamera, PipelineError> {
        self.camera_at(self.frame.direction(polar_deg, azimuth_deg), self.render_size)
    }

    /// The front camera (ψ = δ = 0) at `size²` pixels, for previews.
    pub fn front_camera(&self, size: usize) -> Result<SplatCamera, PipelineError> {
        self.camera_at(self.frame.front, size)
    }

    fn camera_at(&self, dir: [f32; 3], size: usize) -> Result<SplatCamera, PipelineError> {
        let eye = add(self.frame.centre, scale(dir, self.distance));
        Ok(SplatCamera::look_at(eye, self.frame.centre, self.frame.up, self.fov_deg, size, size)?)
    }

    /// Transport by `v` (eq. 5) with the roots pinned, then length
    /// preservation and collision projection (Sec. 3.4, see [`enforce`]).
    pub fn deform(&self, v: &[[f32; 3]]) -> Result<(FlatStrands, CollisionStats), PipelineError> {
        let mut s = self.transport(v)?;
        let stats = self.constrain(&mut s)?;
        Ok((s, stats))
    }

    /// The transport half of [`StrandScene::deform`]: eq. 5 with the roots
    /// pinned to the rest roots.
    pub fn transport(&self, v: &[[f32; 3]]) -> Result<FlatStrands, PipelineError> {
        let mut s = self.rest.with_points(self.field.forward(v)?)?;
        // Roots stay attached to the scalp.
        for &o in &self.rest.offsets[..self.rest.strand_count()] {
            s.points[o] = self.rest.points[o];
        }
        Ok(s)
    }

    /// Backward of [`StrandScene::transport`]: the gradient at every
    /// transported point to the velocities `v`. The pinned roots pass
    /// nothing back, so their entries of `grad_points` are zeroed first.
    pub fn transport_backward(&self, mut grad_points: Vec<[f32; 3]>) -> Result<Vec<[f32; 3]>, PipelineError> {
        for &o in &self.rest.offsets[..self.rest.strand_count()] {
            if let Some(g) = grad_points.get_mut(o) {
                *g = [0.0; 3];
            }
        }
        Ok(self.field.backward(&grad_points)?)
    }

    /// The constraint half of [`StrandScene::deform`] (see [`enforce`]), in
    /// place; returns the first pass's collision statistics.
    pub fn constrain(&self, s: &mut FlatStrands) -> Result<CollisionStats, PipelineError> {
        self.constrain_recorded(s, &mut ConstraintTape::off())
    }

    /// [`StrandScene::constrain`], recording every projection on `tape` so
    /// [`ConstraintTape::backward`] can carry the style gradient back to the
    /// transported points (see [`crate::constraints`] for why it must).
    pub fn constrain_recorded(
        &self,
        s: &mut FlatStrands,
        tape: &mut ConstraintTape,
    ) -> Result<CollisionStats, PipelineError> {
        enforce(s, &self.constraints, CONSTRAINT_PASSES, tape)
    }

    fn strands<'a>(&'a self, s: &'a FlatStrands) -> Strands<'a> {
        Strands { points: &s.points, offsets: &s.offsets, colors: None, root_normals: Some(&self.root_normals) }
    }

    /// Grey render (three equal channels in `[0, 1]`) of `strands` (same
    /// layout as [`StrandScene::rest`]) through `cam`. The strand width is
    /// scaled with the image so previews at another size look the same.
    pub fn render(&self, strands: &FlatStrands, cam: &SplatCamera) -> Result<Image, PipelineError> {
        let style = StrandStyle { width: self.style.width * self.render_size as f32 / cam.height as f32, ..self.style };
        Ok(render(&self.strands(strands), cam, &style)?.0)
    }
}

/// Constraint passes per iteration (see [`enforce`]).
pub const CONSTRAINT_PASSES: usize = 8;

/// [`enforce`] stops its extra passes once every segment is within this
/// relative error of its rest length.
pub const SEGMENT_TOLERANCE: f32 = 1e-3;

/// Tightened collision threshold of [`enforce`]'s extra hard passes, as a
/// fraction of the preset's `τ`.
pub const HARD_TAU_FRACTION: f32 = 0.02;

/// Sec. 3.4's constraints, then alternating hard passes until both hold.
///
/// The first pass is the paper's: length preservation, then the collision
/// projection with threshold `τ` and stiffness `κ` (eq. 12). Its push shows
/// up as stretch wherever a strand lies along the scalp, so further passes
/// alternate length preservation with a *hard* collision projection (only
/// points inside move, onto a shell `10⁻⁴` of the mesh diagonal outside,
/// `κ = 1`), as position-based dynamics alternates its projections, until
/// no point is inside and every segment is within 0.1 % of its rest length,
/// or `passes` run out. A collision pass is always last, so no control point
/// is left inside the mesh; the `τ` repulsion is not repeated, since repeated
/// it would fight length preservation forever on strands lying on the skin.
/// Returns the first pass's statistics (what the deformation caused).
fn enforce(
    s: &mut FlatStrands,
    c: &Constraints,
    passes: usize,
    tape: &mut ConstraintTape,
) -> Result<CollisionStats, PipelineError> {
    let first = c.apply_recorded(s, tape)?;
    let Some(bvh) = &c.collider else { return Ok(first) };
    let hard =
        CollisionParams { tau: c.collision.tau * HARD_TAU_FRACTION, kappa: 1.0, skip_roots: c.collision.skip_roots };
    for _ in 1..passes {
        if max_segment_error(s, &c.rest) < SEGMENT_TOLERANCE {
            break;
        }
        tape.preserve_lengths(s, &c.rest)?;
        tape.project_collisions(s, bvh, hard)?;
    }
    Ok(first)
}

/// Largest relative segment-length error of `s` against `rest`.
fn max_segment_error(s: &FlatStrands, rest: &FlatStrands) -> f32 {
    s.segment_lengths()
        .iter()
        .zip(rest.segment_lengths())
        .map(|(a, b)| ((a - b) / b.max(1e-30)).abs())
        .fold(0.0, f32::max)
}

impl StrandScene {
    /// The stylization of the guides `deformed` (layout of the rest guides,
    /// the leading strands of [`StrandScene::rest`]) carried back to the
    /// groom's own control points `input`, so the written groom has the
    /// input's topology (strand count and points per strand) and can replace
    /// it in the artist's scene.
    ///
    /// The optimization runs on splines re-sampled to the preset's point
    /// count; every input control point lies on its strand's spline, so it
    /// takes the displacement of the closest point of its rest guide polyline
    /// (interpolated along the segment), and the result goes through the
    /// same constraints as an iterate, with the input's own segment lengths.
    pub fn to_input_topology(&self, input: &FlatStrands, deformed: &FlatStrands) -> Result<FlatStrands, PipelineError> {
        let g = self.guide_count;
        if input.strand_count() != g || deformed.strand_count() != g || deformed.offsets[..] != self.rest.offsets[..=g]
        {
            return Err(PipelineError::Parameter(format!(
                "output topology: {} input strands and {} stylized guides for a scene of {g} guides",
                input.strand_count(),
                deformed.strand_count()
            )));
        }
        let mut out = input.clone();
        // Roots under the scalp come out as in the rest groom.
        if let Some(bvh) = &self.constraints.collider {
            lift_roots(&mut out, bvh, self.lift_margin);
        }
        let lifted = out.clone();
        for k in 0..g {
            let (rest, def) = (self.rest.strand(k), deformed.strand(k));
            for p in &mut out.points[input.range(k)] {
                let (seg, t) = closest_on_polyline(rest, *p);
                let j = (seg + 1).min(rest.len() - 1);
                let d0 = sub(def[seg], rest[seg]);
                let d1 = sub(def[j], rest[j]);
                *p = add(*p, add(scale(d0, 1.0 - t), scale(d1, t)));
            }
            // The root stays where the input has it (on the scalp).
            out.points[input.offsets[k]] = lifted.points[input.offsets[k]];
        }
        let c = Constraints {
            rest: lifted,
            collider: self.constraints.collider.clone(),
            collision: self.constraints.collision,
        };
        enforce(&mut out, &c, 200, &mut ConstraintTape::off())?;
        Ok(out)
    }
}

/// Segment index and parameter `t ∈ [0, 1]` of the point of polyline `pts`
/// closest to `p`.
fn closest_on_polyline(pts: &[V3], p: V3) -> (usize, f32) {
    if pts.len() < 2 {
        return (0, 0.0);
    }
    let mut best = (f32::INFINITY, 0, 0.0);
    for (i, w) in pts.windows(2).enumerate() {
        let e = sub(w[1], w[0]);
        let ee = dot(e, e);
        let t = if ee > 0.0 { (dot(sub(p, w[0]), e) / ee).clamp(0.0, 1.0) } else { 0.0 };
        let q = add(w[0], scale(e, t));
        let d = norm(sub(p, q));
        if d < best.0 {
            best = (d, i, t);
        }
    }
    (best.1, best.2)
}

/// The undeformed groom `x₀` the stylization starts from: real grooms do not
/// fit their heads exactly (a tenth of the Bangs groom's control points lie
/// up to 15 units inside its head, some roots 1.7 units under the scalp), so
/// strands whose root is inside are first moved out along the root's normal,
/// rigidly, and then lengths and collisions are enforced in turn until the
/// groom is outside the mesh with its segment lengths kept to 0.1 %. Without
/// this the first iteration's collision pass would move the groom away from
/// the render the targets were matched on.
fn resolve_rest(
    raw: &FlatStrands,
    bvh: &MeshBvh,
    collision: CollisionParams,
    diag: f32,
) -> Result<FlatStrands, PipelineError> {
    let mut s = raw.clone();
    lift_roots(&mut s, bvh, lift_margin(diag));
    let c = Constraints { rest: raw.clone(), collider: Some(bvh.clone()), collision };
    enforce(&mut s, &c, 200, &mut ConstraintTape::off())?;
    Ok(s)
}

/// Margin of [`lift_roots`] for a mesh of bounding-box diagonal `diag`.
fn lift_margin(diag: f32) -> f32 {
    1e-4 * diag
}

/// Moves every strand whose root is inside the mesh rigidly out along the
/// root's normal, to `margin` outside (see [`resolve_rest`]).
fn lift_roots(s: &mut FlatStrands, bvh: &MeshBvh, margin: f32) {
    for k in 0..s.strand_count() {
        let r = s.range(k);
        let hit = bvh.closest_point(s.points[r.start]);
        if hit.signed_distance < 0.0 {
            let push = scale(hit.normal, -hit.signed_distance + margin);
            for p in &mut s.points[r] {
                *p = add(*p, push);
            }
        }
    }
}

/// Centre, radius and front/up axes (see the module notes).
fn view_frame(rest: &FlatStrands, guide_normals: &[V3], head: &TriMesh) -> Result<ViewFrame, PipelineError> {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in &rest.points {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    let centre: V3 = std::array::from_fn(|a| 0.5 * (lo[a] + hi[a]));
    let radius = rest.points.iter().map(|&p| norm(sub(p, centre))).fold(0.0f32, f32::max);
    if !(radius > 0.0 && radius.is_finite()) {
        return Err(StrandError::Invalid("the groom has no extent (all points coincide)".into()).into());
    }
    let mut mean = [0.0f64; 3];
    for n in guide_normals {
        for a in 0..3 {
            mean[a] += n[a] as f64;
        }
    }
    let mean: V3 = mean.map(|c| (c / guide_normals.len().max(1) as f64) as f32);
    let head_centre = head.bbox().map(|(l, h)| std::array::from_fn(|a| 0.5 * (l[a] + h[a]))).unwrap_or(centre);
    let front = if norm(mean) > 0.2 { normalize(mean) } else { None }
        .or_else(|| {
            let d = sub(centre, head_centre);
            if norm(d) > 0.05 * radius {
                normalize(d)
            } else {
                None
            }
        })
        .unwrap_or([0.0, 0.0, 1.0]);
    let world_up = if dot(front, [0.0, 1.0, 0.0]).abs() < 0.95 { [0.0, 1.0, 0.0] } else { [0.0, 0.0, 1.0] };
    let up = normalize(sub(world_up, scale(front, dot(world_up, front)))).unwrap_or([0.0, 1.0, 0.0]);
    let side = cross(front, up);
    Ok(ViewFrame { centre, radius, front, up, side })
}

/// `n` view angles `(ψ, δ)` in degrees within the ranges, by best-candidate
/// sampling on the sphere (see the module notes); deterministic in `seed`.
pub fn poisson_view_angles(
    frame: &ViewFrame,
    polar_deg: (f32, f32),
    azimuth_deg: (f32, f32),
    n: usize,
    seed: u64,
) -> Vec<(f32, f32)> {
    const CANDIDATES: usize = 16;
    let mut rng = strand_rng(seed ^ 0x5EED_CA3E_0000_0001);
    let mut out: Vec<(f32, f32)> = Vec::with_capacity(n);
    let mut dirs: Vec<V3> = Vec::with_capacity(n);
    let lerp = |r: (f32, f32), u: f32| r.0 + (r.1 - r.0) * u;
    for _ in 0..n {
        let mut best = (f32::NEG_INFINITY, (0.0, 0.0), [0.0; 3]);
        for _ in 0..if out.is_empty() { 1 } else { CANDIDATES } {
            // Uniform in solid angle over the polar band: sin ψ uniform.
            let (s0, s1) = (polar_deg.0.to_radians().sin(), polar_deg.1.to_radians().sin());
            let psi = (s0 + (s1 - s0) * rng.uniform_f32()).clamp(-1.0, 1.0).asin().to_degrees();
            let delta = lerp(azimuth_deg, rng.uniform_f32());
            let d = frame.direction(psi, delta);
            let gap = dirs.iter().map(|&e| dot(d, e).clamp(-1.0, 1.0).acos()).fold(f32::INFINITY, f32::min);
            if gap > best.0 {
                best = (gap, (psi, delta), d);
            }
        }
        out.push(best.1);
        dirs.push(best.2);
    }
    out
}

/// What one optimization iteration reports.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IterationReport {
    /// Scale index (0-based).
    pub scale: usize,
    /// Iteration within the scale (1-based).
    pub iteration: u32,
    /// Iterations of this scale.
    pub iterations: u32,
    /// NNST loss of this iteration's view.
    pub loss: f32,
    /// Control points the collision pass found inside the mesh.
    pub inside: usize,
}

/// Result of [`stylize`].
#[derive(Clone, Debug)]
pub struct StylizeResult {
    /// Stylized guides (the groom to write), same layout as the rest guides.
    pub guides: FlatStrands,
    /// Stylized proxies (empty when none were grown).
    pub proxies: FlatStrands,
    /// Final strands, guides then proxies (layout of [`StrandScene::rest`]).
    pub strands: FlatStrands,
    /// Optimized velocities at the field's samples.
    pub velocities: Vec<[f32; 3]>,
    /// Loss of every iteration, in order.
    pub loss_history: Vec<f32>,
    /// Mean NNST loss of the rest groom over the evaluation views.
    pub eval_before: f32,
    /// Mean loss of the stylized groom against the same targets (the
    /// optimized objective).
    pub eval_after: f32,
    /// Mean NNST loss of the stylized groom re-matched on its own renders.
    pub eval_after_rematched: f32,
    /// Evaluation view angles `(ψ, δ)`, degrees.
    pub eval_angles: Vec<(f32, f32)>,
}

impl StylizeResult {
    /// Relative drop of the evaluation loss, `1 − after / before`.
    pub fn loss_drop(&self) -> f32 {
        1.0 - self.eval_after / self.eval_before
    }
}

/// Style targets of one scale: `style` (RGB in `[0, 1]`) as grey, resized
/// to `height` rows, as NNST hyper-columns of its VGG taps.
pub fn style_target(vgg: &Vgg19, style: &Image, height: usize) -> Result<NnstTarget, PipelineError> {
    let img = nst3d_io::image::resize_to_height(&luminance3(style), height);
    let feats = vgg.forward(&img, &NNST_LAYERS, false);
    Ok(NnstTarget::from_style_features(feats.taps(), &NnstParams::default())?)
}

/// Targets of one view (eq. 2): VGG taps of the undeformed render matched
/// to the style; also returns the undeformed groom's loss against them.
pub fn match_view(
    scene: &StrandScene,
    vgg: &Vgg19,
    style: &NnstTarget,
    cam: &SplatCamera,
) -> Result<(NnstMatch, f32), PipelineError> {
    let img = scene.render(&scene.undeformed, cam)?;
    let feats = vgg.forward(&img, &NNST_LAYERS, false);
    let m = style.match_content(feats.taps())?;
    let (loss, _) = nnst_loss_matched(feats.taps(), &m)?;
    Ok((m, loss))
}

/// AdamW's learning rate at scale `l`: the preset's `η` times
/// [`StylizeParams::lr_scale`], in units of the groom radius (module notes).
pub fn scale_learning_rate(scene: &StrandScene, params: &StylizeParams, l: usize) -> f32 {
    params.preset.learning_rates[l] * params.lr_scale * scene.frame.radius
}

/// Wall time of each stage of one [`iteration`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StageTimes {
    /// Eq. 5: `p + W v`, roots pinned.
    pub transport: Duration,
    /// Length preservation and collision projection ([`StrandScene::constrain`]).
    pub constraints: Duration,
    /// Splat render (projection, binning, compositing).
    pub render: Duration,
    /// VGG-19 forward to relu4_1, keeping what the backward needs.
    pub vgg_forward: Duration,
    /// NNST loss against the cached targets and its gradient at the taps.
    pub loss: Duration,
    /// VGG-19 backward to the image.
    pub vgg_backward: Duration,
    /// Splat backward to the control points.
    pub splat_backward: Duration,
    /// Back through the constraint projections to the transported points.
    pub constraints_backward: Duration,
    /// `Wᵀ`: point gradients to the velocities (pinned roots dropped).
    pub field_backward: Duration,
    /// The AdamW step.
    pub optimizer: Duration,
}

impl StageTimes {
    /// The stages' names and times, in pipeline order.
    pub fn stages(&self) -> [(&'static str, Duration); 10] {
        [
            ("transport", self.transport),
            ("constraints", self.constraints),
            ("render", self.render),
            ("vgg_forward", self.vgg_forward),
            ("nnst_loss", self.loss),
            ("vgg_backward", self.vgg_backward),
            ("splat_backward", self.splat_backward),
            ("constraints_backward", self.constraints_backward),
            ("field_backward", self.field_backward),
            ("adamw", self.optimizer),
        ]
    }

    /// Sum of the stages.
    pub fn total(&self) -> Duration {
        self.stages().iter().map(|s| s.1).sum()
    }
}

/// What one [`iteration`] did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepReport {
    /// NNST loss of the view before the step.
    pub loss: f32,
    /// The constraints' first collision pass on this iterate.
    pub stats: CollisionStats,
    /// Where the time went.
    pub times: StageTimes,
}

/// One optimization step of Alg. 1 on a view whose targets are already
/// matched: deform by `v` (flat `3 × samples`), render through `cam`, VGG-19,
/// NNST loss against `matched`, the chain backward to `v`, and one `adam`
/// step. A non-finite loss leaves `v` untouched and is an error.
/// [`stylize`] runs exactly this per iteration; the `strands-iter`
/// benchmark times it.
pub fn iteration(
    scene: &StrandScene,
    vgg: &Vgg19,
    cam: &SplatCamera,
    matched: &NnstMatch,
    v: &mut [f32],
    adam: &mut Adam,
) -> Result<StepReport, PipelineError> {
    let (mut report, grad) = loss_and_gradient(scene, vgg, cam, matched, v)?;
    let clock = Instant::now();
    adam.step(v, &grad);
    report.times.optimizer = clock.elapsed();
    Ok(report)
}

/// The forward and backward of one [`iteration`] without the optimizer
/// step: the view's NNST loss at `v` and its gradient with respect to `v`
/// (flat, like `v`). `report.times.optimizer` is zero. The `strands-iter`
/// benchmark's dump hands this gradient to the PyTorch peer, whose autograd
/// checks it.
pub fn loss_and_gradient(
    scene: &StrandScene,
    vgg: &Vgg19,
    cam: &SplatCamera,
    matched: &NnstMatch,
    v: &[f32],
) -> Result<(StepReport, Vec<f32>), PipelineError> {
    let mut times = StageTimes::default();
    let mut clock = Instant::now();
    let mut lap = |slot: &mut Duration| {
        let now = Instant::now();
        *slot = now - clock;
        clock = now;
    };
    let mut strands = scene.transport(&unflatten(v))?;
    lap(&mut times.transport);
    let mut tape = ConstraintTape::default();
    let stats = scene.constrain_recorded(&mut strands, &mut tape)?;
    lap(&mut times.constraints);
    let s = scene.strands(&strands);
    let (img, cache) = render(&s, cam, &scene.style)?;
    lap(&mut times.render);
    let fwd = vgg.forward(&img, &NNST_LAYERS, true);
    lap(&mut times.vgg_forward);
    let (loss, tap_grads) = nnst_loss_matched(fwd.taps(), matched)?;
    lap(&mut times.loss);
    if !loss.is_finite() {
        return Err(PipelineError::Diverged(format!("loss is {loss}")));
    }
    let grad_img = vgg.backward(&fwd, &tap_grads);
    drop(fwd);
    lap(&mut times.vgg_backward);
    let grad_points = render_backward(&s, cam, &scene.style, &cache, &grad_img)?;
    lap(&mut times.splat_backward);
    let grad_points = tape.backward(&scene.constraints.rest, &grad_points)?;
    lap(&mut times.constraints_backward);
    let grad = flatten(&scene.transport_backward(grad_points)?);
    lap(&mut times.field_backward);
    Ok((StepReport { loss, stats, times }, grad))
}

/// Stylizes the scene's groom with `style` (RGB in `[0, 1]`; its luminance
/// is matched) through `vgg`, reporting every iteration to `progress`.
pub fn stylize(
    scene: &StrandScene,
    style: &Image,
    vgg: &Vgg19,
    params: &StylizeParams,
    progress: &mut dyn FnMut(&IterationReport),
) -> Result<StylizeResult, PipelineError> {
    stylize_with(scene, style, vgg, params, FrameHooks::default(), progress)
}

/// Where an iteration of [`stylize_with`] stands, before it runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct IterationClock {
    /// Scale index (0-based).
    pub scale: usize,
    /// Iteration within the scale (0-based).
    pub iteration: u32,
    /// Iterations of this scale.
    pub iterations: u32,
    /// Iterations of the whole frame already run (0-based index of this one).
    pub done: u32,
    /// Iterations of the whole frame.
    pub total: u32,
}

/// What an animated sequence adds to one frame's optimization (Alg. 1 lines
/// 5 and 7); the default is the static case.
#[derive(Default)]
pub struct FrameHooks<'a> {
    /// Velocities `v_t` at the field's samples to start from instead of
    /// zero (Alg. 1 line 5 starts from zero).
    pub initial: Option<&'a [[f32; 3]]>,
    /// Called before every iteration's transport with `v_t`, which it may
    /// change in place: the EMA of eq. 8 towards the previous frame's field.
    #[allow(clippy::type_complexity)]
    pub before_iteration: Option<&'a mut dyn FnMut(IterationClock, &mut [[f32; 3]]) -> Result<(), PipelineError>>,
}

/// [`stylize`] with a sequence's per-frame [`FrameHooks`].
pub fn stylize_with(
    scene: &StrandScene,
    style: &Image,
    vgg: &Vgg19,
    params: &StylizeParams,
    mut hooks: FrameHooks<'_>,
    progress: &mut dyn FnMut(&IterationReport),
) -> Result<StylizeResult, PipelineError> {
    params.validate()?;
    if style.channels != 3 || style.height < 16 || style.width < 16 {
        return Err(PipelineError::Parameter(format!(
            "style image is {}x{}x{}, need 3 channels and at least 16x16",
            style.channels, style.height, style.width
        )));
    }
    let p = params.preset;
    vgg.prepare(VggLayer::Relu4_1);

    let n = scene.field.sample_count();
    let mut v = match hooks.initial {
        Some(v0) if v0.len() != n => {
            return Err(StrandError::Mismatch { what: "initial velocities", expected: n, got: v0.len() }.into())
        }
        Some(v0) => flatten(v0),
        None => vec![0.0f32; 3 * n],
    };
    let (mut done, total) = (0u32, params.iterations.iter().sum::<u32>());
    let mut adam = Adam::adamw(3 * n, 0.0, params.weight_decay);
    let mut history = Vec::new();

    // Camera angles for all scales from one Poisson sequence, so the
    // scales see different views.
    let per_scale: Vec<usize> = params
        .iterations
        .iter()
        .map(|&it| if params.views_per_scale == 0 { it as usize } else { params.views_per_scale.min(it as usize) })
        .collect();
    let angles = poisson_view_angles(&scene.frame, p.polar_deg, p.azimuth_deg, per_scale.iter().sum(), params.seed);
    let mut first = 0;
    let mut finest = None;
    for (l, &iters) in params.iterations.iter().enumerate() {
        let views = &angles[first..first + per_scale[l]];
        first += per_scale[l];
        let sstyle = style_target(vgg, style, params.style_height(l))?;
        if iters > 0 {
            adam.lr = scale_learning_rate(scene, params, l);
            let mut cache: HashMap<usize, (SplatCamera, NnstMatch)> = HashMap::new();
            for m in 0..iters {
                let k = m as usize % views.len();
                if !cache.contains_key(&k) {
                    let cam = scene.camera(views[k].0, views[k].1)?;
                    let (matched, _) = match_view(scene, vgg, &sstyle, &cam)?;
                    cache.insert(k, (cam, matched));
                }
                let (cam, matched) = &cache[&k];
                if let Some(hook) = hooks.before_iteration.as_mut() {
                    let mut vv = unflatten(&v);
                    hook(IterationClock { scale: l, iteration: m, iterations: iters, done, total }, &mut vv)?;
                    v = flatten(&vv);
                }
                done += 1;
                let step = iteration(scene, vgg, cam, matched, &mut v, &mut adam).map_err(|e| match e {
                    PipelineError::Diverged(why) => {
                        PipelineError::Diverged(format!("{why} at scale {} iteration {}", l + 1, m + 1))
                    }
                    e => e,
                })?;
                history.push(step.loss);
                progress(&IterationReport {
                    scale: l,
                    iteration: m + 1,
                    iterations: iters,
                    loss: step.loss,
                    inside: step.stats.inside,
                });
            }
        }
        finest = Some(sstyle);
    }
    let finest = finest.expect("three scales");

    let (strands, _) = scene.deform(&unflatten(&v))?;
    if strands.points.iter().any(|p| p.iter().any(|c| !c.is_finite())) {
        return Err(PipelineError::Diverged("non-finite control points".into()));
    }
    // The finest scale's cached views are the optimized views; with a fresh
    // camera per iteration, a fixed set drawn from the same distribution.
    let eval_angles = if params.views_per_scale > 0 && params.iterations[2] > 0 {
        angles[angles.len() - per_scale[2]..].to_vec()
    } else {
        poisson_view_angles(&scene.frame, p.polar_deg, p.azimuth_deg, params.eval_views, params.seed ^ 0xE7A1)
    };
    let (mut before, mut after, mut rematched) = (0.0f64, 0.0f64, 0.0f64);
    for &(psi, delta) in &eval_angles {
        let cam = scene.camera(psi, delta)?;
        let (matched, l0) = match_view(scene, vgg, &finest, &cam)?;
        let img = scene.render(&strands, &cam)?;
        let feats = vgg.forward(&img, &NNST_LAYERS, false);
        before += l0 as f64;
        after += nnst_loss_matched(feats.taps(), &matched)?.0 as f64;
        rematched += nnst_loss(feats.taps(), &finest)?.0 as f64;
    }
    let k = eval_angles.len() as f64;
    let g = scene.guide_count;
    let split = strands.offsets[g];
    let guides = FlatStrands { points: strands.points[..split].to_vec(), offsets: strands.offsets[..=g].to_vec() };
    let proxies = FlatStrands {
        points: strands.points[split..].to_vec(),
        offsets: strands.offsets[g..].iter().map(|o| o - split).collect(),
    };
    Ok(StylizeResult {
        guides,
        proxies,
        strands,
        velocities: unflatten(&v),
        loss_history: history,
        eval_before: (before / k) as f32,
        eval_after: (after / k) as f32,
        eval_after_rematched: (rematched / k) as f32,
        eval_angles,
    })
}

/// Rec. 601 luminance in three channels (the painting as grey strands can
/// reach it).
fn luminance3(img: &Image) -> Image {
    let p = img.plane();
    let grey: Vec<f32> =
        (0..p).map(|i| 0.299 * img.data[i] + 0.587 * img.data[p + i] + 0.114 * img.data[2 * p + i]).collect();
    Image::from_vec(3, img.height, img.width, [grey.as_slice(); 3].concat())
}

fn unflatten(v: &[f32]) -> Vec<[f32; 3]> {
    v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
}

fn flatten(v: &[[f32; 3]]) -> Vec<f32> {
    v.iter().flatten().copied().collect()
}

/// Largest relative change of a strand's length (polyline through its
/// control points) between `a` and `b`, same layout.
pub fn max_length_change(a: &FlatStrands, b: &FlatStrands) -> f32 {
    (0..a.strand_count().min(b.strand_count()))
        .map(|s| {
            let la = polyline_length(a.strand(s));
            let lb = polyline_length(b.strand(s));
            ((lb - la) / la.max(1e-30)).abs() as f32
        })
        .fold(0.0, f32::max)
}

/// Length of a polyline.
pub fn polyline_length(pts: &[[f32; 3]]) -> f64 {
    pts.windows(2).map(|w| norm(sub(w[1], w[0])) as f64).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame() -> ViewFrame {
        ViewFrame { centre: [0.0; 3], radius: 1.0, front: [0.0, 0.0, 1.0], up: [0.0, 1.0, 0.0], side: [-1.0, 0.0, 0.0] }
    }

    #[test]
    fn view_angles_are_deterministic_in_range_and_spread() {
        let f = frame();
        let a = poisson_view_angles(&f, (-10.0, 10.0), (-20.0, 20.0), 16, 3);
        assert_eq!(a, poisson_view_angles(&f, (-10.0, 10.0), (-20.0, 20.0), 16, 3));
        assert_ne!(a, poisson_view_angles(&f, (-10.0, 10.0), (-20.0, 20.0), 16, 4));
        assert!(a.iter().all(|&(p, d)| (-10.0..=10.0).contains(&p) && (-20.0..=20.0).contains(&d)));
        // Best-candidate spreading: no two of the first 8 views closer than
        // a quarter of the spacing a regular 8-point grid would have.
        let dirs: Vec<V3> = a[..8].iter().map(|&(p, d)| f.direction(p, d)).collect();
        let min_gap = (0..8)
            .flat_map(|i| (0..i).map(move |j| (i, j)))
            .map(|(i, j)| dot(dirs[i], dirs[j]).clamp(-1.0, 1.0).acos().to_degrees())
            .fold(f32::INFINITY, f32::min);
        let grid_gap = (20.0f32 * 40.0 / 8.0).sqrt();
        assert!(min_gap > 0.25 * grid_gap, "min gap {min_gap} deg");
    }

    #[test]
    fn direction_axes() {
        let f = frame();
        let close = |a: V3, b: V3| (0..3).all(|k| (a[k] - b[k]).abs() < 1e-6);
        assert!(close(f.direction(0.0, 0.0), f.front));
        assert!(close(f.direction(90.0, 0.0), f.up));
        assert!(close(f.direction(0.0, 90.0), f.side));
    }
}
