//! Tile-based front-to-back compositing of projected Gaussians (paper eq. 7),
//! forward and backward side by side.
//!
//! The image is cut into `16 x 16` tiles; every Gaussian is binned into the
//! tiles its 3σ ellipse's bounding box touches, each tile list in global depth
//! order. A tile is one rayon task and walks its list Gaussian by Gaussian,
//! touching only the pixels inside that Gaussian's 3σ ellipse (computed per
//! row), which for thin strand splats is a small fraction of the tile; each
//! pixel still sees its Gaussians in depth order, so this is the same
//! per-pixel sum as the classic pixel-major loop, bit for bit.
//!
//! Per pixel, with `q = dᵀ Σ2D⁻¹ d` and `d` the offset from the splat centre:
//! `α = min(0.99, o · f(q))` and `C = Σ c_i α_i T_i + T_N · background`,
//! `T_i = Π_{j<i} (1 − α_j)`. The footprint `f` is the Gaussian truncated at
//! 3σ (`q < 9`) and shifted down by its value there,
//! `f(q) = (e^{−q/2} − e^{−9/2}) / (1 − e^{−9/2})`, so that it reaches 0
//! continuously at the truncation instead of stepping by 1.1 % of the opacity:
//! a step would make renders jump as a strand moves by a fraction of a pixel,
//! which shows up as noise in both the optimiser and finite-difference checks.
//! A pixel stops after the Gaussian that takes its transmittance below 1e-4
//! (that Gaussian is still composited, so the dropped remainder is < 1e-4).

use rayon::prelude::*;

/// Tile edge in pixels.
pub(crate) const TILE: usize = 16;
/// Upper clamp of a splat's alpha (as in 3DGS: keeps `1 − α` invertible for
/// the backward's transmittance recovery).
pub(crate) const MAX_ALPHA: f32 = 0.99;
/// A pixel is finished once its transmittance falls below this.
pub(crate) const MIN_TRANSMITTANCE: f32 = 1e-4;
/// Squared Mahalanobis radius of the truncation (3σ).
pub(crate) const CUTOFF_Q: f32 = 9.0;
/// `e^{−CUTOFF_Q/2}`.
const EXP_AT_CUTOFF: f32 = 0.011_108_996;
/// Most channels a render can have.
pub(crate) const MAX_CHANNELS: usize = 4;

/// A Gaussian after projection: what the per-pixel loops read.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Splat2D {
    /// Centre in pixels.
    pub mean: [f32; 2],
    /// Inverse 2D covariance `[a, b, c]`: `q = a dx² + 2 b dx dy + c dy²`.
    pub conic: [f32; 3],
    /// Peak opacity `o`.
    pub opacity: f32,
    /// Colour (first `C` entries used).
    pub feat: [f32; MAX_CHANNELS],
    /// Inclusive pixel bounds of the 3σ ellipse, clipped to the image:
    /// `[x0, x1, y0, y1]`.
    pub rect: [u32; 4],
}

/// Per-pixel alpha of a splat and what its backward needs.
#[derive(Clone, Copy, Debug)]
pub(crate) struct AlphaSample {
    pub alpha: f32,
    pub dx: f32,
    pub dy: f32,
    /// `e^{−q/2}`.
    pub gauss: f32,
    /// Whether the 0.99 clamp was active (then alpha has no gradient).
    pub clamped: bool,
}

impl Splat2D {
    /// Alpha at pixel centre `(px, py)`, `None` outside the 3σ ellipse. The
    /// forward, the backward and the brute-force reference all call this, so
    /// they agree bitwise.
    #[inline(always)]
    pub(crate) fn alpha_at(&self, px: f32, py: f32) -> Option<AlphaSample> {
        let dx = px - self.mean[0];
        let dy = py - self.mean[1];
        let [a, b, c] = self.conic;
        let q = (a * dx + 2.0 * b * dy) * dx + c * dy * dy;
        if !(q < CUTOFF_Q) {
            return None;
        }
        let gauss = (-0.5 * q).exp();
        let raw = self.opacity * (gauss - EXP_AT_CUTOFF) * (1.0 / (1.0 - EXP_AT_CUTOFF));
        let clamped = raw > MAX_ALPHA;
        Some(AlphaSample { alpha: if clamped { MAX_ALPHA } else { raw }, dx, dy, gauss, clamped })
    }

