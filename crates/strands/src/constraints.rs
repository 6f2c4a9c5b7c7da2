//! Geometry-aware regularisation of Sec. 3.4, applied as projections after
//! each transport (Alg. 1 lines 9–10): length preservation walking every
//! strand root to tip, then collision projection against the mesh with
//! threshold `τ` and stiffness `κ`.
//!
//! Both projections sit between the transport and the renderer, so the
//! style gradient must flow back through them (in the paper's PyTorch
//! pipeline autograd does this). Passing them through as identity is not
//! enough: length preservation rebuilds each strand root to tip, so moving
//! one control point sideways swings every point after it, and an identity
//! backward points the optimizer the wrong way (the Bangs measurements are
//! in `docs/design/strands.md`). Each projection therefore has its
//! vector-Jacobian product next to it, and [`ConstraintTape`] records a
//! sequence of projections so they can be undone in reverse.

use rayon::prelude::*;

use crate::bvh::MeshBvh;
use crate::strands::FlatStrands;
use crate::StrandError;
use nst3d_core::math::{add, norm, normalize, scale, sub, V3};

/// Mutable per-strand slices of a flat point array.
pub(crate) fn strands_mut<'a>(points: &'a mut [V3], offsets: &[usize]) -> Vec<&'a mut [V3]> {
    let mut out = Vec::with_capacity(offsets.len().saturating_sub(1));
    let mut rest = points;
    for w in offsets.windows(2) {
        let (head, tail) = rest.split_at_mut(w[1] - w[0]);
        out.push(head);
        rest = tail;
    }
    out
}

/// Restores every segment to its rest length, walking each strand from the
/// root (kept where it is) to the tip: segment `k` keeps the direction of
/// the deformed segment `p_{k+1} − p_k` and gets the rest length of
/// `rest`'s segment `k`, so the strand's deformed shape (where the style
/// lives) is kept and only the stretch is removed. A collapsed segment takes
/// the rest direction. `strands` and `rest` must have the same layout.
pub fn preserve_lengths(strands: &mut FlatStrands, rest: &FlatStrands) -> Result<(), StrandError> {
    if strands.offsets != rest.offsets {
        return Err(StrandError::Invalid("length preservation: deformed and rest strands differ in layout".into()));
    }
    let offsets = strands.offsets.clone();
    strands_mut(&mut strands.points, &offsets)
        .into_par_iter()
        .enumerate()
        .for_each(|(s, pts)| preserve_strand_lengths(pts, rest.strand(s)));
    Ok(())
}

/// [`preserve_lengths`] of one strand `pts` against its rest polyline `r`.
fn preserve_strand_lengths(pts: &mut [V3], r: &[V3]) {
    // Deformed directions come from the positions before correction.
    let mut prev_deformed = pts[0];
    for k in 0..pts.len() - 1 {
        let next_deformed = pts[k + 1];
        let rest_seg = sub(r[k + 1], r[k]);
        let len = norm(rest_seg);
        let dir = normalize(sub(next_deformed, prev_deformed)).or_else(|| normalize(rest_seg)).unwrap_or([0.0; 3]);
        let base = pts[k].map(f64::from);
        let target = std::array::from_fn(|a| base[a] + len as f64 * dir[a] as f64);
        pts[k + 1] = snap_to_length(pts[k], target, len as f64);
        prev_deformed = next_deformed;
    }
}

/// Backward of [`preserve_lengths`]: the gradient w.r.t. the points it was
/// given (`input`, before the correction) from the gradient `grad` w.r.t.
/// the points it returned.
///
/// The forward is `p'₀ = q₀`, `p'ₖ₊₁ = p'ₖ + Lₖ dₖ` with
/// `dₖ = (qₖ₊₁ − qₖ)/‖qₖ₊₁ − qₖ‖`, so a point's gradient reaches every
/// direction before it: with `Gₖ = Σ_{j>k} ∂L/∂p'ⱼ`,
/// `∂L/∂dₖ = Lₖ Gₖ`, through the normalisation
/// `∂L/∂uₖ = (∂L/∂dₖ − dₖ (dₖ·∂L/∂dₖ)) / ‖uₖ‖`, and the root collects every
/// point's gradient. A collapsed segment (rest direction) passes nothing;
/// the final rounding to the nearest `f32` is treated as identity.
pub fn preserve_lengths_backward(input: &FlatStrands, rest: &FlatStrands, grad: &[V3]) -> Result<Vec<V3>, StrandError> {
    if input.offsets != rest.offsets || grad.len() != input.points.len() {
        return Err(StrandError::Invalid("length preservation backward: layouts differ".into()));
    }
    let mut out = vec![[0.0f32; 3]; grad.len()];
    let offsets = input.offsets.clone();
    strands_mut(&mut out, &offsets).into_par_iter().enumerate().for_each(|(s, gin)| {
        preserve_strand_lengths_backward(input.strand(s), rest.strand(s), &grad[offsets[s]..offsets[s + 1]], gin)
    });
    Ok(out)
}

