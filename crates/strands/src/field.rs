//! The volumetric deformation field of Sec. 3.1 (eq. 4–5): learnable
//! velocities `v_j` live at sample positions `o_j` taken on the guide
//! strands' control points, and every control point `p_i` (guides and
//! densified proxies alike) is transported by one forward-Euler step with
//! `Δt = 1`:
//!
//! `T(p_i, v) = p_i + I(p_i, v)`, `I(p_i, v) = Σ_{j ∈ N(i)} w_ij v_j`,
//! `w_ij = φ(‖o_j − p_i‖) / Σ_{l ∈ N(i)} φ(‖o_l − p_i‖)`,
//!
//! over the `k` nearest samples `N(i)`. Eq. 5 writes the sum without the
//! normalisation; we normalise (Shepard form) so the weights are a partition
//! of unity: a constant `v` translates the groom rigidly, and the learning
//! rates of Table 1 do not depend on `k` or the sample spacing.
//!
//! The weights depend only on the rest positions `p` and `o`, never on `v`,
//! so `T` is affine in `v`: the weights are computed once into a sparse
//! matrix `W` (rows = points, columns = samples), the forward is `p + W v`
//! and the backward is `∂L/∂v = Wᵀ ∂L/∂p'`. Only `v` is optimised.

use rayon::prelude::*;

use crate::kdtree::KdTree;
use crate::strands::FlatStrands;
use crate::StrandError;
use nst3d_core::math::add;

/// Radial basis function `φ` of eq. 5 (the paper allows "cubic or inverse
/// distance").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kernel {
    /// Compactly supported cubic, Müller et al. 2003's "spiky" kernel
    /// `φ(r) = (1 − r/h)³` for `r < h`, 0 beyond. The support `h` is the
    /// distance to the first sample *not* among the `k` nearest, so the
    /// dropped sample always has weight 0 and the field stays continuous as
    /// points move between neighbourhoods. (A polyharmonic `r³` grows with
    /// distance and only makes sense with a global linear solve, which the
    /// paper does not do.) Not interpolating: a point sitting on a sample
    /// still blends its neighbours.
    Cubic,
    /// Shepard inverse-squared distance `φ(r) = 1 / (r² + ε²)` with
    /// `ε = 10⁻⁴ h` to stay finite on a sample (where it interpolates).
    /// The k-NN truncation makes it jump where neighbour sets change, which
    /// is why [`Kernel::Cubic`] is the default.
    InverseDistance,
}

impl Kernel {
    /// Unnormalised weight at squared distance `r2` with support `h`.
    #[inline]
    fn phi(self, r2: f32, h: f32) -> f64 {
        match self {
            Kernel::Cubic => {
                let t = (1.0 - (r2 as f64).sqrt() / h as f64).max(0.0);
                t * t * t
            }
            Kernel::InverseDistance => {
                let eps = 1e-4 * h as f64;
                1.0 / (r2 as f64 + eps * eps + 1e-30)
            }
        }
    }
}

/// How many guide control points carry a velocity sample (Table 1's
/// sampling density ρ).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SampleDensity {
    /// Fraction `ρ ∈ (0, 1]` of all guide control points, taken at a
    /// uniform stride `1/ρ` over the guides' points in order: global point
    /// `i` is a sample when `⌊(i+1)ρ + ½⌋ > ⌊iρ + ½⌋` (≈ `round(ρN)` in
    /// all). Table 1's counts confirm the reading: velocity samples = ρ ×
    /// guide control points (0.665 × 4 K × 100 = 266 K for Short Hair,
    /// 0.333 × 75.75 K × 8 = 202 K for the Cat — a per-strand floor would
    /// give 2 of 8 points, 152 K). The stride's phase drifts from strand to
    /// strand, so samples are not all at the same strand positions.
    Fraction(f32),
    /// Every `k`-th control point, starting at the root.
    EveryKth(usize),
}

/// Indices (into `guides.points`) of the control points that carry a
/// velocity sample `o_j`, strand by strand.
pub fn velocity_sample_indices(guides: &FlatStrands, density: SampleDensity) -> Result<Vec<usize>, StrandError> {
    match density {
        SampleDensity::Fraction(r) if !(r > 0.0 && r <= 1.0) => {
            return Err(StrandError::Parameter(format!("sampling density ρ = {r} is not in (0, 1]")))
        }
        SampleDensity::EveryKth(0) => {
            return Err(StrandError::Parameter("sampling stride k = 0, need at least 1".into()))
        }
        _ => {}
    }
    let mut out = Vec::new();
    for s in 0..guides.strand_count() {
        for (k, i) in guides.range(s).enumerate() {
            let take = match density {
                SampleDensity::Fraction(r) => {
                    let r = r as f64;
                    ((i + 1) as f64 * r + 0.5).floor() > (i as f64 * r + 0.5).floor()
                }
                SampleDensity::EveryKth(n) => k % n == 0,
            };
            if take {
                out.push(i);
            }
        }
    }
    if out.is_empty() {
        return Err(StrandError::Parameter("sampling density selects no velocity sample".into()));
    }
    Ok(out)
}

