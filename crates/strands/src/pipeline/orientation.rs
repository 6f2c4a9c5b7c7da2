//! The orientation term: the painting's stroke directions as a target for
//! the strands' projected directions, the change of method the strand
//! paper names as future work. NNST alone (eq. 2–3) matches texture
//! statistics, which thin strands meet about as well whichever painting
//! is given: spirals, triangles and paintings left grooms alike (see
//! docs/design/strands.md). Strokes have a direction, and a strand is a
//! direction, so this term asks each visible segment to lie along the
//! painting's stroke at its place on the hair.
//!
//! - **Stroke field.** The structure tensor `J = G_σ * ∇I ∇Iᵀ` of the
//!   painting's luminance at the scale's style size (Sobel gradients,
//!   `σ` = [`STRUCTURE_SIGMA`] pixels); the stroke runs along the smaller
//!   eigenvector, with weight `c = (λ₁ − λ₂)/(λ₁ + λ₂ + ε) · E/(E + E₀)`,
//!   the coherence times a gate on the gradient energy `E = λ₁ + λ₂`
//!   ([`STROKE_GRADIENT`]) so that only visible strokes have a direction.
//!   The coherence is not squared: squared, a painting's loosely brushed
//!   strokes (The Shipwreck's waves) pulled at a fifth of a stripe's
//!   strength and NNST's frizz won there (docs/design/strands.md). Kept in
//!   doubled-angle form `(c cos 2θ, c sin 2θ, c)` so bilinear sampling
//!   averages headless directions correctly.
//! - **Placement.** The painting is laid over the rest hair's box as one
//!   camera sees it (cover fit, centred, aspect kept), so a spiral is drawn
//!   onto the hair as a spiral. A projected preset (long hair) lays it as
//!   the middle camera of its range sees it, whichever view NNST is looking
//!   through (a texture projected from the front camera); the others lay
//!   it over each view's own box. The style's scale on the hair ([`StrokeField::laid_at`],
//!   NNST's `style_scale`: 2 makes strokes twice as large) enlarges it by
//!   that factor, centred, or shrinks it, tiled (below 1): a motif finer
//!   than the groom's field can bend to (a triangle tessellation six across
//!   a fur ball) is then laid at a size the strands can follow.
//! - **Loss.** Over the segments of visible strands, with `d` a segment's
//!   projected vector and `ℓ` the projected length its rest length would
//!   have lying in the picture plane at its rest depth,
//!   `L = Σ w_s · ½ (c − (f₀ (d_x² − d_y²) + f₁ 2 d_x d_y) / ℓ²) / Σ w_s`
//!   with `f` the field at the projected midpoint: `½ c (1 − cos 2(φ − θ))`
//!   for a segment lying in the picture plane at angle `φ`, `½ c` for one
//!   seen end-on. So the term turns segments along the stroke *and* lays
//!   them into the picture plane (combs them), and a segment cannot meet it
//!   by pointing at the camera: an earlier form weighted each segment by
//!   `l²/(l² + l₀²)` of its current projected length, and a spiky head
//!   met it that way, crinkling into frizz. The form is a quadratic in
//!   `d`, smooth where a segment is seen end-on. The weights `w_s` (the
//!   splat's opacity, 0 for culled strands) and `ℓ` are fixed per view.
//!
//! The gradient reaches the points through the angle and through the
//! midpoint's place in the field; it is checked by finite differences
//! here and as part of the whole iteration in `tests/chain_gradient.rs`.

use nst3d_core::Image;
use nst3d_splat::{strand_visible, SplatCamera, StrandStyle, Strands};

use crate::strands::FlatStrands;

/// Structure-tensor smoothing, pixels at the scale's style size.
pub const STRUCTURE_SIGMA: f32 = 3.0;

/// The luminance gradient, per picture height, at which a place of the
/// painting counts half as a stroke: its energy `E₀ = (this / h)²` per
/// pixel at height `h`. Coherence alone is scale-free, so a smooth ramp
/// (0.2 → 0.7 across the picture, 0.5 per height) would be a perfect
/// vertical stroke and comb the hair; weighted by `E/(E + E₀)` it counts
/// 1.5 % at any size, where the edges of stripes count over 95 % (an edge
/// is steep in pixels whatever the size).
pub const STROKE_GRADIENT: f32 = 4.0;