    /// Columns `[x0, x1]` (inclusive, may be empty) of row `y` that can lie
    /// inside the 3σ ellipse, widened by a pixel so rounding never loses one;
    /// [`Splat2D::alpha_at`] makes the exact decision.
    #[inline(always)]
    fn row_span(&self, y: usize, lo: usize, hi: usize) -> (usize, usize) {
        let [a, b, c] = self.conic;
        let dy = y as f32 + 0.5 - self.mean[1];
        let disc = CUTOFF_Q * a - dy * dy * (a * c - b * b);
        if !(disc >= 0.0) {
            return (1, 0);
        }
        let centre = self.mean[0] - b * dy / a - 0.5;
        let half = disc.sqrt() / a + 1.0;
        let x0 = (centre - half).ceil().max(lo.max(self.rect[0] as usize) as f32);
        let x1 = (centre + half).floor().min(hi.min(self.rect[1] as usize) as f32);
        if !(x0 <= x1) {
            return (1, 0);
        }
        (x0 as usize, x1 as usize)
    }
}

/// Per-tile Gaussian lists: tile `t` holds `list[ranges[t]..ranges[t + 1]]`,
/// indices into the splat array, front to back.
#[derive(Clone, Debug)]
pub(crate) struct Bins {
    pub tiles_x: usize,
    pub tiles_y: usize,
    pub ranges: Vec<usize>,
    pub list: Vec<u32>,
}

/// Bins splats into tiles. `order` lists splat indices front to back; filling
/// the lists in that order leaves each tile list sorted without a per-tile sort.
pub(crate) fn bin(splats: &[Splat2D], order: &[u32], width: usize, height: usize) -> Bins {
    let tiles_x = width.div_ceil(TILE);
    let tiles_y = height.div_ceil(TILE);
    let tile_rect = |s: &Splat2D| {
        let [x0, x1, y0, y1] = s.rect.map(|v| v as usize / TILE);
        (x0, x1, y0, y1)
    };
    let mut ranges = vec![0usize; tiles_x * tiles_y + 1];
    for s in splats {
        let (x0, x1, y0, y1) = tile_rect(s);
        for ty in y0..=y1 {
            for tx in x0..=x1 {
                ranges[ty * tiles_x + tx + 1] += 1;
            }
        }
    }
    for t in 0..tiles_x * tiles_y {
        ranges[t + 1] += ranges[t];
    }
    let mut fill = ranges.clone();
    let mut list = vec![0u32; ranges[tiles_x * tiles_y]];
    for &i in order {
        let (x0, x1, y0, y1) = tile_rect(&splats[i as usize]);
        for ty in y0..=y1 {
            for tx in x0..=x1 {
                let slot = &mut fill[ty * tiles_x + tx];
                list[*slot] = i;
                *slot += 1;
            }
        }
    }
    Bins { tiles_x, tiles_y, ranges, list }
}

/// Pixel bounds of tile `t`: `(x0, y0, x1, y1)` inclusive.
fn tile_bounds(bins: &Bins, t: usize, width: usize, height: usize) -> (usize, usize, usize, usize) {
    let (tx, ty) = (t % bins.tiles_x, t / bins.tiles_x);
    let (x0, y0) = (tx * TILE, ty * TILE);
    (x0, y0, (x0 + TILE).min(width) - 1, (y0 + TILE).min(height) - 1)
}

/// Forward result of one tile, pixels row-major within the tile.
struct TileForward<const C: usize> {
    color: Vec<[f32; C]>,
    transmittance: Vec<f32>,
    n_contrib: Vec<u32>,
}

