//! Everything fixed during one stylization ([`StrandScene`]: setup as in the
//! module notes of [`crate::pipeline`]) and the deformation the optimizer
//! drives: transport by the velocities, then the constraints of Sec. 3.4,
//! each with its backward.

use std::sync::OnceLock;

use nst3d_core::groom::{Groom, StrandSpline};
use nst3d_core::math::{add, cross, dot, norm, normalize, scale, sub, V3};
use nst3d_core::mesh::TriMesh;
use nst3d_core::Image;
use nst3d_splat::{render, SplatCamera, SplatOutput, StrandStyle, Strands};

use crate::bvh::MeshBvh;
use crate::color::{initial_colors, StrandColorLayer};
use crate::constraints::{
    strand_length_error, CollisionParams, CollisionStats, ConstraintTape, Constraints, EnforceParams,
};
use crate::densify::{densify_weighted, DensifyParams, ProxyBlend};
use crate::field::DeformationField;
use crate::strands::FlatStrands;
use crate::StrandError;

use super::views::{view_frame, ViewFrame};
use super::{PipelineError, StylizeParams};

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
fn growth_directions(s: &FlatStrands, count: usize) -> Vec<V3> {
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
fn enforce(
    s: &mut FlatStrands,
    c: &Constraints,
    passes: usize,
    tape: &mut ConstraintTape,
) -> Result<CollisionStats, PipelineError> {
    let hard =
        CollisionParams { tau: c.collision.tau * HARD_TAU_FRACTION, kappa: 1.0, skip_roots: c.collision.skip_roots };
    Ok(tape.enforce(s, c, EnforceParams { passes, hard, tolerance: SEGMENT_TOLERANCE })?)
}

/// How a groom file looks from the stylization's cameras, without setting
/// up a stylization (no proxies, no fitting): `nst3d preview` of a groom.
#[derive(Clone, Debug)]
pub struct GroomView {
    /// The cameras' frame.
    pub frame: ViewFrame,
    /// Eye distance from the centre.
    pub distance: f32,
    /// Vertical field of view, degrees.
    pub fov_deg: f32,
    /// Look of the strands at `render_size`.
    pub style: StrandStyle,
    /// The size `style`'s strand width is given for.
    pub render_size: usize,
    /// Scalp normal at every root (culling), when there is a mesh.
    pub root_normals: Option<Vec<V3>>,
}

impl GroomView {
    /// The view of `strands` (growing from `head`, if given) with the
    /// shell and look `params` would stylize it with.
    pub fn new(strands: &FlatStrands, head: Option<&TriMesh>, params: &StylizeParams) -> Result<Self, PipelineError> {
        let root_normals = match head {
            Some(h) => {
                let bvh = MeshBvh::new(h)?;
                Some(strands.roots().iter().map(|&r| bvh.closest_point(r).normal).collect::<Vec<V3>>())
            }
            None => None,
        };
        let growth = growth_directions(strands, strands.strand_count());
        let frame = view_frame(strands, root_normals.as_deref().unwrap_or(&growth), head)?;
        let (distance, fov_deg, style) = shell(&frame, params);
        Ok(GroomView { frame, distance, fov_deg, style, render_size: params.render_size, root_normals })
    }

    /// Grey render of `strands` (the layout the view was made for, or any
    /// groom when there are no root normals) from polar `ψ` / azimuth `δ`
    /// (degrees) at `size²` pixels; strands keep their width relative to the
    /// picture.
    pub fn render(
        &self,
        strands: &FlatStrands,
        polar_deg: f32,
        azimuth_deg: f32,
        size: usize,
    ) -> Result<Image, PipelineError> {
        self.render_colored(strands, None, polar_deg, azimuth_deg, size)
    }

    /// [`GroomView::render`] in `colors`, one per point of `strands` (a
    /// file's own colours); `None` draws white strands.
    pub fn render_colored(
        &self,
        strands: &FlatStrands,
        colors: Option<&[[f32; 3]]>,
        polar_deg: f32,
        azimuth_deg: f32,
        size: usize,
    ) -> Result<Image, PipelineError> {
        let eye = add(self.frame.centre, scale(self.frame.direction(polar_deg, azimuth_deg), self.distance));
        let cam = SplatCamera::look_at(eye, self.frame.centre, self.frame.up, self.fov_deg, size, size)?;
        let style = StrandStyle { width: self.style.width * self.render_size as f32 / size as f32, ..self.style };
        let normals = self.root_normals.as_deref().filter(|n| n.len() == strands.strand_count());
        let s = Strands { points: &strands.points, offsets: &strands.offsets, colors, root_normals: normals };
        Ok(render(&s, &cam, &style)?.0)
    }
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
        // Each input point moves by the displacement of its place on the
        // re-sampled guide, from the input's shape (before the rest groom
        // was fitted outside the mesh) to the stylized one: the fitting's
        // lifts, pushes and turns reach the output too.
        let carry = |out: &mut FlatStrands, k: usize, f: f32| {
            let (raw, def) = (self.raw_guides.strand(k), deformed.strand(k));
            let r = input.range(k);
            for (p, &q) in out.points[r.clone()].iter_mut().zip(&input.points[r]) {
                let (seg, t) = closest_on_polyline(raw, q);
                let j = (seg + 1).min(raw.len() - 1);
                let d0 = sub(def[seg], raw[seg]);
                let d1 = sub(def[j], raw[j]);
                *p = add(q, scale(add(scale(d0, 1.0 - t), scale(d1, t)), f));
            }
        };
        let mut out = input.clone();
        for k in 0..g {
            carry(&mut out, k, 1.0);
        }
        let c = Constraints {
            rest: input.clone(),
            collider: self.constraints.collider.clone(),
            collision: self.constraints.collision,
        };
        match &self.constraints.collider {
            Some(bvh) => {
                // The projections leave roots alone; one the carried
                // displacement left under the scalp comes out rigidly with
                // its strand first, as in the rest groom: lifted after the
                // fit, the rigid move pushed points the fit had just put
                // outside back under the skin (monkey_straight's strand
                // 4140 was written with 8 inside).
                lift_roots(&mut out, bvh, self.lift_margin);
                fit_outside(&mut out, &c, bvh)?;
                // A strand the stylization pushed through a thin part of the
                // mesh (turning cannot free it), or one whose fit left a
                // point under the skin, keeps a smaller share of its
                // displacement, halved until it fits, rather than leaving
                // stretched or inside: at worst the input fitted outside.
                let inside = |p: &V3| bvh.closest_point_within(*p, 0.0).is_some_and(|h| h.signed_distance < 0.0);
                let mut f = 1.0;
                loop {
                    let stuck: Vec<usize> = (0..g)
                        .filter(|&k| {
                            strand_length_error(out.strand(k), input.strand(k)) > STUCK_LENGTH_ERROR
                                || out.strand(k)[1..].iter().any(inside)
                        })
                        .collect();
                    if stuck.is_empty() {
                        break;
                    }
                    f = if f > 1.0 / 64.0 { 0.5 * f } else { 0.0 };
                    for &k in &stuck {
                        carry(&mut out, k, f);
                    }
                    lift_roots(&mut out, bvh, self.lift_margin);
                    fit_outside(&mut out, &c, bvh)?;
                    if f == 0.0 {
                        break;
                    }
                }
            }
            None => {
                enforce(&mut out, &c, 200, &mut ConstraintTape::off())?;
            }
        }
        Ok(out)
    }

    /// Stylized guide colours (one per re-sampled guide point, the leading
    /// points of [`StrandColorLayer::forward`]) carried to the groom's own
    /// control points `input`, as [`StrandScene::to_input_topology`] carries
    /// the shapes: each input point takes the colour of its place on its rest
    /// guide polyline, interpolated along the segment. One list per strand.
    pub fn colors_to_input_topology(
        &self,
        input: &FlatStrands,
        guide_colors: &[[f32; 3]],
    ) -> Result<Vec<Vec<[f32; 3]>>, PipelineError> {
        if guide_colors.len() != self.raw_guides.points.len() {
            return Err(PipelineError::Parameter(format!(
                "colour topology: {} guide colours for a scene of {} guide points",
                guide_colors.len(),
                self.raw_guides.points.len()
            )));
        }
        let carried = ColorCarry::new(self, input)?.forward(guide_colors);
        Ok((0..input.strand_count()).map(|k| carried[input.range(k)].to_vec()).collect())
    }
}

