//! Adam / AdamW with PyTorch's exact update rule (paper Sec. 5.1 uses ADAM to
//! optimize the velocity or density-scale field directly).
//!
//! The update follows `torch.optim.Adam`'s single-tensor CPU path operation by
//! operation, including where it rounds to `f32`, so a run matches the
//! reference to float rounding and Adam settings carry over unchanged.
//!
//! [`color_stage`] is the loop the colour stages of smoke and strands share
//! (views in turn, one Adam step each) with the two constants they agree on.

#![warn(missing_docs)]

pub mod color_stage;
pub mod schedule;

pub use color_stage::{optimise_in_turn, SweepLosses, COLOR_VIEWS, GREY_GUARD};
pub use schedule::{clip_grad_norm, OneCycle};

use rayon::prelude::*;

/// Why an optimizer state or setting was rejected.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum OptimError {
    /// A restored moment vector does not have one entry per parameter.
    #[error("adam state: {what} has {got} entries, the optimizer has {expected} parameters")]
    StateLength {
        /// Which vector (`"m"` or `"v"`).
        what: &'static str,
        /// Its length.
        got: usize,
        /// Parameter count.
        expected: usize,
    },
    /// A restored second moment is negative or not finite, which would make
    /// the update NaN.
    #[error("adam state: second moment v[{index}] = {value} is not a finite non-negative number")]
    BadSecondMoment {
        /// Entry index.
        index: usize,
        /// The offending value.
        value: f32,
    },
    /// A hyperparameter is outside the range PyTorch accepts.
    #[error("adam setting {name} = {value} is invalid (expected {expected})")]
    BadSetting {
        /// Field name.
        name: &'static str,
        /// The offending value.
        value: f32,
        /// Valid range, in words.
        expected: &'static str,
    },
}

/// Parameters per rayon task: large enough that scheduling is noise next to
/// the arithmetic, small enough that both cores get work on a 64³ field.
const CHUNK: usize = 1 << 15;

/// Adam optimizer over one flat parameter vector (e.g. a `128³ x 3` velocity
/// field), with optional L2 (`Adam`) or decoupled (`AdamW`) weight decay.
#[derive(Clone, Debug)]
pub struct Adam {
    /// Learning rate.
    pub lr: f32,
    /// Decay of the first-moment (mean) estimate.
    pub beta1: f32,
    /// Decay of the second-moment (uncentred variance) estimate.
    pub beta2: f32,
    /// Added to the bias-corrected `sqrt(v)`; keeps steps finite where `v ≈ 0`.
    pub eps: f32,
    /// Weight-decay coefficient (0 disables it).
    pub weight_decay: f32,
    /// `true`: AdamW, decay multiplies the parameters by `1 - lr·wd` before the
    /// step. `false`: Adam, decay adds `wd·p` to the gradient.
    pub decoupled: bool,
    m: Vec<f32>,
    v: Vec<f32>,
    step: u64,
}

impl Adam {
    /// Adam over `n` parameters with `torch.optim.Adam`'s defaults
    /// (betas 0.9 / 0.999, eps 1e-8, no weight decay).
    pub fn new(n: usize, lr: f32) -> Self {
        Self {
            lr,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            weight_decay: 0.0,
            decoupled: false,
            m: vec![0.0; n],
            v: vec![0.0; n],
            step: 0,
        }
    }

    /// AdamW (`torch.optim.AdamW`) over `n` parameters with decoupled weight
    /// decay `weight_decay`, other settings as in [`Adam::new`].
    pub fn adamw(n: usize, lr: f32, weight_decay: f32) -> Self {
        Self { weight_decay, decoupled: true, ..Self::new(n, lr) }
    }

    /// Checks the settings against the ranges PyTorch's constructor accepts;
    /// call it after filling the public fields from user input.
    pub fn validate(&self) -> Result<(), OptimError> {
        let bad = |name, value, expected| Err(OptimError::BadSetting { name, value, expected });
        if !(self.lr >= 0.0 && self.lr.is_finite()) {
            return bad("lr", self.lr, "finite, >= 0");
        }
        if !(self.eps >= 0.0 && self.eps.is_finite()) {
            return bad("eps", self.eps, "finite, >= 0");
        }
        if !(0.0..1.0).contains(&self.beta1) {
            return bad("beta1", self.beta1, "in [0, 1)");
        }
        if !(0.0..1.0).contains(&self.beta2) {
            return bad("beta2", self.beta2, "in [0, 1)");
        }
        if !(self.weight_decay >= 0.0 && self.weight_decay.is_finite()) {
            return bad("weight_decay", self.weight_decay, "finite, >= 0");
        }
        Ok(())
    }

