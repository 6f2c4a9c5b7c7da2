//! Whole simulations rather than single frames (paper Sec. 3.2): frame
//! ranges and file-name patterns as render farms hand them over, and the
//! exponential moving average that carries the stylisation from frame to
//! frame along the simulation's own velocity (eq. 4, Algorithm 1).

#![warn(missing_docs)]

pub mod calibrate;
pub mod ema;
pub mod flicker;
pub mod frames;
pub mod job;
pub mod lock;
pub mod store;

pub use frames::{expand_pattern, FrameSpec, FramesError};
pub use job::{default_work_dir, job_fingerprint, settings_key};
pub use lock::WorkLock;
pub use store::DiskStore;
