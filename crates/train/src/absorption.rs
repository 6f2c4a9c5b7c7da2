//! How opaque the training pictures are: the absorption γ each patch is
//! rendered with (`nst3d train --absorption`).
//!
//! `patch` is γ = 8/P for every patch, as the paper's peer draws its
//! patches: a ray through a full patch of density 1 reaches optical depth 8.
//! `frame` sees each patch with its frame's own γ, by the rule every other
//! picture of a frame is drawn with (the optimisation's, the previews', the
//! judge's): 3 over the frame's densest column. Why it matters: a network
//! learns its marks for the opacity it was shown. At 8/P a voxel is several
//! times as opaque as the same voxel in a picture of its whole frame (γ 0.25
//! at 32³ against 0.04–0.22 for the frames here), so marks that read from the
//! front of an opaque patch wash out when a whole frame's rays average them.

use std::str::FromStr;

use nst3d_core::Grid3;

/// The absorption of the training pictures.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Absorption {
    /// γ = 8/P for every patch.
    Patch,
    /// Each patch with its frame's γ: 3 over the frame's densest column.
    Frame,
}

/// Optical depth of a frame's densest column in its pictures.
pub const FRAME_DEPTH: f32 = 3.0;

/// Optical depth of a full patch of density 1 under [`Absorption::Patch`].
pub const PATCH_DEPTH: f32 = 8.0;

impl Absorption {
    /// γ for each of `frames` (densities in `[0, 1]`) cut into patches of
    /// side `patch`.
    pub fn gammas(self, frames: &[Grid3], patch: usize) -> Vec<f32> {
        match self {
            Absorption::Patch => vec![PATCH_DEPTH / patch as f32; frames.len()],
            Absorption::Frame => frames.iter().map(frame_gamma).collect(),
        }
    }

    /// The command line's name.
    pub fn name(self) -> &'static str {
        match self {
            Absorption::Patch => "patch",
            Absorption::Frame => "frame",
        }
    }
}

impl FromStr for Absorption {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "patch" => Ok(Absorption::Patch),
            "frame" => Ok(Absorption::Frame),
            _ => Err(format!("absorption must be patch or frame, got '{s}'")),
        }
    }
}

/// [`FRAME_DEPTH`] over the largest sum of `d` along a line of voxels
/// parallel to an axis (1 for a frame without smoke; it is never drawn).
fn frame_gamma(d: &Grid3) -> f32 {
    let [nx, ny, nz] = d.dims;
    let mut sums = [vec![0.0f32; ny * nz], vec![0.0f32; nx * nz], vec![0.0f32; nx * ny]];
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                let v = d.data[d.index(x, y, z)];
                sums[0][z * ny + y] += v;
                sums[1][z * nx + x] += v;
                sums[2][y * nx + x] += v;
            }
        }
    }
    let densest = sums.iter().flatten().copied().fold(0.0f32, f32::max);
    if densest > 0.0 {
        FRAME_DEPTH / densest
    } else {
        1.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A frame's γ puts its densest column at optical depth 3, whichever
    /// axis that column runs along; `patch` is 8/P whatever the frame.
    #[test]
    fn a_frame_is_seen_with_its_densest_column_at_depth_three() {
        let mut d = Grid3::zeros([4, 5, 6]);
        for y in 0..5 {
            let i = d.index(1, y, 2);
            d.data[i] = 0.5;
        }
        let j = d.index(3, 0, 0);
        d.data[j] = 1.0;
        let g = Absorption::Frame.gammas(std::slice::from_ref(&d), 32);
        assert_eq!(g, vec![3.0 / 2.5]);
        assert_eq!(Absorption::Patch.gammas(&[d.clone(), d], 32), vec![0.25, 0.25]);
        assert_eq!(Absorption::Frame.gammas(&[Grid3::zeros([2, 2, 2])], 32), vec![1.0]);
        for a in [Absorption::Patch, Absorption::Frame] {
            assert_eq!(a.name().parse::<Absorption>(), Ok(a));
        }
        assert!("x".parse::<Absorption>().is_err());
    }
}
