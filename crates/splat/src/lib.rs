//! Differentiable Gaussian-splat renderer for hair/fur strands (strand style
//! transfer paper, Sec. 3.2), on the CPU.
//!
//! Strands come in as polylines of 3D sample points, root first (the caller
//! samples the guide and proxy strands' natural cubic splines densely). Each
//! segment becomes one cylindrical 3D Gaussian (eq. 6), projected with EWA
//! splatting and composited front to back (eq. 7) in `16 x 16` tiles in
//! parallel. Root-to-tip shading and opacity mimic ambient occlusion and
//! translucency ("Rendering Heuristics"), and strands whose root faces away
//! from the camera are dropped ("Visibility").
//!
//! [`render`] returns the image and a [`SplatCache`]; [`render_backward`]
//! maps an image gradient back to every strand sample point. The depth order
//! and the visibility decision are held fixed in the backward (they are
//! piecewise constant); everything else — means, segment directions and
//! lengths in the 3D covariance, the EWA Jacobian — is differentiated.
//!
//! Two deliberate details of the compositing (see `raster.rs`): the Gaussian
//! footprint is truncated at 3σ and shifted down by its value there
//! (`α = min(0.99, o · (e^{−q/2} − e^{−4.5}) / (1 − e^{−4.5}))`), so it
//! fades to zero continuously instead of stepping by 1.1 % of the opacity;
//! and a pixel stops after the splat that takes its transmittance below 1e-4
//! (that splat still counts, so the dropped remainder is below 1e-4).
//!
//! Results are bitwise identical for any rayon thread count: tiles are
//! independent tasks and every cross-tile sum runs in a fixed order.

#![warn(missing_docs)]
// `!(x > 0.0)` is deliberate: it rejects NaN too, which `x <= 0.0` would let through.
#![allow(clippy::neg_cmp_op_on_partial_ord)]
// Channel and axis loops index several arrays in step; iterators would obscure that.
#![allow(clippy::needless_range_loop)]

mod camera;
mod gaussian;
mod raster;

pub use camera::{SplatCamera, DEFAULT_NEAR};

use gaussian::{project_segment, project_segment_backward, ShapeParams};
use nst3d_core::Image;
use raster::{bin, rasterize, rasterize_backward, Bins, RasterState, Splat2D, FEAT_GRAD};
use rayon::prelude::*;

/// Why a strand render could not be set up.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SplatError {
    /// Camera eye, target, up, axes or intrinsics contain NaN or infinity.
    #[error("camera parameters must be finite")]
    NonFiniteCamera,
    /// No view direction.
    #[error("camera eye and target coincide")]
    EyeAtTarget,
    /// The up vector is parallel to the view direction (or zero).
    #[error("camera up vector is parallel to the view direction")]
    DegenerateUp,
    /// Field of view outside (0, 180) degrees.
    #[error("field of view {0} deg is not in (0, 180)")]
    BadFov(f32),
    /// Focal lengths or near plane not positive.
    #[error("camera focal lengths and near plane must be positive")]
    BadIntrinsics,
    /// Zero-sized image.
    #[error("image size {width}x{height} is empty")]
    EmptyImage {
        /// Requested width.
        width: usize,
        /// Requested height.
        height: usize,
    },
    /// Strand offsets do not partition the point array.
    #[error("strand offsets must start at 0, never decrease and end at the point count {points}")]
    BadOffsets {
        /// Number of points given.
        points: usize,
    },
    /// A per-point or per-strand array has the wrong length.
    #[error("{what} has {got} entries, expected {expected}")]
    LengthMismatch {
        /// Which array.
        what: &'static str,
        /// Its length.
        got: usize,
        /// The length it should have.
        expected: usize,
    },
    /// A sample point is NaN or infinite.
    #[error("strand point {0} is not finite")]
    NonFinitePoint(usize),
    /// A root normal is zero or not finite.
    #[error("root normal of strand {0} is zero or not finite")]
    BadRootNormal(usize),
    /// A style parameter is out of range.
    #[error("strand style: {0}")]
    BadStyle(&'static str),
    /// The cache passed to the backward was made for other inputs.
    #[error("splat cache was made for a different camera, style or strand layout")]
    CacheMismatch,
    /// The image gradient's shape differs from the render's.
    #[error("image gradient is {got:?} (channels, height, width), the render is {expected:?}")]
    GradShape {
        /// Shape of the gradient passed in.
        got: [usize; 3],
        /// Shape of the render.
        expected: [usize; 3],
    },
}