/// [`preserve_lengths_backward`] of one strand: `q` the points it was
/// given, `r` its rest polyline, `g` the gradient at its output; adds the
/// gradient at `q` to `gin`.
fn preserve_strand_lengths_backward(q: &[V3], r: &[V3], g: &[V3], gin: &mut [V3]) {
    let mut acc = [0.0f64; 3];
    for k in (0..q.len() - 1).rev() {
        for a in 0..3 {
            acc[a] += g[k + 1][a] as f64;
        }
        let u = sub(q[k + 1], q[k]);
        let len_u = norm(u) as f64;
        if !(len_u > 0.0) || normalize(u).is_none() {
            continue;
        }
        let d = u.map(|c| c as f64 / len_u);
        let l = norm(sub(r[k + 1], r[k])) as f64;
        let gd: [f64; 3] = std::array::from_fn(|a| l * acc[a]);
        let dd = d[0] * gd[0] + d[1] * gd[1] + d[2] * gd[2];
        for a in 0..3 {
            let gu = ((gd[a] - d[a] * dd) / len_u) as f32;
            gin[k + 1][a] += gu;
            gin[k][a] -= gu;
        }
    }
    for a in 0..3 {
        gin[0][a] += (acc[a] + g[0][a] as f64) as f32;
    }
}

/// Rounds `target` (exactly `len` from `base`) to the `f32` point, among
/// the 27 lattice neighbours of its nearest rounding, whose distance to
/// `base` is closest to `len`. Far from the origin an `f32` ulp is a
/// sizeable part of a short segment (1.5e-5 at 200 units, against 0.6-unit
/// segments in the Bangs groom); plain rounding would leave 2–3e-5 relative
/// length error, the search brings it well under 1e-5 without moving the
/// point by more than an ulp.
fn snap_to_length(base: V3, target: [f64; 3], len: f64) -> V3 {
    let r: V3 = target.map(|c| c as f32);
    // The squared distance of a neighbour is separable per axis: with
    // `w = r − base` and the axis nudged by `Δ`, `(w + Δ)² = w² + 2wΔ + Δ²`.
    // So the 27 candidates cost three terms per axis and one sum each, and
    // they are ranked by `|d² − len²|`, which orders them as `|d − len|`
    // does (`d + len` differs between neighbours by ulps). This loop runs
    // for every control point of every iteration; with a square root per
    // candidate it was 8 % of a Short Hair frame.
    let mut d0 = 0.0f64;
    let mut terms = [[0.0f64; 3]; 3];
    for a in 0..3 {
        let w = r[a] as f64 - base[a] as f64;
        d0 += w * w;
        for (slot, q) in [(1, r[a].next_down()), (2, r[a].next_up())] {
            let delta = q as f64 - r[a] as f64;
            terms[a][slot] = 2.0 * w * delta + delta * delta;
        }
    }
    let len2 = len * len;
    // Per axis the plain rounding first, then down, then up, so ties keep
    // the nearest rounding.
    const STEPS: [usize; 3] = [0, 1, 2];
    let mut best = ((d0 - len2).abs(), [0usize; 3]);
    for sz in STEPS {
        for sy in STEPS {
            for sx in STEPS {
                let e = (d0 + terms[0][sx] + terms[1][sy] + terms[2][sz] - len2).abs();
                if e < best.0 {
                    best = (e, [sx, sy, sz]);
                }
            }
        }
    }
    std::array::from_fn(|a| match best.1[a] {
        1 => r[a].next_down(),
        2 => r[a].next_up(),
        _ => r[a],
    })
}

/// Collision projection parameters (eq. 12).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CollisionParams {
    /// Projection threshold `τ ≥ 0` (scene units): points closer than this
    /// to the surface are repelled.
    pub tau: f32,
    /// Stiffness `κ ∈ (0, 1]`: fraction of the way to the `τ` shell a point
    /// is moved.
    pub kappa: f32,
    /// Leave every strand's root alone: roots sit on the scalp by
    /// construction and must stay attached.
    pub skip_roots: bool,
}

impl CollisionParams {
    fn validate(&self) -> Result<(), StrandError> {
        if !(self.tau >= 0.0 && self.tau.is_finite()) {
            return Err(StrandError::Parameter(format!("collision threshold τ = {} must be finite and ≥ 0", self.tau)));
        }
        if !(self.kappa > 0.0 && self.kappa <= 1.0) {
            return Err(StrandError::Parameter(format!("collision stiffness κ = {} is not in (0, 1]", self.kappa)));
        }
        Ok(())
    }
}

