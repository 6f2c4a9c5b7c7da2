//! Learning-rate schedules and gradient clipping for training the
//! feed-forward network (paper Sec. 5.1: "Adam with OneCycle, initial
//! learning rate 5e-6, maximum 1e-4", gradient clipping).

/// PyTorch's `OneCycleLR` (cosine annealing, two phases, momentum cycling):
/// the learning rate rises from `max_lr / div_factor` to `max_lr` over the
/// first `pct_start` of the steps and falls to `initial / final_div_factor`;
/// Adam's `beta1` moves the opposite way between `max_momentum` and
/// `base_momentum`.
#[derive(Clone, Debug, PartialEq)]
pub struct OneCycle {
    /// Steps the schedule spans (`total_steps`).
    pub total_steps: u64,
    /// Peak learning rate.
    pub max_lr: f64,
    /// `initial_lr = max_lr / div_factor`.
    pub div_factor: f64,
    /// `min_lr = initial_lr / final_div_factor`.
    pub final_div_factor: f64,
    /// Fraction of the steps spent rising.
    pub pct_start: f64,
    /// `beta1` at the learning rate's peak.
    pub base_momentum: f64,
    /// `beta1` at the ends.
    pub max_momentum: f64,
}

impl OneCycle {
    /// PyTorch's defaults for `max_lr`, `total_steps` and `div_factor`.
    pub fn new(max_lr: f64, total_steps: u64, div_factor: f64) -> Self {
        Self {
            total_steps,
            max_lr,
            div_factor,
            final_div_factor: 1e4,
            pct_start: 0.3,
            base_momentum: 0.85,
            max_momentum: 0.95,
        }
    }

    /// `(learning rate, beta1)` for step `step` (0-based: the values the
    /// optimiser uses for its first step are those of step 0). Past the end
    /// the last values hold.
    pub fn at(&self, step: u64) -> (f64, f64) {
        let initial = self.max_lr / self.div_factor;
        let min_lr = initial / self.final_div_factor;
        let total = self.total_steps.max(2) as f64;
        let rise_end = self.pct_start * total - 1.0;
        let anneal =
            |start: f64, end: f64, pct: f64| end + (start - end) / 2.0 * ((std::f64::consts::PI * pct).cos() + 1.0);
        let s = (step as f64).min(total - 1.0);
        if s <= rise_end {
            let pct = s / rise_end;
            (anneal(initial, self.max_lr, pct), anneal(self.max_momentum, self.base_momentum, pct))
        } else {
            let pct = (s - rise_end) / (total - 1.0 - rise_end);
            (anneal(self.max_lr, min_lr, pct), anneal(self.base_momentum, self.max_momentum, pct))
        }
    }
}

/// Scales `grads` so their joint L2 norm is at most `max_norm`
/// (`torch.nn.utils.clip_grad_norm_`, which divides by `norm + 1e-6`);
/// returns the norm before clipping.
pub fn clip_grad_norm(grads: &mut [&mut [f32]], max_norm: f32) -> f32 {
    let total = grads.iter().flat_map(|g| g.iter()).map(|&v| (v as f64) * (v as f64)).sum::<f64>().sqrt() as f32;
    let coef = max_norm / (total + 1e-6);
    if coef < 1.0 {
        grads.iter_mut().for_each(|g| g.iter_mut().for_each(|v| *v *= coef));
    }
    total
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Values printed by `torch.optim.lr_scheduler.OneCycleLR(Adam, max_lr=1e-4,
    /// total_steps=11, div_factor=20)` (`get_last_lr()` and
    /// `param_groups[0]["betas"][0]` before each `optimizer.step()`).
    #[test]
    fn one_cycle_matches_torch() {
        let s = OneCycle::new(1e-4, 11, 20.0);
        let want = [
            (0, 4.9999999999999996e-06, 0.95),
            (1, 4.28358393799999e-05, 0.9101728006526316),
            (2, 9.606753682150903e-05, 0.8541394349247273),
            (3, 9.797465880748148e-05, 0.8520253513192751),
            (6, 5.3058317750676945e-05, 0.8969419169589078),
            (9, 4.1046502164583495e-06, 0.9458958292626879),
            (10, 5e-10, 0.95),
        ];
        for (step, lr, beta1) in want {
            let (l, b) = s.at(step);
            assert!((l - lr).abs() / lr < 1e-9, "step {step}: lr {l} vs {lr}");
            assert!((b - beta1).abs() < 1e-9, "step {step}: beta1 {b} vs {beta1}");
        }
    }

    #[test]
    fn clipping_scales_to_the_max_norm() {
        let (mut a, mut b) = (vec![3.0f32], vec![4.0f32]);
        let n = clip_grad_norm(&mut [&mut a, &mut b], 1.0);
        assert_eq!(n, 5.0);
        assert!((a[0] - 0.6).abs() < 1e-6 && (b[0] - 0.8).abs() < 1e-6);
        let mut c = vec![0.1f32];
        clip_grad_norm(&mut [&mut c], 1.0);
        assert_eq!(c[0], 0.1);
    }
}
