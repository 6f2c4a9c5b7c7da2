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
//! `drawn` gives each patch its own γ over the range of frames' depths and
//! shows the network the optical density (`nst3d_network::optical`): a
//! network that cannot see how deep a patch's frame is learns one strength
//! of mark, too strong for shallow frames under `frame`.

use std::str::FromStr;

use nst3d_core::math::SplitMix64;
use nst3d_core::Grid3;
use nst3d_network::optical::{NetInput, DRAWN_GAMMA};

/// The absorption of the training pictures.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Absorption {
    /// γ = 8/P for every patch.
    Patch,
    /// Each patch with its frame's γ: 3 over the frame's densest column.
    Frame,
    /// Each patch with its own γ, drawn log-uniformly over [`DRAWN_GAMMA`],
    /// and the network shown the optical density (`NetInput::Optical`), so
    /// it learns marks for frames of every depth and is told which it sees.
    Drawn,
}

/// Optical depth of a full patch of density 1 under [`Absorption::Patch`].
pub const PATCH_DEPTH: f32 = 8.0;

impl Absorption {
    /// γ for each of `frames` (densities in `[0, 1]`) cut into patches of
    /// side `patch`.
    pub fn gammas(self, frames: &[Grid3], patch: usize) -> Vec<f32> {
        match self {
            Absorption::Patch => vec![PATCH_DEPTH / patch as f32; frames.len()],
            // Drawn: the frame's γ stands until each patch draws its own.
            Absorption::Frame | Absorption::Drawn => frames.iter().map(frame_gamma).collect(),
        }
    }

    /// A patch's own γ from `rng` (only [`Absorption::Drawn`] draws one,
    /// so the other rules keep their runs' streams).
    pub fn draw(self, rng: &mut SplitMix64) -> Option<f32> {
        let (lo, hi) = DRAWN_GAMMA;
        (self == Absorption::Drawn).then(|| lo * (hi / lo).powf(rng.uniform_f32()))
    }

    /// What the network is shown under this rule.
    pub fn input(self) -> NetInput {
        match self {
            Absorption::Drawn => NetInput::Optical,
            Absorption::Patch | Absorption::Frame => NetInput::Density,
        }
    }

    /// The command line's name.
    pub fn name(self) -> &'static str {
        match self {
            Absorption::Patch => "patch",
            Absorption::Frame => "frame",
            Absorption::Drawn => "drawn",
        }
    }
}

impl FromStr for Absorption {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "patch" => Ok(Absorption::Patch),
            "frame" => Ok(Absorption::Frame),
            "drawn" => Ok(Absorption::Drawn),
            _ => Err(format!("absorption must be patch, frame or drawn, got '{s}'")),
        }
    }
}

/// 3 over the frame's densest axis column ([`nst3d_network::optical::frame_gamma`]).
fn frame_gamma(d: &Grid3) -> f32 {
    let [nx, ny, nz] = d.dims;
    let voxels = (0..nz).flat_map(move |z| (0..ny).flat_map(move |y| (0..nx).map(move |x| [x, y, z])));
    nst3d_network::optical::frame_gamma(
        voxels.map(|[x, y, z]| ([x as i32, y as i32, z as i32], d.data[d.index(x, y, z)])).filter(|(_, v)| *v != 0.0),
    )
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
        for a in [Absorption::Patch, Absorption::Frame, Absorption::Drawn] {
            assert_eq!(a.name().parse::<Absorption>(), Ok(a));
        }
        assert!("x".parse::<Absorption>().is_err());
    }

    /// Drawn γ stay in the range and spread over it; the other rules draw
    /// nothing from the stream.
    #[test]
    fn drawn_absorption_spans_its_range_and_leaves_other_streams_alone() {
        let mut rng = SplitMix64::new(5);
        let g: Vec<f32> = (0..2000).map(|_| Absorption::Drawn.draw(&mut rng).unwrap()).collect();
        let (lo, hi) = DRAWN_GAMMA;
        assert!(g.iter().all(|&v| (lo..=hi).contains(&v)));
        let below = g.iter().filter(|&&v| v < (lo * hi).sqrt()).count();
        assert!((900..1100).contains(&below), "log-uniform: half below the geometric mean, got {below}");
        let mut a = SplitMix64::new(5);
        assert_eq!(Absorption::Frame.draw(&mut a), None);
        assert_eq!(a.next_u64(), SplitMix64::new(5).next_u64());
        assert_eq!(Absorption::Drawn.input(), NetInput::Optical);
        assert_eq!(Absorption::Frame.input(), NetInput::Density);
    }
}