/// What a collision pass did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CollisionStats {
    /// Points found inside the mesh before projection.
    pub inside: usize,
    /// Points moved (inside, or outside but closer than `τ`).
    pub moved: usize,
}

/// Pushes control points out of, and away from, the mesh (Sec. 3.4).
///
/// With `s` the signed distance to the closest surface point `x`
/// (negative inside, by pseudo-normal) and `n̂` the outward unit direction
/// (`±(p − x)/‖p − x‖`, or the pseudo-normal when `p` is on the surface):
/// - `0 ≤ s < τ`: `p += κ (τ − s) n̂` (eq. 12, outside branch);
/// - `s < 0`: `p += (−s + κ τ) n̂`, i.e. eq. 11's projection onto `x`
///   followed by eq. 12 at `‖d‖ = 0`, so a penetration is always resolved
///   whatever `κ` (with `τ > 0` the point ends strictly outside).
///
/// Eq. 12 as printed adds `κ(τ − ‖d‖) d/‖d‖` with `d` pointing *into* the
/// mesh in both branches, which would push points inwards; we read it as
/// the outward push the text describes. Because the offset is added to the
/// point, this equals folding the correction into the stylization offset
/// `Δp` as the paper does.
pub fn project_collisions(
    strands: &mut FlatStrands,
    bvh: &MeshBvh,
    params: CollisionParams,
) -> Result<CollisionStats, StrandError> {
    Ok(project_collisions_recorded(strands, bvh, params)?.0)
}

/// The points one collision pass moved, for its backward: per moved point
/// its index, outward direction `n̂` and the fraction `c` of the normal
/// motion the push cancels (`κ` outside, 1 inside).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CollisionRecord {
    moved: Vec<(usize, V3, f32)>,
}

impl CollisionRecord {
    /// Backward of the pass, in place: `g ← g − c (n̂·g) n̂` at every moved
    /// point. The push `κ(τ − s(p)) n̂` has Jacobian `−κ n̂ n̂ᵀ` (`∇s = n̂`);
    /// the turning of `n̂` with `p` (the surface's curvature) is neglected,
    /// exact on flat parts of the mesh.
    pub fn backward(&self, grad: &mut [V3]) {
        for &(i, n, c) in &self.moved {
            cancel_normal(&mut grad[i], n, c);
        }
    }
}

/// The backward of one point's collision push: `g ← g − c (n̂·g) n̂`.
fn cancel_normal(g: &mut V3, n: V3, c: f32) {
    let gn = c * (n[0] * g[0] + n[1] * g[1] + n[2] * g[2]);
    for a in 0..3 {
        g[a] -= gn * n[a];
    }
}

/// [`project_collisions`], also returning what it did for
/// [`CollisionRecord::backward`].
pub fn project_collisions_recorded(
    strands: &mut FlatStrands,
    bvh: &MeshBvh,
    params: CollisionParams,
) -> Result<(CollisionStats, CollisionRecord), StrandError> {
    params.validate()?;
    let mut is_root = vec![false; strands.points.len()];
    if params.skip_roots {
        for &o in &strands.offsets[..strands.strand_count()] {
            is_root[o] = true;
        }
    }
    let pushed: Vec<Option<(V3, f32, bool)>> = strands
        .points
        .par_iter_mut()
        .zip(&is_root)
        .with_min_len(64)
        .map(|(p, &root)| if root { None } else { collide_point(p, bvh, params) })
        .collect();
    let mut stats = CollisionStats::default();
    let mut record = CollisionRecord::default();
    for (i, m) in pushed.into_iter().enumerate() {
        if let Some((n, c, inside)) = m {
            stats.moved += 1;
            stats.inside += inside as usize;
            record.moved.push((i, n, c));
        }
    }
    Ok((stats, record))
}

/// The collision projection of one point `p` (see [`project_collisions`]):
/// its outward direction `n̂`, the fraction `c` of normal motion the push
/// cancels and whether it was inside, or `None` when it did not move.
fn collide_point(p: &mut V3, bvh: &MeshBvh, params: CollisionParams) -> Option<(V3, f32, bool)> {
    let hit = bvh.closest_point_within(*p, params.tau)?;
    let s = hit.signed_distance;
    if s >= params.tau {
        return None;
    }
    let away = sub(*p, hit.point);
    let n = if s.abs() > 1e-7 * (1.0 + norm(*p)) {
        normalize(scale(away, s.signum())).unwrap_or(hit.normal)
    } else {
        hit.normal
    };
    let (push, cancel) =
        if s < 0.0 { (-s + params.kappa * params.tau, 1.0) } else { (params.kappa * (params.tau - s), params.kappa) };
    *p = add(*p, scale(n, push));
    Some((n, cancel, s < 0.0))
}

