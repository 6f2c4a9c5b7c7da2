//! The six examples of Table 1 as presets.
//!
//! Copied from Table 1: guide/densified strand counts, control points,
//! velocity samples, render resolution, iterations, style image sizes and
//! learning rates per scale (`N_scales = 3`), polar `ψ` / azimuth `δ`
//! ranges (degrees), camera distance `r`, visibility threshold `ϵ`,
//! sampling density `ρ`, the temporal parameters `σ, ν, α, β, f_min` of the
//! animated examples, and the reported runtime. The table's "K"/"M" counts
//! are kept at the table's precision (4 K → 4000).
//!
//! Not in Table 1, chosen here (see each field): the RBF kernel and
//! neighbour count, the collision threshold `τ` and stiffness `κ`, the
//! frame rate, and the points per strand (derived: control points /
//! (guides + densified), e.g. 2.66 M / 26.6 K = 100; the Cat gives 7.9,
//! rounded to 8). Our text extraction of the table splits some learning
//! rates across cells ("0.001 | 6"); we read them as 0.0016, 0.0025,
//! 0.0012, 0.0018 and 0.0032 (Grass's middle rate is larger than its first
//! in the table as extracted; kept as read).
//!
//! One departure: Grass culls nothing. Table 1 gives it ϵ = 0.5, but our
//! cameras look across the patch (ψ = δ = 0 is the front view), where a
//! blade's root normal (the ground's, +Y) is perpendicular to the view: at
//! 0.5 every blade was culled in every view and a patch stylized on its
//! ground did not change (loss unchanged, held-out loss NaN).

use crate::constraints::CollisionParams;
use crate::field::{Kernel, SampleDensity};
use crate::temporal::{DerivativeSmoothing, OneEuroParams};

/// One example of Table 1.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Preset {
    /// Short hair, front views (Fig. 1, 14).
    ShortHair,
    /// Short hair, views all around (Fig. 6).
    ShortHair360,
    /// Long hair in wind and gravity, animated (Fig. 7).
    LongHair,
    /// Cat body fur (Fig. 9, 14).
    Cat,
    /// Fur ball in wind, animated (Fig. 8, 11).
    FurBall,
    /// Grass patch, animated (Fig. 12, 13).
    Grass,
}

impl Preset {
    /// The name front ends use (`nst3d strands --preset`, the Python package).
    pub fn key(self) -> &'static str {
        match self {
            Preset::ShortHair => "short-hair",
            Preset::ShortHair360 => "short-hair-360",
            Preset::LongHair => "long-hair",
            Preset::Cat => "cat",
            Preset::FurBall => "fur-ball",
            Preset::Grass => "grass",
        }
    }
}

impl std::str::FromStr for Preset {
    type Err = String;

    /// A preset by its [`Preset::key`]; `_` may stand for `-`.
    fn from_str(s: &str) -> Result<Self, String> {
        let want = s.replace('_', "-");
        Preset::ALL.into_iter().find(|p| p.key() == want).ok_or_else(|| {
            let keys: Vec<&str> = Preset::ALL.iter().map(|p| p.key()).collect();
            format!("unknown preset '{s}' (presets: {})", keys.join(", "))
        })
    }
}

/// Temporal coherency parameters of the animated examples (Sec. 3.3).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TemporalParams {
    /// EMA coefficient `σ`.
    pub ema_sigma: f32,
    /// EMA decaying period `ν` (fraction of a frame's iterations, see
    /// [`crate::ema_blend_factor`]).
    pub ema_nu: f32,
    /// 1€ blending parameter `α` (speed smoothing, eq. 9).
    pub blend_alpha: f32,
    /// 1€ scaling coefficient `β`.
    pub beta: f32,
    /// 1€ minimum cutoff frequency `f_min` (Hz).
    pub min_cutoff_hz: f32,
    /// Frame rate. Not in the paper; 24 fps (film) is our choice.
    pub fps: f32,
}

impl TemporalParams {
    /// The paper-style 1€ filter (animation velocity, constant `α`).
    pub fn one_euro(&self) -> OneEuroParams {
        OneEuroParams {
            min_cutoff: self.min_cutoff_hz,
            beta: self.beta,
            derivative: DerivativeSmoothing::Blend(self.blend_alpha),
            fps: self.fps,
        }
    }
}