/// A row-normalised sparse interpolation matrix `W` (targets × sources) and
/// its transpose, both in compressed-row form so forward and backward are
/// parallel gathers with no atomics and deterministic sums.
#[derive(Clone, Debug)]
pub struct RbfWeights {
    sources: usize,
    row_ptr: Vec<usize>,
    cols: Vec<u32>,
    vals: Vec<f32>,
    t_row_ptr: Vec<usize>,
    t_cols: Vec<u32>,
    t_vals: Vec<f32>,
}

impl RbfWeights {
    /// Weights interpolating values at `sources` onto `targets` with the `k`
    /// nearest sources of each target (see [`Kernel`]).
    pub fn new(sources: &[[f32; 3]], targets: &[[f32; 3]], kernel: Kernel, k: usize) -> Result<Self, StrandError> {
        if sources.is_empty() {
            return Err(StrandError::Invalid("no RBF source positions".into()));
        }
        if k == 0 {
            return Err(StrandError::Parameter("RBF neighbour count k = 0, need at least 1".into()));
        }
        let tree = KdTree::new(sources);
        // Every row holds the same number of weights, so the matrix is
        // filled in place: a row apiece in fresh vectors was 1.2 GB of
        // temporaries for a 3-million-point groom at 48 neighbours, a fifth
        // of the set-up in page clearing and copies.
        let used = k.min(sources.len());
        let mut cols = vec![0u32; targets.len() * used];
        let mut vals = vec![0f32; targets.len() * used];
        cols.par_chunks_mut(used).zip(vals.par_chunks_mut(used)).zip(targets.par_iter()).for_each(
            |((row_cols, row_vals), &p)| {
                let nn = tree.knn(p, k + 1);
                let far = nn[used - 1].0.sqrt();
                // Support: the first excluded sample, or (too few samples)
                // twice the farthest used one, so every used weight is > 0.
                let h = if nn.len() > k { nn[k].0.sqrt() } else { 2.0 * far };
                let h = h.max(far * (1.0 + 1e-6)).max(1e-20);
                let mut w: Vec<f64> = nn[..used].iter().map(|&(r2, _)| kernel.phi(r2, h)).collect();
                let mut sum: f64 = w.iter().sum();
                if sum.is_nan() || sum <= 0.0 {
                    // All used samples sit on the support boundary (ties):
                    // fall back to an average, still a partition of unity.
                    w.iter_mut().for_each(|x| *x = 1.0);
                    sum = used as f64;
                }
                for (e, (&(_, j), &wj)) in nn[..used].iter().zip(&w).enumerate() {
                    row_cols[e] = j;
                    row_vals[e] = (wj / sum) as f32;
                }
            },
        );
        let row_ptr: Vec<usize> = (0..=targets.len()).map(|i| i * used).collect();
        // Transpose by counting sort on the column index.
        let mut t_row_ptr = vec![0usize; sources.len() + 1];
        for &j in &cols {
            t_row_ptr[j as usize + 1] += 1;
        }
        for j in 0..sources.len() {
            t_row_ptr[j + 1] += t_row_ptr[j];
        }
        let mut fill = t_row_ptr.clone();
        let mut t_cols = vec![0u32; cols.len()];
        let mut t_vals = vec![0f32; cols.len()];
        for i in 0..targets.len() {
            for e in row_ptr[i]..row_ptr[i + 1] {
                let j = cols[e] as usize;
                t_cols[fill[j]] = i as u32;
                t_vals[fill[j]] = vals[e];
                fill[j] += 1;
            }
        }
        Ok(RbfWeights { sources: sources.len(), row_ptr, cols, vals, t_row_ptr, t_cols, t_vals })
    }

    /// Number of targets (rows).
    pub fn targets(&self) -> usize {
        self.row_ptr.len() - 1
    }

    /// Number of sources (columns).
    pub fn sources(&self) -> usize {
        self.sources
    }

    /// Number of stored weights.
    pub fn nnz(&self) -> usize {
        self.vals.len()
    }

