//! The colour a groom is stylized to (issue 29; the strand paper names
//! "strand colours are untouched" as its third limitation). The splats
//! already carry a colour `c_i` (eq. 6); here it becomes a parameter.
//!
//! The optimizer holds a raw colour `r` at every guide point (the guides as
//! re-sampled for the stylization). What the renderer draws is
//! - on a guide: `c = S r`, where `S` is [`COLOR_SMOOTH_PASSES`] passes of
//!   the `[¼ ½ ¼]` tent along the strand (ends repeated), so a strand's colour
//!   changes over several points rather than speckling point by point under
//!   Adam's per-parameter steps;
//! - on a proxy: the blend of its guides' colours at the same point index,
//!   with the weights its shape was blended with ([`ProxyBlend`]), so the
//!   hair between guides takes their colours as it takes their shapes, and
//!   the written guides carry every colour the renders showed.
//!
//! `r` is kept in `[0, 1]` (projected after each step, [`project_unit`]), so
//! every drawn colour is in `[0, 1]` too: `S` and the blends are convex.
//! It starts from the input's colours (white where it has none, the grey
//! render's colour), so the stylization moves the artist's colours.
//!
//! `S` with repeated ends is a symmetric matrix, so the backward applies it
//! again; [`StrandColorLayer::backward`] is checked against finite
//! differences below.

use nst3d_core::groom::Groom;

use crate::densify::ProxyBlend;
use crate::strands::FlatStrands;
use crate::StrandError;

/// Tent passes along each guide ([`StrandColorLayer::forward`]).
pub const COLOR_SMOOTH_PASSES: usize = 2;

/// Adam's step on the raw colours, in colour units (`[0, 1]`) per iteration:
/// a colour can cross the whole range in a few dozen iterations, fewer than
/// the shortest preset's coarse scale.
pub const COLOR_LEARNING_RATE: f32 = 0.03;

/// Colours of every rendered point from the raw guide colours, and back.
#[derive(Clone, Debug)]
pub struct StrandColorLayer {
    /// Offsets of the guides (the leading strands of the scene's rest layout).
    guide_offsets: Vec<usize>,
    /// Offsets of the proxies, relative to the first proxy point.
    proxy_offsets: Vec<usize>,
    /// Each proxy's guides and weights.
    blends: Vec<ProxyBlend>,
}

impl StrandColorLayer {
    /// The layer for `rest` (guides, then proxies), whose first
    /// `guide_count` strands are guides and the rest proxies blended by
    /// `blends` (one per proxy).
    pub fn new(rest: &FlatStrands, guide_count: usize, blends: Vec<ProxyBlend>) -> Result<Self, StrandError> {
        let n = rest.strand_count();
        if guide_count > n || blends.len() != n - guide_count {
            return Err(StrandError::Mismatch {
                what: "proxy blends",
                expected: n - guide_count.min(n),
                got: blends.len(),
            });
        }
        if let Some(&(g, _)) = blends.iter().flatten().find(|&&(g, _)| g as usize >= guide_count) {
            return Err(StrandError::Invalid(format!("a proxy blends guide {g} of {guide_count}")));
        }
        let split = rest.offsets[guide_count];
        Ok(Self {
            guide_offsets: rest.offsets[..=guide_count].to_vec(),
            proxy_offsets: rest.offsets[guide_count..].iter().map(|o| o - split).collect(),
            blends,
        })
    }

    /// Raw parameters: one colour per guide point.
    pub fn guide_points(&self) -> usize {
        *self.guide_offsets.last().unwrap_or(&0)
    }

    /// Points the layer colours: guides, then proxies.
    pub fn points(&self) -> usize {
        self.guide_points() + *self.proxy_offsets.last().unwrap_or(&0)
    }

    /// Smoothed guide colours `S r`.
    pub fn guide_colors(&self, raw: &[[f32; 3]]) -> Vec<[f32; 3]> {
        assert_eq!(raw.len(), self.guide_points(), "one raw colour per guide point");
        let mut c = raw.to_vec();
        for w in self.guide_offsets.windows(2) {
            smooth_along(&mut c[w[0]..w[1]], COLOR_SMOOTH_PASSES);
        }
        c
    }

