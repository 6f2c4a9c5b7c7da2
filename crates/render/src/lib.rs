//! The differentiable renderer `R_θ` of the volumetric style transfer (paper
//! eq. 1, 6, 7 and Sec. 5.1): cameras that resample the grid on a
//! camera-aligned lattice (orthographic box or perspective truncated pyramid),
//! the front-to-back transmittance march, the 2x upsampling applied before the
//! network, and the differentiable histogram equalisation. Every op has its
//! backward next to it.

#![warn(missing_docs)]

mod camera;
mod camera_file;
mod equalize;
mod march;
mod render;
mod sphere;
mod upsample;

pub use camera::{Camera, Projection, View};
pub use camera_file::{fov_y_from_lens, world_to_index, Aim, CameraFileError, CameraKey, CameraRig};
pub use equalize::{equalize, equalize_backward, EqCache, EqualizeParams};
pub use march::{march, march_backward, march_emission, march_emission_backward};
pub use render::{
    march_color, march_color_backward, march_color_on, render, render_backward, render_color_backward,
    render_color_view, render_view, ColorRenderCache, RenderCache,
};
pub use sphere::{
    camera_towards, min_angular_distance_deg, omniview, poisson_disk_sphere, ring, sphere_point, sphere_uniform,
};
pub use upsample::{upsample2x, upsample2x_backward};

/// Why a render or equalisation could not be set up.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RenderError {
    /// The grid has a zero-sized axis.
    #[error("cannot render an empty grid")]
    EmptyGrid,
    /// Camera position, target or up vector contains NaN or infinity.
    #[error("camera eye, target and up must be finite")]
    NonFiniteCamera,
    /// No view direction.
    #[error("camera eye and target coincide")]
    EyeAtTarget,
    /// The up vector is parallel to the view direction (or zero).
    #[error("camera up vector is parallel to the view direction")]
    DegenerateUp,
    /// Perspective field of view outside (0, 180) degrees.
    #[error("perspective field of view {0} deg is not in (0, 180)")]
    BadFov(f32),
    /// Perspective film aspect not positive.
    #[error("camera aspect {0} must be positive")]
    BadAspect(f32),
    /// A perspective eye inside or in front of the grid's near bounding plane.
    #[error("perspective camera eye must be outside the grid's bounding box, looking at it")]
    EyeInsideBounds,
    /// The grid projects entirely outside the field of view.
    #[error("the grid is outside the camera's field of view")]
    OutOfView,
    /// The camera lattice would be unreasonably large.
    #[error("camera lattice {0:?} is too large")]
    LatticeTooLarge([usize; 3]),
    /// A precomputed view used with a grid of another size.
    #[error("view was made for a {view:?} grid, not {grid:?}")]
    ViewMismatch {
        /// Grid size the view was made for.
        view: [usize; 3],
        /// Grid size it was used with.
        grid: [usize; 3],
    },
    /// Absorption not finite.
    #[error("absorption gamma {0} must be finite")]
    BadGamma(f32),
    /// Histogram equalisation with zero bins.
    #[error("histogram equalisation needs at least one bin")]
    NoBins,
    /// Background threshold not finite.
    #[error("histogram threshold {0} must be finite")]
    BadThreshold(f32),
    /// Histogram range top not above the background threshold.
    #[error("histogram range top {top} must be finite and above the threshold {threshold}")]
    BadRange {
        /// Requested range top.
        top: f32,
        /// Background threshold.
        threshold: f32,
    },
}
