//! Training patches: a cube cut from the simulation, rotated about its
//! centre and possibly mirrored, so the network learns a stylization that
//! does not depend on the view (Sec. 5.1: θ ∈ [−180°, 180°] about x,
//! φ ∈ [−90°, 90°] about y).

use nst3d_core::{math::SplitMix64, Grid3};
use nst3d_transport::sample_trilinear_rows;

/// Where a training patch comes from: which frame, which corner, which
/// rotation. Drawing the numbers is apart from cutting the patch so that
/// every rank of a distributed run draws the whole batch's numbers from
/// the one shared stream (and so stays in step with it) but cuts only its
/// own patches.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PatchDraw {
    /// Index into the frames.
    pub frame: usize,
    /// The patch's corner in that frame.
    pub origin: [usize; 3],
    /// Its rotation and mirror.
    pub rotation: Rotation,
}

impl PatchDraw {
    /// A random frame, a random corner, a random rotation about x within
    /// ±`theta_deg` and about y within ±`phi_deg`, and a random mirror
    /// (Sec. 5.1), in that order from `rng`. Every frame is at least `p`
    /// voxels along each axis.
    pub fn draw(rng: &mut SplitMix64, frames: &[Grid3], p: usize, theta_deg: f32, phi_deg: f32) -> Self {
        let frame = (rng.next_u64() % frames.len() as u64) as usize;
        let d = &frames[frame];
        let origin: [usize; 3] = std::array::from_fn(|a| (rng.next_u64() % (d.dims[a] - p + 1) as u64) as usize);
        let rotation = Rotation {
            theta: (2.0 * rng.uniform_f32() - 1.0) * theta_deg.to_radians(),
            phi: (2.0 * rng.uniform_f32() - 1.0) * phi_deg.to_radians(),
            mirror: rng.uniform_f32() < 0.5,
        };
        Self { frame, origin, rotation }
    }

    /// The `p³` patch itself ([`rotated_patch`]).
    pub fn cut(&self, frames: &[Grid3], p: usize) -> Grid3 {
        rotated_patch(&frames[self.frame], self.origin, p, &self.rotation)
    }
}

/// A patch's orientation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rotation {
    /// Angle about x, radians.
    pub theta: f32,
    /// Angle about y, radians.
    pub phi: f32,
    /// Mirror x before rotating.
    pub mirror: bool,
}

impl Rotation {
    /// `R = Ry(φ) · Rx(θ) · diag(±1, 1, 1)`, acting on `[x, y, z]`.
    pub fn matrix(&self) -> [[f32; 3]; 3] {
        let (sx, cx) = self.theta.sin_cos();
        let (sy, cy) = self.phi.sin_cos();
        let rx = [[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]];
        let ry = [[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]];
        let mut r = [[0.0f32; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                r[i][j] = (0..3).map(|k| ry[i][k] * rx[k][j]).sum();
            }
        }
        if self.mirror {
            (0..3).for_each(|i| r[i][0] = -r[i][0]);
        }
        r
    }
}

/// The `p³` cube of `volume` whose voxel (0,0,0) is `origin`, resampled
/// trilinearly after rotating it about its centre by `rot`; samples that
/// fall outside the cube read 0. This is PyTorch's `affine_grid` +
/// `grid_sample(align_corners=False, padding_mode="zeros")` on the cropped
/// cube, as `shared/bench/torch_ff_ref.py` does.
///
/// # Panics
/// If the cube does not fit inside `volume`.
pub fn rotated_patch(volume: &Grid3, origin: [usize; 3], p: usize, rot: &Rotation) -> Grid3 {
    assert!((0..3).all(|a| origin[a] + p <= volume.dims[a]), "patch outside the volume");
    let mut cube = Grid3::zeros([p; 3]);
    for z in 0..p {
        for y in 0..p {
            let src = volume.index(origin[0], origin[1] + y, origin[2] + z);
            let dst = cube.index(0, y, z);
            cube.data[dst..dst + p].copy_from_slice(&volume.data[src..src + p]);
        }
    }
    let r = rot.matrix();
    let pf = p as f32;
    // Normalised coordinate of index i (align_corners = false) and back.
    let norm = |i: usize| (2.0 * i as f32 + 1.0) / pf - 1.0;
    let index = |g: f32| ((g + 1.0) * pf - 1.0) / 2.0;
    let data = sample_trilinear_rows(&cube, p * p * p, p, |row, pos| {
        let (y, z) = (norm(row % p), norm(row / p));
        for (x, out) in pos.iter_mut().enumerate() {
            let q = [norm(x), y, z];
            *out = std::array::from_fn(|a| index(r[a][0] * q[0] + r[a][1] * q[1] + r[a][2] * q[2]));
        }
    });
    Grid3::from_vec([p; 3], data)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identity_rotation_crops() {
        let v = Grid3::from_vec([4, 4, 4], (0..64).map(|i| i as f32).collect());
        let c = rotated_patch(&v, [1, 1, 1], 2, &Rotation { theta: 0.0, phi: 0.0, mirror: false });
        assert_eq!(c.data, vec![21.0, 22.0, 25.0, 26.0, 37.0, 38.0, 41.0, 42.0]);
        let m = rotated_patch(&v, [1, 1, 1], 2, &Rotation { theta: 0.0, phi: 0.0, mirror: true });
        assert_eq!(m.data, vec![22.0, 21.0, 26.0, 25.0, 38.0, 37.0, 42.0, 41.0]);
    }

    #[test]
    fn half_turn_about_x_flips_y_and_z() {
        let v = Grid3::from_vec([3, 3, 3], (0..27).map(|i| i as f32).collect());
        let c = rotated_patch(&v, [0, 0, 0], 3, &Rotation { theta: std::f32::consts::PI, phi: 0.0, mirror: false });
        for z in 0..3 {
            for y in 0..3 {
                for x in 0..3 {
                    let want = v.data[v.index(x, 2 - y, 2 - z)];
                    assert!((c.data[c.index(x, y, z)] - want).abs() < 1e-4);
                }
            }
        }
    }
}