/// Strand geometry to render: strand `i` is `points[offsets[i]..offsets[i + 1]]`,
/// root first. Strands with fewer than two points draw nothing.
#[derive(Clone, Copy, Debug)]
pub struct Strands<'a> {
    /// Sample points of all strands, concatenated.
    pub points: &'a [[f32; 3]],
    /// `n_strands + 1` increasing offsets into `points`, from 0 to `points.len()`.
    pub offsets: &'a [usize],
    /// Optional per-point base colour (a segment uses the mean of its two
    /// end points); white when absent. Repeat a value along a strand for a
    /// per-strand colour.
    pub colors: Option<&'a [[f32; 3]]>,
    /// Optional per-strand normal of the mesh at the root, for visibility
    /// culling; `None` renders every strand.
    pub root_normals: Option<&'a [[f32; 3]]>,
}

impl Strands<'_> {
    /// Number of strands.
    pub fn len(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// True when there are no strands.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn validate(&self) -> Result<(), SplatError> {
        let n = self.points.len();
        let ok = self.offsets.first() == Some(&0)
            && self.offsets.last() == Some(&n)
            && self.offsets.windows(2).all(|w| w[0] <= w[1]);
        if !ok {
            return Err(SplatError::BadOffsets { points: n });
        }
        if let Some(c) = self.colors {
            if c.len() != n {
                return Err(SplatError::LengthMismatch { what: "colors", got: c.len(), expected: n });
            }
        }
        if let Some(nrm) = self.root_normals {
            if nrm.len() != self.len() {
                let (got, expected) = (nrm.len(), self.len());
                return Err(SplatError::LengthMismatch { what: "root_normals", got, expected });
            }
            if let Some(i) = nrm.iter().position(|v| !v.iter().all(|c| c.is_finite()) || v.iter().all(|&c| c == 0.0)) {
                return Err(SplatError::BadRootNormal(i));
            }
        }
        if let Some(i) = self.points.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
            return Err(SplatError::NonFinitePoint(i));
        }
        Ok(())
    }
}

/// What the render's channels hold.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SplatOutput {
    /// Three channels: shaded colour composited over the background.
    Rgb,
    /// Two channels: Rec. 709 luminance of the shaded colour composited over
    /// the background's luminance, and coverage `1 − T_N`.
    GreyAlpha,
}

impl SplatOutput {
    /// Number of image channels.
    pub fn channels(self) -> usize {
        match self {
            SplatOutput::Rgb => 3,
            SplatOutput::GreyAlpha => 2,
        }
    }
}