fn tile_forward<const C: usize>(
    splats: &[Splat2D],
    list: &[u32],
    (x0, y0, x1, y1): (usize, usize, usize, usize),
    background: [f32; C],
) -> TileForward<C> {
    let tw = x1 - x0 + 1;
    let npx = tw * (y1 - y0 + 1);
    let mut color = vec![[0.0f32; C]; npx];
    let mut trans = vec![1.0f32; npx];
    let mut n_contrib = vec![0u32; npx];
    let mut finished = 0usize;
    'splats: for (li, &gi) in list.iter().enumerate() {
        let s = &splats[gi as usize];
        let (r0, r1) = (y0.max(s.rect[2] as usize), y1.min(s.rect[3] as usize));
        for y in r0..=r1 {
            let (c0, c1) = s.row_span(y, x0, x1);
            for x in c0..=c1 {
                let p = (y - y0) * tw + (x - x0);
                let t = trans[p];
                if t < MIN_TRANSMITTANCE {
                    continue;
                }
                let Some(a) = s.alpha_at(x as f32 + 0.5, y as f32 + 0.5) else { continue };
                let w = a.alpha * t;
                for ch in 0..C {
                    color[p][ch] += w * s.feat[ch];
                }
                let t_next = t * (1.0 - a.alpha);
                trans[p] = t_next;
                n_contrib[p] = li as u32 + 1;
                if t_next < MIN_TRANSMITTANCE {
                    finished += 1;
                    if finished == npx {
                        break 'splats;
                    }
                }
            }
        }
    }
    for (c, t) in color.iter_mut().zip(&trans) {
        for ch in 0..C {
            c[ch] += t * background[ch];
        }
    }
    TileForward { color, transmittance: trans, n_contrib }
}

/// Per-pixel state the forward leaves for the backward.
#[derive(Clone, Debug)]
pub(crate) struct RasterState {
    /// Final transmittance `T_N` per pixel (row-major, image-sized).
    pub transmittance: Vec<f32>,
    /// Per pixel, one past the tile-list position of its last composited splat.
    pub n_contrib: Vec<u32>,
}

/// Composites all tiles; returns the planar `C x H x W` image and the state
/// for the backward.
pub(crate) fn rasterize<const C: usize>(
    splats: &[Splat2D],
    bins: &Bins,
    width: usize,
    height: usize,
    background: [f32; C],
) -> (Vec<f32>, RasterState) {
    let ntiles = bins.tiles_x * bins.tiles_y;
    let tiles: Vec<TileForward<C>> = (0..ntiles)
        .into_par_iter()
        .map(|t| {
            let list = &bins.list[bins.ranges[t]..bins.ranges[t + 1]];
            tile_forward::<C>(splats, list, tile_bounds(bins, t, width, height), background)
        })
        .collect();
    let plane = width * height;
    let mut image = vec![0.0f32; C * plane];
    let mut state = RasterState { transmittance: vec![0.0; plane], n_contrib: vec![0; plane] };
    for (t, tile) in tiles.iter().enumerate() {
        let (x0, y0, x1, y1) = tile_bounds(bins, t, width, height);
        let tw = x1 - x0 + 1;
        for y in y0..=y1 {
            for x in x0..=x1 {
                let (p, q) = ((y - y0) * tw + (x - x0), y * width + x);
                for ch in 0..C {
                    image[ch * plane + q] = tile.color[p][ch];
                }
                state.transmittance[q] = tile.transmittance[p];
                state.n_contrib[q] = tile.n_contrib[p];
            }
        }
    }
    (image, state)
}

/// Gradient of the loss w.r.t. one splat's projected parameters and its
/// feature: `[d mean_x, d mean_y, d conic_a, d conic_b, d conic_c, d feat_0,
/// d feat_1, d feat_2]` (features past the image's channels get zero).
pub(crate) type SplatGrad = [f32; 8];

/// Where a splat's feature gradient starts in a [`SplatGrad`].
pub(crate) const FEAT_GRAD: usize = 5;

