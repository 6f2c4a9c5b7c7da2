//! Groom-side stages of strand stylization (strand style transfer paper,
//! Sec. 3.1, 3.3, 3.4 and Table 1), everything except rendering and the
//! style loss:
//!
//! - [`DeformationField`]: learnable velocities `v_j` at samples `o_j` on
//!   the guides, RBF-interpolated onto every control point and applied by
//!   one forward-Euler step (eq. 4–5), with its backward (`Wᵀ`).
//! - [`densify`]: proxy strands rooted on the scalp between the guides.
//! - [`StrandColorLayer`]: the colour a groom is stylized to,
//!   offsets at sites on the guides spread by the field's RBF weights.
//! - [`preserve_lengths`], [`project_collisions`] over a [`MeshBvh`]
//!   (Sec. 3.4), combined in [`Constraints`].
//! - [`ema_blend_factor`], [`ema_blend`], [`transport_velocities`] and the
//!   [`OneEuroFilter`] for animated grooms (Sec. 3.3).
//! - [`fur_ball`], [`grass_patch`], [`Wind`] and the Table 1 [`Preset`]s.
//!
//! Per optimisation step (Alg. 1): EMA on `v` → `DeformationField::forward`
//! → `preserve_lengths` → `project_collisions` → render; the render's
//! gradient on the points goes back through both projections
//! ([`ConstraintTape`] records them and back-propagates in reverse, as
//! autograd does in the paper's PyTorch pipeline), then through
//! `DeformationField::backward`.
//!
//! [`sequence`] runs it over the frames of an animated groom with the EMA
//! and 1€ filter of Sec. 3.3, and measures the flicker.
//!
//! [`pipeline`] assembles all of it with the splat renderer, VGG-19 and the
//! NNST loss into one stylization of a groom (`nst3d strands`).
//!
//! All stages work on [`FlatStrands`]: every control point in one array,
//! guides first, then proxies.

#![warn(missing_docs)]

mod bvh;
mod color;
mod constraints;
mod densify;
mod field;
mod generators;
mod kdtree;
pub mod pipeline;
mod preset;
pub mod sequence;
mod strands;
mod temporal;
mod winding;

pub use bvh::{closest_point_on_triangle, ClosestHit, Feature, MeshBvh};
pub use color::{initial_colors, StrandColorLayer, COLOR_LEARNING_RATE, COLOR_NEIGHBORS, COLOR_SITES};
pub use constraints::{
    preserve_lengths, preserve_lengths_backward, project_collisions, project_collisions_recorded, CollisionParams,
    CollisionRecord, CollisionStats, ConstraintTape, Constraints, EnforceParams,
};
pub use densify::{densify, densify_weighted, DensifyParams, ProxyBlend};
pub use field::{velocity_sample_indices, DeformationField, Kernel, RbfWeights, SampleDensity};
pub use generators::{fur_ball, grass_patch, uv_sphere, FurBallParams, GrassParams, Wind};
pub use kdtree::KdTree;
pub use preset::{Preset, PresetParams, TemporalParams, ORIENTATION_EMA_NU};
pub use sequence::{
    check_topology, EmaClock, Flow, FrameFlicker, FrameResult, SequenceError, SequenceMap, SequenceParams,
    SequenceReport, SequenceStylizer,
};
pub use strands::FlatStrands;
pub use temporal::{
    ema_blend, ema_blend_factor, smoothing_factor, transport_velocities, DerivativeSmoothing, OneEuroFilter,
    OneEuroHistory, OneEuroParams,
};
pub use winding::WindingNumber;

/// The generator of the strand stages' samplers (densification roots,
/// procedural grooms, camera angles): SplitMix64 started at `seed` xor a
/// fixed salt. The salt only keeps the streams of grooms saved so far; it has
/// no statistical purpose.
pub(crate) fn strand_rng(seed: u64) -> nst3d_core::math::SplitMix64 {
    nst3d_core::math::SplitMix64::new(seed ^ 0x5DEE_CE66_D1CE_4E5B)
}

/// Everything that can go wrong in the groom stages; one line naming the
/// problem.
#[derive(Debug, thiserror::Error)]
pub enum StrandError {
    /// Input geometry that cannot be used (empty, non-finite, bad indices).
    #[error("invalid input: {0}")]
    Invalid(String),
    /// A parameter outside its valid range.
    #[error("bad parameter: {0}")]
    Parameter(String),
    /// Two inputs that must match in length do not.
    #[error("{what}: expected {expected}, got {got}")]
    Mismatch {
        /// Which input.
        what: &'static str,
        /// Length required.
        expected: usize,
        /// Length given.
        got: usize,
    },
}