/// Look of the strands. Shade and opacity vary linearly from root to tip
/// with the segment index (`u = (k + ½) / n_segments` for segment `k`), which
/// does not depend on the geometry, so they carry no gradient.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StrandStyle {
    /// Cross-section standard deviation `s_y = s_z` of every splat (world units).
    pub width: f32,
    /// Long-axis standard deviation `s_x` as a fraction of the segment length:
    /// 0.5 puts consecutive splats one σ from their shared end point, so
    /// they overlap into a continuous strand.
    pub length_sigma: f32,
    /// Colour multiplier at the root (darker: little light reaches it).
    pub root_shade: f32,
    /// Colour multiplier at the tip.
    pub tip_shade: f32,
    /// Splat opacity `o` at the root (opaque).
    pub root_opacity: f32,
    /// Splat opacity at the tip (translucent).
    pub tip_opacity: f32,
    /// Colour where no strand covers the pixel.
    pub background: [f32; 3],
    /// Visibility threshold ε: a strand is culled when its root normal ·
    /// unit direction from the root to the eye is below this. Slightly
    /// negative values keep long strands growing from the silhouette.
    pub visibility_threshold: f32,
    /// Low-pass filter added to the 2D covariance diagonal, in pixels², as in
    /// 3DGS (0.3): keeps sub-pixel-wide strands at least about a pixel wide
    /// on screen, so they neither alias nor vanish between pixel centres.
    pub dilation: f32,
    /// Channel layout of the result.
    pub output: SplatOutput,
}

impl Default for StrandStyle {
    /// A groom about one unit across: 0.003-wide strands, dark opaque roots,
    /// bright translucent tips, black background, ε = 0, RGB.
    fn default() -> Self {
        Self {
            width: 0.003,
            length_sigma: 0.5,
            root_shade: 0.3,
            tip_shade: 1.0,
            root_opacity: 1.0,
            tip_opacity: 0.3,
            background: [0.0; 3],
            visibility_threshold: 0.0,
            dilation: 0.3,
            output: SplatOutput::Rgb,
        }
    }
}

impl StrandStyle {
    fn validate(&self) -> Result<(), SplatError> {
        let finite = [self.width, self.length_sigma, self.root_shade, self.tip_shade]
            .iter()
            .chain(&self.background)
            .chain(&[self.visibility_threshold, self.dilation])
            .all(|v| v.is_finite());
        if !finite {
            return Err(SplatError::BadStyle("parameters must be finite"));
        }
        if !(self.width > 0.0) {
            return Err(SplatError::BadStyle("width must be positive"));
        }
        if !(self.length_sigma > 0.0) {
            return Err(SplatError::BadStyle("length_sigma must be positive"));
        }
        let unit = |o: f32| (0.0..=1.0).contains(&o);
        if !unit(self.root_opacity) || !unit(self.tip_opacity) {
            return Err(SplatError::BadStyle("opacities must be in [0, 1]"));
        }
        if !(self.dilation >= 0.0) {
            return Err(SplatError::BadStyle("dilation must not be negative"));
        }
        Ok(())
    }

    fn shape(&self) -> ShapeParams {
        ShapeParams { width: self.width as f64, length_sigma: self.length_sigma as f64, dilation: self.dilation as f64 }
    }
}

/// What [`render`] keeps for [`render_backward`]: the projected splats, their
/// tile lists and the per-pixel compositing state.
#[derive(Clone, Debug)]
pub struct SplatCache {
    splats: Vec<Splat2D>,
    /// Index of each splat's root-side point (the other end is the next point).
    seg_point: Vec<u32>,
    /// Each splat's position along its strand, `u` of the shade ramp.
    seg_u: Vec<f32>,
    bins: Bins,
    state: RasterState,
    camera: SplatCamera,
    style: StrandStyle,
    n_points: usize,
    n_strands: usize,
    visible_strands: usize,
}

impl SplatCache {
    /// Number of splats drawn (segments of visible strands in front of the
    /// near plane whose 3σ ellipse touches the image).
    pub fn splat_count(&self) -> usize {
        self.splats.len()
    }

    /// Number of strands that passed visibility culling.
    pub fn visible_strands(&self) -> usize {
        self.visible_strands
    }
}

