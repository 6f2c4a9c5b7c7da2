//! One stylization of a static groom (Alg. 1 without its temporal lines):
//! guides → proxies → deformation field → per iteration a camera, transport,
//! constraints, splat render, VGG-19, NNST loss, and the whole chain backward
//! to the velocities `v`, stepped with AdamW over the preset's three scales.
//!
//! Setup ([`StrandScene::new`]):
//! - guides are the groom's strands, each re-sampled as a natural cubic
//!   spline ([`StrandSpline`]) to the preset's points per strand at even arc
//!   length; proxies come from [`densify`] on the head mesh with the same
//!   point count; both are the `p` of eq. 5 and the field's samples `o` sit
//!   on the guides at the preset's density `ρ`.
//! - The view frame: centre and radius `R` of the rest strands' bounding
//!   box (centre) and enclosing sphere (radius). *Front* is the direction the
//!   groom faces, the mean of the head's pseudo-normals at the guide roots
//!   (falling back to the mesh-centre → groom-centre direction, then +Z, when
//!   the normals cancel, as on a fur ball), made horizontal. *Up* is +Y:
//!   the scene is always y-up (`nst3d_groom` turns a z-up file into this
//!   frame and the result back), so the cameras circle the up axis and the
//!   polar angle 0 is the horizon.
//! - Units: the paper's assets are about one unit across, ours can be
//!   hundreds (the Bangs head is ~240 units). The preset's camera distance
//!   `r` and learning rates `η` are therefore read in units of `R`: the eye
//!   sits `r·R` from the centre, a step of AdamW moves a velocity by about
//!   `η·R`. The field of view is fitted so the enclosing sphere fills the
//!   frame; strands are drawn [`StylizeParams::strand_width_px`] pixels wide
//!   (σ of the cross-section at the centre's depth).
//! - Rendering: grey strands on black (root dark, tip bright, opaque roots,
//!   translucent tips: [`StrandStyle::default`]'s heuristics), culled by the
//!   head normal at the root with the preset's threshold `ϵ`; the grey image
//!   is fed to VGG-19 as three equal channels, and the painting is matched by
//!   its luminance (a grey render cannot reach colour statistics).
//!
//! Cameras: directions on the shell within the polar `ψ` / azimuth `δ`
//! ranges around the front, spread by best-candidate sampling (Mitchell's
//! Poisson-disk approximation: each new direction is the farthest, in angle,
//! of 16 seeded random candidates from those already taken), so every prefix
//! of the sequence covers the ranges evenly and a seed fixes it.
//!
//! Loss: eq. 2–3. Every scale's targets `T` of a view are matched on the
//! *undeformed* render `R_θ(x₀)` against the style image resized for the
//! scale, as the paper writes eq. 2. ([`StylizeParams::rematch`] matches the
//! finer scales on the groom as the coarser scales left it instead, as NNST
//! re-matches each scale on its output; off by default: the gaps of the
//! deformed groom feed back into its targets and every style then drives
//! the same clumps, docs/design/strands.md.) The loss is `‖Φ(R_θ(x)) − T‖²` averaged over
//! hyper-columns (relu1_1, relu2_1, relu3_1, relu4_1, NNST's grid of a
//! quarter resolution). Gradients flow NNST → VGG backward → splat backward →
//! back through every constraint projection of the iterate (the recorded
//! [`ConstraintTape`], as autograd would in the paper's PyTorch pipeline) →
//! `Wᵀ` of the field.
//!
//! Matching cost: each view's targets need one match (`N_c × N_s × D`)
//! per scale. Views are *cached*: each scale draws
//! [`StylizeParams::views_per_scale`] cameras, matches each once on `x₀`
//! and cycles its iterations through them; `views_per_scale = 0` restores
//! the paper's new camera every iteration. A match is cheap next to an
//! iteration at small renders, but approaches the cost of an iteration at
//! the preset's full 600² render against 300² styles, which is where the
//! cache pays; the default is 8 cached views per scale.
//!
//! Step size: the preset's `η` read as `η·R` (see Units) times
//! [`StylizeParams::lr_scale`], 1 by default (Table 1's rates as published;
//! it was 0.3 while targets were matched on `x₀` for every scale, where
//! larger steps found another stylization than the one matched).
//!
//! The measurements behind both defaults are in `docs/design/strands.md`
//! ("Measurements behind the pipeline's defaults").
//!
//! Evaluation, held out: [`HeldOut`], the hair-only NNST loss from views
//! the optimizer never used, before and after (see [`held_out_loss`]).
//!
//! Evaluation, optimized: the optimized views — the finest scale's cached cameras (or,
//! with a new camera per iteration, [`StylizeParams::eval_views`] fixed
//! cameras from the same distribution, separately seeded) — matched on the
//! undeformed groom against the finest scale's style. The initial loss is the NNST loss
//! of the rest groom, the final one the same objective on the stylized
//! groom; the loss re-matched on the final render is reported too.
//!
//! The code, one job per file: `params.rs` ([`StylizeParams`]), `scene/`
//! ([`StrandScene`]: setup and the deformation `v ↦ x` with its backward;
//! `fit.rs` fits the rest groom outside the head, `topology.rs` carries the
//! result back to the groom's own points, `view.rs` draws a groom file),
//! `views.rs` (view frame, camera angles, style targets and matching),
//! `step.rs` (one [`iteration`]) and `multiscale.rs` (the loop over scales,
//! [`stylize_with`], and the evaluation).
//!
//! [`ConstraintTape`]: crate::ConstraintTape
//! [`StrandSpline`]: nst3d_core::groom::StrandSpline
//! [`StrandStyle::default`]: nst3d_splat::StrandStyle::default
//! [`densify`]: fn@crate::densify

