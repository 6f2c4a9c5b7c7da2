//! Everything fixed during one stylization ([`StrandScene`]: setup as in the
//! module notes of [`crate::pipeline`]) and the deformation the optimizer
//! drives: transport by the velocities, then the constraints of Sec. 3.4,
//! each with its backward.

use nst3d_core::groom::{Groom, StrandSpline};
use nst3d_core::math::{add, dot, norm, scale, sub, V3};
use nst3d_core::mesh::TriMesh;
use nst3d_core::Image;
use nst3d_splat::{render, SplatCamera, SplatOutput, StrandStyle, Strands};

use crate::bvh::MeshBvh;
use crate::constraints::{CollisionParams, CollisionStats, ConstraintTape, Constraints, EnforceParams};
use crate::densify::{densify, DensifyParams};
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
}

impl StrandScene {
    /// Builds guides, proxies, field, constraints and view frame from a
    /// groom and the mesh it grows from. Without a mesh there is no
    /// collision projection and no visibility culling, proxies grow around
    /// the guide roots, and the groom's own box sets the scale.
    pub fn new(groom: &Groom, head: Option<&TriMesh>, params: &StylizeParams) -> Result<Self, PipelineError> {
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
        let bvh = head.map(MeshBvh::new).transpose()?;
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
        let (lo, hi) = match head {
            Some(h) => h.bbox().ok_or_else(|| StrandError::Invalid("the head mesh has no vertices".into()))?,
            None => points_bbox(&guides.points),
        };
        let diag = norm(sub(hi, lo));
        let collision = p.collision(diag);
        let rest = match &bvh {
            Some(bvh) => resolve_rest(&raw, bvh, collision, diag)?,
            None => raw,
        };
        let guide_count = guides.strand_count();
        let rest_guides = FlatStrands {
            points: rest.points[..rest.offsets[guide_count]].to_vec(),
            offsets: rest.offsets[..=guide_count].to_vec(),
        };
        let field = DeformationField::on_guides(&rest_guides, &rest, p.sample_density(), p.kernel, p.neighbors)?;
        let root_normals: Option<Vec<V3>> =
            bvh.as_ref().map(|bvh| rest.roots().iter().map(|&r| bvh.closest_point(r).normal).collect());
        // Without a mesh the guides' growth directions stand in for the
        // scalp normals when choosing the front.
        let growth: Vec<V3> = (0..guide_count)
            .map(|k| {
                let g = rest.strand(k);
                g.get(1).and_then(|&q| nst3d_core::math::normalize(sub(q, g[0]))).unwrap_or([0.0; 3])
            })
            .collect();
        let frame = view_frame(&rest, root_normals.as_ref().map_or(&growth[..], |n| &n[..guide_count]), head)?;
        let constraints = Constraints { rest: rest.clone(), collider: bvh, collision };

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

    pub(super) fn strands<'a>(&'a self, s: &'a FlatStrands) -> Strands<'a> {
        Strands { points: &s.points, offsets: &s.offsets, colors: None, root_normals: self.root_normals.as_deref() }
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
