//! Small grids are refined before they are stylized. A painting's strokes
//! need voxels to live in: on a grid a few dozen voxels across, the finest
//! octave's patterns are one or two voxels wide and the result reads as a
//! smeared blob (plume48's frame 20, 18x18x20 voxels, docs/design/volumes.md).
//! The density (and, for a sequence, the simulation's
//! velocity) is trilinearly resampled to `k` times the resolution and the
//! stylized grid is written with a transform `k` times finer, so it still
//! sits exactly where the original was in world space.

use anyhow::{bail, Result};
use nst3d_core::Grid3;
use nst3d_io::vdb::Transform;
use nst3d_sequence::ema::{SequenceError, Simulation};
use nst3d_transport::resize_grid;

/// Below this many voxels along its largest side a grid is refined by
/// default ([`Upsample::Auto`]).
pub const AUTO_BELOW: usize = 32;
/// [`Upsample::Auto`] refines a small grid until its largest side reaches this.
pub const AUTO_TARGET: usize = 64;
/// The largest factor [`Upsample::Auto`] picks.
pub const AUTO_MAX: usize = 4;

/// How much finer than the file the stylized grid is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Upsample {
    /// Refine grids whose largest side is below [`AUTO_BELOW`] voxels until it
    /// reaches [`AUTO_TARGET`] (at most [`AUTO_MAX`] times); keep larger ones.
    Auto,
    /// This factor (1 keeps the file's resolution).
    Factor(usize),
}

impl std::str::FromStr for Upsample {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "auto" => Ok(Upsample::Auto),
            _ => match s.parse::<usize>() {
                Ok(k) if (1..=8).contains(&k) => Ok(Upsample::Factor(k)),
                _ => Err(format!("'{s}' is not auto or a factor from 1 to 8")),
            },
        }
    }
}

impl Upsample {
    /// The factor for a grid whose active box is `dims` voxels.
    pub fn factor(self, dims: [usize; 3]) -> usize {
        match self {
            Upsample::Factor(k) => k.max(1),
            Upsample::Auto => {
                let largest = dims.iter().copied().max().unwrap_or(0);
                if largest == 0 || largest >= AUTO_BELOW {
                    1
                } else {
                    AUTO_TARGET.div_ceil(largest).min(AUTO_MAX)
                }
            }
        }
    }
}

/// The transform of a grid `k` times finer over the same world-space box:
/// fine voxel `i'` has its centre at coarse index `(i' + 0.5) / k − 0.5`, so
/// coarse voxel `o` is split into fine voxels `k·o .. k·o + k − 1`.
pub fn refine_transform(t: &Transform, k: usize) -> Transform {
    let kf = k as f64;
    let mut out = t.clone();
    let shift = 0.5 / kf - 0.5;
    for r in 0..3 {
        let m = t.index_to_world[r];
        out.index_to_world[r] = [m[0] / kf, m[1] / kf, m[2] / kf, m[3] + shift * (m[0] + m[1] + m[2])];
    }
    out.voxel_size = t.voxel_size.map(|v| v / kf);
    out
}

/// The index of the fine voxel where coarse voxel `origin` begins.
pub fn refine_origin(origin: [i32; 3], k: usize) -> Result<[i32; 3]> {
    let mut out = [0; 3];
    for a in 0..3 {
        out[a] = match i32::try_from(k).ok().and_then(|k| origin[a].checked_mul(k)) {
            Some(v) => v,
            None => bail!("the grid's index {origin:?} is too far out to refine {k} times"),
        };
    }
    Ok(out)
}

/// `g` trilinearly resampled to `k` times its size along every axis.
pub fn refine_density(g: &Grid3, k: usize) -> Grid3 {
    if k == 1 {
        return g.clone();
    }
    let dims = g.dims.map(|n| n * k);
    let mut out = resize_grid(g, dims);
    // Trilinear weights are non-negative, so only rounding can go below 0.
    out.data.iter_mut().for_each(|v| *v = v.max(0.0));
    out
}

