//! Training the feed-forward network of volumetric style transfer (paper
//! Sec. 4 and 5.1, "Feed-Forward Training"): each step takes a random,
//! randomly rotated and mirrored patch of a simulation, runs the network
//! ([`nst3d_network::FeedForward`]), applies its output as a density scale
//! `d · (1 + tanh o)` (eq. 3) or a velocity `vmax · tanh o` (eq. 1), renders
//! the result with the transmittance renderer, scores it with the VGG-19
//! Gram loss against the painting and updates the weights with clipped Adam
//! under a OneCycle schedule.

#![warn(missing_docs)]

pub mod absorption;
pub mod axes;
pub mod bench;
pub mod curve;
pub mod distributed;
pub mod job;
pub mod patch;
pub mod step;

pub use absorption::Absorption;
pub use axes::{Axis, Sight, ViewAxes};
pub use job::{train, train_on, TrainReport, TrainSettings};
pub use patch::{rotated_patch, Rotation};
pub use step::{Stylization, TrainStep};