/// A painting's stroke directions in doubled-angle form, row-major.
#[derive(Clone, Debug)]
pub struct StrokeField {
    width: usize,
    height: usize,
    /// `(c cos 2θ, c sin 2θ, c)` per pixel.
    data: Vec<[f32; 3]>,
    /// See [`StrokeField::strength`].
    strength: f32,
    /// See [`StrokeField::laid_at`].
    motif_scale: f32,
}

impl StrokeField {
    /// Width and height in pixels.
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// The stroke field of `grey` (channel 0 is read; `[0, 1]`).
    pub fn from_grey(grey: &Image) -> Self {
        let (h, w) = (grey.height, grey.width);
        let px = |x: isize, y: isize| {
            grey.data[y.clamp(0, h as isize - 1) as usize * w + x.clamp(0, w as isize - 1) as usize]
        };
        let mut t = vec![[0.0f32; 3]; h * w];
        for y in 0..h as isize {
            for x in 0..w as isize {
                let gx = (px(x + 1, y - 1) + 2.0 * px(x + 1, y) + px(x + 1, y + 1)
                    - px(x - 1, y - 1)
                    - 2.0 * px(x - 1, y)
                    - px(x - 1, y + 1))
                    / 8.0;
                let gy = (px(x - 1, y + 1) + 2.0 * px(x, y + 1) + px(x + 1, y + 1)
                    - px(x - 1, y - 1)
                    - 2.0 * px(x, y - 1)
                    - px(x + 1, y - 1))
                    / 8.0;
                t[y as usize * w + x as usize] = [gx * gx, gx * gy, gy * gy];
            }
        }
        let j = blur(&t, w, h, STRUCTURE_SIGMA);
        let mean_trace = j.iter().map(|v| (v[0] + v[2]) as f64).sum::<f64>() / (w * h).max(1) as f64;
        let eps = 1e-2 * mean_trace as f32 + 1e-12;
        let stroke_energy = (STROKE_GRADIENT / h.max(1) as f32).powi(2);
        let (mut gated, mut coherent) = (0.0f64, 0.0f64);
        let data = j
            .iter()
            .map(|&[jxx, jxy, jyy]| {
                let disc = ((jxx - jyy).powi(2) + 4.0 * jxy * jxy).max(0.0).sqrt();
                let energy = jxx + jyy;
                let coherence = disc / (energy + eps);
                let c = coherence * energy / (energy + stroke_energy);
                (gated, coherent) = (gated + c as f64, coherent + coherence as f64);
                // The gradient's doubled angle is atan2(2 jxy, jxx − jyy);
                // the stroke is perpendicular: its doubled angle is opposite.
                let (c2, s2) = (-(jxx - jyy) / (disc + 1e-12), -(2.0 * jxy) / (disc + 1e-12));
                [c * c2, c * s2, c]
            })
            .collect();
        let strength = if coherent > 0.0 { (gated / coherent) as f32 } else { 0.0 };
        Self { width: w, height: h, data, strength, motif_scale: 1.0 }
    }

    /// The field laid over the hair at `style_scale` times the cover-fit
    /// size: 2 lays the painting at twice the hair's box, centred; 0.5 at
    /// half it, tiled.
    pub fn laid_at(mut self, style_scale: f32) -> Self {
        self.motif_scale = style_scale;
        self
    }

    /// How much of the painting's coherent structure is visible strokes
    /// (`Σ c / Σ coherence`, in `[0, 1]`): each scale's orientation weight
    /// is scaled by its field's, since setting `λ` from gradient norms
    /// would otherwise undo the energy gate (a ramp's faint field would be
    /// scaled up to a stroked painting's strength).
    pub fn strength(&self) -> f32 {
        self.strength
    }

