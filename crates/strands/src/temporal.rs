//! Temporal coherency for animated grooms (Sec. 3.3).
//!
//! **EMA of velocities across frames (eq. 8).** Frame `t`'s optimised field
//! is blended with the previous frame's field carried along the animation:
//! `v̂ᵗ = (1 − f) vᵗ + f T(vᵗ⁻¹, uᵗ⁻¹)`, with the decaying blend
//! `f(ν, σ) = (1 − min(1, m/ν)) σ`: `σ` at the first iteration, falling
//! linearly to 0 once `m ≥ ν`, so later iterations are free to refine.
//! The paper calls `m` "the optimization iteration step" and `ν` the "EMA
//! decaying period", but Table 1 gives `ν ∈ {0.6, 0.7}`: with raw iteration
//! counts that would disable the EMA from iteration 1, so we read `m` as the
//! *fraction* of the frame's iterations done (`iteration / total` in
//! `[0, 1]`) — the EMA then fades out over the first 60–70 % of each frame.
//! [`ema_blend_factor`] just evaluates the formula; pass raw counts and `ν`
//! in iterations if that is the reading you want.
//!
//! **Transport of the previous field** ([`transport_velocities`]): the
//! samples `o` of frame `t−1` move with the animation velocity `uᵗ⁻¹`
//! (forward Euler, `Δt = 1` frame, the same `T` as eq. 5) and the field is
//! re-interpolated at frame `t`'s samples with the same RBF kernel.
//!
//! **1€ filter (eq. 9–10, Casiez et al. 2012)** on the optimised control
//! point positions, per point: `γ = 2πωΔt / (2πωΔt + 1)` with
//! `ω = f_min + β ‖û‖` and `Δt = 1/FPS`, `p̂ᵗ = γ pᵗ + (1 − γ) p̂ᵗ⁻¹`. The
//! speed `û` is a low-passed derivative: in the standard filter the
//! derivative is estimated from the signal, `(pᵗ − p̂ᵗ⁻¹)·FPS`, and smoothed
//! with the cutoff `d_cutoff`; the paper instead feeds the animation's
//! control-point velocity `uᵗ` and smooths it with a constant `α` (eq. 9).
//! Both are [`DerivativeSmoothing`] choices of one filter.

use std::f32::consts::TAU;

use crate::field::{Kernel, RbfWeights};
use crate::StrandError;
use nst3d_core::math::{add, norm, scale, V3};

/// EMA blending weight `f(ν, σ) = (1 − min(1, m/ν)) σ` of eq. 8 (see the
/// module notes for the meaning of `m`).
pub fn ema_blend_factor(m: f32, nu: f32, sigma: f32) -> Result<f32, StrandError> {
    if !(nu > 0.0 && nu.is_finite()) {
        return Err(StrandError::Parameter(format!("EMA decaying period ν = {nu} must be > 0")));
    }
    if !(0.0..=1.0).contains(&sigma) {
        return Err(StrandError::Parameter(format!("EMA coefficient σ = {sigma} is not in [0, 1]")));
    }
    Ok((1.0 - (m.max(0.0) / nu).min(1.0)) * sigma)
}

/// `v̂ = (1 − f) v + f v_prev` (eq. 8), `v_prev` already transported to this
/// frame's samples.
pub fn ema_blend(current: &[[f32; 3]], transported_prev: &[[f32; 3]], f: f32) -> Result<Vec<[f32; 3]>, StrandError> {
    if current.len() != transported_prev.len() {
        return Err(StrandError::Mismatch {
            what: "previous-frame velocities",
            expected: current.len(),
            got: transported_prev.len(),
        });
    }
    Ok(current.iter().zip(transported_prev).map(|(&v, &w)| add(scale(v, 1.0 - f), scale(w, f))).collect())
}

/// Carries frame `t−1`'s field to frame `t`: samples `prev_samples` move by
/// `prev_motion` (the animation's per-frame displacement `uᵗ⁻¹` at each
/// sample) and the velocities `prev_velocities` are interpolated from those
/// moved positions onto `new_samples` with `kernel` over `k` neighbours.
pub fn transport_velocities(
    prev_samples: &[[f32; 3]],
    prev_velocities: &[[f32; 3]],
    prev_motion: &[[f32; 3]],
    new_samples: &[[f32; 3]],
    kernel: Kernel,
    k: usize,
) -> Result<Vec<[f32; 3]>, StrandError> {
    for (what, len) in [("previous velocities", prev_velocities.len()), ("previous sample motion", prev_motion.len())] {
        if len != prev_samples.len() {
            return Err(StrandError::Mismatch { what, expected: prev_samples.len(), got: len });
        }
    }
    let moved: Vec<V3> = prev_samples.iter().zip(prev_motion).map(|(&o, &u)| add(o, u)).collect();
    RbfWeights::new(&moved, new_samples, kernel, k)?.apply(prev_velocities)
}

