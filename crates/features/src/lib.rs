//! Differentiable VGG-19 feature extraction on the CPU: the style
//! representation of the paper (Sec. 3) is Gram matrices of these features,
//! and every optimisation iteration runs the network forward to the style
//! taps and backward to the rendered image.
//!
//! Weights are frozen, so only input gradients exist. Activations are kept
//! channels-last ([`FeatureMap`]); 3x3 convolutions run as Winograd
//! F(4x4, 3x3) with precomputed kernel transforms (forward and the flipped
//! kernel for backward) and an AVX-512 product kernel when the CPU has one.

#![warn(missing_docs)]

mod conv;
mod conv_bf16;
mod gemm;
pub mod ops;
mod simd;
mod tensor;
mod vgg;
mod winograd;

pub use conv::{Conv1x1, Conv3x3, ConvAlgorithm};
pub use ops::{relu, relu_backward, MaxPool2x2, PoolArgmax};
pub use tensor::{FeatureMap, Padding};
pub use vgg::{Vgg19, VggFlavor, VggForward, VggLayer};

/// Why a network or layer could not be built.
#[derive(Debug, thiserror::Error)]
pub enum FeaturesError {
    /// The checkpoint lacks a tensor the network needs.
    #[error("VGG-19 weights: missing tensor `{0}`")]
    MissingKey(String),
    /// A tensor has the wrong shape.
    #[error("VGG-19 weights: tensor `{key}` has shape {found:?}, expected {expected:?}")]
    BadShape {
        /// State-dict key.
        key: String,
        /// Shape in the checkpoint.
        found: Vec<usize>,
        /// Shape the architecture needs.
        expected: Vec<usize>,
    },
    /// Neither known key layout was found.
    #[error("not a VGG-19 checkpoint: neither `features.0.weight` (torchvision) nor `0.weight` of shape [3, 3, 1, 1] (Gatys normalised VGG) found")]
    UnknownFlavor,
    /// The weights file could not be found or read.
    #[error(transparent)]
    Weights(#[from] nst3d_weights::WeightsError),
    /// A weights file that was read but is not a usable VGG-19.
    #[error("{}: {source}", path.display())]
    File {
        /// The file.
        path: std::path::PathBuf,
        /// What is wrong with its tensors.
        source: Box<FeaturesError>,
    },
    /// A layer name that is not a VGG-19 ReLU.
    #[error("unknown VGG-19 layer `{0}` (expected relu1_1 .. relu5_1, e.g. relu3_1)")]
    UnknownLayer(String),
    /// Weight/bias lengths inconsistent with the channel counts.
    #[error("convolution {cin} -> {cout} channels: got {weight} weights and {bias} biases")]
    BadConv {
        /// Input channels.
        cin: usize,
        /// Output channels.
        cout: usize,
        /// Weight values given.
        weight: usize,
        /// Bias values given.
        bias: usize,
    },
}