    /// The colour of every rendered point (guides, then proxies) from the
    /// raw guide colours.
    pub fn forward(&self, raw: &[[f32; 3]]) -> Vec<[f32; 3]> {
        let mut out = self.guide_colors(raw);
        out.reserve(self.points() - out.len());
        for (i, blend) in self.blends.iter().enumerate() {
            let len = self.proxy_offsets[i + 1] - self.proxy_offsets[i];
            for k in 0..len {
                let mut c = [0.0f32; 3];
                for &(g, w) in blend {
                    let src = out[self.guide_offsets[g as usize] + self.matching_point(g as usize, k, len)];
                    for ch in 0..3 {
                        c[ch] += w * src[ch];
                    }
                }
                out.push(c);
            }
        }
        out
    }

    /// Gradient w.r.t. the raw guide colours, given the gradient w.r.t. every
    /// rendered point's colour (the layout [`StrandColorLayer::forward`] returns).
    pub fn backward(&self, grad: &[[f32; 3]]) -> Vec<[f32; 3]> {
        assert_eq!(grad.len(), self.points(), "one gradient per rendered point");
        let gp = self.guide_points();
        let mut g_smoothed = grad[..gp].to_vec();
        for (i, blend) in self.blends.iter().enumerate() {
            let (lo, hi) = (self.proxy_offsets[i], self.proxy_offsets[i + 1]);
            for k in 0..hi - lo {
                let d = grad[gp + lo + k];
                for &(g, w) in blend {
                    let dst =
                        &mut g_smoothed[self.guide_offsets[g as usize] + self.matching_point(g as usize, k, hi - lo)];
                    for ch in 0..3 {
                        dst[ch] += w * d[ch];
                    }
                }
            }
        }
        // S is symmetric: its adjoint is itself.
        for w in self.guide_offsets.windows(2) {
            smooth_along(&mut g_smoothed[w[0]..w[1]], COLOR_SMOOTH_PASSES);
        }
        g_smoothed
    }

    /// The point of guide `g` a proxy's point `k` of `len` takes its colour
    /// from: the same index when the counts agree (as the scene builds
    /// them), else the same fraction of the strand.
    fn matching_point(&self, g: usize, k: usize, len: usize) -> usize {
        let glen = self.guide_offsets[g + 1] - self.guide_offsets[g];
        if glen == len || len < 2 {
            k.min(glen.saturating_sub(1))
        } else {
            ((k as f64 * (glen - 1) as f64 / (len - 1) as f64).round() as usize).min(glen - 1)
        }
    }
}

/// `passes` passes of the `[¼ ½ ¼]` tent along one strand's colours, the
/// ends repeated (a symmetric operator: rows 0 and n−1 are `[¾ ¼]`, `[¼ ¾]`).
pub fn smooth_along(c: &mut [[f32; 3]], passes: usize) {
    let n = c.len();
    if n < 2 {
        return;
    }
    let mut prev = vec![[0.0f32; 3]; n];
    for _ in 0..passes {
        prev.copy_from_slice(c);
        for i in 0..n {
            let (a, b) = (prev[i.saturating_sub(1)], prev[(i + 1).min(n - 1)]);
            for ch in 0..3 {
                c[i][ch] = 0.25 * a[ch] + 0.5 * prev[i][ch] + 0.25 * b[ch];
            }
        }
    }
}

/// Keeps every raw colour channel in `[0, 1]` (after each optimizer step).
pub fn project_unit(raw: &mut [f32]) {
    for v in raw {
        *v = v.clamp(0.0, 1.0);
    }
}

