//! Transport functions `T` of the volumetric style transfer (paper Sec. 3.1
//! and 3.3): the velocity-mode linear mapping `I(d, g + v)` with trilinear
//! interpolation `I` and its smooth velocity `S w`, the density-mode
//! modulation `d · s`, their backward passes, the artist-facing limiters,
//! and the resampling that carries fields between optimisation octaves.
//!
//! All positions and velocities are in voxel-index units of the grid they
//! belong to (voxel centres at integers, `[x, y, z]` order).

#![warn(missing_docs)]

mod resample;
mod sample;
mod smooth;
mod transport;

pub use resample::{downsample2, downsample2_backward, resize_grid, resize_velocity};
pub use sample::{sample_trilinear, sample_trilinear_backward, sample_trilinear_rows, sample_trilinear_rows_backward};
pub use smooth::{tent_smooth, tent_smooth_flat, tent_smooth_into};
pub use transport::{advect_linear, advect_linear_backward, clamp_scale, limit_velocity, modulate, modulate_backward};