/// The linear map that carries colours from the re-sampled guides' points
/// to the groom's own control points (layout of the input): each input
/// point takes the colour of its place on its rest guide polyline,
/// interpolated along the segment, as [`StrandScene::to_input_topology`]
/// carries the shapes. Its [`ColorCarry::backward`] is the transpose, so
/// the colour stage can draw the strands as written and take the
/// gradient back to the guides.
#[derive(Clone, Debug)]
pub struct ColorCarry {
    /// Per input point: the two guide points (indices into the guides'
    /// points) and the weight `t` of the second.
    pairs: Vec<(u32, u32, f32)>,
    /// Points of the guides.
    guide_points: usize,
}

impl ColorCarry {
    /// The carry from `scene`'s guides to `input` (the groom's own points,
    /// one strand per guide).
    pub fn new(scene: &StrandScene, input: &FlatStrands) -> Result<Self, PipelineError> {
        let g = scene.guide_count;
        if input.strand_count() != g {
            return Err(PipelineError::Parameter(format!(
                "colour topology: {} input strands for a scene of {g} guides",
                input.strand_count()
            )));
        }
        let mut pairs = Vec::with_capacity(input.points.len());
        for k in 0..g {
            let (raw, r) = (scene.raw_guides.strand(k), scene.raw_guides.range(k));
            for &q in input.strand(k) {
                let (seg, t) = closest_on_polyline(raw, q);
                let j = (seg + 1).min(raw.len() - 1);
                pairs.push(((r.start + seg) as u32, (r.start + j) as u32, t));
            }
        }
        Ok(Self { pairs, guide_points: scene.raw_guides.points.len() })
    }