    /// Bilinear sample at continuous pixel coordinates `(u, v)` (pixel
    /// centres at integers), zero outside, and its derivatives along `u`
    /// and `v`.
    fn sample(&self, u: f32, v: f32) -> ([f32; 3], [f32; 3], [f32; 3]) {
        let (x0, y0) = (u.floor(), v.floor());
        let (fx, fy) = (u - x0, v - y0);
        let tiled = self.motif_scale < 1.0;
        let at = |x: f32, y: f32| -> [f32; 3] {
            let (x, y) =
                if tiled { (x.rem_euclid(self.width as f32), y.rem_euclid(self.height as f32)) } else { (x, y) };
            if x < 0.0 || y < 0.0 || x >= self.width as f32 || y >= self.height as f32 {
                [0.0; 3]
            } else {
                self.data[y as usize * self.width + x as usize]
            }
        };
        let (a, b, c, d) = (at(x0, y0), at(x0 + 1.0, y0), at(x0, y0 + 1.0), at(x0 + 1.0, y0 + 1.0));
        let mut val = [0.0; 3];
        let mut du = [0.0; 3];
        let mut dv = [0.0; 3];
        for k in 0..3 {
            let top = a[k] + fx * (b[k] - a[k]);
            let bottom = c[k] + fx * (d[k] - c[k]);
            val[k] = top + fy * (bottom - top);
            du[k] = (1.0 - fy) * (b[k] - a[k]) + fy * (d[k] - c[k]);
            dv[k] = bottom - top;
        }
        (val, du, dv)
    }
}

/// Separable Gaussian blur of a 3-channel field, edges replicated.
fn blur(src: &[[f32; 3]], w: usize, h: usize, sigma: f32) -> Vec<[f32; 3]> {
    let r = (3.0 * sigma).ceil().max(1.0) as isize;
    let mut k: Vec<f32> = (-r..=r).map(|i| (-(i * i) as f32 / (2.0 * sigma * sigma)).exp()).collect();
    let s: f32 = k.iter().sum();
    k.iter_mut().for_each(|v| *v /= s);
    let pass = |src: &[[f32; 3]], horizontal: bool| -> Vec<[f32; 3]> {
        let mut out = vec![[0.0f32; 3]; w * h];
        for y in 0..h as isize {
            for x in 0..w as isize {
                let mut acc = [0.0f32; 3];
                for (i, kv) in (-r..=r).zip(&k) {
                    let (sx, sy) = if horizontal {
                        ((x + i).clamp(0, w as isize - 1), y)
                    } else {
                        (x, (y + i).clamp(0, h as isize - 1))
                    };
                    let p = src[sy as usize * w + sx as usize];
                    (0..3).for_each(|c| acc[c] += kv * p[c]);
                }
                out[y as usize * w + x as usize] = acc;
            }
        }
        out
    };
    pass(&pass(src, true), false)
}

/// The stroke field laid over one view: where each picture pixel falls in
/// the painting, and each segment's fixed weight.
#[derive(Clone, Debug)]
pub struct OrientationView {
    /// Picture pixel of the painting's centre.
    centre: [f32; 2],
    /// Picture pixels per painting pixel.
    scale: f32,
    /// Half the painting's size, in painting pixels.
    half: [f32; 2],
    /// Weight of each segment (indexed by its first point), 0 where none.
    weights: Vec<f32>,
    /// `1/ℓ²` of each segment: its rest length laid in the picture plane at
    /// its rest depth, in pixels (indexed by its first point).
    inv_full2: Vec<f32>,
    /// `Σ w_s` of the whole view, the loss's normaliser (kept when
    /// [`OrientationView::shared`] splits the weights among paintings).
    total: f64,
    /// The camera the field is laid through.
    cam: SplatCamera,
}

