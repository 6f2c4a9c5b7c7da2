//! Cameras and the camera-aligned sample lattice they induce (paper Sec. 5.1,
//! "Perspective Camera").
//!
//! A camera turns into a `W x H x D` lattice of sample positions in the grid's
//! index space: column `c` runs to the camera's right, row `r = 0` is the top
//! of the picture, depth slice `k = 0` is nearest the eye. The transmittance
//! march then runs over the lattice exactly as over an axis-aligned grid.
//!
//! Pattern scale must not depend on zoom, so the lattice is sized from the
//! grid rather than from an output resolution: the window is the projected
//! bounding box of the grid, and `W`, `H` are how many voxels wide and high it
//! is at the bounding plane nearest the camera (one pixel ≈ one voxel there);
//! `D` is the voxel count along the view.

use crate::RenderError;
use nst3d_core::math::{cross, dot, sub, try_unit};

/// How the camera projects the volume onto the image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Projection {
    /// Parallel rays: the lattice is a box fitted around the grid.
    Orthographic,
    /// Rays through the eye: the lattice is the truncated pyramid between the
    /// near and far bounding planes of the grid.
    Perspective,
}

nst3d_core::named_enum!(Projection, "a camera projection", { Orthographic => "orthographic", Perspective => "perspective" });

/// A camera in the grid's index space (voxel units, voxel centres at integer
/// coordinates); the caller maps world space to index space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Orthographic or perspective.
    pub projection: Projection,
    /// Eye position.
    pub eye: [f32; 3],
    /// Point looked at; the view direction is `target - eye`.
    pub target: [f32; 3],
    /// Approximate up direction; must not be parallel to the view direction.
    pub up: [f32; 3],
    /// Vertical field of view in degrees (perspective only): parts of the
    /// grid outside it are not rendered.
    pub fov_y_deg: f32,
    /// Film width / height (perspective only), giving the horizontal field of view.
    pub aspect: f32,
}

/// Vertical field of view of the helper cameras.
const DEFAULT_FOV_Y_DEG: f32 = 30.0;

impl Camera {
    /// Default view: orthographic, looking along −z from the +z side with +y
    /// up, so image columns follow +x and row 0 is the highest y. The eye is
    /// far enough that the whole grid fits a perspective view too (see
    /// [`Camera::with_projection`]).
    pub fn front(dims: [usize; 3]) -> Self {
        Self::orbit(dims, 0.0, 0.0)
    }

    /// The [`Camera::front`] view rotated around the grid centre: `azimuth_deg`
    /// about +y (positive moves the eye towards +x), then `elevation_deg` up
    /// towards +y. Gives the camera set Θ of eq. 1; elevation ±90 is
    /// degenerate with the +y up vector.
    pub fn orbit(dims: [usize; 3], azimuth_deg: f32, elevation_deg: f32) -> Self {
        let centre = dims.map(|n| (n as f32 - 1.0) * 0.5);
        let [nx, ny, nz] = dims.map(|n| n.max(1) as f32);
        let aspect = nx / ny;
        let half_fov = (DEFAULT_FOV_Y_DEG.to_radians() * 0.5).tan();
        // Far enough that the bounding sphere fits the vertical field of view.
        let radius = 0.5 * (nx * nx + ny * ny + nz * nz).sqrt();
        let dist = radius / half_fov.min(half_fov * aspect) + radius;
        let (az, el) = (azimuth_deg.to_radians(), elevation_deg.to_radians());
        let dir = [az.sin() * el.cos(), el.sin(), az.cos() * el.cos()];
        Self {
            projection: Projection::Orthographic,
            eye: std::array::from_fn(|a| centre[a] + dist * dir[a]),
            target: centre,
            up: [0.0, 1.0, 0.0],
            fov_y_deg: DEFAULT_FOV_Y_DEG,
            aspect,
        }
    }

    /// The same camera with another projection.
    pub fn with_projection(self, projection: Projection) -> Self {
        Self { projection, ..self }
    }

    /// The sample lattice this camera induces on a grid of `dims`.
    pub fn view(&self, dims: [usize; 3]) -> Result<View, RenderError> {
        View::build(self, dims, true)
    }
}

/// Affine index map `base + i·s0 + j·s1 + k·s2` between two dense layouts.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Affine {
    pub base: isize,
    pub strides: [isize; 3],
}

/// A lattice that is a general resampling of the grid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Frustum {
    pub eye: [f32; 3],
    pub forward: [f32; 3],
    pub right: [f32; 3],
    pub up: [f32; 3],
    /// Window: `u = u0 + (c + 0.5) du` to the right, `v = v0 − (r + 0.5) dv`
    /// up (so row 0 is the top); tangents for perspective, voxels for ortho.
    pub u0: f32,
    pub du: f32,
    pub v0: f32,
    pub dv: f32,
    /// Depth of slice `k` along `forward`: `t0 + (k + 0.5) dt`.
    pub t0: f32,
    pub dt: f32,
    pub perspective: bool,
}