    /// Number of parameters this optimizer tracks.
    pub fn len(&self) -> usize {
        self.m.len()
    }

    /// True when it tracks no parameters.
    pub fn is_empty(&self) -> bool {
        self.m.is_empty()
    }

    /// One Adam step: updates `params` in place from `grads` and advances the
    /// moment estimates.
    ///
    /// # Panics
    /// If `params` or `grads` does not have [`Adam::len`] entries (a
    /// programming error: the optimizer is built for one field).
    pub fn step(&mut self, params: &mut [f32], grads: &[f32]) {
        let n = self.len();
        assert_eq!(params.len(), n, "adam step: params length");
        assert_eq!(grads.len(), n, "adam step: grads length");
        self.step += 1;
        // Scalars are formed in f64 and rounded to f32 where they meet the
        // tensors, as Python floats do in torch's update.
        let t = self.step as i32;
        let (lr, b1, b2, wd) =
            (as_typed(self.lr), as_typed(self.beta1), as_typed(self.beta2), as_typed(self.weight_decay));
        let k = Coeffs {
            weight: (1.0 - b1) as f32,
            beta2: self.beta2,
            one_minus_beta2: (1.0 - b2) as f32,
            neg_step_size: (-(lr / (1.0 - b1.powi(t)))) as f32,
            bias_c2_sqrt: (1.0 - b2.powi(t)).sqrt() as f32,
            eps: self.eps,
            l2: if self.decoupled { 0.0 } else { self.weight_decay },
            shrink: if self.decoupled && wd != 0.0 { Some((1.0 - lr * wd) as f32) } else { None },
        };
        params
            .par_chunks_mut(CHUNK)
            .zip(grads.par_chunks(CHUNK))
            .zip(self.m.par_chunks_mut(CHUNK))
            .zip(self.v.par_chunks_mut(CHUNK))
            .for_each(|(((p, g), m), v)| k.apply(p, g, m, v));
    }

    /// Forgets the moment estimates and the step count (a fresh start, e.g. at
    /// a new octave), keeping the settings.
    pub fn reset_state(&mut self) {
        self.m.fill(0.0);
        self.v.fill(0.0);
        self.step = 0;
    }

    /// Resets the state for a parameter vector of a new length `n` (the field
    /// grows between octaves), keeping the settings.
    pub fn resize(&mut self, n: usize) {
        self.m = vec![0.0; n];
        self.v = vec![0.0; n];
        self.step = 0;
    }

    /// First moments, second moments and steps taken, for checkpoints.
    pub fn state(&self) -> (&[f32], &[f32], u64) {
        (&self.m, &self.v, self.step)
    }

    /// Restores a checkpointed state (see [`Adam::state`]); rejects moments
    /// of the wrong length or a second moment that would make updates NaN.
    pub fn set_state(&mut self, m: &[f32], v: &[f32], step: u64) -> Result<(), OptimError> {
        let expected = self.len();
        for (what, got) in [("m", m.len()), ("v", v.len())] {
            if got != expected {
                return Err(OptimError::StateLength { what, got, expected });
            }
        }
        if let Some((index, &value)) = v.iter().enumerate().find(|(_, x)| !(x.is_finite() && **x >= 0.0)) {
            return Err(OptimError::BadSecondMoment { index, value });
        }
        self.m.copy_from_slice(m);
        self.v.copy_from_slice(v);
        self.step = step;
        Ok(())
    }
}

/// The `f64` a setting was written as: `0.999f32` widened directly is
/// 0.99900001..., which makes `1 - beta2` 1.3e-5 off from the `1 - 0.999` the
/// reference computes in Python; going through the shortest decimal that
/// round-trips the `f32` recovers the value the user typed.
fn as_typed(x: f32) -> f64 {
    x.to_string().parse().unwrap_or(x as f64)
}

/// Per-step constants of the update, already rounded to `f32`.
struct Coeffs {
    weight: f32,
    beta2: f32,
    one_minus_beta2: f32,
    neg_step_size: f32,
    bias_c2_sqrt: f32,
    eps: f32,
    l2: f32,
    shrink: Option<f32>,
}

impl Coeffs {
    /// The update on one chunk, in torch's operation order:
    /// decay, `m.lerp_(g, 1-β1)`, `v = v·β2 + (1-β2)·g²`,
    /// `denom = sqrt(v)/sqrt(bc2) + eps`, `p += (-lr/bc1)·m / denom`.
    #[inline]
    fn apply(&self, p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32]) {
        for (((p, &g), m), v) in p.iter_mut().zip(g).zip(m.iter_mut()).zip(v.iter_mut()) {
            if let Some(s) = self.shrink {
                *p *= s;
            }
            let g = if self.l2 != 0.0 { g + self.l2 * *p } else { g };
            // torch's lerp switches formula at weight 0.5 for accuracy.
            *m = if self.weight < 0.5 { *m + self.weight * (g - *m) } else { g - (g - *m) * (1.0 - self.weight) };
            *v = *v * self.beta2 + self.one_minus_beta2 * g * g;
            let denom = v.sqrt() / self.bias_c2_sqrt + self.eps;
            *p += self.neg_step_size * *m / denom;
        }
    }
}