mod color_stage;
mod multiscale;
mod orientation;
mod params;
mod scene;
mod step;
mod style_map;
mod views;

use nst3d_core::groom::GroomError;
use nst3d_features::VggLayer;
use nst3d_loss::nnst::NnstError;
use nst3d_splat::SplatError;

// Re-exported so callers of [`iteration`] (the `strands-iter` benchmark)
// can hold its inputs without depending on every stage crate.
pub use nst3d_loss::nnst::{NnstMatch, NnstTarget};
pub use nst3d_optim::Adam;
pub use nst3d_splat::SplatCamera;

pub use color_stage::{
    color_iterations, color_view_angles, color_view_loss, stylize_color, stylize_color_mapped, ColorStageResult,
    ColorTargets, ColorView, WrittenGroom, COLOR_ELEVATIONS, COLOR_LAYERS, COLOR_PASSES, COLOR_VIEWS, GREY_GUARD,
};
pub use multiscale::{
    held_out_loss, scale_learning_rate, stylize, stylize_mapped, stylize_with, FrameHooks, HeldOut, IterationClock,
    IterationReport, StylizeResult,
};
pub use orientation::{orientation_loss, OrientationView, StrokeField, STRUCTURE_SIGMA};
pub use params::StylizeParams;
pub use scene::{
    max_length_change, polyline_length, ColorCarry, GroomView, StrandScene, CONSTRAINT_PASSES, HARD_TAU_FRACTION,
    SEGMENT_TOLERANCE,
};
pub use step::{
    iteration, iteration_with, loss_and_gradient, loss_and_gradient_with, OrientationTerm, StageTimes, StepReport,
};
pub use style_map::{MapKind, PaintingTargets, StrandShares};
pub use views::{hair_columns, hair_pixels};
pub use views::{match_view, match_view_on, poisson_view_angles, style_target, ViewFrame};

use crate::StrandError;

/// VGG-19 taps of the NNST hyper-columns.
pub const NNST_LAYERS: [VggLayer; 4] = [VggLayer::Relu1_1, VggLayer::Relu2_1, VggLayer::Relu3_1, VggLayer::Relu4_1];

/// Why a stylization could not run; one line naming the problem.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// A groom stage failed (bad geometry or parameter).
    #[error(transparent)]
    Strands(#[from] StrandError),
    /// A strand could not be re-sampled as a spline.
    #[error("groom: {0}")]
    Groom(#[from] GroomError),
    /// The renderer refused its input.
    #[error("render: {0}")]
    Render(#[from] SplatError),
    /// The style loss refused its input.
    #[error(transparent)]
    Loss(#[from] NnstError),
    /// The colour stage's Gram loss refused its input.
    #[error("colour loss: {0}")]
    Gram(#[from] nst3d_loss::LossError),
    /// A setting outside its valid range.
    #[error("bad parameter: {0}")]
    Parameter(String),
    /// The optimization diverged.
    #[error("stylization diverged: {0}")]
    Diverged(String),
    /// The caller asked the job to stop ([`nst3d_core::stop`]).
    #[error(transparent)]
    Interrupted(#[from] nst3d_core::stop::Interrupted),
}
