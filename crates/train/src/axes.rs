//! Which way a training patch is seen. The renderer marches a grid along
//! its z axis; a network trained on pictures along z alone learns where the
//! camera is. It is convolutional, not rotation-equivariant, so rotating
//! the patch's *content* (Sec. 5.1's augmentation, [`crate::patch`]) does not
//! hide the grid's z from it: the models trained so stretched their scale
//! field along z (on a held-out bake the log-scale's correlation one voxel
//! apart was 0.97 along z, 0.57 and 0.06 across; docs/design/feedforward.md), a
//! column is as bright as a stroke when seen end on, and from the side, as
//! every other camera sees it, the columns are streaks. Seeing each patch
//! along another of its axes takes that away.
//!
//! Turning an axis to z is a cyclic permutation of the grid's axes (it
//! keeps the handedness, so no picture is mirrored); its backward is the
//! inverse permutation, checked below as an exact adjoint.
//!
//! Seen only along its axes, a network still learns its grid: strokes that
//! read along x, y and z need not read from between them, where the
//! optimisation's cameras and every judge's ring look. `sphere` shows each
//! patch through a perspective camera from a direction drawn uniformly on
//! the sphere, as the omniview cameras of Sec. 4 are placed, so the
//! network's output is seen from every direction relative to its grid.

use std::str::FromStr;

use nst3d_core::Grid3;
use nst3d_render::{camera_towards, sphere_point, Camera, Projection};

/// A grid axis a patch is rendered along.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Axis {
    /// Along x: the grid's (y, z, x) become the picture's (x, y, depth).
    X,
    /// Along y: (z, x, y).
    Y,
    /// Along z, the renderer's own direction: no permutation.
    Z,
}

impl Axis {
    /// The three, in order.
    pub const ALL: [Axis; 3] = [Axis::X, Axis::Y, Axis::Z];

    /// Which original axis becomes each axis of the turned grid.
    fn source(self) -> [usize; 3] {
        match self {
            Axis::X => [1, 2, 0],
            Axis::Y => [2, 0, 1],
            Axis::Z => [0, 1, 2],
        }
    }
}

/// The axes each training step renders its patch along (`nst3d train --view-axes`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ViewAxes {
    /// Always z, as the paper's peer (`torch_ff_ref.py`) and the first
    /// models trained.
    Z,
    /// One of x, y and z per step, drawn at random: the same work as `Z`.
    Random,
    /// All three per step, the loss their mean: three renders and VGG-19
    /// passes per network pass.
    All,
    /// One perspective camera per step from a uniformly drawn direction
    /// (module docs).
    Sphere,
}

/// How one picture of a step sees its patch.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Sight {
    /// Marched along a grid axis (turned to z, no camera).
    Along(Axis),
    /// Through [`camera_towards`] the unit direction, perspective.
    From([f64; 3]),
}

impl Sight {
    /// The camera of a [`Sight::From`] for a patch of `dims`.
    pub fn camera(self, dims: [usize; 3]) -> Option<Camera> {
        match self {
            Sight::Along(_) => None,
            Sight::From(dir) => Some(camera_towards(dir, dims, Projection::Perspective)),
        }
    }
}

impl ViewAxes {
    /// The sights of one step; `draw` gives numbers in `[0, 1)` (one for
    /// `Random`, two for `Sphere`).
    pub fn pick(self, mut draw: impl FnMut() -> f32) -> Vec<Sight> {
        match self {
            ViewAxes::Z => vec![Sight::Along(Axis::Z)],
            ViewAxes::Random => vec![Sight::Along(Axis::ALL[((draw() * 3.0) as usize).min(2)])],
            ViewAxes::All => Axis::ALL.map(Sight::Along).to_vec(),
            ViewAxes::Sphere => {
                let u = draw() as f64;
                vec![Sight::From(sphere_point(u, draw() as f64))]
            }
        }
    }

    /// The command line's name.
    pub fn name(self) -> &'static str {
        match self {
            ViewAxes::Z => "z",
            ViewAxes::Random => "random",
            ViewAxes::All => "all",
            ViewAxes::Sphere => "sphere",
        }
    }
}

impl FromStr for ViewAxes {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "z" => Ok(ViewAxes::Z),
            "random" => Ok(ViewAxes::Random),
            "all" => Ok(ViewAxes::All),
            "sphere" => Ok(ViewAxes::Sphere),
            _ => Err(format!("view axes must be z, random, all or sphere, got '{s}'")),
        }
    }
}

/// `d` with `axis` turned to z, so the renderer marches along it.
pub fn turn_to_z(d: &Grid3, axis: Axis) -> Grid3 {
    let src = axis.source();
    let dims = src.map(|a| d.dims[a]);
    let mut out = Grid3::zeros(dims);
    let mut i = 0;
    for c in 0..dims[2] {
        for b in 0..dims[1] {
            for a in 0..dims[0] {
                let mut p = [0usize; 3];
                (p[src[0]], p[src[1]], p[src[2]]) = (a, b, c);
                out.data[i] = d.data[d.index(p[0], p[1], p[2])];
                i += 1;
            }
        }
    }
    out
}