fn tile_backward<const C: usize>(
    splats: &[Splat2D],
    list: &[u32],
    (x0, y0, x1, y1): (usize, usize, usize, usize),
    background: [f32; C],
    transmittance: &[f32],
    n_contrib: &[u32],
    grad_color: &[[f32; C]],
) -> Vec<SplatGrad> {
    let tw = x1 - x0 + 1;
    let mut trans = transmittance.to_vec();
    // Colour of everything behind the current splat, divided by the
    // transmittance in front of it (3DGS's `accum_rec`); starts as the background.
    let mut behind = vec![background; trans.len()];
    let mut grads = vec![[0.0f32; 8]; list.len()];
    let last = n_contrib.iter().copied().max().unwrap_or(0) as usize;
    for li in (0..last).rev() {
        let s = &splats[list[li] as usize];
        let [ca, cb, cc] = s.conic;
        let mut g = [0.0f32; 8];
        let (r0, r1) = (y0.max(s.rect[2] as usize), y1.min(s.rect[3] as usize));
        for y in r0..=r1 {
            let (c0, c1) = s.row_span(y, x0, x1);
            for x in c0..=c1 {
                let p = (y - y0) * tw + (x - x0);
                if li as u32 >= n_contrib[p] {
                    continue;
                }
                let Some(a) = s.alpha_at(x as f32 + 0.5, y as f32 + 0.5) else { continue };
                // Undo this splat's factor to get the transmittance in front of it.
                let t = trans[p] / (1.0 - a.alpha);
                trans[p] = t;
                let mut d_alpha = 0.0f32;
                // The splat adds `α T feat` to the pixel (eq. 7), clamped or not.
                let w = a.alpha * t;
                for ch in 0..C {
                    g[FEAT_GRAD + ch] += w * grad_color[p][ch];
                    d_alpha += (s.feat[ch] - behind[p][ch]) * grad_color[p][ch];
                    behind[p][ch] = a.alpha * s.feat[ch] + (1.0 - a.alpha) * behind[p][ch];
                }
                if a.clamped {
                    continue;
                }
                d_alpha *= t;
                let d_q = d_alpha * s.opacity * (-0.5 / (1.0 - EXP_AT_CUTOFF)) * a.gauss;
                let (dx, dy) = (a.dx, a.dy);
                g[0] -= 2.0 * d_q * (ca * dx + cb * dy);
                g[1] -= 2.0 * d_q * (cb * dx + cc * dy);
                g[2] += d_q * dx * dx;
                g[3] += d_q * 2.0 * dx * dy;
                g[4] += d_q * dy * dy;
            }
        }
        grads[li] = g;
    }
    grads
}