/// A sequence of constraint projections applied to one groom, recorded so
/// the style gradient can be taken back through them in reverse
/// ([`ConstraintTape::backward`]).
#[derive(Clone, Debug, Default)]
pub struct ConstraintTape {
    steps: Vec<TapeStep>,
    /// Applies projections without recording them (no copies of the groom
    /// for a backward that will not run).
    off: bool,
}

#[derive(Clone, Debug)]
enum TapeStep {
    /// Length preservation; the points it was given.
    Lengths(FlatStrands),
    /// A collision pass.
    Collisions(CollisionRecord),
    /// [`ConstraintTape::enforce`]: what happened to each strand.
    PerStrand(Vec<StrandTape>),
}

/// The projections [`ConstraintTape::enforce`] applied to one strand.
#[derive(Clone, Debug, Default)]
struct StrandTape {
    steps: Vec<StrandStep>,
}

#[derive(Clone, Debug)]
enum StrandStep {
    /// Length preservation; the strand's points before it.
    Lengths(Vec<V3>),
    /// A collision pass: per moved point its index in the strand, `n̂` and `c`.
    Collisions(Vec<(u32, V3, f32)>),
}

/// How [`ConstraintTape::enforce`] alternates the two projections.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EnforceParams {
    /// Most passes a strand gets; the first is the paper's (length
    /// preservation, then the collision projection with the constraints'
    /// own `τ` and `κ`).
    pub passes: usize,
    /// Collision parameters of every pass after the first.
    pub hard: CollisionParams,
    /// A strand stops once each of its segments is within this relative
    /// error of its rest length.
    pub tolerance: f32,
}

/// Largest relative error of a strand's segment lengths against its rest polyline.
pub(crate) fn strand_length_error(pts: &[V3], rest: &[V3]) -> f32 {
    pts.windows(2)
        .zip(rest.windows(2))
        .map(|(p, r)| {
            let l = norm(sub(r[1], r[0]));
            ((norm(sub(p[1], p[0])) - l) / l.max(1e-30)).abs()
        })
        .fold(0.0, f32::max)
}

impl ConstraintTape {
    /// A tape that records nothing: the projections run as usual, for
    /// callers that need no gradient.
    pub fn off() -> Self {
        ConstraintTape { steps: Vec::new(), off: true }
    }

    /// Length preservation of `strands` against `rest`, recorded.
    pub fn preserve_lengths(&mut self, strands: &mut FlatStrands, rest: &FlatStrands) -> Result<(), StrandError> {
        if self.off {
            return preserve_lengths(strands, rest);
        }
        let input = strands.clone();
        preserve_lengths(strands, rest)?;
        self.steps.push(TapeStep::Lengths(input));
        Ok(())
    }

    /// A collision pass on `strands`, recorded.
    pub fn project_collisions(
        &mut self,
        strands: &mut FlatStrands,
        bvh: &MeshBvh,
        params: CollisionParams,
    ) -> Result<CollisionStats, StrandError> {
        let (stats, record) = project_collisions_recorded(strands, bvh, params)?;
        if !self.off {
            self.steps.push(TapeStep::Collisions(record));
        }
        Ok(stats)
    }

    /// Both constraints, strand by strand, recorded: a first pass as
    /// [`Constraints::apply`], then, only on strands whose segments are
    /// still off their rest lengths by more than `e.tolerance` (a strand
    /// lying along the skin, whose collision push stretched it), length
    /// preservation and the `e.hard` collision projection in turn, up to
    /// `e.passes` passes. A collision pass is always a strand's last. Most
    /// strands of a groom never touch the mesh and are done after the first
    /// pass, so a few strands on the skin no longer make every control point
    /// of the groom go through every pass. Returns the first pass's
    /// statistics.
    pub fn enforce(
        &mut self,
        strands: &mut FlatStrands,
        c: &Constraints,
        e: EnforceParams,
    ) -> Result<CollisionStats, StrandError> {
        if strands.offsets != c.rest.offsets {
            return Err(StrandError::Invalid("constraints: deformed and rest strands differ in layout".into()));
        }
        c.collision.validate()?;
        e.hard.validate()?;
        let record = !self.off;
        let offsets = strands.offsets.clone();
        let per: Vec<(CollisionStats, StrandTape)> = strands_mut(&mut strands.points, &offsets)
            .into_par_iter()
            .enumerate()
            .map(|(k, pts)| {
                let r = c.rest.strand(k);
                let (mut stats, mut tape) = (CollisionStats::default(), StrandTape::default());
                for pass in 0..e.passes.max(1) {
                    if pass > 0 && (c.collider.is_none() || strand_length_error(pts, r) < e.tolerance) {
                        break;
                    }
                    if record {
                        tape.steps.push(StrandStep::Lengths(pts.to_vec()));
                    }
                    preserve_strand_lengths(pts, r);
                    let Some(bvh) = &c.collider else { continue };
                    let params = if pass == 0 { c.collision } else { e.hard };
                    let mut moved = Vec::new();
                    for (i, p) in pts.iter_mut().enumerate().skip(params.skip_roots as usize) {
                        if let Some((n, cancel, inside)) = collide_point(p, bvh, params) {
                            if pass == 0 {
                                stats.moved += 1;
                                stats.inside += inside as usize;
                            }
                            moved.push((i as u32, n, cancel));
                        }
                    }
                    if record {
                        tape.steps.push(StrandStep::Collisions(moved));
                    }
                }
                (stats, tape)
            })
            .collect();
        let mut stats = CollisionStats::default();
        let mut tapes = Vec::with_capacity(if record { per.len() } else { 0 });
        for (s, t) in per {
            stats.moved += s.moved;
            stats.inside += s.inside;
            if record {
                tapes.push(t);
            }
        }
        if record {
            self.steps.push(TapeStep::PerStrand(tapes));
        }
        Ok(stats)
    }