/// All parameters of one preset.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PresetParams {
    /// Example name as in Table 1.
    pub name: &'static str,
    /// Guide strands (Table 1).
    pub guide_strands: usize,
    /// Densified proxy strands `M` (Table 1).
    pub densified_strands: usize,
    /// Control points over guides and proxies (Table 1).
    pub control_points: usize,
    /// Velocity samples (Table 1; = ρ × guide control points).
    pub velocity_samples: usize,
    /// Control points per strand (derived, see module notes).
    pub points_per_strand: usize,
    /// Differentiable render resolution `w_c × h_c` (Table 1).
    pub render_size: (u32, u32),
    /// Iterations per scale `N_iters` (Table 1).
    pub iterations: [u32; 3],
    /// Style image size `W_s × H_s` per scale (Table 1).
    pub style_sizes: [(u32, u32); 3],
    /// Learning rate `η` per scale (Table 1).
    pub learning_rates: [f32; 3],
    /// Polar angle range `ψ`, degrees (Table 1).
    pub polar_deg: (f32, f32),
    /// Azimuthal angle range `δ`, degrees (Table 1).
    pub azimuth_deg: (f32, f32),
    /// Camera distance `r` to the centroid, metres (Table 1).
    pub camera_distance: f32,
    /// Visibility threshold `ϵ` (Table 1).
    pub visibility_threshold: f32,
    /// Velocity field sampling density `ρ` (Table 1).
    pub sampling_density: f32,
    /// Temporal parameters; `None` for the static examples (Table 1).
    pub temporal: Option<TemporalParams>,
    /// Reported runtime on an RTX 3090, seconds per frame (Table 1).
    pub runtime_s_per_frame: f32,
    /// RBF kernel. Not in Table 1: cubic, the smooth choice (see
    /// [`Kernel::Cubic`]).
    pub kernel: Kernel,
    /// Samples blended per point (eq. 5's neighbourhood). Not in the
    /// paper: 48. With 8, every point of a 100-point strand blends only
    /// samples of its own strand, so each strand kinks on its own (frizz)
    /// and the NNST loss rose on a curly head (+10.9 %); 48 reach across
    /// strands and along them, and the same run descends (−1.8 %).
    pub neighbors: usize,
    /// Weight of the orientation term beside NNST
    /// ([`crate::pipeline::StylizeParams::orientation`]). Not in the paper
    /// (its future work), chosen per groom by the layout judge of the
    /// cross test (docs/design/strands.md): 3 for the fur ball (with the
    /// painting at 3, its result toward each of six styles nearer that
    /// style in 15 of 15 pairs, and 15 of 15 on a spiky head; at 1 the
    /// head passed 11), grass (15 of 15 at 1.5; NNST alone 2) and long hair
    /// (15 of 15 with the painting projected from the middle camera,
    /// [`PresetParams::orientation_projector`]; 14 at 2, 12 at 1; laid over
    /// each view instead 12 at 1, 10 at 2); 0 for the presets not yet
    /// cross-tested (short hair, the cat), which run the paper's NNST loss
    /// alone.
    pub orientation: f32,
    /// The painting's scale on the hair
    /// ([`crate::pipeline::StylizeParams::style_scale`]). Not in the paper:
    /// 1 lays the painting over the hair's box in each view. A motif finer
    /// than the strands can bend to is left unfollowed (a triangle
    /// tessellation six across a fur ball: its result stayed 0.99 of the
    /// rest's misalignment with the triangles at 1, 0.89 at 2, 0.41 at 3),
    /// so the fur ball takes 3 (15 of 15 pairs of the cross test; 14 at 2),
    /// grass 1.5 (15 of 15; 12 at 1 and at 2) and long hair 1.5 (with the
    /// term at 1 laid over each view: 12 of 15; 10 at 1, 4 at 2).
    pub style_scale: f32,
    /// Whether the orientation term projects the painting from the middle
    /// of the camera range ([`PresetParams::orientation_projector`]) rather
    /// than laying it over each view's own box. Not in the paper; chosen
    /// per groom by the cross test's layout judge: long hair passed 15 of 15
    /// pairs projected (12 laid per view), where a spiky head at the
    /// fur-ball preset passed 14 projected (15 per view) and the fur ball 15
    /// either way.
    pub projected: bool,
    /// Collision threshold `τ` as a fraction of the collider's bounding-box
    /// diagonal. Not in the paper: 0.5 %, a few strand widths on a head.
    pub collision_tau_rel: f32,
    /// Collision stiffness `κ`. Not in the paper: 0.5.
    pub collision_kappa: f32,
}

impl PresetParams {
    /// Sampling density as a [`SampleDensity`].
    pub fn sample_density(&self) -> SampleDensity {
        SampleDensity::Fraction(self.sampling_density)
    }

    /// Collision parameters for a collider whose bounding box has diagonal
    /// `diagonal` (roots are kept attached).
    pub fn collision(&self, diagonal: f32) -> CollisionParams {
        CollisionParams { tau: self.collision_tau_rel * diagonal, kappa: self.collision_kappa, skip_roots: true }
    }

    /// Total iterations per frame (`|Θ|` in Alg. 1).
    pub fn total_iterations(&self) -> u32 {
        self.iterations.iter().sum()
    }

