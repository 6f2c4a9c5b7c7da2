//! Everything fixed during one stylization ([`StrandScene`]: setup as in the
//! module notes of [`crate::pipeline`]) and the deformation the optimizer
//! drives: transport by the velocities, then the constraints of Sec. 3.4,
//! each with its backward.
//!
//! By job: this module builds the scene and drives the deformation;
//! [`fit`] fits the rest groom outside the head before anything starts,
//! [`topology`] carries the stylized guides (and colours) back to the
//! groom's own points for writing, and [`view`] draws a groom file from the
//! stylization's cameras without a scene (previews).

use std::sync::OnceLock;

use nst3d_core::groom::{Groom, StrandSpline};
use nst3d_core::math::{norm, normalize, sub, V3};
use nst3d_core::mesh::TriMesh;
use nst3d_core::Image;
use nst3d_splat::{render, SplatCamera, SplatOutput, StrandStyle, Strands};

use crate::bvh::MeshBvh;
use crate::color::{initial_colors, StrandColorLayer};
use crate::constraints::{CollisionParams, CollisionStats, ConstraintTape, Constraints, EnforceParams};
use crate::densify::{densify_weighted, DensifyParams, ProxyBlend};
use crate::field::DeformationField;
use crate::strands::FlatStrands;
use crate::StrandError;

use super::views::{view_frame, ViewFrame};
use super::{PipelineError, StylizeParams};

mod fit;
mod topology;
mod view;

use fit::{lift_margin, points_bbox, resolve_rest};
pub use topology::{max_length_change, polyline_length, ColorCarry};
pub use view::GroomView;

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
    /// The guides as re-sampled from the input, before [`resolve_rest`]
    /// fitted them outside the mesh: the output is the input plus the
    /// displacement from these ([`StrandScene::to_input_topology`]).
    pub raw_guides: FlatStrands,
    /// The groom's own control points (its topology, before re-sampling):
    /// what the written file holds ([`StrandScene::to_input_topology`]).
    pub input: FlatStrands,
    /// The field of eq. 5 on the guides, acting on every rest point.
    pub field: DeformationField,
    /// Length preservation and collision against the head.
    pub constraints: Constraints,
    /// Head normal at every strand root, for visibility culling; `None`
    /// for a groom without a mesh (every strand is drawn).
    pub root_normals: Option<Vec<[f32; 3]>>,
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
    /// The colours of the rendered points from the colour offsets,
    /// starting at the input's colours; built on first use
    /// ([`StrandScene::color_layer`]).
    color_layer: OnceLock<StrandColorLayer>,
    /// What the colour layer is built from: each proxy's guide blend and the
    /// guides' starting colours.
    color_inputs: (Vec<ProxyBlend>, Vec<[f32; 3]>),
}

impl StrandScene {
    /// Builds guides, proxies, field, constraints and view frame from a
    /// groom and the mesh it grows from. Without a mesh there is no
    /// collision projection and no visibility culling, proxies grow around
    /// the guide roots, and the groom's own box sets the scale.
    pub fn new(groom: &Groom, head: Option<&TriMesh>, params: &StylizeParams) -> Result<Self, PipelineError> {
        Self::build(groom, head, params, &mut |_| {})
    }

