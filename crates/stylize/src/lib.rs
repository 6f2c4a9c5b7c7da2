//! The optimisation of paper Sec. 3 for one frame: a velocity field (eq. 2)
//! or a density scale field (eq. 5) is fitted over several octaves so that
//! renders of the transported density match a painting's Gram statistics.
//!
//! - [`field`]: the optimised quantity and its transport `T` (one type for both modes).
//! - [`color`]: the smoke's colour as a luminance-1, smoothed chroma layer.
//! - [`view`]: one camera's loss `L(R_θ(d*))` and its gradient w.r.t. `d*`.
//! - [`guided`]: several paintings split by a style map (guided Gram loss);
//!   [`guided_color`]: their colour, each over its region.
//! - [`frame`]: the multi-octave Adam loop over a single density grid.
//! - [`bench`]: the `volume-iter` benchmark work of `shared/bench/README.md`.

#![warn(missing_docs)]

pub mod bench;
pub mod color;
pub mod color_stage;
pub mod field;
pub mod frame;
pub mod guided;
pub mod guided_color;
pub mod view;

pub use color_stage::{
    stylize_color, stylize_color_map, ColorProgress, ColorResult, ColorStageParams, JointDensity, COLOR_VIEWS,
};
pub use field::{Field, Limits, Mode, Tape};
pub use frame::{stylize_frame, stylize_frame_map, stylize_frame_views, FrameParams, FrameResult, Progress};
pub use guided::{region_guides, MapLoss};
pub use view::{color_view_image, view_image, StyleSpec, ViewError, ViewLoss, ViewSpec};