    /// Gradient w.r.t. the points before the first recorded projection from
    /// the gradient w.r.t. the points after the last.
    pub fn backward(&self, rest: &FlatStrands, grad: &[V3]) -> Result<Vec<V3>, StrandError> {
        let mut g = grad.to_vec();
        for step in self.steps.iter().rev() {
            match step {
                TapeStep::Lengths(input) => g = preserve_lengths_backward(input, rest, &g)?,
                TapeStep::Collisions(record) => record.backward(&mut g),
                TapeStep::PerStrand(tapes) => {
                    if tapes.len() != rest.strand_count() || g.len() != rest.points.len() {
                        return Err(StrandError::Invalid("constraints backward: layouts differ".into()));
                    }
                    let offsets = &rest.offsets;
                    strands_mut(&mut g, offsets).into_par_iter().zip(tapes).enumerate().for_each(|(k, (gk, tape))| {
                        let r = rest.strand(k);
                        let mut gin = vec![[0.0f32; 3]; gk.len()];
                        for step in tape.steps.iter().rev() {
                            match step {
                                StrandStep::Lengths(q) => {
                                    gin.iter_mut().for_each(|x| *x = [0.0; 3]);
                                    preserve_strand_lengths_backward(q, r, gk, &mut gin);
                                    gk.copy_from_slice(&gin);
                                }
                                StrandStep::Collisions(moved) => {
                                    for &(i, n, c) in moved {
                                        cancel_normal(&mut gk[i as usize], n, c);
                                    }
                                }
                            }
                        }
                    });
                }
            }
        }
        Ok(g)
    }
}

/// Both Sec. 3.4 constraints bound to a rest groom and a collider, applied
/// in the paper's order (length preservation while transporting, collision
/// after the step).
#[derive(Clone, Debug)]
pub struct Constraints {
    /// Rest strands (lengths are measured on these).
    pub rest: FlatStrands,
    /// Collider, if any.
    pub collider: Option<MeshBvh>,
    /// Collision parameters.
    pub collision: CollisionParams,
}

impl Constraints {
    /// Applies length preservation then collision projection in place.
    pub fn apply(&self, strands: &mut FlatStrands) -> Result<CollisionStats, StrandError> {
        self.apply_recorded(strands, &mut ConstraintTape::off())
    }