impl OrientationView {
    /// `field` laid over the box of the `hair` pixels (row-major, `cam`'s
    /// picture) of the rest groom (see [`StrokeField::laid_at`]), with the
    /// segment weights of `rest` seen through `cam`. `None` when no hair is
    /// in sight.
    pub fn new(
        field: &StrokeField,
        rest: &Strands,
        hair: &[bool],
        style: &StrandStyle,
        cam: &SplatCamera,
    ) -> Option<Self> {
        let (w, h) = (cam.width, cam.height);
        let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
        for (i, _) in hair.iter().enumerate().filter(|(_, &on)| on) {
            let (x, y) = (i % w, i / w);
            (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x + 1), y1.max(y + 1));
        }
        if x1 <= x0 || h == 0 {
            return None;
        }
        let (bw, bh) = ((x1 - x0) as f32, (y1 - y0) as f32);
        let field_size = field.size();
        let cover = (bw / field_size.0 as f32).max(bh / field_size.1 as f32);
        let scale = cover * field.motif_scale;
        let centre = [(x0 + x1) as f32 / 2.0, (y0 + y1) as f32 / 2.0];
        let half = [field_size.0 as f32 / 2.0, field_size.1 as f32 / 2.0];
        let (weights, inv_full2) = segment_weights(rest, style, cam);
        let total = weights.iter().map(|&w| w as f64).sum();
        Some(Self { centre, scale, half, weights, inv_full2, total, cam: *cam })
    }

    /// The view with each segment's weight times its strand's share of
    /// this view's painting (`shares` per point, a style map's), normalised
    /// by the whole view's weight: the views of all the paintings sum to
    /// the term of one field blended strand by strand.
    pub fn shared(mut self, shares: &[f32]) -> Self {
        self.weights.iter_mut().zip(shares).for_each(|(w, s)| *w *= s);
        self
    }

    /// Painting pixel coordinates of picture pixel `p` (pixel centres of
    /// the painting at integers), and their derivative per picture pixel.
    fn to_field(&self, p: [f32; 2]) -> ([f32; 2], f32) {
        let u = (p[0] - self.centre[0]) / self.scale + self.half[0] - 0.5;
        let v = (p[1] - self.centre[1]) / self.scale + self.half[1] - 0.5;
        ([u, v], 1.0 / self.scale)
    }
}

/// Opacity along the strand of each segment of `rest` (0 for culled
/// strands' segments), and `1/ℓ²` of its rest length laid in the picture
/// plane at its midpoint's depth.
fn segment_weights(rest: &Strands, style: &StrandStyle, cam: &SplatCamera) -> (Vec<f32>, Vec<f32>) {
    let pts = rest.points;
    let mut w = vec![0.0f32; pts.len()];
    let mut inv_full2 = vec![0.0f32; pts.len()];
    for s in 0..rest.offsets.len() - 1 {
        if !strand_visible(rest, s, cam.eye, style.visibility_threshold) {
            continue;
        }
        let (first, end) = (rest.offsets[s], rest.offsets[s + 1]);
        let segs = (end - first - 1).max(1) as f32;
        for i in first..end - 1 {
            let (a, b) = (pts[i], pts[i + 1]);
            let len = ((0..3).map(|k| (b[k] - a[k]).powi(2)).sum::<f32>()).sqrt();
            let z = cam.to_camera([0, 1, 2].map(|k| 0.5 * (a[k] + b[k])))[2];
            let full = len * cam.fx.max(cam.fy) / z.max(1e-6);
            if !(full > 1e-6) {
                continue;
            }
            let u = ((i - first) as f32 + 0.5) / segs;
            w[i] = style.root_opacity + (style.tip_opacity - style.root_opacity) * u;
            inv_full2[i] = 1.0 / (full * full);
        }
    }
    (w, inv_full2)
}

/// `∂x/∂p` and `∂y/∂p` of the pixel coordinates of world point `p`.
fn projection_jacobian(cam: &SplatCamera, p: [f32; 3]) -> [[f32; 3]; 2] {
    let t = cam.to_camera(p);
    let iz = 1.0 / t[2];
    let row = |axis: [f32; 3], f: f32, tc: f32| -> [f32; 3] {
        [0, 1, 2].map(|k| f * (axis[k] * iz - tc * cam.forward[k] * iz * iz))
    };
    [row(cam.right, cam.fx, t[0]), row(cam.down, cam.fy, t[1])]
}

