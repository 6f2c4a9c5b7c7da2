//! One cylindrical 3D Gaussian per strand segment and its EWA projection
//! (paper eq. 6 and `Σ2D = J W Σ3D Wᵀ Jᵀ`), forward and backward side by side.
//!
//! For a segment from `a` to `b` with `d = b - a`, the Gaussian sits at the
//! midpoint `m = (a + b) / 2`, its long axis is the unit direction `e = d/|d|`
//! with standard deviation `s_x = length_sigma * |d|` and both cross-section
//! axes have `s_y = s_z = width`. Because the cross-section is round, the
//! rotation `R(q)` of eq. 6 only matters through `e`, and
//! `Σ3D = R diag(s_x², w², w²) Rᵀ = w² I + (s_x² - w²) e eᵀ
//!      = w² I + (length_sigma² - w² / |d|²) d dᵀ`,
//! which needs no quaternion and has a simple derivative in `d`.
//!
//! All of this runs in `f64` (it is per Gaussian, not per pixel, so the cost
//! is negligible) to keep the backward accurate for thin, elongated splats.

use crate::camera::SplatCamera;

/// Shape parameters shared by every Gaussian of a render.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ShapeParams {
    /// Cross-section standard deviation (world units).
    pub width: f64,
    /// Long-axis standard deviation as a fraction of the segment length.
    pub length_sigma: f64,
    /// Low-pass filter added to the 2D covariance diagonal (pixels²).
    pub dilation: f64,
}

/// Everything the backward needs from the forward projection of one segment.
#[derive(Clone, Copy, Debug)]
pub(crate) struct SegmentProjection {
    /// Camera-space midpoint (right, down, forward).
    t: [f64; 3],
    /// World-space segment vector `d = b - a`.
    d: [f64; 3],
    /// Camera-space segment vector `W d`.
    dc: [f64; 3],
    /// `length_sigma² - w² / |d|²`, the coefficient of `d dᵀ` in `Σ3D`.
    coef: f64,
    /// `|d|²`.
    dd: f64,
    /// Nonzero entries of the EWA Jacobian: `J00, J02, J11, J12`.
    j: [f64; 4],
    /// `g = J W d`.
    g: [f64; 2],
    /// 2D covariance `[xx, xy, yy]` including the dilation.
    pub cov: [f64; 3],
    /// Its inverse, the conic `[a, b, c]` with `q = a dx² + 2 b dx dy + c dy²`.
    pub conic: [f64; 3],
    /// Projected midpoint in pixels.
    pub mean: [f64; 2],
    /// Camera-space depth of the midpoint, used for ordering.
    pub depth: f64,
}

fn to64(p: [f32; 3]) -> [f64; 3] {
    p.map(f64::from)
}

fn rotate(cam: &SplatCamera, v: [f64; 3]) -> [f64; 3] {
    let dot = |a: [f32; 3]| a[0] as f64 * v[0] + a[1] as f64 * v[1] + a[2] as f64 * v[2];
    [dot(cam.right), dot(cam.down), dot(cam.forward)]
}

fn rotate_back(cam: &SplatCamera, v: [f64; 3]) -> [f64; 3] {
    let (r, d, f) = (cam.right, cam.down, cam.forward);
    std::array::from_fn(|i| r[i] as f64 * v[0] + d[i] as f64 * v[1] + f[i] as f64 * v[2])
}

/// `w² / |d|²`, taken as 0 for a degenerate (zero-length) segment: then
/// `d dᵀ = 0` and the splat is an isotropic blob of the cross-section size.
fn width_over_len2(width: f64, dd: f64) -> f64 {
    if dd > 1e-30 {
        width * width / dd
    } else {
        0.0
    }
}

/// Projects segment `a -> b`; `None` when its midpoint is nearer than the
/// camera's near plane or its 2D covariance is singular.
pub(crate) fn project_segment(
    a: [f32; 3],
    b: [f32; 3],
    cam: &SplatCamera,
    shape: &ShapeParams,
) -> Option<SegmentProjection> {
    let (a, b) = (to64(a), to64(b));
    let m: [f64; 3] = std::array::from_fn(|i| 0.5 * (a[i] + b[i]) - cam.eye[i] as f64);
    let d: [f64; 3] = std::array::from_fn(|i| b[i] - a[i]);
    let t = rotate(cam, m);
    if !(t[2] >= cam.near as f64) {
        return None;
    }
    let dc = rotate(cam, d);
    let dd = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
    let coef = shape.length_sigma * shape.length_sigma - width_over_len2(shape.width, dd);
    let (fx, fy) = (cam.fx as f64, cam.fy as f64);
    let iz = 1.0 / t[2];
    let j = [fx * iz, -fx * t[0] * iz * iz, fy * iz, -fy * t[1] * iz * iz];
    // W Σ3D Wᵀ = w² I + coef (W d)(W d)ᵀ since W is a rotation, so
    // Σ2D = w² J Jᵀ + coef g gᵀ with g = J W d.
    let g = [j[0] * dc[0] + j[1] * dc[2], j[2] * dc[1] + j[3] * dc[2]];
    let w2 = shape.width * shape.width;
    let jjt = [j[0] * j[0] + j[1] * j[1], j[1] * j[3], j[2] * j[2] + j[3] * j[3]];
    let cov = [
        w2 * jjt[0] + coef * g[0] * g[0] + shape.dilation,
        w2 * jjt[1] + coef * g[0] * g[1],
        w2 * jjt[2] + coef * g[1] * g[1] + shape.dilation,
    ];
    let det = cov[0] * cov[2] - cov[1] * cov[1];
    if !(det > 1e-12 && cov[0] > 0.0) {
        return None;
    }
    let conic = [cov[2] / det, -cov[1] / det, cov[0] / det];
    let mean = [fx * t[0] * iz + cam.cx as f64, fy * t[1] * iz + cam.cy as f64];
    Some(SegmentProjection { t, d, dc, coef, dd, j, g, cov, conic, mean, depth: t[2] })
}