/// Whether strand `i` survives visibility culling: its root normal · the
/// unit direction from the root to `eye` is at least `eps` (always, without
/// normals).
pub fn strand_visible(strands: &Strands, i: usize, eye: [f32; 3], eps: f32) -> bool {
    let Some(normals) = strands.root_normals else { return true };
    let root = strands.points[strands.offsets[i]];
    let n = normals[i];
    let v = [eye[0] - root[0], eye[1] - root[1], eye[2] - root[2]];
    let (nn, vv) = (n.iter().map(|c| c * c).sum::<f32>().sqrt(), v.iter().map(|c| c * c).sum::<f32>().sqrt());
    if vv == 0.0 {
        return true;
    }
    (n[0] * v[0] + n[1] * v[1] + n[2] * v[2]) / (nn * vv) >= eps
}

/// Rec. 709 luma weights of [`SplatOutput::GreyAlpha`].
const LUMA_709: [f32; 3] = [0.2126, 0.7152, 0.0722];

/// `d`'s bits mapped to a `u32` whose unsigned order is `f32::total_cmp`'s:
/// negative values reversed below the positive ones.
fn total_order_key(d: f32) -> u32 {
    let bits = d.to_bits();
    if bits >> 31 == 1 {
        !bits
    } else {
        bits | 0x8000_0000
    }
}

fn luminance(c: [f32; 3]) -> f32 {
    LUMA_709[0] * c[0] + LUMA_709[1] * c[1] + LUMA_709[2] * c[2]
}

fn lerp(a: f32, b: f32, u: f32) -> f32 {
    a + (b - a) * u
}

/// Renders the strands: returns the `C x H x W` image (`C` from
/// `style.output`) and the cache the backward needs.
pub fn render(strands: &Strands, cam: &SplatCamera, style: &StrandStyle) -> Result<(Image, SplatCache), SplatError> {
    strands.validate()?;
    cam.validate()?;
    style.validate()?;
    let shape = style.shape();
    let (width, height) = (cam.width, cam.height);
    // Segments of visible strands: (root-side point index, position along strand).
    let mut segments: Vec<(u32, f32)> = Vec::new();
    let mut visible_strands = 0;
    for i in 0..strands.len() {
        if !strand_visible(strands, i, cam.eye, style.visibility_threshold) {
            continue;
        }
        visible_strands += 1;
        let (lo, hi) = (strands.offsets[i], strands.offsets[i + 1]);
        if hi - lo < 2 {
            continue;
        }
        let nseg = (hi - lo - 1) as f32;
        segments.extend((lo..hi - 1).map(|p| (p as u32, ((p - lo) as f32 + 0.5) / nseg)));
    }
    let projected: Vec<Option<(Splat2D, f32)>> = segments
        .par_iter()
        .map(|&(p, u)| {
            let (a, b) = (strands.points[p as usize], strands.points[p as usize + 1]);
            let sp = project_segment(a, b, cam, &shape)?;
            let rx = 3.0 * sp.cov[0].sqrt() * (1.0 + 1e-6);
            let ry = 3.0 * sp.cov[2].sqrt() * (1.0 + 1e-6);
            let span = |c: f64, r: f64, n: usize| {
                let lo = (c - r - 0.5).ceil().max(0.0);
                let hi = (c + r - 0.5).floor().min(n as f64 - 1.0);
                (lo <= hi).then_some((lo as u32, hi as u32))
            };
            let (x0, x1) = span(sp.mean[0], rx, width)?;
            let (y0, y1) = span(sp.mean[1], ry, height)?;
            let base = match strands.colors {
                Some(c) => {
                    let (ca, cb) = (c[p as usize], c[p as usize + 1]);
                    std::array::from_fn(|k| 0.5 * (ca[k] + cb[k]))
                }
                None => [1.0; 3],
            };
            let shade = lerp(style.root_shade, style.tip_shade, u);
            let rgb = base.map(|v| v * shade);
            let feat = match style.output {
                SplatOutput::Rgb => [rgb[0], rgb[1], rgb[2], 0.0],
                SplatOutput::GreyAlpha => [luminance(rgb), 1.0, 0.0, 0.0],
            };
            let splat = Splat2D {
                mean: sp.mean.map(|v| v as f32),
                conic: sp.conic.map(|v| v as f32),
                opacity: lerp(style.root_opacity, style.tip_opacity, u),
                feat,
                rect: [x0, x1, y0, y1],
            };
            Some((splat, sp.depth as f32))
        })
        .collect();
    let mut splats = Vec::new();
    let mut seg_point = Vec::new();
    let mut seg_u = Vec::new();
    let mut depth = Vec::new();
    for (opt, &(p, u)) in projected.iter().zip(&segments) {
        if let Some((s, d)) = opt {
            splats.push(*s);
            seg_point.push(p);
            seg_u.push(u);
            depth.push(*d);
        }
    }
    // Front to back; ties broken by index so the order is total and
    // reproducible. One u64 key per splat (depth in `total_cmp` order above
    // the index), sorted on every thread: the comparator sort through the
    // depth array was a serial 75 ms of a Short Hair render (1 M splats).
    let mut keys: Vec<u64> =
        depth.par_iter().enumerate().map(|(i, &d)| (u64::from(total_order_key(d)) << 32) | i as u64).collect();
    keys.par_sort_unstable();
    let order: Vec<u32> = keys.par_iter().map(|&k| k as u32).collect();
    let bins = bin(&splats, &order, width, height);
    let bg = style.background;
    let (data, state) = match style.output {
        SplatOutput::Rgb => rasterize::<3>(&splats, &bins, width, height, bg),
        SplatOutput::GreyAlpha => rasterize::<2>(&splats, &bins, width, height, [luminance(bg), 0.0]),
    };
    let image = Image::from_vec(style.output.channels(), height, width, data);
    let cache = SplatCache {
        splats,
        seg_point,
        seg_u,
        bins,
        state,
        camera: *cam,
        style: *style,
        n_points: strands.points.len(),
        n_strands: strands.len(),
        visible_strands,
    };
    Ok((image, cache))
}

