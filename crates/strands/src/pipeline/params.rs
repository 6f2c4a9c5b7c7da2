//! The settings of one stylization: the Table 1 preset plus the knobs the
//! command line exposes, checked once before any work starts.

use crate::preset::PresetParams;

use super::PipelineError;

/// Settings of one stylization: the Table 1 preset plus the knobs the
/// command line exposes.
#[derive(Clone, Debug, PartialEq)]
pub struct StylizeParams {
    /// The preset (Table 1).
    pub preset: PresetParams,
    /// Square render size `w_c = h_c`; the preset's style sizes are scaled
    /// by `render_size / preset render width` so patterns keep their size
    /// relative to the picture.
    pub render_size: usize,
    /// Iterations per scale (the preset's, or scaled by the caller).
    pub iterations: [u32; 3],
    /// Proxy strands `M` to grow.
    pub proxies: usize,
    /// Seed of densification and camera sampling.
    pub seed: u64,
    /// Multiplier on the preset's learning rates.
    pub lr_scale: f32,
    /// The painting's scale on the hair: multiplies the preset's style
    /// sizes, so 2 draws the painting's strokes twice as large on the groom,
    /// and the size the orientation term lays the painting at
    /// ([`super::StrokeField::laid_at`]).
    pub style_scale: f32,
    /// AdamW decoupled weight decay (PyTorch's default 0.01): pulls unused
    /// velocities back towards the rest groom.
    pub weight_decay: f32,
    /// Cameras (cached matches) per scale; 0 draws a new camera for every
    /// iteration as the paper does (see the module notes).
    pub views_per_scale: usize,
    /// Evaluation cameras: the first this many of the finest scale's views,
    /// or with `views_per_scale` 0 as many drawn from the same ranges.
    pub eval_views: usize,
    /// Views the optimizer never uses, from which the result's
    /// [`HeldOut`](super::HeldOut) hair-only loss is measured (0: not measured).
    pub held_out_views: usize,
    /// Strand cross-section σ in pixels at the groom centre's depth.
    pub strand_width_px: f32,
    /// Match each scale's NNST targets on the groom as the previous scales
    /// left it, as NNST matches each scale on its current output, instead
    /// of on the rest groom `R(x₀)` for every scale as the paper's eq. 2
    /// is written (see the module notes; off by default).
    pub rematch: bool,
    /// Weight of the orientation term (the painting's stroke directions as
    /// targets for the strands' projected directions, see
    /// [`super::orientation`]) relative to the NNST loss: `λ` is set at the
    /// first iteration so that its gradient is this times the NNST
    /// gradient's norm. 0 runs the paper's NNST loss alone; the preset's
    /// [`PresetParams::orientation`] by default.
    pub orientation: f32,
    /// Stylize the strands' colour with their shape: per-point
    /// colours ([`StrandColorLayer`](crate::StrandColorLayer)) optimized
    /// with the velocities against the painting in colour.
    pub color: bool,
}

impl StylizeParams {
    /// The preset's settings at its own render size, with proxies scaled to
    /// keep Table 1's proxy/guide ratio for `guides` guide strands.
    pub fn from_preset(preset: PresetParams, guides: usize) -> Self {
        let ratio = preset.densified_strands as f64 / preset.guide_strands.max(1) as f64;
        StylizeParams {
            preset,
            render_size: preset.render_size.0 as usize,
            iterations: preset.iterations,
            proxies: (ratio * guides as f64).round() as usize,
            seed: 0,
            lr_scale: 1.0,
            style_scale: preset.style_scale,
            weight_decay: 0.01,
            views_per_scale: 8,
            eval_views: 4,
            held_out_views: 4,
            strand_width_px: 0.5,
            rematch: false,
            orientation: preset.orientation,
            color: false,
        }
    }

    /// Iterations per scale rescaled to about `total` in all, keeping the
    /// preset's proportions (each scale at least one).
    pub fn with_total_iterations(mut self, total: u32) -> Self {
        let sum: u32 = self.preset.iterations.iter().sum::<u32>().max(1);
        self.iterations =
            self.preset.iterations.map(|n| ((n as f64 * total as f64 / sum as f64).round() as u32).max(1));
        self
    }

    /// Style image height of scale `l` at this render size.
    pub fn style_height(&self, l: usize) -> usize {
        let s = self.style_scale as f64 * self.render_size as f64 / self.preset.render_size.1.max(1) as f64;
        ((self.preset.style_sizes[l].1 as f64 * s).round() as usize).max(16)
    }

    /// The look's two settings in one line, printed before a job starts
    /// (the cross test reads the style scale its results were made at).
    pub fn look_line(&self) -> String {
        format!("the look: orientation term {}, painting at style scale {}", self.orientation, self.style_scale)
    }

    pub(super) fn validate(&self) -> Result<(), PipelineError> {
        let bad = |m: String| Err(PipelineError::Parameter(m));
        if self.render_size < 32 || self.render_size > 4096 {
            return bad(format!("render size {} must be 32..=4096 pixels", self.render_size));
        }
        if self.iterations.iter().all(|&n| n == 0) {
            return bad("no iterations".into());
        }
        if !(self.lr_scale.is_finite() && self.lr_scale > 0.0) {
            return bad(format!("learning-rate scale {} must be positive", self.lr_scale));
        }
        if !(self.style_scale.is_finite() && self.style_scale > 0.0) {
            return bad(format!("style scale {} must be positive", self.style_scale));
        }
        if !(self.strand_width_px.is_finite() && self.strand_width_px > 0.0) {
            return bad(format!("strand width {} px must be positive", self.strand_width_px));
        }
        if !(self.preset.camera_distance > 1.0) {
            return bad(format!("camera distance r = {} must exceed 1 groom radius", self.preset.camera_distance));
        }
        if !(self.orientation.is_finite() && self.orientation >= 0.0) {
            return bad(format!("orientation weight {} must be 0 or positive", self.orientation));
        }
        if self.eval_views == 0 {
            return bad("need at least one evaluation view".into());
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::preset::Preset;

    /// `style_scale` multiplies every scale's style size (after the render
    /// size's own factor) and must be positive.
    #[test]
    fn style_scale_multiplies_the_style_sizes() {
        let base = StylizeParams::from_preset(Preset::ShortHair.params(), 100);
        let sizes = |p: &StylizeParams| [0, 1, 2].map(|l| p.style_height(l));
        assert_eq!(sizes(&base), [160, 240, 300]);
        let half_render = StylizeParams { render_size: 300, ..base.clone() };
        assert_eq!(sizes(&half_render), [80, 120, 150]);
        let doubled = StylizeParams { render_size: 300, style_scale: 2.0, ..base.clone() };
        assert_eq!(sizes(&doubled), [160, 240, 300]);
        for bad in [0.0, -1.0, f32::NAN] {
            assert!(StylizeParams { style_scale: bad, ..base.clone() }.validate().is_err(), "{bad}");
        }
        assert!(base.validate().is_ok());
    }
}