/// The orientation loss of `strands` (the layout of the rest groom the view
/// was built from) in view `view` of `field`, seen through the view's own
/// camera, and its gradient with respect to every point.
pub fn orientation_loss(field: &StrokeField, view: &OrientationView, strands: &FlatStrands) -> (f32, Vec<[f32; 3]>) {
    let cam = &view.cam;
    let pts = &strands.points;
    let mut grad = vec![[0.0f32; 3]; pts.len()];
    let total = view.total;
    if total <= 0.0 {
        return (0.0, grad);
    }
    let mut loss = 0.0f64;
    for s in 0..strands.offsets.len() - 1 {
        for i in strands.offsets[s]..strands.offsets[s + 1] - 1 {
            let w = view.weights[i];
            if w == 0.0 {
                continue;
            }
            let (a, b) = (cam.project(pts[i]), cam.project(pts[i + 1]));
            let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
            let k = view.inv_full2[i];
            // The doubled-angle vector of `d`, scaled by `|d|²/ℓ²`.
            let (ca, sa) = ((dx * dx - dy * dy) * k, 2.0 * dx * dy * k);
            let (uv, duv) = view.to_field([(a[0] + b[0]) / 2.0, (a[1] + b[1]) / 2.0]);
            let (f, fu, fv) = field.sample(uv[0], uv[1]);
            loss += (w * 0.5 * (f[2] - f[0] * ca - f[1] * sa)) as f64;
            let g = w / total as f32;
            // ∂/∂(dx, dy) of the quadratic form.
            let gdx = -(f[0] * dx + f[1] * dy) * k;
            let gdy = -(-f[0] * dy + f[1] * dx) * k;
            // ∂/∂(midpoint) through the field's place.
            let gm = |d: [f32; 3]| 0.5 * (d[2] - d[0] * ca - d[1] * sa) * duv;
            let (gmx, gmy) = (gm(fu), gm(fv));
            let ga = [g * (-gdx + 0.5 * gmx), g * (-gdy + 0.5 * gmy)];
            let gb = [g * (gdx + 0.5 * gmx), g * (gdy + 0.5 * gmy)];
            for (idx, gp) in [(i, ga), (i + 1, gb)] {
                let j = projection_jacobian(cam, pts[idx]);
                for k in 0..3 {
                    grad[idx][k] += gp[0] * j[0][k] + gp[1] * j[1][k];
                }
            }
        }
    }
    ((loss / total) as f32, grad)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::{check_gradient, pseudo_random};

    /// A grey image of diagonal stripes, `n` pixels square.
    fn stripes(n: usize) -> Image {
        let data = (0..n * n)
            .map(|i| {
                let (x, y) = ((i % n) as f32, (i / n) as f32);
                if ((x + y) * std::f32::consts::PI / 8.0).sin() > 0.0 {
                    1.0
                } else {
                    0.0
                }
            })
            .collect();
        Image::from_vec(1, n, n, data)
    }

    #[test]
    fn stripes_give_their_direction_with_full_coherence() {
        let f = StrokeField::from_grey(&stripes(48));
        // Stripes along x + y = const run at −45° in the picture (y down):
        // doubled angle −90°, so (cos, sin) of it is (0, −1).
        let [c2, s2, c] = f.data[24 * 48 + 24];
        assert!(c > 0.9, "coherence {c}");
        assert!(c2.abs() < 0.05 * c && (s2 + c).abs() < 0.05 * c, "({c2}, {s2}, {c})");
    }

    /// A smooth ramp has a coherent gradient but no stroke: it must not
    /// give the hair a direction.
    #[test]
    fn a_smooth_ramp_has_almost_no_stroke() {
        // 0.2 → 0.7 across 200 pixels, as the cross test's ramp at a
        // scale's style size.
        let n = 200;
        let ramp = Image::from_vec(1, n, n, (0..n * n).map(|i| 0.2 + 0.5 * (i % n) as f32 / n as f32).collect());
        let c = StrokeField::from_grey(&ramp).data[100 * n + 100][2];
        assert!(c < 0.1, "ramp weight {c}");
        assert!(StrokeField::from_grey(&ramp).strength() < 0.1);
        // The same ramp at a coarse scale's 16 pixels, 0.03 per pixel.
        let small = Image::from_vec(1, 16, 16, (0..256).map(|i| 0.2 + 0.5 * (i % 16) as f32 / 16.0).collect());
        assert!(StrokeField::from_grey(&small).strength() < 0.1, "{}", StrokeField::from_grey(&small).strength());
        let edge = StrokeField::from_grey(&stripes(48)).data[24 * 48 + 24][2];
        assert!(edge > 0.9, "stripes weight {edge}");
        assert!(StrokeField::from_grey(&stripes(48)).strength() > 0.9);
    }

    /// The style's scale on the hair: at 1 the painting covers the hair's
    /// box; at 2 the box's edge falls at the painting's quarter; at 0.5 the
    /// painting is half the box, tiled, so the box's edge falls on the
    /// painting's edge one tile out.
    #[test]
    fn the_style_scale_sets_the_painting_s_size_on_the_hair() {
        let (w, h) = (64usize, 64usize);
        let hair: Vec<bool> = (0..w * h).map(|i| (16..48).contains(&(i % w)) && (16..48).contains(&(i / w))).collect();
        let g = groom();
        let rest = Strands { points: &g.points, offsets: &g.offsets, colors: None, root_normals: None };
        let (style, cam) = (StrandStyle::default(), camera());
        let field = StrokeField::from_grey(&stripes(40));
        let u_at_right_edge = |scale: f32| {
            let laid = field.clone().laid_at(scale);
            let view = OrientationView::new(&laid, &rest, &hair, &style, &cam).unwrap();
            view.to_field([48.0, 32.0]).0[0] + 0.5
        };
        assert!((u_at_right_edge(1.0) - 40.0).abs() < 1e-4);
        assert!((u_at_right_edge(2.0) - 30.0).abs() < 1e-4);
        assert!((u_at_right_edge(0.5) - 60.0).abs() < 1e-4);
        let tiled = field.clone().laid_at(0.5);
        for (u, v) in [(45.3f32, 12.7f32), (-7.2, 30.1)] {
            let (a, b) = (tiled.sample(u, v).0, tiled.sample(u.rem_euclid(40.0), v).0);
            assert!((0..3).all(|k| (a[k] - b[k]).abs() < 1e-6), "{a:?} {b:?}");
        }
        assert_eq!(field.sample(45.3, 12.7).0, [0.0; 3], "untiled: nothing beyond the painting");
    }

    fn camera() -> SplatCamera {
        SplatCamera::look_at([0.3, 0.2, 3.0], [0.0; 3], [0.0, 1.0, 0.0], 40.0, 64, 64).unwrap()
    }

    fn groom() -> FlatStrands {
        let mut points = Vec::new();
        let mut offsets = vec![0];
        let r = pseudo_random(40 * 3, 9);
        for s in 0..10 {
            for k in 0..4 {
                let j = (s * 4 + k) * 3;
                points.push([
                    -0.5 + 0.1 * s as f32 + 0.05 * r[j],
                    -0.5 + 0.3 * k as f32 + 0.05 * r[j + 1],
                    0.05 * r[j + 2],
                ]);
            }
            offsets.push(points.len());
        }
        FlatStrands { points, offsets }
    }

    #[test]
    fn orientation_gradient_matches_finite_differences() {
        let field = StrokeField::from_grey(&stripes(40));
        let g = groom();
        let cam = camera();
        let rest = Strands { points: &g.points, offsets: &g.offsets, colors: None, root_normals: None };
        let style = StrandStyle::default();
        let hair: Vec<bool> = (0..64 * 64).map(|i| (10..50).contains(&(i / 64))).collect();
        let view = OrientationView::new(&field, &rest, &hair, &style, &cam).unwrap();
        let x: Vec<f32> = g.points.iter().flatten().copied().collect();
        let loss = |x: &[f32]| {
            let s =
                FlatStrands { points: x.chunks(3).map(|c| [c[0], c[1], c[2]]).collect(), offsets: g.offsets.clone() };
            orientation_loss(&field, &view, &s).0 as f64
        };
        let (l, grad) = orientation_loss(&field, &view, &g);
        assert!(l > 0.0 && l < 1.0, "loss {l}");
        let grad: Vec<f32> = grad.iter().flatten().copied().collect();
        // A step of 3e-3 (a hundredth of the segment spacing): at 1e-3 the
        // f32 loss's rounding is 2 % of the smallest checked entries (1e-3
        // against a largest of 0.18).
        let r = check_gradient(&x, &grad, loss, 3e-3, 120, 1e-3);
        assert!(r.max_rel_err < 2e-2, "{r:?}");
    }
}
