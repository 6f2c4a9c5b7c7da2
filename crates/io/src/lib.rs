//! File formats in and out of nst3d: OpenVDB volumes, grooms, meshes,
//! images, and the write-to-temporary-then-rename rule every output follows.
//! Every reader and writer fails with one [`Error`]: the file and an
//! [`ErrorKind`].

#![warn(missing_docs)]

pub mod atomic;
mod bytes;
mod error;
pub mod groom;
pub mod image;
pub mod mesh;
pub mod vdb;

pub use error::{Error, ErrorKind};
