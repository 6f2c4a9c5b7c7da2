//! Finite-difference gradient check shared by every differentiable op's tests.
//!
//! An op is checked through a scalar probe `L(x) = <w, f(x)>` with fixed random
//! weights `w`: the analytic gradient `J^T w` from the op's backward must match
//! central differences of `L` in `f64`-accumulated form.

/// Deterministic pseudo-random numbers in `[-1, 1)` (xorshift), so checks are
/// reproducible without a dependency.
pub fn pseudo_random(n: usize, seed: u64) -> Vec<f32> {
    let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    (0..n)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            ((s >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
        })
        .collect()
}

/// Result of a gradient check: the worst relative error over checked entries.
#[derive(Debug, Clone, Copy)]
pub struct GradCheck {
    /// max |analytic - numeric| / max(|analytic|, |numeric|, floor).
    pub max_rel_err: f64,
    /// Entry where it happened.
    pub worst_index: usize,
}

/// Compares `analytic` (gradient of the scalar `loss` at `x`) with central
/// differences of step `eps` at up to `max_checks` entries spread over `x`.
///
/// `loss` must be a pure function of `x`. `floor` keeps the relative error
/// meaningful where both gradients are near zero.
pub fn check_gradient(
    x: &[f32],
    analytic: &[f32],
    mut loss: impl FnMut(&[f32]) -> f64,
    eps: f32,
    max_checks: usize,
    floor: f64,
) -> GradCheck {
    assert_eq!(x.len(), analytic.len());
    let stride = (x.len() / max_checks.max(1)).max(1);
    let mut probe = x.to_vec();
    let mut worst = GradCheck { max_rel_err: 0.0, worst_index: 0 };
    for i in (0..x.len()).step_by(stride) {
        let orig = probe[i];
        probe[i] = orig + eps;
        let up = loss(&probe);
        probe[i] = orig - eps;
        let down = loss(&probe);
        probe[i] = orig;
        let numeric = (up - down) / (2.0 * eps as f64);
        let a = analytic[i] as f64;
        let rel = (a - numeric).abs() / a.abs().max(numeric.abs()).max(floor);
        if rel > worst.max_rel_err {
            worst = GradCheck { max_rel_err: rel, worst_index: i };
        }
    }
    worst
}

/// `<w, y>` accumulated in `f64`: the scalar probe used with [`check_gradient`].
pub fn dot(w: &[f32], y: &[f32]) -> f64 {
    w.iter().zip(y).map(|(a, b)| *a as f64 * *b as f64).sum()
}

/// The relative error of one directional derivative: the analytic `g · v`
/// against the central difference of `loss_along(t) = L(x + t v)` at `±step`.
/// One quotient checks a whole block of entries at once, well above the
/// loss's rounding even where each entry's own gradient is tiny (the first
/// layers of a deep chain), which a per-entry check with a floor passes
/// whatever their values.
pub fn directional(analytic: &[f32], v: &[f32], step: f32, mut loss_along: impl FnMut(f32) -> f64) -> f64 {
    assert_eq!(analytic.len(), v.len());
    let numeric = (loss_along(step) - loss_along(-step)) / (2.0 * step as f64);
    let a = dot(v, analytic);
    (a - numeric).abs() / a.abs().max(numeric.abs())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn square_passes_and_wrong_gradient_fails() {
        let x = pseudo_random(50, 1);
        let good: Vec<f32> = x.iter().map(|v| 2.0 * v).collect();
        let bad: Vec<f32> = x.iter().map(|v| 3.0 * v).collect();
        let f = |p: &[f32]| p.iter().map(|v| (*v as f64).powi(2)).sum::<f64>();
        assert!(check_gradient(&x, &good, f, 1e-3, 50, 1e-3).max_rel_err < 1e-3);
        assert!(check_gradient(&x, &bad, f, 1e-3, 50, 1e-3).max_rel_err > 0.1);
    }

    #[test]
    fn directional_passes_and_wrong_gradient_fails() {
        let x = pseudo_random(50, 2);
        let v = pseudo_random(50, 3);
        let along = |t: f32| x.iter().zip(&v).map(|(a, b)| ((a + t * b) as f64).powi(2)).sum::<f64>();
        let good: Vec<f32> = x.iter().map(|v| 2.0 * v).collect();
        let bad: Vec<f32> = x.iter().map(|v| 2.4 * v).collect();
        assert!(directional(&good, &v, 1e-2, along) < 1e-4);
        assert!(directional(&bad, &v, 1e-2, along) > 0.1);
    }
}