/// The gradient w.r.t. the grid [`turn_to_z`] was given, from the gradient
/// `g` w.r.t. its output: the inverse permutation.
pub fn turn_to_z_backward(g: &Grid3, axis: Axis) -> Grid3 {
    let src = axis.source();
    let mut dims = [0usize; 3];
    (0..3).for_each(|k| dims[src[k]] = g.dims[k]);
    let mut out = Grid3::zeros(dims);
    let mut i = 0;
    for c in 0..g.dims[2] {
        for b in 0..g.dims[1] {
            for a in 0..g.dims[0] {
                let mut p = [0usize; 3];
                (p[src[0]], p[src[1]], p[src[2]]) = (a, b, c);
                let j = out.index(p[0], p[1], p[2]);
                out.data[j] = g.data[i];
                i += 1;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::{dot, pseudo_random};

    #[test]
    fn turning_x_to_z_puts_x_in_depth() {
        let d = Grid3::from_vec([2, 3, 4], (0..24).map(|i| i as f32).collect());
        let t = turn_to_z(&d, Axis::X);
        assert_eq!(t.dims, [3, 4, 2]);
        for z in 0..4 {
            for y in 0..3 {
                for x in 0..2 {
                    // The turned grid's (a, b, c) is the original's (y, z, x).
                    assert_eq!(t.at(y, z, x), d.at(x, y, z));
                }
            }
        }
        let t = turn_to_z(&d, Axis::Y);
        assert_eq!(t.dims, [4, 2, 3]);
        assert_eq!(t.at(3, 1, 2), d.at(1, 2, 3));
        assert_eq!(turn_to_z(&d, Axis::Z).data, d.data);
    }

    /// The backward is the forward's adjoint: ⟨turn(d), g⟩ = ⟨d, back(g)⟩
    /// for any d and g (exact for a permutation; a linear map needs no
    /// finite differences beyond this).
    #[test]
    fn the_backward_is_the_adjoint() {
        let dims = [3, 4, 5];
        let d = Grid3::from_vec(dims, pseudo_random(60, 1));
        for axis in Axis::ALL {
            let t = turn_to_z(&d, axis);
            let g = Grid3::from_vec(t.dims, pseudo_random(60, 2));
            let back = turn_to_z_backward(&g, axis);
            assert_eq!(back.dims, dims);
            assert!((dot(&t.data, &g.data) - dot(&d.data, &back.data)).abs() < 1e-9, "{axis:?}");
            assert_eq!(turn_to_z_backward(&t, axis).data, d.data, "{axis:?}: not the inverse");
        }
    }

    #[test]
    fn random_picks_each_axis() {
        assert_eq!(ViewAxes::Random.pick(|| 0.0), vec![Sight::Along(Axis::X)]);
        assert_eq!(ViewAxes::Random.pick(|| 0.5), vec![Sight::Along(Axis::Y)]);
        assert_eq!(ViewAxes::Random.pick(|| 0.999_999_9), vec![Sight::Along(Axis::Z)]);
        assert_eq!(ViewAxes::All.pick(|| unreachable!()).len(), 3);
        assert_eq!("all".parse::<ViewAxes>(), Ok(ViewAxes::All));
        assert_eq!("sphere".parse::<ViewAxes>(), Ok(ViewAxes::Sphere));
        assert!("xy".parse::<ViewAxes>().is_err());
    }

    /// Sphere sights are unit directions spread over the whole sphere: the
    /// mean of many is near the centre and every octant is drawn.
    #[test]
    fn sphere_sights_cover_the_sphere() {
        let mut rng = nst3d_core::math::SplitMix64::new(3);
        let mut mean = [0.0f64; 3];
        let mut octants = [0usize; 8];
        for _ in 0..4000 {
            let [Sight::From(d)] = ViewAxes::Sphere.pick(|| rng.uniform_f32())[..] else { panic!("one camera") };
            assert!((d.iter().map(|x| x * x).sum::<f64>() - 1.0).abs() < 1e-6);
            (0..3).for_each(|a| mean[a] += d[a] / 4000.0);
            octants[(d[0] > 0.0) as usize + 2 * (d[1] > 0.0) as usize + 4 * (d[2] > 0.0) as usize] += 1;
        }
        assert!(mean.iter().all(|m| m.abs() < 0.05), "{mean:?}");
        assert!(octants.iter().all(|&n| n > 350), "{octants:?}");
        let cam = Sight::From([0.0, 0.0, 1.0]).camera([8; 3]).unwrap();
        assert_eq!(cam.target, [3.5; 3]);
    }
}