/// A simulation seen `k` times finer: densities resampled, velocities
/// resampled and scaled by `k` (they are in voxels per frame).
pub struct Refined<S> {
    /// The simulation at the file's resolution.
    pub inner: S,
    /// The refinement factor.
    pub k: usize,
}

impl<S: Simulation> Simulation for Refined<S> {
    fn len(&self) -> usize {
        self.inner.len()
    }
    fn dims(&self) -> [usize; 3] {
        self.inner.dims().map(|n| n * self.k)
    }
    fn density(&self, t: usize) -> Result<Grid3, SequenceError> {
        Ok(refine_density(&self.inner.density(t)?, self.k))
    }
    fn velocity(&self, t: usize) -> Result<Option<Vec<[f32; 3]>>, SequenceError> {
        let Some(u) = self.inner.velocity(t)? else { return Ok(None) };
        if self.k == 1 {
            return Ok(Some(u));
        }
        let (dims, fine) = (self.inner.dims(), self.dims());
        let kf = self.k as f32;
        let comps: Vec<Grid3> =
            (0..3).map(|a| resize_grid(&Grid3::from_vec(dims, u.iter().map(|v| v[a] * kf).collect()), fine)).collect();
        Ok(Some((0..comps[0].len()).map(|i| [comps[0].data[i], comps[1].data[i], comps[2].data[i]]).collect()))
    }
    fn linked(&self, t: usize) -> bool {
        self.inner.linked(t)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn world(t: &Transform, p: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|r| {
            let m = t.index_to_world[r];
            m[0] * p[0] + m[1] * p[1] + m[2] * p[2] + m[3]
        })
    }

    #[test]
    fn refined_voxels_tile_the_coarse_voxel_in_world_space() {
        let mut t = Transform::scale_translate([0.1, 0.2, 0.3], [1.0, -2.0, 0.5]);
        // A rotation part too: the refinement must not assume a diagonal map.
        t.index_to_world[0][1] = 0.05;
        for k in [2usize, 3] {
            let f = refine_transform(&t, k);
            let o = refine_origin([4, -3, 7], k).unwrap();
            // The mean of the fine centres inside coarse voxel (4, -3, 7) is its centre.
            let mut mean = [0.0; 3];
            for dz in 0..k {
                for dy in 0..k {
                    for dx in 0..k {
                        let p = world(&f, [o[0] + dx as i32, o[1] + dy as i32, o[2] + dz as i32].map(f64::from));
                        (0..3).for_each(|a| mean[a] += p[a] / (k * k * k) as f64);
                    }
                }
            }
            let c = world(&t, [4.0, -3.0, 7.0]);
            for a in 0..3 {
                assert!((mean[a] - c[a]).abs() < 1e-9, "k {k}: {mean:?} vs {c:?}");
            }
            assert!((f.voxel_size[1] - 0.2 / k as f64).abs() < 1e-12);
        }
    }

    #[test]
    fn auto_refines_only_small_grids() {
        assert_eq!(Upsample::Auto.factor([18, 18, 20]), 4);
        assert_eq!(Upsample::Auto.factor([24, 20, 30]), 3);
        assert_eq!(Upsample::Auto.factor([32, 32, 41]), 1);
        assert_eq!(Upsample::Auto.factor([51, 49, 96]), 1);
        assert_eq!(Upsample::Auto.factor([0, 0, 0]), 1);
        assert_eq!(Upsample::Factor(2).factor([200, 200, 200]), 2);
        assert_eq!("3".parse::<Upsample>(), Ok(Upsample::Factor(3)));
        assert!("0".parse::<Upsample>().is_err() && "x".parse::<Upsample>().is_err());
    }

    #[test]
    fn refined_density_keeps_the_mass_per_world_volume() {
        let g = Grid3::from_vec([3, 2, 2], (0..12).map(|i| i as f32 / 11.0).collect());
        let f = refine_density(&g, 2);
        assert_eq!(f.dims, [6, 4, 4]);
        let mean = |g: &Grid3| g.data.iter().sum::<f32>() / g.data.len() as f32;
        assert!((mean(&f) - mean(&g)).abs() < 0.02, "{} vs {}", mean(&f), mean(&g));
    }
}