/// Backward of [`project_segment`]: from the gradients of the loss w.r.t. the
/// projected mean and the conic `[a, b, c]` (with `b` the single off-diagonal
/// parameter, appearing twice in the quadratic form) to the gradients w.r.t.
/// the segment's end points `a` and `b`.
pub(crate) fn project_segment_backward(
    p: &SegmentProjection,
    cam: &SplatCamera,
    shape: &ShapeParams,
    d_mean: [f64; 2],
    d_conic: [f64; 3],
) -> ([f64; 3], [f64; 3]) {
    let (fx, fy) = (cam.fx as f64, cam.fy as f64);
    let [ca, cb, cc] = p.conic;
    // dL/dA as a full symmetric matrix (b sits in two entries), then
    // dL/dΣ = -A (dL/dA) A.
    let ga = [d_conic[0], 0.5 * d_conic[1], d_conic[2]];
    // M = (dL/dA) A
    let m00 = ga[0] * ca + ga[1] * cb;
    let m01 = ga[0] * cb + ga[1] * cc;
    let m10 = ga[1] * ca + ga[2] * cb;
    let m11 = ga[1] * cb + ga[2] * cc;
    let gs = [-(ca * m00 + cb * m10), -(ca * m01 + cb * m11), -(cb * m01 + cc * m11)];
    // Σ2D = w² J Jᵀ + coef g gᵀ: gradients for J (through both terms), g, coef.
    let gg = [gs[0] * p.g[0] + gs[1] * p.g[1], gs[1] * p.g[0] + gs[2] * p.g[1]];
    let d_coef = p.g[0] * gg[0] + p.g[1] * gg[1];
    let d_g = [2.0 * p.coef * gg[0], 2.0 * p.coef * gg[1]];
    let w2 = shape.width * shape.width;
    let [j00, j02, j11, j12] = p.j;
    // dL/dJ = 2 w² G J + (dL/dg)(W d)ᵀ, only at J's nonzero entries.
    let d_j00 = 2.0 * w2 * gs[0] * j00 + d_g[0] * p.dc[0];
    let d_j02 = 2.0 * w2 * (gs[0] * j02 + gs[1] * j12) + d_g[0] * p.dc[2];
    let d_j11 = 2.0 * w2 * gs[2] * j11 + d_g[1] * p.dc[1];
    let d_j12 = 2.0 * w2 * (gs[1] * j02 + gs[2] * j12) + d_g[1] * p.dc[2];
    // g = J (W d)
    let d_dc = [d_g[0] * j00, d_g[1] * j11, d_g[0] * j02 + d_g[1] * j12];
    // J and the projected mean depend on the camera-space midpoint t.
    let [tx, ty, tz] = p.t;
    let iz = 1.0 / tz;
    let iz2 = iz * iz;
    let mut d_t = [-d_j02 * fx * iz2 + d_mean[0] * fx * iz, -d_j12 * fy * iz2 + d_mean[1] * fy * iz, 0.0];
    d_t[2] = -d_j00 * fx * iz2 + d_j02 * 2.0 * fx * tx * iz2 * iz - d_j11 * fy * iz2 + d_j12 * 2.0 * fy * ty * iz2 * iz
        - d_mean[0] * fx * tx * iz2
        - d_mean[1] * fy * ty * iz2;
    let d_m = rotate_back(cam, d_t);
    let mut d_d = rotate_back(cam, d_dc);
    // coef = length_sigma² - w² / |d|², |d|² is rotation invariant.
    if p.dd > 1e-30 {
        let k = d_coef * 2.0 * w2 / (p.dd * p.dd);
        for i in 0..3 {
            d_d[i] += k * p.d[i];
        }
    }
    let da = std::array::from_fn(|i| 0.5 * d_m[i] - d_d[i]);
    let db = std::array::from_fn(|i| 0.5 * d_m[i] + d_d[i]);
    (da, db)
}
