//! What the network is shown: the density, or the optical density the
//! pictures are made of.
//!
//! A picture of a frame (eq. 6 with exposure γ, as every picture nst3d
//! draws) depends on the density only through `γ · d`, and γ is set per
//! frame: 3 over the frame's densest column ([`FRAME_DEPTH`]). A network
//! shown `d` alone cannot tell a deep frame (γ 0.04) from a shallow one
//! (γ 0.2), whose same voxels read five times fainter or stronger, so it
//! learns one strength of mark for the frames it was trained on. Shown the
//! optical density `γ · d / OPTICAL_REFERENCE`, it sees what the renderer
//! sees, and a frame of any depth is inside what it learned when training
//! drew γ over [`DRAWN_GAMMA`].

use std::collections::{BTreeMap, HashMap};

/// Optical depth of a frame's densest column in its pictures.
pub const FRAME_DEPTH: f32 = 3.0;

/// The γ at which the optical input equals the density (about the middle
/// of [`DRAWN_GAMMA`] on a log scale), so inputs stay near `[0, 1]`.
pub const OPTICAL_REFERENCE: f32 = 0.1;

/// The range training draws each patch's γ from (log-uniform) when the
/// network is shown optical density: the frames here span 0.04 (two
/// 50 × 50 × 90 VDB frames) to 0.22 (a 48³ plume).
pub const DRAWN_GAMMA: (f32, f32) = (0.03, 0.3);

/// The model metadata key that says what the network is shown.
pub const INPUT_KEY: &str = "input";

/// What the network's input channel holds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum NetInput {
    /// The density over the frame's largest value, in `[0, 1]` (the paper's).
    #[default]
    Density,
    /// That density times `γ / OPTICAL_REFERENCE`, γ the picture's absorption.
    Optical,
}

impl NetInput {
    /// What a model's metadata says (no key: [`NetInput::Density`]).
    pub fn of(info: &BTreeMap<String, String>) -> Result<Self, String> {
        match info.get(INPUT_KEY).map(String::as_str) {
            None | Some("density") => Ok(NetInput::Density),
            Some("optical") => Ok(NetInput::Optical),
            Some(other) => Err(format!("metadata '{INPUT_KEY}' is '{other}', this nst3d reads density or optical")),
        }
    }

    /// The factor from the normalised density to the network's input for
    /// pictures of absorption `gamma`.
    pub fn gain(self, gamma: f32) -> f32 {
        match self {
            NetInput::Density => 1.0,
            NetInput::Optical => gamma / OPTICAL_REFERENCE,
        }
    }
}

/// A frame's γ: [`FRAME_DEPTH`] over the largest sum of density along a line
/// of voxels parallel to an axis, from its voxels `(index, value)` (1 for a
/// frame without smoke; it is never drawn).
pub fn frame_gamma(voxels: impl Iterator<Item = ([i32; 3], f32)>) -> f32 {
    let mut sums: [HashMap<[i32; 2], f32>; 3] = Default::default();
    for ([x, y, z], v) in voxels {
        *sums[0].entry([y, z]).or_default() += v;
        *sums[1].entry([x, z]).or_default() += v;
        *sums[2].entry([x, y]).or_default() += v;
    }
    let densest = sums.iter().flat_map(|s| s.values()).copied().fold(0.0f32, f32::max);
    if densest > 0.0 {
        FRAME_DEPTH / densest
    } else {
        1.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The densest column counts on any axis; an empty frame gets 1.
    #[test]
    fn a_frame_is_seen_with_its_densest_column_at_depth_three() {
        let column = (0..5).map(|y| ([1, y, 2], 0.5));
        assert_eq!(frame_gamma(column.chain([([3, 0, 0], 1.0)])), 3.0 / 2.5);
        assert_eq!(frame_gamma(std::iter::empty()), 1.0);
    }

    /// The metadata names round-trip; an unknown one is refused.
    #[test]
    fn the_input_is_read_from_the_metadata() {
        let mut info = BTreeMap::new();
        assert_eq!(NetInput::of(&info), Ok(NetInput::Density));
        info.insert(INPUT_KEY.to_string(), "optical".to_string());
        assert_eq!(NetInput::of(&info), Ok(NetInput::Optical));
        assert_eq!(NetInput::Optical.gain(0.05), 0.5);
        assert_eq!(NetInput::Density.gain(0.05), 1.0);
        info.insert(INPUT_KEY.to_string(), "x".to_string());
        assert!(NetInput::of(&info).is_err());
    }
}
