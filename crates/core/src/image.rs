//! Planar (channel-major) `f32` image, the layout of a PyTorch `(C, H, W)` tensor.

/// `channels x height x width` values, row-major within a channel.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    /// Number of channels (1 for a render, 3 for RGB).
    pub channels: usize,
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
    /// `channels * height * width` values, `(c * height + y) * width + x`.
    pub data: Vec<f32>,
}

impl Image {
    /// An all-zero image.
    pub fn zeros(channels: usize, height: usize, width: usize) -> Self {
        Self { channels, height, width, data: vec![0.0; channels * height * width] }
    }

    /// Wraps existing data; panics if the length does not match.
    pub fn from_vec(channels: usize, height: usize, width: usize, data: Vec<f32>) -> Self {
        assert_eq!(data.len(), channels * height * width, "image data length");
        Self { channels, height, width, data }
    }

    /// Pixels per channel.
    pub fn plane(&self) -> usize {
        self.height * self.width
    }

    /// Channel `c` as a slice.
    pub fn channel(&self, c: usize) -> &[f32] {
        let p = self.plane();
        &self.data[c * p..(c + 1) * p]
    }
}
