//! The stylized guides (and their colours) carried back to the groom's own
//! control points, so the written groom has the input's topology.

use nst3d_core::math::{add, dot, norm, scale, sub, V3};

use super::fit::{fit_outside, lift_roots, STUCK_LENGTH_ERROR};
use super::{enforce, StrandScene};
use crate::constraints::{strand_length_error, ConstraintTape, Constraints};
use crate::pipeline::PipelineError;
use crate::strands::FlatStrands;

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