impl Frustum {
    /// Start and step (per column) of the positions of lattice row `r`, slice `k`.
    #[inline]
    pub fn row(&self, r: usize, k: usize) -> ([f32; 3], [f32; 3]) {
        let t = self.t0 + (k as f32 + 0.5) * self.dt;
        let scale = if self.perspective { t } else { 1.0 };
        let u = self.u0 + 0.5 * self.du;
        let v = self.v0 - (r as f32 + 0.5) * self.dv;
        let start =
            std::array::from_fn(|a| self.eye[a] + t * self.forward[a] + scale * (u * self.right[a] + v * self.up[a]));
        let step = std::array::from_fn(|a| scale * self.du * self.right[a]);
        (start, step)
    }
}

/// How lattice samples relate to grid voxels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Sampling {
    /// Axis-aligned orthographic view: every lattice sample is a voxel centre,
    /// so the lattice is a permutation (axis swaps and flips) of the grid.
    Axis {
        /// Grid index of lattice voxel `(c, r, k)`.
        lattice_to_grid: Affine,
        /// Lattice index of grid voxel `(x, y, z)`.
        grid_to_lattice: Affine,
    },
    /// Anything else: trilinear resampling at the frustum's positions.
    Resample(Frustum),
}

/// The camera-aligned sample lattice of one camera on one grid size.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct View {
    /// Lattice size `[W, H, D]`: image width, image height, depth slices.
    pub dims: [usize; 3],
    /// Size of the grid the view was made for.
    pub grid_dims: [usize; 3],
    pub(crate) sampling: Sampling,
}

/// Upper bound on lattice voxels, against absurd cameras exhausting memory.
const MAX_LATTICE: usize = 1 << 30;

/// Below this depth a bounding-box corner counts as at or behind the eye.
const MIN_DEPTH: f32 = 1e-3;

/// Below this length an eye-to-target or right vector counts as no direction.
const MIN_AXIS_NORM: f32 = 1e-6;

/// The grid axis and sign of a unit vector that is (numerically) a coordinate axis.
fn as_axis(v: [f32; 3]) -> Option<(usize, isize)> {
    (0..3).find(|&a| v[a].abs() > 1.0 - 1e-6).map(|a| (a, if v[a] > 0.0 { 1 } else { -1 }))
}

/// Number of lattice cells covering `extent` voxels at about one voxel each.
fn cells(extent: f32) -> usize {
    (extent.round() as usize).max(1)
}

/// Min and max of `f` over the box corners in camera coordinates.
fn span(coords: &[[f32; 3]], f: &dyn Fn(&[f32; 3]) -> f32) -> (f32, f32) {
    coords.iter().map(f).fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)))
}

/// The window of the view (`(u_lo, u_hi, v_lo, v_hi)`: in voxels for
/// orthographic cameras, tangents for perspective ones), the lattice size
/// and whether it is perspective, for the box corners `coords` in camera
/// coordinates at depths `t_near..t_far`.
#[allow(clippy::type_complexity)]
fn window(
    cam: &Camera,
    coords: &[[f32; 3]],
    (t_near, t_far): (f32, f32),
) -> Result<((f32, f32, f32, f32), [usize; 3], bool), RenderError> {
    Ok(match cam.projection {
        Projection::Orthographic => {
            let (u_lo, u_hi) = span(coords, &|c| c[0]);
            let (v_lo, v_hi) = span(coords, &|c| c[1]);
            let lattice = [cells(u_hi - u_lo), cells(v_hi - v_lo), cells(t_far - t_near)];
            ((u_lo, u_hi, v_lo, v_hi), lattice, false)
        }
        Projection::Perspective => {
            if !(cam.fov_y_deg > 0.0 && cam.fov_y_deg < 180.0) {
                return Err(RenderError::BadFov(cam.fov_y_deg));
            }
            if !(cam.aspect > 0.0 && cam.aspect.is_finite()) {
                return Err(RenderError::BadAspect(cam.aspect));
            }
            if t_near < MIN_DEPTH {
                return Err(RenderError::EyeInsideBounds);
            }
            let tan_y = (cam.fov_y_deg.to_radians() * 0.5).tan();
            let tan_x = tan_y * cam.aspect;
            // Projected bounding box in tangent space, clipped to the field of view.
            let (u_lo, u_hi) = span(coords, &|c| c[0] / c[2]);
            let (v_lo, v_hi) = span(coords, &|c| c[1] / c[2]);
            let (u_lo, u_hi) = (u_lo.max(-tan_x), u_hi.min(tan_x));
            let (v_lo, v_hi) = (v_lo.max(-tan_y), v_hi.min(tan_y));
            if u_lo >= u_hi || v_lo >= v_hi {
                return Err(RenderError::OutOfView);
            }
            // At the nearest bounding plane a tangent span `s` is `s · t_near` voxels.
            let lattice = [cells((u_hi - u_lo) * t_near), cells((v_hi - v_lo) * t_near), cells(t_far - t_near)];
            ((u_lo, u_hi, v_lo, v_hi), lattice, true)
        }
    })
}

