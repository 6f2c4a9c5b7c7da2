//! Differentiable histogram equalisation (paper eq. 7): `Ĩ = I · cdf(I)`,
//! where `cdf` is the distribution of the grey values of the smoke, black
//! background ignored. Dense smoke renders as flat white patches; scaling by
//! the cdf restores contrast there so the style loss has something to shape.
//!
//! To be differentiable the histogram is soft: each foreground value is split
//! linearly between the two nearest bin centres (a triangle kernel), and the
//! cdf is the exact cumulative of that piecewise-constant density, so it is
//! continuous and piecewise linear in both the value it is evaluated at and
//! every pixel of the histogram. The gradient includes the path through the
//! histogram itself. The range top (the brightest pixel unless fixed) is held
//! constant, like a stop-gradient.

use crate::RenderError;
use nst3d_core::Image;

/// Settings of [`equalize`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EqualizeParams {
    /// Histogram bins between `threshold` and the range top.
    pub bins: usize,
    /// Pixels at or below this are background: not counted, and mapped to 0.
    pub threshold: f32,
    /// Top of the histogram range; `None` uses each channel's brightest
    /// pixel. Pixels above it have `cdf = 1`.
    pub range_max: Option<f32>,
}

impl Default for EqualizeParams {
    fn default() -> Self {
        Self { bins: 256, threshold: 1e-3, range_max: None }
    }
}

/// Soft histogram of one channel.
#[derive(Clone, Debug)]
struct ChannelHist {
    lo: f32,
    delta: f32,
    /// Foreground pixel count `M` (0: channel all background).
    count: f64,
    hist: Vec<f64>,
    /// `prefix[b] = Σ_{j<b} hist[j]`, `bins + 1` entries.
    prefix: Vec<f64>,
}

impl ChannelHist {
    fn bins(&self) -> usize {
        self.hist.len()
    }

    /// Position of `t` in bin-centre units and the lower bin of its split, or
    /// `None` when the pixel is background; `Err(bin)` marks a clamped end bin.
    #[inline]
    fn split(&self, t: f32) -> Option<Result<(usize, f64), usize>> {
        if t <= self.lo {
            return None;
        }
        let u = (t - self.lo) as f64 / self.delta as f64 - 0.5;
        let last = self.bins() - 1;
        Some(if u <= 0.0 {
            Err(0)
        } else if u >= last as f64 {
            Err(last)
        } else {
            let i = u.floor() as usize;
            Ok((i, u - i as f64))
        })
    }

    /// `(cdf(t), bin, fraction)`: `bin = bins` (fraction 0) above the range,
    /// `None` at or below its bottom.
    #[inline]
    fn cdf(&self, t: f32) -> Option<(f64, usize, f64)> {
        let s = (t - self.lo) as f64 / self.delta as f64;
        if s <= 0.0 || self.count == 0.0 {
            return None;
        }
        let b = self.bins();
        if s >= b as f64 {
            return Some((1.0, b, 0.0));
        }
        let k = s.floor() as usize;
        let f = s - k as f64;
        Some(((self.prefix[k] + f * self.hist[k]) / self.count, k, f))
    }
}

/// What [`equalize_backward`] needs from the forward pass.
#[derive(Clone, Debug)]
pub struct EqCache {
    input: Image,
    channels: Vec<ChannelHist>,
}

/// Histogram equalisation `Ĩ = I · cdf(I)` per channel (paper eq. 7).
pub fn equalize(img: &Image, params: &EqualizeParams) -> Result<(Image, EqCache), RenderError> {
    if params.bins == 0 {
        return Err(RenderError::NoBins);
    }
    if !params.threshold.is_finite() {
        return Err(RenderError::BadThreshold(params.threshold));
    }
    if let Some(top) = params.range_max {
        if !(top > params.threshold && top.is_finite()) {
            return Err(RenderError::BadRange { top, threshold: params.threshold });
        }
    }
    let lo = params.threshold;
    let mut out = Image::zeros(img.channels, img.height, img.width);
    let mut channels = Vec::with_capacity(img.channels);
    for c in 0..img.channels {
        let plane = img.channel(c);
        let top = params.range_max.unwrap_or_else(|| plane.iter().copied().fold(lo, f32::max));
        let mut h = ChannelHist {
            lo,
            delta: (top - lo) / params.bins as f32,
            count: 0.0,
            hist: vec![0.0; params.bins],
            prefix: vec![0.0; params.bins + 1],
        };
        if top > lo {
            for &t in plane {
                match h.split(t) {
                    None => {}
                    Some(Err(b)) => h.hist[b] += 1.0,
                    Some(Ok((i, w))) => {
                        h.hist[i] += 1.0 - w;
                        h.hist[i + 1] += w;
                    }
                }
            }
            h.count = plane.iter().filter(|&&t| t > lo).count() as f64;
            for b in 0..params.bins {
                h.prefix[b + 1] = h.prefix[b] + h.hist[b];
            }
        }
        let dst = &mut out.data[c * img.plane()..][..img.plane()];
        for (d, &t) in dst.iter_mut().zip(plane) {
            *d = h.cdf(t).map_or(0.0, |(cdf, _, _)| (t as f64 * cdf) as f32);
        }
        channels.push(h);
    }
    Ok((out, EqCache { input: img.clone(), channels }))
}