    /// [`Constraints::apply`], recording both projections on `tape`.
    pub fn apply_recorded(
        &self,
        strands: &mut FlatStrands,
        tape: &mut ConstraintTape,
    ) -> Result<CollisionStats, StrandError> {
        tape.preserve_lengths(strands, &self.rest)?;
        match &self.collider {
            Some(bvh) => tape.project_collisions(strands, bvh, self.collision),
            None => Ok(CollisionStats::default()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::pseudo_random;

    #[test]
    fn length_preservation_restores_rest_lengths() {
        let rest =
            FlatStrands::from_strands((0..20).map(|s| {
                (0..15).map(|k| [s as f32, k as f32 * 0.1 + (k * k) as f32 * 0.01, 0.3 * s as f32]).collect()
            }))
            .unwrap();
        let noise = pseudo_random(rest.points.len() * 3, 5);
        let mut def = rest.clone();
        for (p, n) in def.points.iter_mut().zip(noise.chunks(3)) {
            for a in 0..3 {
                p[a] += 0.3 * n[a];
            }
        }
        // One collapsed segment must not produce NaNs.
        def.points[5] = def.points[4];
        let roots = def.roots();
        preserve_lengths(&mut def, &rest).unwrap();
        assert_eq!(def.roots(), roots);
        for (a, b) in def.segment_lengths().iter().zip(rest.segment_lengths()) {
            assert!((a - b).abs() <= 1e-5 * b, "{a} vs {b}");
        }
        let other = FlatStrands::from_strands([vec![[0.0; 3], [1.0; 3]]]).unwrap();
        assert!(preserve_lengths(&mut def, &other).is_err());
    }

    #[test]
    fn snapping_finds_the_lattice_neighbour_nearest_the_length() {
        // Against the plain search: every one of the 27 neighbours measured
        // with a square root. Coordinates from 0.1 to 300 units, segments
        // from 1e-3 to 1 (ulps up to 3e-5: a large part of a short segment).
        let noise = pseudo_random(6 * 4000, 0x5A4F);
        for (i, c) in noise.chunks(6).enumerate() {
            let magnitude = [0.1f32, 3.0, 40.0, 300.0][i % 4];
            let len = [1e-3f64, 0.02, 0.3, 1.0][(i / 4) % 4];
            let base: V3 = std::array::from_fn(|a| c[a] * magnitude);
            let dir = normalize([c[3], c[4], c[5]]).unwrap_or([1.0, 0.0, 0.0]);
            let target: [f64; 3] = std::array::from_fn(|a| base[a] as f64 + len * dir[a] as f64);
            let dist = |q: V3| (0..3).map(|a| (q[a] as f64 - base[a] as f64).powi(2)).sum::<f64>().sqrt();
            let r: V3 = target.map(|x| x as f32);
            let mut plain = f64::INFINITY;
            for dz in [0, -1, 1] {
                for dy in [0, -1, 1] {
                    for dx in [0, -1, 1] {
                        let q: V3 = std::array::from_fn(|a| match [dx, dy, dz][a] {
                            -1 => r[a].next_down(),
                            1 => r[a].next_up(),
                            _ => r[a],
                        });
                        plain = plain.min((dist(q) - len).abs());
                    }
                }
            }
            let got = (dist(snap_to_length(base, target, len)) - len).abs();
            assert!(got <= plain + 1e-12 * len, "case {i}: error {got:e}, the plain search finds {plain:e}");
        }
    }

    #[test]
    fn collision_parameters_are_validated() {
        let mesh = crate::generators::uv_sphere(1.0, 8, 16);
        let bvh = MeshBvh::new(&mesh).unwrap();
        let mut s = FlatStrands::from_strands([vec![[0.0; 3], [0.1, 0.0, 0.0]]]).unwrap();
        let bad = CollisionParams { tau: 0.1, kappa: 0.0, skip_roots: false };
        assert!(project_collisions(&mut s, &bvh, bad).is_err());
        let bad = CollisionParams { tau: -1.0, kappa: 0.5, skip_roots: false };
        assert!(project_collisions(&mut s, &bvh, bad).is_err());
        let ok = CollisionParams { tau: 0.1, kappa: 0.5, skip_roots: false };
        let st = project_collisions(&mut s, &bvh, ok).unwrap();
        assert_eq!(st.inside, 2);
        assert!(s.points.iter().all(|&p| bvh.signed_distance(p) >= 0.05 * 0.999));
    }

    fn flat(p: &[V3]) -> Vec<f32> {
        p.iter().flatten().copied().collect()
    }

    fn unflat(x: &[f32]) -> Vec<V3> {
        x.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
    }

    #[test]
    fn length_preservation_gradient_matches_finite_differences() {
        use nst3d_core::gradcheck::{check_gradient, dot};
        let rest = FlatStrands::from_strands((0..4).map(|s| {
            (0..7).map(|k| [0.2 * s as f32, k as f32 * 0.3 + (k * k) as f32 * 0.02, 0.1 * (k as f32).sin()]).collect()
        }))
        .unwrap();
        let noise = pseudo_random(rest.points.len() * 3, 11);
        let mut q = rest.clone();
        for (p, n) in q.points.iter_mut().zip(noise.chunks(3)) {
            for a in 0..3 {
                p[a] += 0.1 * n[a];
            }
        }
        let w = pseudo_random(rest.points.len() * 3, 12);
        let analytic = flat(&preserve_lengths_backward(&q, &rest, &unflat(&w)).unwrap());
        let x = flat(&q.points);
        let check = check_gradient(
            &x,
            &analytic,
            |x| {
                let mut s = q.with_points(unflat(x)).unwrap();
                preserve_lengths(&mut s, &rest).unwrap();
                dot(&w, &flat(&s.points))
            },
            1e-3,
            usize::MAX,
            1e-2,
        );
        assert!(check.max_rel_err < 2e-2, "{check:?}");
    }

    /// A large box with its top face at `z = 0`: points near that face see a
    /// flat surface, where the collision backward's neglected turning of the
    /// normal is zero.
    fn flat_top_box() -> nst3d_core::mesh::TriMesh {
        nst3d_core::mesh::TriMesh {
            vertices: vec![
                [-5.0, -5.0, -5.0],
                [5.0, -5.0, -5.0],
                [5.0, 5.0, -5.0],
                [-5.0, 5.0, -5.0],
                [-5.0, -5.0, 0.0],
                [5.0, -5.0, 0.0],
                [5.0, 5.0, 0.0],
                [-5.0, 5.0, 0.0],
            ],
            triangles: vec![
                [0, 2, 1],
                [0, 3, 2],
                [4, 5, 6],
                [4, 6, 7],
                [0, 1, 5],
                [0, 5, 4],
                [1, 2, 6],
                [1, 6, 5],
                [2, 3, 7],
                [2, 7, 6],
                [3, 0, 4],
                [3, 4, 7],
            ],
            normals: None,
        }
    }

    #[test]
    fn collision_gradient_matches_finite_differences_on_a_flat_face() {
        use nst3d_core::gradcheck::{check_gradient, dot};
        let cube = flat_top_box();
        let bvh = MeshBvh::new(&cube).unwrap();
        let pts: Vec<V3> = vec![[0.3, 0.2, -0.3], [1.0, -0.5, 0.05], [-0.7, 0.4, 0.5], [0.1, 1.1, -0.02]];
        let s0 = FlatStrands::from_strands([pts.clone()]).unwrap();
        let params = CollisionParams { tau: 0.1, kappa: 0.6, skip_roots: false };
        let w = pseudo_random(12, 3);
        let mut s = s0.clone();
        let (stats, record) = project_collisions_recorded(&mut s, &bvh, params).unwrap();
        assert_eq!((stats.inside, stats.moved), (2, 3));
        let mut g = unflat(&w);
        record.backward(&mut g);
        let check = check_gradient(
            &flat(&pts),
            &flat(&g),
            |x| {
                let mut s = s0.with_points(unflat(x)).unwrap();
                project_collisions(&mut s, &bvh, params).unwrap();
                dot(&w, &flat(&s.points))
            },
            1e-3,
            usize::MAX,
            1e-2,
        );
        assert!(check.max_rel_err < 1e-2, "{check:?}");
    }

    /// On a mesh of overlapping parts (Suzanne, ears and eyes pushed into
    /// the head), collision passes take points that are inside by the
    /// winding number to outside by it, including those whose nearest
    /// triangle is buried in another part (a strand was seen whose
    /// points were pushed from the head into an ear and back): after one
    /// pass at most 0.5 % are left inside (18 of 9,560 here, all but 2 in
    /// front of an eye, where the socket's hole makes `w` 0.7–0.75), after
    /// a second none.
    #[test]
    fn collisions_leave_overlapping_parts_by_the_outside() {
        let mesh = crate::bvh::tests::data("grooms/monkey_curly_mesh.obj");
        let bvh = MeshBvh::new(&mesh).unwrap();
        let wn = crate::winding::WindingNumber::new(&mesh.vertices, &mesh.triangles);
        let (lo, hi) = mesh.bbox().unwrap();
        let inside: Vec<V3> = pseudo_random(3 * 20_000, 17)
            .chunks(3)
            .map(|c| std::array::from_fn(|a| lo[a] + (0.5 + 0.5 * c[a]) * (hi[a] - lo[a])))
            .filter(|&q: &V3| wn.exact(q) > 0.8)
            .collect();
        let deep = inside.iter().filter(|&&q| wn.exact(q) > 1.2).count();
        assert!(inside.len() > 2000 && deep > 20, "{} inside, {deep} in two parts", inside.len());
        let mut s = FlatStrands::from_strands(inside.iter().map(|&q| vec![q, q])).unwrap();
        let params = CollisionParams { tau: 0.01, kappa: 1.0, skip_roots: false };
        let stats = project_collisions(&mut s, &bvh, params).unwrap();
        assert_eq!(stats.inside, 2 * inside.len());
        let inside_after = |s: &FlatStrands, at: f64| s.points.iter().filter(|&&q| wn.exact(q) >= at).count();
        let (once, once_clearly) = (inside_after(&s, 0.5), inside_after(&s, 0.8));
        project_collisions(&mut s, &bvh, params).unwrap();
        let (twice, twice_clearly) = (inside_after(&s, 0.5), inside_after(&s, 0.8));
        assert!(
            once * 200 <= s.points.len() && twice == 0,
            "inside after one pass {once} ({once_clearly} with w ≥ 0.8), after two {twice} ({twice_clearly})"
        );
    }

    #[test]
    fn tape_chains_length_and_collision_backward() {
        use nst3d_core::gradcheck::{check_gradient, dot};
        let mesh = crate::generators::uv_sphere(1.0, 24, 48);
        let bvh = MeshBvh::new(&mesh).unwrap();
        let rest = FlatStrands::from_strands((0..3).map(|s| {
            let a = s as f32 * 0.7;
            (0..6)
                .map(|k| {
                    let r = 1.0 + 0.15 * k as f32;
                    [r * a.cos(), r * a.sin(), 0.05 * k as f32]
                })
                .collect()
        }))
        .unwrap();
        let noise = pseudo_random(rest.points.len() * 3, 21);
        let mut q = rest.clone();
        for (p, n) in q.points.iter_mut().zip(noise.chunks(3)) {
            for a in 0..3 {
                p[a] += 0.05 * n[a];
            }
        }
        let c = Constraints {
            rest: rest.clone(),
            collider: Some(bvh),
            collision: CollisionParams { tau: 0.02, kappa: 0.5, skip_roots: true },
        };
        let w = pseudo_random(rest.points.len() * 3, 22);
        let mut tape = ConstraintTape::default();
        let mut s = q.clone();
        c.apply_recorded(&mut s, &mut tape).unwrap();
        let analytic = flat(&tape.backward(&rest, &unflat(&w)).unwrap());
        let check = check_gradient(
            &flat(&q.points),
            &analytic,
            |x| {
                let mut s = q.with_points(unflat(x)).unwrap();
                c.apply(&mut s).unwrap();
                dot(&w, &flat(&s.points))
            },
            1e-3,
            usize::MAX,
            1e-2,
        );
        assert!(check.max_rel_err < 3e-2, "{check:?}");
    }

    #[test]
    fn enforce_per_strand_equals_the_projections_on_the_whole_groom() {
        let bvh = MeshBvh::new(&flat_top_box()).unwrap();
        // Strands rooted on the flat top face that arc up and back down into
        // the box, so the first collision pass stretches them and extra
        // passes run.
        let rest = FlatStrands::from_strands((0..4).map(|s| {
            let (x0, y0) = (-1.0 + 0.6 * s as f32, 0.3 * s as f32);
            (0..8)
                .map(|k| {
                    let t = k as f32 * 0.25;
                    [x0 + 0.4 * t, y0 - 0.1 * t, 0.5 * t - 0.35 * t * t]
                })
                .collect()
        }))
        .unwrap();
        let noise = pseudo_random(rest.points.len() * 3, 31);
        let mut q = rest.clone();
        for (p, n) in q.points.iter_mut().zip(noise.chunks(3)) {
            for a in 0..3 {
                p[a] += 0.03 * n[a];
            }
        }
        let collision = CollisionParams { tau: 0.02, kappa: 0.5, skip_roots: true };
        let c = Constraints { rest: rest.clone(), collider: Some(bvh.clone()), collision };
        let hard = CollisionParams { tau: 0.001, kappa: 1.0, skip_roots: true };
        // Every strand runs every pass, as the whole-groom sequence below.
        let e = EnforceParams { passes: 4, hard, tolerance: 0.0 };
        let mut tape = ConstraintTape::default();
        let mut s = q.clone();
        let stats = tape.enforce(&mut s, &c, e).unwrap();
        assert!(stats.inside > 0, "the test groom must penetrate: {stats:?}");
        let w = pseudo_random(rest.points.len() * 3, 32);
        let analytic = tape.backward(&rest, &unflat(&w)).unwrap();

        // The same projections on the whole groom at once, recorded step by
        // step, give the same points and the same gradient; each of those
        // has its finite-difference check above. (A finite-difference check
        // of the repeated passes themselves is ill-posed: each hard pass
        // leaves the points it moved exactly on the kink of the next one.)
        let mut global = ConstraintTape::default();
        let mut s2 = q.clone();
        c.apply_recorded(&mut s2, &mut global).unwrap();
        for _ in 1..e.passes {
            global.preserve_lengths(&mut s2, &rest).unwrap();
            global.project_collisions(&mut s2, &bvh, hard).unwrap();
        }
        assert_eq!(s.points, s2.points);
        assert_eq!(analytic, global.backward(&rest, &unflat(&w)).unwrap());

        // With a tolerance, strands that need no extra pass stop after the
        // first and the rest go on.
        let mut tape = ConstraintTape::default();
        let mut s3 = q.clone();
        tape.enforce(&mut s3, &c, EnforceParams { tolerance: 1e-3, passes: 50, ..e }).unwrap();
        let TapeStep::PerStrand(t) = &tape.steps[0] else { panic!("enforce records per strand") };
        assert!(t.iter().any(|t| t.steps.len() > 2), "some strand needed extra passes");
        let roots = &s3.offsets[..s3.strand_count()];
        let inside = (0..s3.points.len()).filter(|i| !roots.contains(i) && s3.points[*i][2] < 0.0).count();
        assert_eq!(inside, 0, "points left inside (roots excepted)");
    }
}