/// `γ = 2π f_c Δt / (2π f_c Δt + 1)`: the exponential-smoothing factor of a
/// first-order low-pass with cutoff `f_c` (Hz) sampled every `Δt` seconds
/// (eq. 10).
pub fn smoothing_factor(cutoff_hz: f32, dt: f32) -> f32 {
    let r = TAU * cutoff_hz * dt;
    r / (r + 1.0)
}

/// How the 1€ filter low-passes the speed that drives its cutoff.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum DerivativeSmoothing {
    /// Standard 1€: the derivative is estimated from the signal and smoothed
    /// with this cutoff frequency (Hz, Casiez et al. use 1).
    Cutoff(f32),
    /// Paper eq. 9: a constant blend `α ∈ (0, 1]` (Table 1's "1€ filter
    /// blending parameter").
    Blend(f32),
}

/// 1€ filter parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OneEuroParams {
    /// Minimum cutoff frequency `f_min` (Hz).
    pub min_cutoff: f32,
    /// Speed coefficient `β` (cutoff Hz per unit/second of speed).
    pub beta: f32,
    /// Speed smoothing.
    pub derivative: DerivativeSmoothing,
    /// Frame rate; `Δt = 1/fps`.
    pub fps: f32,
}

impl OneEuroParams {
    fn validate(&self) -> Result<(), StrandError> {
        let bad = |m: String| Err(StrandError::Parameter(m));
        if !(self.min_cutoff > 0.0 && self.min_cutoff.is_finite()) {
            return bad(format!("1€ min cutoff f_min = {} must be > 0", self.min_cutoff));
        }
        if !(self.beta >= 0.0 && self.beta.is_finite()) {
            return bad(format!("1€ speed coefficient β = {} must be ≥ 0", self.beta));
        }
        if !(self.fps > 0.0 && self.fps.is_finite()) {
            return bad(format!("frame rate {} must be > 0", self.fps));
        }
        match self.derivative {
            DerivativeSmoothing::Cutoff(c) if !(c > 0.0 && c.is_finite()) => {
                bad(format!("1€ derivative cutoff {c} must be > 0"))
            }
            DerivativeSmoothing::Blend(a) if !(a > 0.0 && a <= 1.0) => {
                bad(format!("1€ blending α = {a} is not in (0, 1]"))
            }
            _ => Ok(()),
        }
    }
}

/// A 1€ filter's history: the last filtered value and derivative per point.
pub type OneEuroHistory = (Vec<V3>, Vec<V3>);

/// Per-point 1€ filter over a sequence of frames of the same point set.
#[derive(Clone, Debug)]
pub struct OneEuroFilter {
    params: OneEuroParams,
    /// `(p̂ᵗ⁻¹, ûᵗ⁻¹)` per point after the first frame.
    state: Option<OneEuroHistory>,
}

impl OneEuroFilter {
    /// A filter that has seen no frame yet.
    pub fn new(params: OneEuroParams) -> Result<Self, StrandError> {
        params.validate()?;
        Ok(OneEuroFilter { params, state: None })
    }

    /// Forgets the history (next frame passes through).
    pub fn reset(&mut self) {
        self.state = None;
    }

    /// The history: `(p̂ᵗ⁻¹, ûᵗ⁻¹)` per point, `None` before the first frame
    /// (what a resumed sequence must restore, see [`crate::sequence`]).
    pub fn history(&self) -> Option<(&[V3], &[V3])> {
        self.state.as_ref().map(|(x, d)| (x.as_slice(), d.as_slice()))
    }

    /// Restores a history saved with [`OneEuroFilter::history`].
    pub fn set_history(&mut self, history: Option<OneEuroHistory>) -> Result<(), StrandError> {
        if let Some((x, d)) = &history {
            if x.len() != d.len() {
                return Err(StrandError::Mismatch { what: "1€ derivative history", expected: x.len(), got: d.len() });
            }
        }
        self.state = history;
        Ok(())
    }

    /// Filters one frame, estimating the speed from the signal (standard
    /// 1€). The first frame passes through unchanged.
    pub fn filter(&mut self, points: &[[f32; 3]]) -> Result<Vec<[f32; 3]>, StrandError> {
        self.step(points, None)
    }

    /// Filters one frame with the animation's control-point velocity `u`
    /// (units per second) as the speed, as in eq. 9.
    pub fn filter_with_velocity(
        &mut self,
        points: &[[f32; 3]],
        velocity: &[[f32; 3]],
    ) -> Result<Vec<[f32; 3]>, StrandError> {
        if velocity.len() != points.len() {
            return Err(StrandError::Mismatch {
                what: "point velocities",
                expected: points.len(),
                got: velocity.len(),
            });
        }
        self.step(points, Some(velocity))
    }

