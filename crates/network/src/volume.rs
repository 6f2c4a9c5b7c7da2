//! A multi-channel 3D tensor.

use nst3d_core::Grid3;

/// `channels` 3D grids of `dims = [x, y, z]` voxels, stored channel by
/// channel, each z-major then y then x (PyTorch's `(C, D, H, W)`).
#[derive(Clone, Debug, PartialEq)]
pub struct Volume {
    /// Number of channels `C`.
    pub channels: usize,
    /// Voxels along x, y, z.
    pub dims: [usize; 3],
    /// `C · z · y · x` values.
    pub data: Vec<f32>,
}

impl Volume {
    /// All zeros.
    pub fn zeros(channels: usize, dims: [usize; 3]) -> Self {
        Self { channels, dims, data: vec![0.0; channels * dims.iter().product::<usize>()] }
    }

    /// Wraps `data`.
    ///
    /// # Panics
    /// If `data` does not hold `channels · x · y · z` values.
    pub fn from_vec(channels: usize, dims: [usize; 3], data: Vec<f32>) -> Self {
        assert_eq!(data.len(), channels * dims.iter().product::<usize>(), "volume data length");
        Self { channels, dims, data }
    }

    /// A one-channel volume holding a density grid.
    pub fn from_grid(g: &Grid3) -> Self {
        Self { channels: 1, dims: g.dims, data: g.data.clone() }
    }

    /// Voxels per channel.
    pub fn voxels(&self) -> usize {
        self.dims.iter().product()
    }

    /// Channel `c`'s values.
    pub fn channel(&self, c: usize) -> &[f32] {
        let n = self.voxels();
        &self.data[c * n..][..n]
    }
}