    /// Colours of the input's points from the guides' `colors` (one per
    /// guide point).
    pub fn forward(&self, colors: &[[f32; 3]]) -> Vec<[f32; 3]> {
        self.pairs
            .iter()
            .map(|&(a, b, t)| {
                let (ca, cb) = (colors[a as usize], colors[b as usize]);
                std::array::from_fn(|ch| ca[ch] + (cb[ch] - ca[ch]) * t)
            })
            .collect()
    }

    /// The transpose of [`ColorCarry::forward`]: a gradient w.r.t. the
    /// input's point colours carried back to the guides' points.
    pub fn backward(&self, grad: &[[f32; 3]]) -> Vec<[f32; 3]> {
        let mut out = vec![[0.0f32; 3]; self.guide_points];
        for (&(a, b, t), gr) in self.pairs.iter().zip(grad) {
            for ch in 0..3 {
                out[a as usize][ch] += (1.0 - t) * gr[ch];
                out[b as usize][ch] += t * gr[ch];
            }
        }
        out
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
    fit_outside(&mut s, &c, bvh)?;
    Ok(s)
}

/// The constraints enforced to convergence on `s` (lengths of `c.rest`,
/// outside `bvh`). A strand the projections could not fit threads through
/// the mesh (in one side of an ear and out of the other, or pushed through
/// a thin part by the stylization): pushing each point to its nearest side
/// stretches it across. Such a strand is first turned rigidly about its
/// root to the nearest pose with the least penetration, then fitted like
/// the others.
fn fit_outside(s: &mut FlatStrands, c: &Constraints, bvh: &MeshBvh) -> Result<(), PipelineError> {
    let mut fitted = s.clone();
    enforce(&mut fitted, c, 200, &mut ConstraintTape::off())?;
    let stuck: Vec<usize> = (0..s.strand_count())
        .filter(|&k| strand_length_error(fitted.strand(k), c.rest.strand(k)) > STUCK_LENGTH_ERROR)
        .collect();
    if stuck.is_empty() {
        *s = fitted;
        return Ok(());
    }
    for &k in &stuck {
        let r = s.range(k);
        turn_out_of_mesh(&mut s.points[r], bvh);
    }
    enforce(s, c, 200, &mut ConstraintTape::off())?;
    Ok(())
}

/// Relative segment-length error above which [`resolve_rest`] turns a
/// strand out of the mesh.
const STUCK_LENGTH_ERROR: f32 = 0.01;

/// Turns the strand `pts` rigidly about its root, by the smallest of a
/// fan of angles (7.5° steps up to 180°, 8 axes perpendicular to the root's
/// normal) that minimises the summed depth of its points inside the mesh.
/// The fan reaches past 90° for a strand grown from a face buried in
/// another part (monkey_straight's strand 4140, rooted on the ear where it
/// sinks into the head): its root is lifted out of the head's side, the
/// strand points back into the head, and only turning it round frees it;
/// up to 90° the best pose was still 0.02 deep and the fit stretched it
/// 8.6 %.
fn turn_out_of_mesh(pts: &mut [V3], bvh: &MeshBvh) {
    let root = pts[0];
    let depth = |q: &[V3]| -> f32 { q.iter().skip(1).map(|&p| (-bvh.signed_distance(p)).max(0.0)).sum() };
    let n = bvh.closest_point(root).normal;
    let helper = if n[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
    let Some(e1) = normalize(cross(n, helper)) else { return };
    let e2 = cross(n, e1);
    let mut best = (depth(pts), pts.to_vec());
    'search: for step in 1..=24 {
        let theta = (7.5 * step as f32).to_radians();
        for a in 0..8 {
            let phi = a as f32 * std::f32::consts::TAU / 8.0;
            let axis = add(scale(e1, phi.cos()), scale(e2, phi.sin()));
            let turned: Vec<V3> = pts.iter().map(|&p| add(root, rotate(sub(p, root), axis, theta))).collect();
            let d = depth(&turned);
            if d < best.0 {
                best = (d, turned);
            }
        }
        if best.0 == 0.0 {
            break 'search;
        }
    }
    pts.copy_from_slice(&best.1);
}

/// `v` rotated by `theta` about the unit `axis` (Rodrigues).
fn rotate(v: V3, axis: V3, theta: f32) -> V3 {
    let (c, s) = (theta.cos(), theta.sin());
    add(add(scale(v, c), scale(cross(axis, v), s)), scale(axis, dot(axis, v) * (1.0 - c)))
}

/// Bounding box of a point set.
fn points_bbox(points: &[V3]) -> (V3, V3) {
    let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for p in points {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    (lo, hi)
}

/// Margin of [`lift_roots`] for a mesh of bounding-box diagonal `diag`.
fn lift_margin(diag: f32) -> f32 {
    1e-4 * diag
}

/// Pushes [`lift_roots`] makes at most per strand.
const LIFT_PASSES: usize = 8;

/// Moves every strand whose root is inside the mesh rigidly out along the
/// root's normal, to `margin` outside (see [`resolve_rest`]), pushing again
/// while the root is still inside: on a mesh of overlapping parts the way
/// out is the nearest surface the root can leave the whole mesh by, and one
/// push along its pseudo-normal can stop short of it near a seam
/// (monkey_curly's strand 16, rooted 0.1 inside where an eye meets the
/// head, was left 0.0013 inside after one push and written so; two push it
/// out). On a single closed surface one push always suffices.
fn lift_roots(s: &mut FlatStrands, bvh: &MeshBvh, margin: f32) {
    for k in 0..s.strand_count() {
        let r = s.range(k);
        for _ in 0..LIFT_PASSES {
            let hit = bvh.closest_point(s.points[r.start]);
            if hit.signed_distance >= 0.0 {
                break;
            }
            let push = scale(hit.normal, -hit.signed_distance + margin);
            for p in &mut s.points[r.clone()] {
                *p = add(*p, push);
            }
        }
    }
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

    /// A root deep in the seam where Suzanne's eye meets the head (the input
    /// root of monkey_curly's strand 16, 0.1 inside) is lifted outside the
    /// whole mesh, by the collider's test and by ray parity; one push along
    /// the pseudo-normal left it 0.0013 inside and the written groom had
    /// it so.
    #[test]
    fn a_root_in_a_seam_of_overlapping_parts_is_lifted_out() {
        let mesh = crate::bvh::tests::data("grooms/monkey_curly_mesh.obj");
        let bvh = MeshBvh::new(&mesh).unwrap();
        let root = [-0.18110968, -0.65078723, 0.4164371];
        assert!(bvh.closest_point(root).signed_distance < -0.05 && bvh.inside_by_ray_parity(root));
        let mut s =
            FlatStrands::from_strands([vec![root, add(root, [0.0, -0.1, 0.1]), add(root, [0.0, -0.2, 0.2])]]).unwrap();
        let before = s.clone();
        let (lo, hi) = mesh.bbox().unwrap();
        let diag = norm(sub(hi, lo));
        lift_roots(&mut s, &bvh, lift_margin(diag));
        let lifted = s.points[0];
        assert!(bvh.closest_point(lifted).signed_distance >= 0.0, "root still inside: {lifted:?}");
        assert!(!bvh.inside_by_ray_parity(lifted), "root inside by ray parity: {lifted:?}");
        // Rigidly: every point moved by the root's displacement.
        let d = sub(lifted, root);
        for (a, b) in s.points.iter().zip(&before.points) {
            assert!(norm(sub(sub(*a, *b), d)) < 1e-6);
        }
    }

    #[test]
    fn a_strand_threading_through_the_mesh_is_turned_out_with_its_length() {
        let sphere = crate::generators::uv_sphere(1.0, 32, 64);
        let bvh = MeshBvh::new(&sphere).unwrap();
        // Rooted on the sphere, entering it at 45° and leaving through the
        // far side of the cap: each point's nearest way out differs.
        let (root, dir) =
            ([1.0f32, 0.0, 0.0], [-std::f32::consts::FRAC_1_SQRT_2, 0.0, std::f32::consts::FRAC_1_SQRT_2]);
        let raw =
            FlatStrands::from_strands([(0..12).map(|k| add(root, scale(dir, 0.15 * k as f32))).collect()]).unwrap();
        assert!(raw.points[1..].iter().any(|&p| bvh.is_inside(p)));
        let collision = CollisionParams { tau: 0.01, kappa: 0.5, skip_roots: true };
        let fitted = resolve_rest(&raw, &bvh, collision, 2.0 * 3f32.sqrt()).unwrap();
        let inside = fitted.points[1..].iter().filter(|&&p| bvh.is_inside(p)).count();
        assert_eq!(inside, 0, "points left inside");
        let change = max_length_change(&raw, &fitted);
        assert!(change < 0.01, "length changed by {change}");
    }

    /// monkey_straight's strand 4140 grows from Suzanne's ear where it
    /// sinks into the head: its root and first point are inside the whole
    /// mesh. Lifted out of the head's side, it points back in; turning it
    /// up to 90° left it 0.02 deep and the fit stretched it 8.6 %, and the
    /// written groom, lifted again after its fit, had 8 points inside. The
    /// rest fit keeps its length with no point inside.
    #[test]
    fn a_strand_grown_from_a_buried_face_is_turned_round() {
        let mesh = crate::bvh::tests::data("grooms/monkey_curly_mesh.obj");
        let bvh = MeshBvh::new(&mesh).unwrap();
        let wn = crate::winding::WindingNumber::new(&mesh.vertices, &mesh.triangles);
        let (lo, hi) = mesh.bbox().unwrap();
        let diag = norm(sub(hi, lo));
        let raw = FlatStrands::from_strands([vec![
            [0.871285439, 0.326230258, 0.127717257],
            [0.853215098, 0.350033998, 0.14729321],
            [0.829127431, 0.38727501, 0.167325288],
            [0.803541183, 0.43222484, 0.182709873],
            [0.77819562, 0.481632352, 0.193571836],
            [0.751199365, 0.538507342, 0.202306166],
            [0.71989578, 0.607746363, 0.210016042],
            [0.686623514, 0.684837282, 0.214677855],
            [0.653997719, 0.764476836, 0.215443537],
            [0.61955595, 0.852038682, 0.214635789],
            [0.580241024, 0.953878641, 0.212977946],
            [0.538416922, 1.06406701, 0.208613724],
            [0.497795135, 1.17432666, 0.200648367],
            [0.455831826, 1.2909025, 0.190322086],
            [0.408953458, 1.4225421, 0.178297073],
            [0.358742565, 1.56580722, 0.163922623],
            [0.313386321, 1.70175886, 0.147172511],
        ]])
        .unwrap();
        assert!(wn.exact(raw.points[0]) > 0.5 && wn.exact(raw.points[1]) > 0.5);
        let collision = CollisionParams { tau: 0.005 * diag, kappa: 0.5, skip_roots: true };
        let fitted = resolve_rest(&raw, &bvh, collision, diag).unwrap();
        let inside = fitted.points.iter().filter(|&&q| wn.exact(q) >= 0.5).count();
        assert_eq!(inside, 0, "points left inside");
        let change = max_length_change(&raw, &fitted);
        assert!(change < 0.01, "length changed by {change}");
    }
}
