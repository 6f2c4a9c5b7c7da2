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

    /// The [`LUMA`] luminance of an RGB image, repeated in three channels
    /// (the picture a grey renderer can reach, fed to a network that wants RGB).
    ///
    /// # Panics
    /// If the image does not have three channels.
    pub fn luminance3(&self) -> Image {
        assert_eq!(self.channels, 3, "luminance of an RGB image");
        let p = self.plane();
        let grey: Vec<f32> = (0..p).map(|i| (0..3).map(|c| LUMA[c] * self.data[c * p + i]).sum()).collect();
        Image::from_vec(3, self.height, self.width, [grey.as_slice(); 3].concat())
    }

    /// Backward of [`Image::luminance3`]: given the gradient w.r.t. the grey
    /// image `grad` (three channels), the gradient w.r.t. the RGB image.
    /// Every grey channel is `Σ_c LUMA[c] · rgb[c]`, so each RGB channel
    /// gets its luma weight times the sum of the three grey gradients.
    ///
    /// # Panics
    /// If `grad` does not have three channels.
    pub fn luminance3_backward(grad: &Image) -> Image {
        assert_eq!(grad.channels, 3, "gradient of a three-channel grey image");
        let p = grad.plane();
        let mut out = Image::zeros(3, grad.height, grad.width);
        for i in 0..p {
            let g: f32 = (0..3).map(|c| grad.data[c * p + i]).sum();
            for (c, w) in LUMA.iter().enumerate() {
                out.data[c * p + i] = w * g;
            }
        }
        out
    }
}

/// Rec. 601 luma weights of R, G and B (PIL's `convert("L")`): the one
/// definition of "grey" for paintings, judges and the colour layer, whose
/// luminance under these weights is held at 1.
pub const LUMA: [f32; 3] = [0.299, 0.587, 0.114];

/// How the values of a `C x P` feature matrix lie in memory.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    /// Channel-major, PyTorch's `(C, H, W)`: element `(c, p)` at `c · P + p`.
    Planar,
    /// Pixel-major, `(H, W, C)`: element `(c, p)` at `p · C + c`. This is how
    /// the VGG network keeps its activations, and the layout in which a
    /// Gram product `F Fᵀ` streams both operands contiguously.
    ChannelsLast,
}

/// A layer's features borrowed as the `C x P` matrix `F` of the Gram
/// formulas (`P = height · width` pixels), in either [`Layout`], so a loss
/// can read the network's activations where they lie instead of copying
/// them into planar images.
#[derive(Clone, Copy, Debug)]
pub struct FeatureView<'a> {
    /// Channels `C`.
    pub channels: usize,
    /// Rows of the feature map.
    pub height: usize,
    /// Columns of the feature map.
    pub width: usize,
    /// Memory layout of `data`.
    pub layout: Layout,
    /// `C · height · width` values.
    pub data: &'a [f32],
}

impl FeatureView<'_> {
    /// Pixels `P` per channel.
    pub fn pixels(&self) -> usize {
        self.height * self.width
    }

    /// (row, column) strides of `F` as a `C x P` matrix in `data`.
    pub fn strides(&self) -> (usize, usize) {
        match self.layout {
            Layout::Planar => (self.pixels(), 1),
            Layout::ChannelsLast => (1, self.channels),
        }
    }
}

impl<'a> From<&'a Image> for FeatureView<'a> {
    fn from(img: &'a Image) -> Self {
        Self { channels: img.channels, height: img.height, width: img.width, layout: Layout::Planar, data: &img.data }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gradcheck::{check_gradient, dot, pseudo_random};

    /// [`Image::luminance3_backward`] against central differences of
    /// [`Image::luminance3`].
    #[test]
    fn luminance3_backward_matches_finite_differences() {
        let x = pseudo_random(3 * 4 * 5, 1);
        let w = pseudo_random(3 * 4 * 5, 2);
        let g = Image::luminance3_backward(&Image::from_vec(3, 4, 5, w.clone()));
        let loss = |v: &[f32]| dot(&w, &Image::from_vec(3, 4, 5, v.to_vec()).luminance3().data);
        let r = check_gradient(&x, &g.data, loss, 1e-2, x.len(), 1e-4);
        assert!(r.max_rel_err < 1e-3, "{r:?}");
    }
}
