//! Dense scalar voxel grid.
//!
//! Layout is the one PyTorch uses for a `(D, H, W)` tensor: `x` fastest, then
//! `y`, then `z`, so `index = (z * ny + y) * nx + x`. Keeping the same order
//! means fixtures produced with PyTorch compare element for element.

/// A dense `nx * ny * nz` grid of `f32` values (density, a scale field, ...).
#[derive(Clone, Debug, PartialEq)]
pub struct Grid3 {
    /// Size along x, y, z.
    pub dims: [usize; 3],
    /// Values, `x` fastest (see module docs).
    pub data: Vec<f32>,
}

impl Grid3 {
    /// A grid of zeros.
    pub fn zeros(dims: [usize; 3]) -> Self {
        Self { dims, data: vec![0.0; dims[0] * dims[1] * dims[2]] }
    }

    /// Wraps existing data; panics if the length does not match `dims`
    /// (a programming error, never user input).
    pub fn from_vec(dims: [usize; 3], data: Vec<f32>) -> Self {
        assert_eq!(data.len(), dims[0] * dims[1] * dims[2], "grid data length");
        Self { dims, data }
    }

    /// Number of voxels.
    pub fn len(&self) -> usize {
        self.data.len()
    }

    /// True when the grid has no voxels.
    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    /// Linear index of voxel `(x, y, z)`.
    #[inline]
    pub fn index(&self, x: usize, y: usize, z: usize) -> usize {
        (z * self.dims[1] + y) * self.dims[0] + x
    }

    /// Value at voxel `(x, y, z)`.
    #[inline]
    pub fn at(&self, x: usize, y: usize, z: usize) -> f32 {
        self.data[self.index(x, y, z)]
    }

    /// Largest value (0 for an empty grid).
    pub fn max(&self) -> f32 {
        self.data.iter().copied().fold(0.0, f32::max)
    }
}