/// Learning rate for octave `octave` (0 = coarsest) of a multi-octave run:
/// `base_lr · decay^octave`.
///
/// Finer octaves add detail on an already stylized field, so artists often
/// want smaller steps there; `decay = 1` keeps the paper's single learning
/// rate for every octave.
pub fn octave_lr(base_lr: f32, decay: f32, octave: usize) -> f32 {
    (base_lr as f64 * (decay as f64).powi(octave as i32)) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_step_moves_by_lr_against_the_gradient_sign() {
        // With bias correction, step 1 is lr · g/|g| (up to eps) for any g.
        let mut opt = Adam::new(4, 0.1);
        let mut p = vec![1.0, -2.0, 0.5, 3.0];
        opt.step(&mut p, &[0.3, -5.0, 1e-3, 0.0]);
        let want = [0.9, -1.9, 0.4, 3.0];
        for (a, b) in p.iter().zip(want) {
            assert!((a - b).abs() < 1e-5, "{a} vs {b}");
        }
        assert_eq!(opt.state().2, 1);
    }

    #[test]
    fn parallel_chunks_match_small_pieces() {
        // The update is elementwise, so one optimizer over a multi-chunk
        // vector must equal many optimizers over unaligned pieces of it.
        let n = 3 * CHUNK + 17;
        let piece = 1000;
        let mut p: Vec<f32> = (0..n).map(|i| (i % 13) as f32 * 0.1).collect();
        let mut p_ref = p.clone();
        let mut opt = Adam::adamw(n, 0.01, 0.1);
        let mut pieces: Vec<Adam> = p.chunks(piece).map(|c| Adam::adamw(c.len(), 0.01, 0.1)).collect();
        for s in 0..3 {
            let g: Vec<f32> = (0..n).map(|i| ((i * 37 + s * 11) % 101) as f32 * 0.01 - 0.5).collect();
            opt.step(&mut p, &g);
            for ((pp, gg), o) in p_ref.chunks_mut(piece).zip(g.chunks(piece)).zip(&mut pieces) {
                o.step(pp, gg);
            }
        }
        assert_eq!(p, p_ref);
    }

    #[test]
    fn state_roundtrip_and_reset() {
        let mut a = Adam::new(3, 0.05);
        let mut p = vec![0.1, 0.2, 0.3];
        a.step(&mut p, &[1.0, -1.0, 0.5]);
        let (m, v, s) = a.state();
        let (m, v) = (m.to_vec(), v.to_vec());
        let mut b = Adam::new(3, 0.05);
        b.set_state(&m, &v, s).unwrap();
        let mut pa = p.clone();
        a.step(&mut pa, &[0.2, 0.2, 0.2]);
        b.step(&mut p, &[0.2, 0.2, 0.2]);
        assert_eq!(pa, p);
        b.reset_state();
        assert_eq!(b.state(), (&[0.0; 3][..], &[0.0; 3][..], 0));
        b.resize(5);
        assert_eq!(b.len(), 5);
    }

    #[test]
    fn bad_state_and_settings_are_errors() {
        let mut a = Adam::new(3, 0.05);
        assert_eq!(
            a.set_state(&[0.0; 2], &[0.0; 3], 1),
            Err(OptimError::StateLength { what: "m", got: 2, expected: 3 })
        );
        assert_eq!(
            a.set_state(&[0.0; 3], &[0.0, -1.0, 0.0], 1),
            Err(OptimError::BadSecondMoment { index: 1, value: -1.0 })
        );
        assert!(a.validate().is_ok());
        a.beta2 = 1.0;
        assert!(matches!(a.validate(), Err(OptimError::BadSetting { name: "beta2", .. })));
        a.beta2 = 0.999;
        a.lr = f32::NAN;
        let e = a.validate().unwrap_err().to_string();
        assert!(e.contains("lr") && !e.contains('\n'), "{e}");
    }

    #[test]
    fn octave_lr_is_geometric() {
        assert_eq!(octave_lr(0.2, 1.0, 2), 0.2);
        assert!((octave_lr(2.0, 0.5, 2) - 0.5).abs() < 1e-7);
    }
}