    /// [`StrandScene::new`], saying each stage of the set-up to `status`
    /// as it starts (a production groom takes seconds here).
    pub fn build(
        groom: &Groom,
        head: Option<&TriMesh>,
        params: &StylizeParams,
        status: &mut dyn FnMut(&str),
    ) -> Result<Self, PipelineError> {
        params.validate()?;
        let p = params.preset;
        if groom.strands.is_empty() {
            return Err(StrandError::Invalid("the groom has no strands".into()).into());
        }
        let n = p.points_per_strand.max(2);
        status(&format!("re-sampling {} guides to {n} points", groom.strands.len()));
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
        let bvh = head.map(MeshBvh::new).transpose()?;
        let mut raw = guides.clone();
        let mut blends = Vec::new();
        if params.proxies > 0 {
            status(&format!("growing {} proxy strands", params.proxies));
            let dp = DensifyParams {
                count: params.proxies,
                points_per_strand: Some(n),
                seed: params.seed,
                ..Default::default()
            };
            let (proxies, b) = densify_weighted(&guides, head, &dp)?;
            raw.append(&proxies);
            blends = b;
        }
        let (lo, hi) = match head {
            Some(h) => h.bbox().ok_or_else(|| StrandError::Invalid("the head mesh has no vertices".into()))?,
            None => points_bbox(&guides.points),
        };
        let diag = norm(sub(hi, lo));
        let collision = p.collision(diag);
        let rest = match &bvh {
            Some(bvh) => {
                status(&format!("fitting {} control points outside the mesh", raw.points.len()));
                resolve_rest(&raw, bvh, collision, diag)?
            }
            None => raw,
        };
        let guide_count = guides.strand_count();
        let rest_guides = FlatStrands {
            points: rest.points[..rest.offsets[guide_count]].to_vec(),
            offsets: rest.offsets[..=guide_count].to_vec(),
        };
        status("building the velocity field");
        let field = DeformationField::on_guides(&rest_guides, &rest, p.sample_density(), p.kernel, p.neighbors)?;
        let root_normals: Option<Vec<V3>> =
            bvh.as_ref().map(|bvh| rest.roots().iter().map(|&r| bvh.closest_point(r).normal).collect());
        let growth = growth_directions(&rest, guide_count);
        let frame = view_frame(&rest, root_normals.as_ref().map_or(&growth[..], |n| &n[..guide_count]), head)?;
        let constraints = Constraints { rest: rest.clone(), collider: bvh, collision };

        let (distance, fov_deg, style) = shell(&frame, params);
        let guide_colors = initial_colors(groom, &vec![n; guide_count]);
        let mut scene = StrandScene {
            color_layer: OnceLock::new(),
            color_inputs: (blends, guide_colors),
            undeformed: rest.clone(),
            rest,
            guide_count,
            raw_guides: guides,
            input: FlatStrands::from_groom(groom)?,
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

    /// The colour layer. Built on the first call: its RBF
    /// weights cost as much as the deformation field's (a k-nearest search
    /// for every control point, ~5 s of a Short Hair set-up), and a groom
    /// stylized without `--color` never needs them.
    pub fn color_layer(&self) -> Result<&StrandColorLayer, PipelineError> {
        if let Some(layer) = self.color_layer.get() {
            return Ok(layer);
        }
        let (blends, guide_colors) = &self.color_inputs;
        let layer = StrandColorLayer::new(&self.rest, self.guide_count, blends, guide_colors)?;
        Ok(self.color_layer.get_or_init(|| layer))
    }

    /// Which guides each proxy was blended from, and with what weights
    /// (empty without proxies).
    pub fn proxy_blends(&self) -> &[ProxyBlend] {
        &self.color_inputs.0
    }

    /// `s` for the renderer, in `colors` (one per point; white without).
    pub(super) fn strands<'a>(&'a self, s: &'a FlatStrands, colors: Option<&'a [[f32; 3]]>) -> Strands<'a> {
        Strands { points: &s.points, offsets: &s.offsets, colors, root_normals: self.root_normals.as_deref() }
    }

    /// Grey render (three equal channels in `[0, 1]`) of `strands` (same
    /// layout as [`StrandScene::rest`]) through `cam`. The strand width is
    /// scaled with the image so previews at another size look the same.
    pub fn render(&self, strands: &FlatStrands, cam: &SplatCamera) -> Result<Image, PipelineError> {
        self.render_colored(strands, None, cam)
    }

    /// [`StrandScene::render`] with a colour per point (the layout of
    /// [`StrandColorLayer::forward`]); `None` draws white strands, the grey render.
    pub fn render_colored(
        &self,
        strands: &FlatStrands,
        colors: Option<&[[f32; 3]]>,
        cam: &SplatCamera,
    ) -> Result<Image, PipelineError> {
        let style = StrandStyle { width: self.style.width * self.render_size as f32 / cam.height as f32, ..self.style };
        Ok(render(&self.strands(strands, colors), cam, &style)?.0)
    }
}

/// The camera shell about `frame` for `params`: the eye distance (the
/// preset's multiple of the groom's radius), the field of view that fits the
/// enclosing sphere with a 5 % margin, and the strands' look, their width
/// `params.strand_width_px` pixels at the render size.
pub(super) fn shell(frame: &ViewFrame, params: &StylizeParams) -> (f32, f32, StrandStyle) {
    let p = params.preset;
    let distance = p.camera_distance * frame.radius;
    let half = (1.0 / p.camera_distance).asin() * 1.05;
    let fov_deg = (2.0 * half).to_degrees().min(120.0);
    let pixel = 2.0 * distance * (0.5 * fov_deg.to_radians()).tan() / params.render_size as f32;
    let style = StrandStyle {
        width: params.strand_width_px * pixel,
        visibility_threshold: p.visibility_threshold,
        output: SplatOutput::Rgb,
        ..StrandStyle::default()
    };
    (distance, fov_deg, style)
}

/// Growth direction of every strand (first segment), standing in for the
/// scalp normals when a groom has no mesh.
pub(super) fn growth_directions(s: &FlatStrands, count: usize) -> Vec<V3> {
    (0..count)
        .map(|k| {
            let g = s.strand(k);
            g.get(1).and_then(|&q| normalize(sub(q, g[0]))).unwrap_or([0.0; 3])
        })
        .collect()
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
/// or `passes` run out — strand by strand ([`ConstraintTape::enforce`]), so
/// only the strands on the skin pay for the extra passes. A collision pass is always last, so no control point
/// is left inside the mesh; the `τ` repulsion is not repeated, since repeated
/// it would fight length preservation forever on strands lying on the skin.
/// Returns the first pass's statistics (what the deformation caused).
pub(super) fn enforce(
    s: &mut FlatStrands,
    c: &Constraints,
    passes: usize,
    tape: &mut ConstraintTape,
) -> Result<CollisionStats, PipelineError> {
    let hard =
        CollisionParams { tau: c.collision.tau * HARD_TAU_FRACTION, kappa: 1.0, skip_roots: c.collision.skip_roots };
    Ok(tape.enforce(s, c, EnforceParams { passes, hard, tolerance: SEGMENT_TOLERANCE })?)
}
