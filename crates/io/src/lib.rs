//! File formats in and out of nst3d: OpenVDB volumes, images, and the
//! write-to-temporary-then-rename rule every output follows.

pub mod atomic;
pub mod groom;
pub mod image;
pub mod mesh;
pub mod vdb;
