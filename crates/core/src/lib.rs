//! Shared value types of nst3d: the dense voxel grid every stage passes along,
//! the planar image the renderer produces and the network consumes, and the
//! finite-difference gradient check every differentiable op is tested with.

pub mod fixture;
pub mod gradcheck;
pub mod grid;
pub mod image;
pub mod math;

pub use grid::Grid3;
pub use image::Image;