/// Gradients [`render_backward_all`] returns, per strand sample point.
#[derive(Clone, Debug, PartialEq)]
pub struct SplatGradients {
    /// W.r.t. the point's position.
    pub points: Vec<[f32; 3]>,
    /// W.r.t. the point's base colour ([`Strands::colors`]; white when
    /// absent, and the gradient is the one at white).
    pub colors: Vec<[f32; 3]>,
}

/// Gradient of a loss w.r.t. every strand sample point, given its gradient
/// `grad_image` w.r.t. the image [`render`] returned. `strands`, `cam` and
/// `style` must be the ones the cache was made with. Points of culled
/// strands and of off-screen segments get zero.
pub fn render_backward(
    strands: &Strands,
    cam: &SplatCamera,
    style: &StrandStyle,
    cache: &SplatCache,
    grad_image: &Image,
) -> Result<Vec<[f32; 3]>, SplatError> {
    Ok(backward(strands, cam, style, cache, grad_image, false)?.points)
}

/// [`render_backward`] with the gradient w.r.t. every point's base colour
/// too (the colour a groom's points are stylized to). A segment's
/// splat has feature `shade(u) · (c_a + c_b) / 2` (RGB, or its luminance
/// beside a constant alpha channel), so each end point gets half of the
/// splat's colour gradient times the shade.
pub fn render_backward_all(
    strands: &Strands,
    cam: &SplatCamera,
    style: &StrandStyle,
    cache: &SplatCache,
    grad_image: &Image,
) -> Result<SplatGradients, SplatError> {
    backward(strands, cam, style, cache, grad_image, true)
}