    /// `(source index, weight)` pairs of target `i`'s row.
    pub fn row(&self, i: usize) -> impl Iterator<Item = (usize, f32)> + '_ {
        let r = self.row_ptr[i]..self.row_ptr[i + 1];
        self.cols[r.clone()].iter().zip(&self.vals[r]).map(|(&j, &w)| (j as usize, w))
    }

    /// `W v`: source values interpolated at every target.
    pub fn apply(&self, v: &[[f32; 3]]) -> Result<Vec<[f32; 3]>, StrandError> {
        check_len("source values", self.sources, v.len())?;
        Ok(gather(&self.row_ptr, &self.cols, &self.vals, v))
    }

    /// `Wᵀ g`: the adjoint of [`RbfWeights::apply`], sending target
    /// gradients back to the sources.
    pub fn apply_transpose(&self, g: &[[f32; 3]]) -> Result<Vec<[f32; 3]>, StrandError> {
        check_len("target gradients", self.targets(), g.len())?;
        Ok(gather(&self.t_row_ptr, &self.t_cols, &self.t_vals, g))
    }
}

fn check_len(what: &'static str, expected: usize, got: usize) -> Result<(), StrandError> {
    if expected != got {
        return Err(StrandError::Mismatch { what, expected, got });
    }
    Ok(())
}

/// Compressed-row matrix times a vector of 3-vectors, one row per task.
fn gather(row_ptr: &[usize], cols: &[u32], vals: &[f32], x: &[[f32; 3]]) -> Vec<[f32; 3]> {
    (0..row_ptr.len() - 1)
        .into_par_iter()
        .with_min_len(256)
        .map(|i| {
            let mut acc = [0f64; 3];
            for e in row_ptr[i]..row_ptr[i + 1] {
                let (w, xv) = (vals[e] as f64, x[cols[e] as usize]);
                for a in 0..3 {
                    acc[a] += w * xv[a] as f64;
                }
            }
            acc.map(|c| c as f32)
        })
        .collect()
}

/// The deformation field of eq. 5 bound to a fixed set of rest points: the
/// velocity samples `o_j`, the rest control points `p_i` and their
/// precomputed interpolation weights.
#[derive(Clone, Debug)]
pub struct DeformationField {
    samples: Vec<[f32; 3]>,
    rest: Vec<[f32; 3]>,
    weights: RbfWeights,
    kernel: Kernel,
}

impl DeformationField {
    /// Field with samples at `samples` (the `o_j`) acting on `rest_points`
    /// (the `p_i`: guides and proxies), each point blending its `k` nearest
    /// samples with `kernel`.
    pub fn new(
        samples: Vec<[f32; 3]>,
        rest_points: &[[f32; 3]],
        kernel: Kernel,
        k: usize,
    ) -> Result<Self, StrandError> {
        let weights = RbfWeights::new(&samples, rest_points, kernel, k)?;
        Ok(DeformationField { samples, rest: rest_points.to_vec(), weights, kernel })
    }

    /// The usual setup: samples on the guides at `density`, acting on all
    /// points of `strands` (guides followed by any proxies). `guides` must be
    /// the leading strands of `strands` or a separate set.
    pub fn on_guides(
        guides: &FlatStrands,
        strands: &FlatStrands,
        density: SampleDensity,
        kernel: Kernel,
        k: usize,
    ) -> Result<Self, StrandError> {
        let idx = velocity_sample_indices(guides, density)?;
        let samples = idx.iter().map(|&i| guides.points[i]).collect();
        Self::new(samples, &strands.points, kernel, k)
    }

    /// Sample positions `o_j`.
    pub fn samples(&self) -> &[[f32; 3]] {
        &self.samples
    }

    /// Number of learnable velocities (`v` has this many 3-vectors).
    pub fn sample_count(&self) -> usize {
        self.samples.len()
    }

    /// Rest control points `p_i`.
    pub fn rest_points(&self) -> &[[f32; 3]] {
        &self.rest
    }

    /// Kernel the weights were built with.
    pub fn kernel(&self) -> Kernel {
        self.kernel
    }

    /// The precomputed interpolation matrix `W`.
    pub fn weights(&self) -> &RbfWeights {
        &self.weights
    }

    /// Displacement `I(p_i, v)` of every rest point.
    pub fn displacement(&self, v: &[[f32; 3]]) -> Result<Vec<[f32; 3]>, StrandError> {
        self.weights.apply(v)
    }

    /// Forward: transported points `T(p_i, v) = p_i + I(p_i, v)`.
    pub fn forward(&self, v: &[[f32; 3]]) -> Result<Vec<[f32; 3]>, StrandError> {
        let mut d = self.weights.apply(v)?;
        d.par_iter_mut().zip(&self.rest).for_each(|(d, &p)| *d = add(*d, p));
        Ok(d)
    }