/// Backward of [`equalize`]: `∂L/∂I` for `grad_out = ∂L/∂Ĩ`, through both the
/// pixel's own cdf lookup and the histogram every foreground pixel builds.
///
/// # Panics
/// If `grad_out` does not have the equalised image's shape.
pub fn equalize_backward(cache: &EqCache, grad_out: &Image) -> Image {
    let img = &cache.input;
    assert!(
        grad_out.channels == img.channels && grad_out.height == img.height && grad_out.width == img.width,
        "equalize_backward: gradient shape differs from the image"
    );
    let mut grad = Image::zeros(img.channels, img.height, img.width);
    for (c, h) in cache.channels.iter().enumerate() {
        let plane = img.channel(c);
        let g_plane = grad_out.channel(c);
        let bins = h.bins();
        // Adjoint of the cdf lookups w.r.t. the histogram: a lookup in bin k
        // reads every bin below k fully (`below[k]`) and bin k by its fraction.
        let mut below = vec![0f64; bins + 1];
        let mut partial = vec![0f64; bins];
        let dst = &mut grad.data[c * img.plane()..][..img.plane()];
        for ((d, &t), &g) in dst.iter_mut().zip(plane).zip(g_plane) {
            if let Some((cdf, k, f)) = h.cdf(t) {
                let a = g as f64 * t as f64 / h.count;
                below[k] += a;
                if k < bins {
                    partial[k] += a * f;
                    // Own lookup: d(t · cdf(t))/dt = cdf + t · hist[k] / (M Δ).
                    *d = (g as f64 * (cdf + t as f64 * h.hist[k] / (h.count * h.delta as f64))) as f32;
                } else {
                    *d = g;
                }
            }
        }
        // grad_hist[j] = Σ_{k>j} below[k] + partial[j].
        let mut grad_hist = vec![0f64; bins];
        let mut suffix = 0f64;
        for j in (0..bins).rev() {
            suffix += below[j + 1];
            grad_hist[j] = suffix + partial[j];
        }
        // Each interior foreground pixel moves mass between its two bins at rate 1/Δ.
        for (d, &t) in dst.iter_mut().zip(plane) {
            if let Some(Ok((i, _))) = h.split(t) {
                *d += ((grad_hist[i + 1] - grad_hist[i]) / h.delta as f64) as f32;
            }
        }
    }
    grad
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::{check_gradient, dot, pseudo_random};

    #[test]
    fn bright_flat_region_gains_contrast() {
        // Mostly-white smoke with a few darker pixels and background.
        let mut v = vec![0.0f32; 20];
        v[5..15].iter_mut().enumerate().for_each(|(i, x)| *x = 0.9 + 0.01 * i as f32);
        v[15..18].copy_from_slice(&[0.2, 0.3, 0.4]);
        let img = Image::from_vec(1, 4, 5, v);
        let (out, _) = equalize(&img, &EqualizeParams { bins: 32, ..Default::default() }).unwrap();
        assert_eq!(out.data[0], 0.0);
        // The brightest pixel keeps its value (cdf = 1), darker ones are pushed down.
        assert!((out.data[14] - img.data[14]).abs() < 1e-6);
        assert!(out.data[5] < 0.5 * img.data[5]);
        assert!(out.data.windows(2).skip(5).take(9).all(|w| w[1] > w[0]));
    }

    #[test]
    fn equalize_gradient_check() {
        // Values at quarter-bin offsets keep finite differences away from the
        // kinks at bin edges (cdf) and bin centres (soft histogram).
        let bins = 16;
        let (lo, top) = (0.05f32, 1.05f32);
        let delta = (top - lo) / bins as f32;
        let r = pseudo_random(64, 31);
        let data: Vec<f32> = r
            .iter()
            .enumerate()
            .map(|(i, x)| {
                if i % 9 == 0 {
                    0.0 // background
                } else {
                    let b = ((x * 0.5 + 0.5) * (bins as f32 + 1.0)).floor();
                    lo + (b + if i % 2 == 0 { 0.25 } else { 0.75 }) * delta
                }
            })
            .collect();
        let params = EqualizeParams { bins, threshold: lo, range_max: Some(top) };
        let img = Image::from_vec(1, 8, 8, data);
        let w = pseudo_random(64, 32);
        let (_, cache) = equalize(&img, &params).unwrap();
        let grad = equalize_backward(&cache, &Image::from_vec(1, 8, 8, w.clone()));
        let res = check_gradient(
            &img.data,
            &grad.data,
            |x| dot(&w, &equalize(&Image::from_vec(1, 8, 8, x.to_vec()), &params).unwrap().0.data),
            1e-3,
            64,
            1e-2,
        );
        assert!(res.max_rel_err < 5e-3, "{res:?}");
    }

    #[test]
    fn bad_params_are_errors() {
        let img = Image::zeros(1, 2, 2);
        assert!(equalize(&img, &EqualizeParams { bins: 0, ..Default::default() }).is_err());
        let p = EqualizeParams { range_max: Some(0.0), ..Default::default() };
        assert!(equalize(&img, &p).is_err());
    }
}