/// [`render_backward_all`]; without `colors` its colour gradients are left
/// empty (the shape's iterations never read them: three million points'
/// worth of sums and conversions at Short Hair size).
fn backward(
    strands: &Strands,
    cam: &SplatCamera,
    style: &StrandStyle,
    cache: &SplatCache,
    grad_image: &Image,
    colors: bool,
) -> Result<SplatGradients, SplatError> {
    strands.validate()?;
    if cache.camera != *cam
        || cache.style != *style
        || cache.n_points != strands.points.len()
        || cache.n_strands != strands.len()
    {
        return Err(SplatError::CacheMismatch);
    }
    let (width, height) = (cam.width, cam.height);
    let expected = [style.output.channels(), height, width];
    let got = [grad_image.channels, grad_image.height, grad_image.width];
    if got != expected {
        return Err(SplatError::GradShape { got, expected });
    }
    let bg = style.background;
    let splat_grads = match style.output {
        SplatOutput::Rgb => {
            rasterize_backward::<3>(&cache.splats, &cache.bins, width, height, bg, &cache.state, &grad_image.data)
        }
        SplatOutput::GreyAlpha => rasterize_backward::<2>(
            &cache.splats,
            &cache.bins,
            width,
            height,
            [luminance(bg), 0.0],
            &cache.state,
            &grad_image.data,
        ),
    };
    let shape = style.shape();
    let seg_grads: Vec<([f64; 3], [f64; 3])> = cache
        .seg_point
        .par_iter()
        .zip(&splat_grads)
        .map(|(&p, g)| {
            let (a, b) = (strands.points[p as usize], strands.points[p as usize + 1]);
            // The forward kept this segment, so with the same points it
            // projects again; failing that, the points were changed.
            let sp = project_segment(a, b, cam, &shape).ok_or(SplatError::CacheMismatch)?;
            Ok(project_segment_backward(&sp, cam, &shape, [g[0], g[1]], [g[2], g[3], g[4]]))
        })
        .collect::<Result<_, SplatError>>()?;
    let mut acc = vec![[0.0f64; 3]; strands.points.len()];
    for (&p, (ga, gb)) in cache.seg_point.iter().zip(&seg_grads) {
        for k in 0..3 {
            acc[p as usize][k] += ga[k];
            acc[p as usize + 1][k] += gb[k];
        }
    }
    let f32s = |v: Vec<[f64; 3]>| v.into_par_iter().map(|g| g.map(|x| x as f32)).collect();
    if !colors {
        return Ok(SplatGradients { points: f32s(acc), colors: Vec::new() });
    }
    let mut acc_color = vec![[0.0f64; 3]; strands.points.len()];
    for ((&p, g), &u) in cache.seg_point.iter().zip(&splat_grads).zip(&cache.seg_u) {
        let half_shade = 0.5 * lerp(style.root_shade, style.tip_shade, u) as f64;
        let d_rgb: [f64; 3] = match style.output {
            SplatOutput::Rgb => std::array::from_fn(|k| g[FEAT_GRAD + k]),
            SplatOutput::GreyAlpha => LUMA_709.map(|w| w as f64 * g[FEAT_GRAD]),
        };
        for k in 0..3 {
            acc_color[p as usize][k] += half_shade * d_rgb[k];
            acc_color[p as usize + 1][k] += half_shade * d_rgb[k];
        }
    }
    Ok(SplatGradients { points: f32s(acc), colors: f32s(acc_color) })
}

#[cfg(test)]
mod tests {
    use super::total_order_key;

    #[test]
    fn depth_keys_sort_as_total_cmp() {
        let mut v = vec![
            3.5f32,
            -0.0,
            0.0,
            -2.0,
            f32::INFINITY,
            f32::NEG_INFINITY,
            1e-30,
            -1e-30,
            7.25,
            f32::MIN_POSITIVE,
            -f32::MAX,
            f32::MAX,
        ];
        let mut by_key = v.clone();
        v.sort_by(|a, b| a.total_cmp(b));
        by_key.sort_by_key(|&d| total_order_key(d));
        assert_eq!(
            v.iter().map(|d| d.to_bits()).collect::<Vec<_>>(),
            by_key.iter().map(|d| d.to_bits()).collect::<Vec<_>>()
        );
    }
}