    /// Backward of [`DeformationField::forward`]: `∂L/∂v = Wᵀ ∂L/∂p'` from
    /// the gradient on the transported points (`T` is affine in `v`, so this
    /// is exact at any `v`).
    pub fn backward(&self, grad_points: &[[f32; 3]]) -> Result<Vec<[f32; 3]>, StrandError> {
        self.weights.apply_transpose(grad_points)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::{check_gradient, dot, pseudo_random};
    use nst3d_core::math::V3;

    fn pts(n: usize, seed: u64) -> Vec<V3> {
        pseudo_random(3 * n, seed).chunks(3).map(|c| [c[0], c[1], c[2]]).collect()
    }
    fn flat(v: &[V3]) -> Vec<f32> {
        v.iter().flatten().copied().collect()
    }
    fn unflat(x: &[f32]) -> Vec<V3> {
        x.chunks(3).map(|c| [c[0], c[1], c[2]]).collect()
    }

    #[test]
    fn forward_backward_gradcheck_both_kernels() {
        for kernel in [Kernel::Cubic, Kernel::InverseDistance] {
            let field = DeformationField::new(pts(60, 1), &pts(300, 2), kernel, 6).unwrap();
            let v = flat(&pts(60, 3));
            let w = flat(&pts(300, 4));
            let analytic = flat(&field.backward(&unflat(&w)).unwrap());
            let loss = |x: &[f32]| dot(&w, &flat(&field.forward(&unflat(x)).unwrap()));
            // T is affine in v, so any step is exact up to rounding: a large one
            // keeps f32 rounding of the outputs out of the difference.
            let r = check_gradient(&v, &analytic, loss, 0.5, 180, 1e-2);
            assert!(r.max_rel_err < 1e-3, "{kernel:?}: {r:?}");
        }
    }

    #[test]
    fn partition_of_unity_and_sparsity() {
        for kernel in [Kernel::Cubic, Kernel::InverseDistance] {
            let field = DeformationField::new(pts(40, 5), &pts(200, 6), kernel, 5).unwrap();
            let t = [0.1, -0.2, 0.3];
            let moved = field.forward(&vec![t; 40]).unwrap();
            for (m, p) in moved.iter().zip(field.rest_points()) {
                for a in 0..3 {
                    assert!((m[a] - p[a] - t[a]).abs() < 1e-5);
                }
            }
            assert!(field.weights().nnz() <= 200 * 5);
            for i in 0..200 {
                assert!(field.weights().row(i).all(|(_, w)| (0.0..=1.0 + 1e-6).contains(&w)));
            }
        }
        // Inverse distance interpolates at the samples themselves.
        let s = pts(30, 7);
        let field = DeformationField::new(s.clone(), &s, Kernel::InverseDistance, 4).unwrap();
        let v = pts(30, 8);
        let d = field.displacement(&v).unwrap();
        for (a, b) in d.iter().zip(&v) {
            assert!((0..3).all(|c| (a[c] - b[c]).abs() < 1e-4));
        }
    }

    #[test]
    fn cubic_field_is_continuous_across_neighbourhood_changes() {
        // Walk a point along a line through a cloud; the displacement must
        // change by O(step), with no jump when a sample enters or leaves N(i).
        let s = pts(50, 9);
        let v = pts(50, 10);
        let line: Vec<V3> = (0..2001).map(|i| [-1.0 + i as f32 * 1e-3, 0.1, -0.05]).collect();
        let field = DeformationField::new(s, &line, Kernel::Cubic, 6).unwrap();
        let d = field.displacement(&v).unwrap();
        let max_jump =
            d.windows(2).map(|w| nst3d_core::math::norm(nst3d_core::math::sub(w[1], w[0]))).fold(0.0, f32::max);
        assert!(max_jump < 0.05, "max jump {max_jump}");
    }

    #[test]
    fn sampling_density_counts() {
        let strands =
            FlatStrands::from_strands((0..10).map(|s| (0..100).map(|k| [s as f32, k as f32, 0.0]).collect())).unwrap();
        let n = |d| velocity_sample_indices(&strands, d).unwrap().len();
        assert_eq!(n(SampleDensity::Fraction(1.0)), 1000);
        assert_eq!(n(SampleDensity::Fraction(0.5)), 500);
        assert_eq!(n(SampleDensity::Fraction(0.665)), 665);
        assert_eq!(n(SampleDensity::EveryKth(10)), 100);
        let nine =
            FlatStrands::from_strands((0..10).map(|s| (0..9).map(|k| [s as f32, k as f32, 0.0]).collect())).unwrap();
        assert_eq!(velocity_sample_indices(&nine, SampleDensity::Fraction(0.333)).unwrap().len(), 30);
        assert!(velocity_sample_indices(&strands, SampleDensity::Fraction(0.0)).is_err());
        assert!(velocity_sample_indices(&strands, SampleDensity::EveryKth(0)).is_err());
    }
}
