//! Whole simulations rather than single frames (paper Sec. 3.2): the
//! exponential moving average that carries the stylisation from frame to
//! frame along the simulation's own velocity (eq. 4, Algorithm 1), the
//! per-frame state its sweeps keep on disk, and the flicker that judges it.
//! Frame lists, the lock and the job fingerprint are `nst3d-job`'s.

#![warn(missing_docs)]

pub mod calibrate;
pub mod ema;
pub mod flicker;
pub mod store;

pub use store::DiskStore;
