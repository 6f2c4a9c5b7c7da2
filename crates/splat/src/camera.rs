//! The pinhole camera the strands are splatted through (paper Sec. 3: views
//! are sampled on a spherical shell around the groom and look at its centroid).
//!
//! Conventions: the image plane spans `[0, width] x [0, height]` pixels, pixel
//! `(x, y)` has its centre at `(x + 0.5, y + 0.5)`, row 0 is the top of the
//! picture, and a camera-space point `t` (x right, y down, z along the view)
//! lands at `(fx * tx / tz + cx, fy * ty / tz + cy)` with square pixels and
//! the principal point at the image centre.

use crate::SplatError;
use nst3d_core::math::{cross, sub, try_unit};

/// Camera-space depths below this are behind (or too close to) the eye to
/// splat: EWA's local affine approximation of the projection breaks down there.
pub const DEFAULT_NEAR: f32 = 1e-2;

/// A pinhole camera: world-to-camera rotation, eye and intrinsics.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SplatCamera {
    /// Eye (centre of projection) in world space.
    pub eye: [f32; 3],
    /// Camera x axis in world space (image columns grow along it).
    pub right: [f32; 3],
    /// Camera y axis in world space (image rows grow along it).
    pub down: [f32; 3],
    /// Camera z axis in world space (the viewing direction).
    pub forward: [f32; 3],
    /// Focal length in pixels, horizontal.
    pub fx: f32,
    /// Focal length in pixels, vertical.
    pub fy: f32,
    /// Principal point, pixels from the left edge.
    pub cx: f32,
    /// Principal point, pixels from the top edge.
    pub cy: f32,
    /// Image width in pixels.
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
    /// Gaussians whose camera-space depth is below this are not drawn
    /// (defaults to [`DEFAULT_NEAR`]; world units).
    pub near: f32,
}

/// Below this length a view or right vector counts as no direction.
const MIN_AXIS_NORM: f32 = 1e-12;

impl SplatCamera {
    /// A camera at `eye` looking at `target`, rolled so that `up` points up in
    /// the picture, with vertical field of view `fov_y_deg` and a
    /// `width x height` image (horizontal field of view follows from the
    /// aspect ratio, pixels are square).
    pub fn look_at(
        eye: [f32; 3],
        target: [f32; 3],
        up: [f32; 3],
        fov_y_deg: f32,
        width: usize,
        height: usize,
    ) -> Result<Self, SplatError> {
        if eye.iter().chain(&target).chain(&up).any(|v| !v.is_finite()) {
            return Err(SplatError::NonFiniteCamera);
        }
        if !(fov_y_deg > 0.0 && fov_y_deg < 180.0) {
            return Err(SplatError::BadFov(fov_y_deg));
        }
        if width == 0 || height == 0 {
            return Err(SplatError::EmptyImage { width, height });
        }
        let forward = try_unit(sub(target, eye), MIN_AXIS_NORM).ok_or(SplatError::EyeAtTarget)?;
        let right = try_unit(cross(forward, up), MIN_AXIS_NORM).ok_or(SplatError::DegenerateUp)?;
        // Image rows grow downwards, so the camera y axis is "down", not "up".
        let down = cross(forward, right);
        let fy = 0.5 * height as f32 / (0.5 * fov_y_deg.to_radians()).tan();
        Ok(Self {
            eye,
            right,
            down,
            forward,
            fx: fy,
            fy,
            cx: 0.5 * width as f32,
            cy: 0.5 * height as f32,
            width,
            height,
            near: DEFAULT_NEAR,
        })
    }

    /// Camera-space coordinates `(right, down, forward)` of a world point.
    pub fn to_camera(&self, p: [f32; 3]) -> [f32; 3] {
        let d = sub(p, self.eye);
        let dot = |a: [f32; 3]| a[0] * d[0] + a[1] * d[1] + a[2] * d[2];
        [dot(self.right), dot(self.down), dot(self.forward)]
    }

    /// Pixel coordinates of a world point (meaningless behind the eye).
    pub fn project(&self, p: [f32; 3]) -> [f32; 2] {
        let t = self.to_camera(p);
        [self.fx * t[0] / t[2] + self.cx, self.fy * t[1] / t[2] + self.cy]
    }

    pub(crate) fn validate(&self) -> Result<(), SplatError> {
        let vals = self.eye.iter().chain(&self.right).chain(&self.down).chain(&self.forward);
        if vals.chain([&self.fx, &self.fy, &self.cx, &self.cy, &self.near]).any(|v| !v.is_finite()) {
            return Err(SplatError::NonFiniteCamera);
        }
        if self.width == 0 || self.height == 0 {
            return Err(SplatError::EmptyImage { width: self.width, height: self.height });
        }
        if !(self.fx > 0.0 && self.fy > 0.0 && self.near > 0.0) {
            return Err(SplatError::BadIntrinsics);
        }
        Ok(())
    }
}