    fn step(&mut self, x: &[V3], u: Option<&[V3]>) -> Result<Vec<V3>, StrandError> {
        let dt = 1.0 / self.params.fps;
        let Some((prev_x, prev_d)) = &mut self.state else {
            let d0 = u.map_or_else(|| vec![[0.0; 3]; x.len()], |u| u.to_vec());
            self.state = Some((x.to_vec(), d0));
            return Ok(x.to_vec());
        };
        if prev_x.len() != x.len() {
            return Err(StrandError::Mismatch { what: "points per frame", expected: prev_x.len(), got: x.len() });
        }
        let a_d = match self.params.derivative {
            DerivativeSmoothing::Cutoff(c) => smoothing_factor(c, dt),
            DerivativeSmoothing::Blend(a) => a,
        };
        for i in 0..x.len() {
            let raw_d = match u {
                Some(u) => u[i],
                None => std::array::from_fn(|a| (x[i][a] - prev_x[i][a]) / dt),
            };
            let d: V3 = std::array::from_fn(|a| a_d * raw_d[a] + (1.0 - a_d) * prev_d[i][a]);
            let g = smoothing_factor(self.params.min_cutoff + self.params.beta * norm(d), dt);
            prev_x[i] = std::array::from_fn(|a| g * x[i][a] + (1.0 - g) * prev_x[i][a]);
            prev_d[i] = d;
        }
        Ok(prev_x.clone())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::pseudo_random;

    /// Scalar 1€ filter written straight from Casiez et al. 2012 (Fig. 4
    /// pseudo-code), as an independent reference.
    struct Reference {
        min_cutoff: f64,
        beta: f64,
        d_cutoff: f64,
        rate: f64,
        x_hat: Option<f64>,
        dx_hat: f64,
    }
    impl Reference {
        fn alpha(&self, cutoff: f64) -> f64 {
            let tau = 1.0 / (2.0 * std::f64::consts::PI * cutoff);
            let te = 1.0 / self.rate;
            1.0 / (1.0 + tau / te)
        }
        fn filter(&mut self, x: f64) -> f64 {
            let Some(prev) = self.x_hat else {
                self.x_hat = Some(x);
                return x;
            };
            let dx = (x - prev) * self.rate;
            self.dx_hat = self.alpha(self.d_cutoff) * dx + (1.0 - self.alpha(self.d_cutoff)) * self.dx_hat;
            let cutoff = self.min_cutoff + self.beta * self.dx_hat.abs();
            let a = self.alpha(cutoff);
            let out = a * x + (1.0 - a) * prev;
            self.x_hat = Some(out);
            out
        }
    }

    fn run(params: OneEuroParams, xs: &[f32]) -> Vec<f32> {
        let mut f = OneEuroFilter::new(params).unwrap();
        xs.iter().map(|&x| f.filter(&[[x, 0.0, 0.0]]).unwrap()[0][0]).collect()
    }

    #[test]
    fn one_euro_matches_reference_reduces_jitter_and_tracks_steps() {
        let fps = 60.0;
        let params = OneEuroParams { min_cutoff: 1.0, beta: 0.5, derivative: DerivativeSmoothing::Cutoff(1.0), fps };
        let noise = pseudo_random(600, 21);
        let truth: Vec<f32> = (0..600).map(|i| (TAU * 0.25 * i as f32 / fps).sin()).collect();
        let noisy: Vec<f32> = truth.iter().zip(&noise).map(|(t, n)| t + 0.05 * n).collect();
        let got = run(params, &noisy);
        let mut r = Reference { min_cutoff: 1.0, beta: 0.5, d_cutoff: 1.0, rate: fps as f64, x_hat: None, dx_hat: 0.0 };
        for (&g, &x) in got.iter().zip(&noisy) {
            assert!((g as f64 - r.filter(x as f64)).abs() < 1e-5);
        }
        // Jitter: RMS of the frame-to-frame change minus the true change.
        // (after a one-second warm-up).
        let jitter = |s: &[f32]| {
            let e: f32 = (61..s.len()).map(|i| ((s[i] - s[i - 1]) - (truth[i] - truth[i - 1])).powi(2)).sum();
            (e / (s.len() - 61) as f32).sqrt()
        };
        assert!(jitter(&got) < 0.3 * jitter(&noisy), "{} vs {}", jitter(&got), jitter(&noisy));
        let err: f32 = got[60..].iter().zip(&truth[60..]).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
        assert!(err < 0.1, "tracking error {err}");

        // A unit step: the speed term opens the cutoff, so the lag is short;
        // a plain low-pass at f_min lags far more.
        let step: Vec<f32> = (0..120).map(|i| if i < 60 { 0.0 } else { 1.0 }).collect();
        let fast = run(OneEuroParams { beta: 5.0, ..params }, &step);
        let slow = run(OneEuroParams { beta: 0.0, ..params }, &step);
        let lag = |s: &[f32]| s[60..].iter().position(|&v| v >= 0.9).unwrap_or(usize::MAX);
        assert!(lag(&fast) <= 5, "1€ lag {}", lag(&fast));
        assert!(lag(&slow) > 4 * lag(&fast), "low-pass lag {}", lag(&slow));
    }

    #[test]
    fn one_euro_with_animation_velocity_follows_eq_9_10() {
        let params =
            OneEuroParams { min_cutoff: 9.0, beta: 0.2, derivative: DerivativeSmoothing::Blend(0.34), fps: 24.0 };
        let mut f = OneEuroFilter::new(params).unwrap();
        let (x0, x1, u0, u1) = ([0.0f32; 3], [1.0f32, 2.0, 0.0], [0.0f32, 3.0, 0.0], [0.0f32, 1.0, 0.0]);
        assert_eq!(f.filter_with_velocity(&[x0], &[u0]).unwrap(), vec![x0]);
        let out = f.filter_with_velocity(&[x1], &[u1]).unwrap()[0];
        let u_hat = 0.34 * 1.0 + 0.66 * 3.0;
        let w = 9.0 + 0.2 * u_hat;
        let dt = 1.0 / 24.0;
        let g = TAU * w * dt / (TAU * w * dt + 1.0);
        assert!((out[0] - g).abs() < 1e-6 && (out[1] - 2.0 * g).abs() < 1e-6);
        assert!(OneEuroFilter::new(OneEuroParams { fps: 0.0, ..params }).is_err());
        assert!(OneEuroFilter::new(OneEuroParams { derivative: DerivativeSmoothing::Blend(1.5), ..params }).is_err());
        assert!(f.filter(&[x0, x1]).is_err());
    }

    #[test]
    fn ema_blend_limits() {
        assert_eq!(ema_blend_factor(0.0, 0.7, 1.0).unwrap(), 1.0);
        assert_eq!(ema_blend_factor(0.7, 0.7, 1.0).unwrap(), 0.0);
        assert_eq!(ema_blend_factor(0.95, 0.7, 1.0).unwrap(), 0.0);
        assert!((ema_blend_factor(0.35, 0.7, 0.8).unwrap() - 0.4).abs() < 1e-6);
        let mut last = 1.0;
        for i in 0..=20 {
            let f = ema_blend_factor(i as f32 / 20.0, 0.6, 1.0).unwrap();
            assert!(f <= last);
            last = f;
        }
        assert!(ema_blend_factor(0.1, 0.0, 1.0).is_err());
        assert!(ema_blend_factor(0.1, 0.5, 1.5).is_err());
        let (v, w) = ([[1.0, 2.0, 3.0]], [[-1.0, 0.0, 5.0]]);
        assert_eq!(ema_blend(&v, &w, 0.0).unwrap(), v.to_vec());
        assert_eq!(ema_blend(&v, &w, 1.0).unwrap(), w.to_vec());
        assert_eq!(ema_blend(&v, &w, 0.5).unwrap(), vec![[0.0, 1.0, 4.0]]);
        assert!(ema_blend(&v, &[], 0.5).is_err());
    }

    #[test]
    fn transport_follows_the_animation() {
        let o: Vec<V3> = pseudo_random(3 * 80, 31).chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
        let v: Vec<V3> = pseudo_random(3 * 80, 32).chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
        let u = vec![[0.3, -0.1, 0.2]; 80];
        let moved: Vec<V3> = o.iter().map(|&p| add(p, u[0])).collect();
        // Rigid motion of the samples: the field is carried unchanged.
        let t = transport_velocities(&o, &v, &u, &moved, Kernel::InverseDistance, 4).unwrap();
        for (a, b) in t.iter().zip(&v) {
            assert!((0..3).all(|c| (a[c] - b[c]).abs() < 1e-4));
        }
        let constant = vec![[1.0, 2.0, -1.0]; 80];
        let t = transport_velocities(&o, &constant, &u, &o, Kernel::Cubic, 6).unwrap();
        assert!(t.iter().all(|a| (0..3).all(|c| (a[c] - constant[0][c]).abs() < 1e-5)));
        assert!(transport_velocities(&o, &v[..3], &u, &o, Kernel::Cubic, 6).is_err());
    }
}