    /// The camera angles `(ψ, δ)` from which the orientation term projects
    /// the painting onto the hair: with [`PresetParams::projected`], the
    /// middle of the camera range of a preset that faces the groom from one
    /// side, so every view asks a strand for the same direction
    /// (docs/design/strands.md, "Projected from one camera"); `None`
    /// otherwise and for a preset seen from all round, where each view lays
    /// the painting over its own box.
    pub fn orientation_projector(&self) -> Option<(f32, f32)> {
        let (polar, azimuth) = (self.polar_deg, self.azimuth_deg);
        (self.projected && azimuth.1 - azimuth.0 < 180.0)
            .then(|| ((polar.0 + polar.1) / 2.0, (azimuth.0 + azimuth.1) / 2.0))
    }
}

const BASE: PresetParams = PresetParams {
    name: "",
    guide_strands: 0,
    densified_strands: 0,
    control_points: 0,
    velocity_samples: 0,
    points_per_strand: 0,
    render_size: (600, 600),
    iterations: [20, 30, 50],
    style_sizes: [(0, 0); 3],
    learning_rates: [0.0; 3],
    polar_deg: (-10.0, 10.0),
    azimuth_deg: (-10.0, 10.0),
    camera_distance: 0.0,
    visibility_threshold: 0.0,
    sampling_density: 0.0,
    temporal: None,
    runtime_s_per_frame: 0.0,
    kernel: Kernel::Cubic,
    neighbors: 48,
    orientation: 0.0,
    style_scale: 1.0,
    projected: false,
    collision_tau_rel: 0.005,
    collision_kappa: 0.5,
};

/// The EMA's decaying period `ν` of a sequence stylized with the orientation
/// term, where the preset's is shorter. Table 1's periods (0.6 for the fur
/// ball) let the field go from the previous frame's for the last 40 % of
/// each scale's iterations; the term keeps combing through them, so the
/// field grew frame over frame (the fur ball in the wind: the NNST loss of
/// the output rose from 1.52e1 to 1.74e1 over 12 frames, and the sequence
/// flickered 1.24× as much as frames stylized alone). With `ν = 3` the blend
/// never lets go (`f` falls from 1 to 2/3 over a scale) and the same
/// sequence flickered 0.31× per-frame at `W = 1`, 0.43× at the fur-ball
/// preset's `W = 3` with the painting at 2, but 0.53× with it at 3, whose
/// larger strokes comb further; `ν = 6` (1 to 5/6) brings that to 0.46×
/// at about the same loss (docs/design/strands.md).
pub const ORIENTATION_EMA_NU: f32 = 6.0;

const fn temporal(ema_nu: f32, blend_alpha: f32, beta: f32, min_cutoff_hz: f32) -> Option<TemporalParams> {
    Some(TemporalParams { ema_sigma: 1.0, ema_nu, blend_alpha, beta, min_cutoff_hz, fps: 24.0 })
}

impl Preset {
    /// Every preset, in Table 1's order.
    pub const ALL: [Preset; 6] =
        [Preset::ShortHair, Preset::ShortHair360, Preset::LongHair, Preset::Cat, Preset::FurBall, Preset::Grass];

    /// The preset's parameters.
    pub fn params(self) -> PresetParams {
        match self {
            Preset::ShortHair => SHORT_HAIR,
            Preset::ShortHair360 => SHORT_HAIR_360,
            Preset::LongHair => LONG_HAIR,
            Preset::Cat => CAT,
            Preset::FurBall => FUR_BALL,
            Preset::Grass => GRASS,
        }
    }
}

/// Table 1's Short Hair (Fig. 1).
const SHORT_HAIR: PresetParams = PresetParams {
    name: "Short Hair",
    guide_strands: 4_000,
    densified_strands: 22_600,
    control_points: 2_660_000,
    velocity_samples: 266_000,
    points_per_strand: 100,
    style_sizes: [(160, 160), (240, 240), (300, 300)],
    learning_rates: [0.0026, 0.0016, 0.0009],
    camera_distance: 5.0,
    visibility_threshold: 0.3,
    sampling_density: 0.665,
    runtime_s_per_frame: 138.0,
    ..BASE
};

/// Short Hair seen from all round (Table 1's 360° row).
const SHORT_HAIR_360: PresetParams = PresetParams {
    name: "Short Hair 360",
    iterations: [70, 100, 170],
    polar_deg: (-20.0, 20.0),
    azimuth_deg: (-180.0, 180.0),
    runtime_s_per_frame: 512.0,
    ..SHORT_HAIR
};

