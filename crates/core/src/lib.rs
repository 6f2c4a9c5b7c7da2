//! Shared value types of nst3d: the dense voxel grid every stage passes along,
//! the planar image the renderer produces and the network consumes, the
//! groom and triangle mesh the strand pipeline works on, the `Reporter` a
//! long job reports its progress through, and the
//! finite-difference gradient check every differentiable op is tested with.

#![warn(missing_docs)]

pub mod axis;
pub mod bf16;
pub mod fill;
pub mod fixture;
pub mod gradcheck;
pub mod grid;
pub mod groom;
pub mod image;
pub mod linalg;
pub mod math;
pub mod memory;
pub mod mesh;
pub mod microkernel;
pub mod names;
pub mod precision;
pub mod report;
pub mod stats;
pub mod stop;

pub use axis::UpAxis;
pub use grid::Grid3;
pub use groom::{Groom, GroomError, Strand, StrandSpline};
pub use image::{FeatureView, Image, Layout};
pub use mesh::TriMesh;
pub use report::{Reporter, Silent};