/// The raw colours a stylization starts from: the groom's own per-point
/// colours, re-sampled to `points` at even arc length along each strand as
/// the guides are (white for a strand without colours), clamped to `[0, 1]`.
pub fn initial_colors(groom: &Groom, points: usize) -> Vec<[f32; 3]> {
    let mut out = Vec::with_capacity(groom.strands.len() * points);
    for s in &groom.strands {
        let Some(colors) = s.colors.as_ref().filter(|c| c.len() == s.points.len() && !c.is_empty()) else {
            out.extend(std::iter::repeat([1.0; 3]).take(points));
            continue;
        };
        // Cumulative arc length of the input polyline.
        let mut arc = vec![0.0f64; s.points.len()];
        for i in 1..s.points.len() {
            let d: f64 = (0..3).map(|k| (s.points[i][k] - s.points[i - 1][k]) as f64).map(|v| v * v).sum();
            arc[i] = arc[i - 1] + d.sqrt();
        }
        let total = *arc.last().unwrap_or(&0.0);
        for j in 0..points {
            let at = if points < 2 { 0.0 } else { total * j as f64 / (points - 1) as f64 };
            let i = arc.partition_point(|&a| a <= at).clamp(1, arc.len().max(2) - 1).min(arc.len() - 1);
            let (a, b) = (colors[i.saturating_sub(1)], colors[i]);
            let span = arc[i] - arc[i.saturating_sub(1)];
            let t = if span > 0.0 { ((at - arc[i - 1]) / span).clamp(0.0, 1.0) as f32 } else { 0.0 };
            out.push(std::array::from_fn(|ch| (a[ch] + (b[ch] - a[ch]) * t).clamp(0.0, 1.0)));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::{check_gradient, pseudo_random};
    use nst3d_core::groom::Strand;

    /// Two guides of 5 and 4 points and two proxies of 5 points.
    fn layer() -> StrandColorLayer {
        let strand = |n: usize| (0..n).map(|k| [0.0, k as f32, 0.0]).collect::<Vec<_>>();
        let rest = FlatStrands::from_strands(vec![strand(5), strand(4), strand(5), strand(5)]).unwrap();
        StrandColorLayer::new(&rest, 2, vec![vec![(0, 0.7), (1, 0.3)], vec![(1, 1.0)]]).unwrap()
    }

    #[test]
    fn backward_matches_finite_differences() {
        let l = layer();
        let raw: Vec<f32> = pseudo_random(3 * l.guide_points(), 3);
        let w = pseudo_random(3 * l.points(), 4);
        let unflat = |x: &[f32]| x.chunks(3).map(|c| [c[0], c[1], c[2]]).collect::<Vec<_>>();
        let grad = l.backward(&unflat(&w));
        let analytic: Vec<f32> = grad.iter().flatten().copied().collect();
        let loss = |x: &[f32]| {
            let c = l.forward(&unflat(x));
            c.iter().flatten().zip(&w).map(|(a, b)| (*a as f64) * (*b as f64)).sum::<f64>()
        };
        // The layer is linear: a large step has no truncation error and
        // keeps the f32 rounding of the forward small against it.
        let res = check_gradient(&raw, &analytic, loss, 0.5, raw.len(), 1e-3);
        assert!(res.max_rel_err < 1e-4, "{res:?}");
    }

    #[test]
    fn colours_stay_in_range_and_a_constant_stays_constant() {
        let l = layer();
        let c = l.forward(&vec![[0.2, 0.5, 0.9]; l.guide_points()]);
        assert_eq!(c.len(), l.points());
        for v in &c {
            for (a, b) in v.iter().zip([0.2, 0.5, 0.9]) {
                assert!((a - b).abs() < 1e-6, "{v:?}");
            }
        }
        let mut raw = vec![-0.5, 0.5, 1.5];
        project_unit(&mut raw);
        assert_eq!(raw, [0.0, 0.5, 1.0]);
    }

    #[test]
    fn smoothing_spreads_a_spike_and_keeps_its_sum() {
        let mut c = vec![[0.0; 3]; 7];
        c[3] = [1.0; 3];
        smooth_along(&mut c, 1);
        assert_eq!(c[2][0], 0.25);
        assert_eq!(c[3][0], 0.5);
        assert_eq!(c[4][0], 0.25);
        smooth_along(&mut c, 3);
        let sum: f32 = c.iter().map(|v| v[0]).sum();
        assert!((sum - 1.0).abs() < 1e-6, "{sum}");
    }

    #[test]
    fn initial_colours_follow_the_input_along_the_strand() {
        let mut a = Strand::new(vec![[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 3.0, 0.0]]);
        a.colors = Some(vec![[0.0; 3], [1.0; 3], [0.0, 1.0, 0.5]]);
        let b = Strand::new(vec![[1.0, 0.0, 0.0], [1.0, 1.0, 0.0]]);
        let g = Groom { strands: vec![a, b] };
        let c = initial_colors(&g, 4);
        assert_eq!(c.len(), 8);
        assert_eq!(c[0], [0.0; 3]);
        // 1 unit along the strand: the second input point.
        assert!((c[1][0] - 1.0).abs() < 1e-6, "{:?}", c[1]);
        // 2 units: halfway between the last two points.
        assert!((c[2][0] - 0.5).abs() < 1e-6 && (c[2][2] - 0.75).abs() < 1e-6, "{:?}", c[2]);
        assert_eq!(c[3], [0.0, 1.0, 0.5]);
        assert!(c[4..].iter().all(|&v| v == [1.0; 3]), "no colours: white");
    }
}