/// Table 1's Long Hair, animated.
const LONG_HAIR: PresetParams = PresetParams {
    name: "Long Hair",
    guide_strands: 8_180,
    densified_strands: 4_120,
    control_points: 1_230_000,
    velocity_samples: 409_000,
    points_per_strand: 100,
    style_sizes: [(200, 200), (240, 240), (320, 320)],
    learning_rates: [0.0034, 0.0025, 0.0016],
    polar_deg: (-20.0, 20.0),
    camera_distance: 2.5,
    visibility_threshold: 0.6,
    sampling_density: 0.5,
    temporal: temporal(0.7, 0.3, 0.25, 8.0),
    runtime_s_per_frame: 149.0,
    orientation: 3.0,
    style_scale: 1.5,
    projected: true,
    ..BASE
};

/// Table 1's Cat.
const CAT: PresetParams = PresetParams {
    name: "Cat",
    guide_strands: 75_750,
    densified_strands: 177_250,
    control_points: 2_000_000,
    velocity_samples: 202_000,
    points_per_strand: 8,
    render_size: (800, 800),
    style_sizes: [(80, 80), (160, 160), (260, 260)],
    learning_rates: [0.002, 0.0012, 0.0006],
    camera_distance: 2.0,
    visibility_threshold: 0.2,
    sampling_density: 0.333,
    runtime_s_per_frame: 179.0,
    ..BASE
};

/// Table 1's Fur Ball in the wind, with the look's settings (see the fields).
const FUR_BALL: PresetParams = PresetParams {
    name: "Fur Ball",
    guide_strands: 8_000,
    densified_strands: 42_000,
    control_points: 450_000,
    velocity_samples: 72_000,
    points_per_strand: 9,
    render_size: (500, 500),
    style_sizes: [(30, 30), (150, 150), (240, 240)],
    learning_rates: [0.0025, 0.0018, 0.0009],
    polar_deg: (-15.0, 15.0),
    azimuth_deg: (-15.0, 15.0),
    camera_distance: 3.0,
    visibility_threshold: 0.5,
    sampling_density: 1.0,
    temporal: temporal(0.6, 0.34, 0.2, 9.0),
    runtime_s_per_frame: 53.0,
    orientation: 3.0,
    style_scale: 3.0,
    ..BASE
};

/// Table 1's Grass Patch, with the look's settings (see the fields).
const GRASS: PresetParams = PresetParams {
    name: "Grass Patch",
    guide_strands: 3_000,
    densified_strands: 9_000,
    control_points: 108_000,
    velocity_samples: 18_000,
    points_per_strand: 9,
    style_sizes: [(120, 120), (180, 180), (225, 225)],
    learning_rates: [0.0028, 0.0032, 0.0012],
    camera_distance: 2.0,
    // Not Table 1's 0.5: see the module notes.
    visibility_threshold: -1.0,
    sampling_density: 0.666,
    temporal: temporal(0.6, 0.34, 0.3, 9.0),
    runtime_s_per_frame: 26.0,
    orientation: 3.0,
    style_scale: 1.5,
    ..BASE
};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_counts_are_consistent() {
        for p in Preset::ALL.map(Preset::params) {
            // Control points = (guides + proxies) × points per strand, and
            // velocity samples = ρ × guide control points, within the
            // table's rounding (3 significant digits).
            let cp = (p.guide_strands + p.densified_strands) * p.points_per_strand;
            assert!((cp as f64 / p.control_points as f64 - 1.0).abs() < 0.015, "{}: {cp}", p.name);
            let vs = p.sampling_density as f64 * (p.guide_strands * p.points_per_strand) as f64;
            assert!((vs / p.velocity_samples as f64 - 1.0).abs() < 0.015, "{}: {vs}", p.name);
            assert_eq!(p.temporal.is_some(), matches!(p.name, "Long Hair" | "Fur Ball" | "Grass Patch"));
            assert!(p.collision(2.0).tau > 0.0);
        }
        let sh = Preset::ShortHair360.params();
        assert_eq!((sh.total_iterations(), sh.azimuth_deg, sh.guide_strands), (340, (-180.0, 180.0), 4000));
        let fb = Preset::FurBall.params().temporal.unwrap().one_euro();
        assert_eq!((fb.min_cutoff, fb.beta, fb.derivative), (9.0, 0.2, DerivativeSmoothing::Blend(0.34)));
    }

    #[test]
    fn a_projected_preset_projects_the_painting_from_the_middle_of_its_range() {
        for preset in Preset::ALL {
            let p = preset.params();
            let expected = match preset {
                Preset::LongHair => Some((0.0, 0.0)),
                _ => None,
            };
            assert_eq!(p.orientation_projector(), expected, "{}", p.name);
        }
        let off_centre =
            PresetParams { polar_deg: (0.0, 30.0), azimuth_deg: (10.0, 50.0), ..Preset::LongHair.params() };
        assert_eq!(off_centre.orientation_projector(), Some((15.0, 30.0)));
        let all_round = PresetParams { projected: true, ..Preset::ShortHair360.params() };
        assert_eq!(all_round.orientation_projector(), None);
    }
}
