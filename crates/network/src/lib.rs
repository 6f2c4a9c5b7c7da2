//! The feed-forward network of volumetric style transfer (paper Sec. 4,
//! Fig. 9) and the differentiable 3D ops it is built from: convolution
//! (forward, input gradient and weight gradient), trilinear ×2 upsampling
//! and LeakyReLU. Each op's backward sits beside its forward and is checked
//! against finite differences and against PyTorch fixtures
//! (`tools/fixtures/network_ops.py`).
//!
//! Tensors are [`Volume`]s: `C` channels of a 3D grid, PyTorch's `(C, D, H,
//! W)` order with `D = z`, `H = y`, `W = x`.

#![warn(missing_docs)]

pub mod activation;
pub mod apply;
pub mod bench;
pub mod conv3d;
pub mod feedforward;
pub mod model;
pub mod texture;
pub mod tiled;
pub mod upsample;
pub mod volume;

pub use activation::{leaky_relu, leaky_relu_backward, LEAKY_SLOPE};
pub use conv3d::{Conv3d, Conv3dGrads};
pub use feedforward::FeedForward;
pub use model::{Model, ModelError};
pub use texture::SolidTexture;
pub use tiled::{infer_tiled, RECEPTIVE_RADIUS};
pub use upsample::{upsample2, upsample2_backward};
pub use volume::Volume;