/// Backward of [`rasterize`]: per splat gradient of the loss, given the
/// planar image gradient. Deterministic for any thread count: tiles write
/// per-list-entry results, summed per splat in tile order.
pub(crate) fn rasterize_backward<const C: usize>(
    splats: &[Splat2D],
    bins: &Bins,
    width: usize,
    height: usize,
    background: [f32; C],
    state: &RasterState,
    grad_image: &[f32],
) -> Vec<[f64; 8]> {
    let ntiles = bins.tiles_x * bins.tiles_y;
    let plane = width * height;
    let per_entry: Vec<Vec<SplatGrad>> = (0..ntiles)
        .into_par_iter()
        .map(|t| {
            let bounds @ (x0, y0, x1, y1) = tile_bounds(bins, t, width, height);
            let list = &bins.list[bins.ranges[t]..bins.ranges[t + 1]];
            if list.is_empty() {
                return Vec::new();
            }
            let mut trans = Vec::with_capacity(TILE * TILE);
            let mut n_contrib = Vec::with_capacity(TILE * TILE);
            let mut grad_color = Vec::with_capacity(TILE * TILE);
            for y in y0..=y1 {
                for x in x0..=x1 {
                    let q = y * width + x;
                    trans.push(state.transmittance[q]);
                    n_contrib.push(state.n_contrib[q]);
                    grad_color.push(std::array::from_fn::<f32, C, _>(|ch| grad_image[ch * plane + q]));
                }
            }
            tile_backward::<C>(splats, list, bounds, background, &trans, &n_contrib, &grad_color)
        })
        .collect();
    let mut out = vec![[0.0f64; 8]; splats.len()];
    for (t, grads) in per_entry.iter().enumerate() {
        let list = &bins.list[bins.ranges[t]..bins.ranges[t + 1]];
        for (&gi, g) in list.iter().zip(grads) {
            let acc = &mut out[gi as usize];
            for k in 0..8 {
                acc[k] += g[k] as f64;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Eq. 7 evaluated the slow way: every splat at every pixel, in depth order.
    fn brute_force<const C: usize>(
        splats: &[Splat2D],
        order: &[u32],
        width: usize,
        height: usize,
        background: [f32; C],
    ) -> Vec<f32> {
        let plane = width * height;
        let mut image = vec![0.0f32; C * plane];
        for y in 0..height {
            for x in 0..width {
                let mut t = 1.0f32;
                let mut c = [0.0f32; C];
                for &i in order {
                    let Some(a) = splats[i as usize].alpha_at(x as f32 + 0.5, y as f32 + 0.5) else {
                        continue;
                    };
                    for ch in 0..C {
                        c[ch] += a.alpha * t * splats[i as usize].feat[ch];
                    }
                    t *= 1.0 - a.alpha;
                    if t < MIN_TRANSMITTANCE {
                        break;
                    }
                }
                for ch in 0..C {
                    image[ch * plane + y * width + x] = c[ch] + t * background[ch];
                }
            }
        }
        image
    }

    fn random_splats(n: usize, width: usize, height: usize, seed: u64) -> Vec<Splat2D> {
        let r = nst3d_core::gradcheck::pseudo_random(n * 8, seed);
        (0..n)
            .map(|i| {
                let v = &r[i * 8..i * 8 + 8];
                let mean = [(v[0] * 0.6 + 0.5) * width as f32, (v[1] * 0.6 + 0.5) * height as f32];
                // Random elongated covariance: rotate diag(s1², s2²).
                let (s1, s2, th) = (3.0 + 8.0 * v[2].abs(), 0.6 + 0.5 * v[3].abs(), v[4] * 3.0);
                let (c, s) = (th.cos(), th.sin());
                let cov =
                    [c * c * s1 * s1 + s * s * s2 * s2, c * s * (s1 * s1 - s2 * s2), s * s * s1 * s1 + c * c * s2 * s2];
                let det = cov[0] * cov[2] - cov[1] * cov[1];
                let (rx, ry) = (3.0 * cov[0].sqrt(), 3.0 * cov[2].sqrt());
                let clip = |lo: f32, hi: f32, n: usize| {
                    ((lo - 0.5).ceil().max(0.0) as u32, (hi - 0.5).floor().min(n as f32 - 1.0) as u32)
                };
                let (x0, x1) = clip(mean[0] - rx, mean[0] + rx, width);
                let (y0, y1) = clip(mean[1] - ry, mean[1] + ry, height);
                Splat2D {
                    mean,
                    conic: [cov[2] / det, -cov[1] / det, cov[0] / det],
                    opacity: 0.5 + 0.5 * v[5].abs(),
                    feat: [v[6].abs(), v[7].abs(), 0.5, 1.0],
                    rect: [x0, x1, y0, y1],
                }
            })
            .collect()
    }

    #[test]
    fn tiled_matches_brute_force() {
        let (w, h) = (45, 37);
        let splats = random_splats(120, w, h, 7);
        let order: Vec<u32> = (0..splats.len() as u32).collect();
        let bins = bin(&splats, &order, w, h);
        let bg = [0.2, 0.1, 0.3];
        let (tiled, _) = rasterize::<3>(&splats, &bins, w, h, bg);
        let brute = brute_force::<3>(&splats, &order, w, h, bg);
        let err = tiled.iter().zip(&brute).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
        assert!(err < 1e-5, "tiled vs brute force max error {err}");
        assert!(tiled.iter().any(|&v| v > 0.5), "scene should have visible splats");
    }
}
