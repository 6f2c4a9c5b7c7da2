//! The flat point layout every stage works on: all control points of all
//! strands in one array (guides first, then densified proxies), with strand
//! boundaries kept as offsets. The deformation field only sees points; the
//! constraints need the strand structure to walk root to tip.

use nst3d_core::groom::{Groom, Strand};

use crate::StrandError;
use nst3d_core::math::{norm, sub, V3};

/// Control points of a set of strands, stored contiguously.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FlatStrands {
    /// All control points, strand after strand, each root first.
    pub points: Vec<[f32; 3]>,
    /// Strand `s` owns `points[offsets[s]..offsets[s + 1]]`; starts with 0
    /// and ends with `points.len()`.
    pub offsets: Vec<usize>,
}

impl FlatStrands {
    /// Flattens a groom (attributes are dropped: stylization moves points
    /// only). Every strand needs at least two points.
    pub fn from_groom(groom: &Groom) -> Result<Self, StrandError> {
        Self::from_strands(groom.strands.iter().map(|s| s.points.clone()))
    }

    /// Flattens strands given as point lists. Every strand needs at least two
    /// finite points.
    pub fn from_strands(strands: impl IntoIterator<Item = Vec<[f32; 3]>>) -> Result<Self, StrandError> {
        let mut out = FlatStrands { points: Vec::new(), offsets: vec![0] };
        for (i, s) in strands.into_iter().enumerate() {
            if s.len() < 2 {
                return Err(StrandError::Invalid(format!("strand {i} has {} point(s), need at least 2", s.len())));
            }
            if s.iter().any(|p| p.iter().any(|c| !c.is_finite())) {
                return Err(StrandError::Invalid(format!("strand {i} has a non-finite point")));
            }
            out.points.extend_from_slice(&s);
            out.offsets.push(out.points.len());
        }
        if out.strand_count() == 0 {
            return Err(StrandError::Invalid("no strands".into()));
        }
        Ok(out)
    }

    /// Rebuilds a groom from these points (no widths or colours).
    pub fn to_groom(&self) -> Groom {
        Groom { strands: (0..self.strand_count()).map(|s| Strand::new(self.strand(s).to_vec())).collect() }
    }

    /// Number of strands.
    pub fn strand_count(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// Index range of strand `s` in [`FlatStrands::points`].
    pub fn range(&self, s: usize) -> std::ops::Range<usize> {
        self.offsets[s]..self.offsets[s + 1]
    }

    /// Control points of strand `s`, root first.
    pub fn strand(&self, s: usize) -> &[[f32; 3]] {
        &self.points[self.range(s)]
    }

    /// Root (first control point) of every strand.
    pub fn roots(&self) -> Vec<[f32; 3]> {
        self.offsets[..self.strand_count()].iter().map(|&o| self.points[o]).collect()
    }

    /// Rest length of every segment, in strand order: segment `k` of strand
    /// `s` is stored at `offsets[s] - s + k` (one fewer segment than points
    /// per strand). Used by [`crate::preserve_lengths`].
    pub fn segment_lengths(&self) -> Vec<f32> {
        let mut out = Vec::with_capacity(self.points.len() - self.strand_count());
        for s in 0..self.strand_count() {
            out.extend(self.strand(s).windows(2).map(|w| norm(sub(w[1], w[0]))));
        }
        out
    }

    /// Same strand structure with other points (e.g. the deformed ones);
    /// fails when the point count differs.
    pub fn with_points(&self, points: Vec<[f32; 3]>) -> Result<Self, StrandError> {
        if points.len() != self.points.len() {
            return Err(StrandError::Mismatch { what: "points", expected: self.points.len(), got: points.len() });
        }
        Ok(FlatStrands { points, offsets: self.offsets.clone() })
    }

    /// Appends all strands of `other` (proxies after guides).
    pub fn append(&mut self, other: &FlatStrands) {
        let base = self.points.len();
        self.points.extend_from_slice(&other.points);
        self.offsets.extend(other.offsets[1..].iter().map(|o| o + base));
    }
}

/// Linear arc-length resampling of a polyline to `n >= 2` points, root and
/// tip kept. Polyline rather than spline: it never fails on repeated points
/// and guides are dense enough that the difference is below a strand width.
pub(crate) fn resample_polyline(pts: &[V3], n: usize) -> Vec<V3> {
    let mut acc = Vec::with_capacity(pts.len());
    let mut s = 0.0f64;
    acc.push(0.0);
    for w in pts.windows(2) {
        s += norm(sub(w[1], w[0])) as f64;
        acc.push(s);
    }
    let total = s;
    (0..n)
        .map(|k| {
            let target = total * k as f64 / (n - 1) as f64;
            if total <= 0.0 {
                return pts[0];
            }
            let j = acc.partition_point(|&a| a < target).clamp(1, pts.len() - 1);
            let span = acc[j] - acc[j - 1];
            let f = if span > 0.0 { ((target - acc[j - 1]) / span).clamp(0.0, 1.0) } else { 0.0 };
            nst3d_core::math::lerp(pts[j - 1], pts[j], f as f32)
        })
        .collect()
}
