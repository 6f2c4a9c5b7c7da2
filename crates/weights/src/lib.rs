//! Reading pretrained network weights: PyTorch `.pth` (legacy pickle and zip
//! archives) and `.safetensors`, into plain `f32` tensors by name.

use std::collections::BTreeMap;

/// One named tensor: its shape (PyTorch order) and values, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct TensorData {
    /// Dimensions, outermost first (a conv weight is `[cout, cin, kh, kw]`).
    pub shape: Vec<usize>,
    /// `shape.iter().product()` values.
    pub data: Vec<f32>,
}

/// Tensors of a checkpoint by their state-dict key (e.g. `"2.weight"`).
pub type TensorMap = BTreeMap<String, TensorData>;
