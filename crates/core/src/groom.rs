//! Hair and fur grooms as values: the strands the strand stylization
//! pipeline optimizes, independent of the file format they came from (the
//! readers and writers live in `nst3d-io`). The paper represents strands as
//! natural cubic splines through their control points ([`StrandSpline`]).

mod spline;

pub use spline::StrandSpline;

/// One hair strand: a polyline of control points from root to tip, plus
/// optional per-point attributes when the file carries them.
#[derive(Clone, Debug, PartialEq)]
pub struct Strand {
    /// Control points, root first.
    pub points: Vec<[f32; 3]>,
    /// Per-point width (diameter, file units), when the file stores one.
    pub widths: Option<Vec<f32>>,
    /// Per-point linear RGB colour in `[0, 1]`, when the file stores one.
    pub colors: Option<Vec<[f32; 3]>>,
}

impl Strand {
    /// A strand with points only.
    pub fn new(points: Vec<[f32; 3]>) -> Self {
        Self { points, widths: None, colors: None }
    }
}

/// A groom: the set of strands stylized together.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Groom {
    /// Strands in file order.
    pub strands: Vec<Strand>,
}

impl Groom {
    /// Total number of control points over all strands.
    pub fn point_count(&self) -> usize {
        self.strands.iter().map(|s| s.points.len()).sum()
    }

    /// Number of strands.
    pub fn strand_count(&self) -> usize {
        self.strands.len()
    }

    /// Axis-aligned bounds `(min, max)` of all points; `None` without points.
    pub fn bbox(&self) -> Option<([f32; 3], [f32; 3])> {
        let mut it = self.strands.iter().flat_map(|s| s.points.iter());
        let first = *it.next()?;
        let (mut lo, mut hi) = (first, first);
        for p in it {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        Some((lo, hi))
    }

    /// Checks the invariants the stylizer relies on: at least one strand,
    /// every strand with at least two points (a spline needs a segment),
    /// finite coordinates, and attribute arrays as long as the point array.
    /// The error names the first offending strand.
    pub fn validate(&self) -> Result<(), GroomError> {
        if self.strands.is_empty() {
            return Err(GroomError::NoStrands);
        }
        let bad = |strand: usize, reason: String| GroomError::InvalidStrand { strand, reason };
        for (i, s) in self.strands.iter().enumerate() {
            if s.points.len() < 2 {
                return Err(bad(i, format!("has {} point(s), need at least 2", s.points.len())));
            }
            if let Some(j) = s.points.iter().position(|p| p.iter().any(|c| !c.is_finite())) {
                return Err(bad(i, format!("point {j} is not finite: {:?}", s.points[j])));
            }
            if let Some(w) = &s.widths {
                if w.len() != s.points.len() {
                    return Err(bad(i, format!("{} widths for {} points", w.len(), s.points.len())));
                }
                if let Some(j) = w.iter().position(|c| !c.is_finite()) {
                    return Err(bad(i, format!("width {j} is not finite")));
                }
            }
            if let Some(c) = &s.colors {
                if c.len() != s.points.len() {
                    return Err(bad(i, format!("{} colours for {} points", c.len(), s.points.len())));
                }
            }
        }
        Ok(())
    }

    /// Gives this groom the per-point attributes of `from` (widths and
    /// colours, or their absence), keeping its own points: how a stylized
    /// groom, written in its input's topology, gets the input's attributes
    /// back unchanged. `from` must have the same topology, the same number
    /// of strands with the same number of points each, in the same order;
    /// otherwise nothing is changed and the error names the first
    /// difference.
    pub fn copy_attributes_from(&mut self, from: &Groom) -> Result<(), GroomError> {
        let mismatch = |reason: String| GroomError::TopologyMismatch { reason };
        if self.strands.len() != from.strands.len() {
            return Err(mismatch(format!(
                "{} strands, the groom whose attributes it takes has {}",
                self.strands.len(),
                from.strands.len()
            )));
        }
        if let Some((i, (a, b))) =
            self.strands.iter().zip(&from.strands).enumerate().find(|(_, (a, b))| a.points.len() != b.points.len())
        {
            return Err(mismatch(format!(
                "strand {i} has {} points, the groom whose attributes it takes has {}",
                a.points.len(),
                b.points.len()
            )));
        }
        for (a, b) in self.strands.iter_mut().zip(&from.strands) {
            a.widths.clone_from(&b.widths);
            a.colors.clone_from(&b.colors);
        }
        Ok(())
    }
}

/// Why a groom's values cannot be stylized: an invariant of
/// [`Groom::validate`] broken, or control points no spline fits. It names no
/// file because a groom in memory has none; `nst3d-io` attaches the path when
/// the groom came from (or goes to) a file.
#[derive(Clone, Debug, PartialEq)]
pub enum GroomError {
    /// The groom holds no strand at all.
    NoStrands,
    /// One strand breaks an invariant of [`Groom::validate`].
    InvalidStrand {
        /// Index of the strand in the groom.
        strand: usize,
        /// What is wrong with it.
        reason: String,
    },
    /// A spline cannot be built from the given control points.
    Spline {
        /// What is wrong with the control points.
        reason: String,
    },
    /// Two grooms that should have the same strands do not
    /// ([`Groom::copy_attributes_from`]).
    TopologyMismatch {
        /// The first difference.
        reason: String,
    },
}

impl std::fmt::Display for GroomError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // `<groom>` stands where a file name would be, so an in-memory
        // groom's message reads like a file's ("<path>: strand 3 ...").
        match self {
            GroomError::NoStrands => write!(f, "<groom>: groom has no strands"),
            GroomError::InvalidStrand { strand, reason } => write!(f, "<groom>: strand {strand} {reason}"),
            GroomError::Spline { reason } => write!(f, "cannot build strand spline: {reason}"),
            GroomError::TopologyMismatch { reason } => write!(f, "<groom>: not the same strands: {reason}"),
        }
    }
}

impl std::error::Error for GroomError {}
