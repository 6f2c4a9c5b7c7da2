//! What every nst3d job shares, whatever it stylizes: frame ranges and
//! file-name patterns as render farms hand them over ([`FrameSpec`],
//! [`expand_pattern`]), the lock that keeps two blades off one job
//! ([`WorkLock`]) and the fingerprint that names a job's work folder from
//! its settings and inputs, so a rerun finds its saved state again and a
//! changed job never resumes a stale one ([`job_fingerprint`], [`JobId`]),
//! the one format every job saves its state in ([`State`]) and how a job
//! starts: lock, then resume from its own state or start afresh
//! ([`Resume`], [`StateFiles`]), and how a farm's stop signal reaches it
//! ([`signals`]).
//!
//! The volume, groom and training jobs use it; none of them needs the
//! others' optimisers to get a lock or a frame list.

#![warn(missing_docs)]

pub mod fingerprint;
pub mod frames;
pub mod lock;
pub mod resume;
pub mod signals;
pub mod state;

pub use fingerprint::{default_work_dir, job_fingerprint, settings_key, JobId};
pub use frames::{expand_pattern, FrameSpec, FramesError};
pub use lock::WorkLock;
pub use resume::{Resume, StateError, StateFiles};
pub use state::State;