impl View {
    /// Builds the lattice; `allow_axis` permits the permutation shortcut for
    /// axis-aligned orthographic views (tests turn it off to compare).
    pub(crate) fn build(cam: &Camera, dims: [usize; 3], allow_axis: bool) -> Result<Self, RenderError> {
        if dims.contains(&0) {
            return Err(RenderError::EmptyGrid);
        }
        let finite = |v: [f32; 3]| v.iter().all(|x| x.is_finite());
        if !finite(cam.eye) || !finite(cam.target) || !finite(cam.up) {
            return Err(RenderError::NonFiniteCamera);
        }
        let forward = try_unit(sub(cam.target, cam.eye), MIN_AXIS_NORM).ok_or(RenderError::EyeAtTarget)?;
        let right = try_unit(cross(forward, cam.up), MIN_AXIS_NORM).ok_or(RenderError::DegenerateUp)?;
        let up = cross(right, forward);

        // Bounding box of the voxel cells (centres at integers, so faces at -0.5 and n - 0.5).
        let corners: Vec<[f32; 3]> = (0..8)
            .map(|i| std::array::from_fn(|a| if i >> a & 1 == 1 { dims[a] as f32 - 0.5 } else { -0.5 }))
            .collect();
        let cam_coords: Vec<[f32; 3]> = corners
            .iter()
            .map(|&q| {
                let p = sub(q, cam.eye);
                [dot(p, right), dot(p, up), dot(p, forward)]
            })
            .collect();
        let (t_near, t_far) = span(&cam_coords, &|c| c[2]);
        let window = window(cam, &cam_coords, (t_near, t_far))?;
        let ((u_lo, u_hi, v_lo, v_hi), lattice, perspective) = window;
        let frustum = Frustum {
            eye: cam.eye,
            forward,
            right,
            up,
            u0: u_lo,
            du: (u_hi - u_lo) / lattice[0] as f32,
            v0: v_hi,
            dv: (v_hi - v_lo) / lattice[1] as f32,
            t0: t_near,
            dt: (t_far - t_near) / lattice[2] as f32,
            perspective,
        };
        if lattice.iter().try_fold(1usize, |acc, &n| acc.checked_mul(n)).is_none_or(|n| n > MAX_LATTICE) {
            return Err(RenderError::LatticeTooLarge(lattice));
        }

        let axes = match cam.projection {
            Projection::Orthographic if allow_axis => {
                match (as_axis(right), as_axis(up.map(|x| -x)), as_axis(forward)) {
                    (Some(c), Some(r), Some(k)) => Some([c, r, k]),
                    _ => None,
                }
            }
            _ => None,
        };
        let sampling = match axes {
            Some(axes) => {
                // The fitted box spans exactly the voxel cells, so the lattice is the grid permuted.
                debug_assert_eq!(lattice, axes.map(|(a, _)| dims[a]));
                Sampling::Axis {
                    lattice_to_grid: Self::lattice_to_grid(dims, axes),
                    grid_to_lattice: Self::grid_to_lattice(dims, axes),
                }
            }
            None => Sampling::Resample(frustum),
        };
        Ok(Self { dims: lattice, grid_dims: dims, sampling })
    }

    /// Lattice axis `l` walks grid axis `axes[l].0` in direction `axes[l].1`,
    /// starting from the grid's far end when that direction is negative.
    fn lattice_to_grid(dims: [usize; 3], axes: [(usize, isize); 3]) -> Affine {
        let gs = [1, dims[0] as isize, (dims[0] * dims[1]) as isize];
        let mut m = Affine { base: 0, strides: [0; 3] };
        for (l, &(a, sign)) in axes.iter().enumerate() {
            if sign < 0 {
                m.base += (dims[a] as isize - 1) * gs[a];
            }
            m.strides[l] = sign * gs[a];
        }
        m
    }

    /// Inverse of [`View::lattice_to_grid`].
    fn grid_to_lattice(dims: [usize; 3], axes: [(usize, isize); 3]) -> Affine {
        let ld = axes.map(|(a, _)| dims[a] as isize);
        let ls = [1, ld[0], ld[0] * ld[1]];
        let mut m = Affine { base: 0, strides: [0; 3] };
        for (l, &(a, sign)) in axes.iter().enumerate() {
            if sign < 0 {
                m.base += (dims[a] as isize - 1) * ls[l];
            }
            m.strides[a] = sign * ls[l];
        }
        m
    }

    /// True when the view needs no resampling (axis-aligned orthographic).
    pub fn is_axis_aligned(&self) -> bool {
        matches!(self.sampling, Sampling::Axis { .. })
    }
}
