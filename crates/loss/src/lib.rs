//! Gram-matrix style loss (Gatys et al.), the objective of volumetric style
//! transfer (paper Sec. 3): the renders of the stylized smoke must carry the
//! style image's VGG-19 feature correlations at a few layers.
//!
//! Everything mirrors `../shared/bench/torch_ref.py`:
//! `gram(f) = F Fᵀ / (h·w)` with `F` the `C x (h·w)` feature matrix, and the
//! loss is `Σ_l w_l · F.mse_loss(gram(F_l), G_l)`.
//!
//! Each differentiable op has its backward right after its forward.

#![warn(missing_docs)]

mod gram_bf16;
pub mod nnst;

use nst3d_core::linalg::{matmul, matmul_into, parallelism, Parallelism};
use nst3d_core::{precision, FeatureView, Layout};
use rayon::prelude::*;

/// Why a style target or style loss could not be built from the given inputs.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum LossError {
    /// The per-layer weight list does not have one weight per feature layer.
    #[error("style weights: got {weights} weights for {layers} feature layers")]
    WeightCount {
        /// Number of weights given.
        weights: usize,
        /// Number of feature layers.
        layers: usize,
    },
    /// A style weight is NaN or infinite.
    #[error("style weight of layer {layer} is not finite ({value})")]
    NonFiniteWeight {
        /// Layer index.
        layer: usize,
        /// The offending weight.
        value: f32,
    },
    /// The features to score do not have as many layers as the target.
    #[error("style loss: got {got} feature layers, the style target has {expected}")]
    LayerCount {
        /// Layers passed in.
        got: usize,
        /// Layers in the target.
        expected: usize,
    },
    /// A feature layer has a different channel count than the target's Gram.
    #[error("style loss: layer {layer} has {got} channels, the style target has {expected}")]
    ChannelCount {
        /// Layer index.
        layer: usize,
        /// Channels of the features passed in.
        got: usize,
        /// Channels of the target layer.
        expected: usize,
    },
    /// A feature layer has no pixels, so its Gram matrix (divided by `h·w`) is undefined.
    #[error("feature layer {layer} is empty ({channels} x {height} x {width})")]
    EmptyLayer {
        /// Layer index.
        layer: usize,
        /// Channels.
        channels: usize,
        /// Rows.
        height: usize,
        /// Columns.
        width: usize,
    },
}

/// Upper bound on the pixel chunks of [`gram`]; enough to keep two to eight
/// threads busy without many partial Grams to sum.
const MAX_GRAM_CHUNKS: usize = 8;

/// Gram matrix `G = F Fᵀ / (h·w)` of a layer's features, `F` the `C x (h·w)`
/// matrix of `f` in whichever layout it lies: symmetric `C x C`, row-major.
///
/// Dividing by the pixel count (not by `C·h·w`) matches the reference, so the
/// same style weights mean the same thing in both. An empty map (no pixels)
/// gives an all-zero Gram. Channels-last features (the network's own layout)
/// are the fast case: both operands of the product then stream contiguously,
/// where planar ones make `gemm` repack a transposed operand (2-3x slower at
/// relu1_1, docs/design/performance.md).
pub fn gram(f: FeatureView<'_>) -> Vec<f32> {
    let (c, p) = (f.channels, f.pixels());
    if p == 0 {
        return vec![0.0; c * c];
    }
    let scale = 1.0 / p as f32;
    if let Some(k) = precision::path().kernel() {
        return gram_bf16::gram(k, f, scale);
    }
    let (_, col) = f.strides();
    // Shallow layers are C x C outputs over a very long k = h·w (64 x 256² at
    // relu1_1): too few output tiles for gemm to spread over threads, so the
    // pixels are split into column chunks whose partial Grams are summed. The
    // chunk count depends on the shape only, so results do not change with
    // the thread count.
    let chunks = (p / c.max(256)).clamp(1, MAX_GRAM_CHUNKS);
    let mut g = if chunks == 1 {
        upper_gram(c, p, f.data, f.strides(), scale, parallelism(c, c, p))
    } else {
        let width = p.div_ceil(chunks);
        (0..chunks)
            .into_par_iter()
            .map(|i| {
                let (k0, k1) = (i * width, ((i + 1) * width).min(p));
                upper_gram(c, k1 - k0, &f.data[k0 * col..], f.strides(), scale, Parallelism::None)
            })
            .collect::<Vec<_>>()
            .into_iter()
            // Summed in chunk order (not rayon's reduce tree) for the
            // thread-count independence promised above.
            .reduce(|mut a, b| {
                a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                a
            })
            .expect("at least one chunk")
    };
    // Mirror the upper triangle: G is exactly symmetric, which the loss relies on.
    for i in 0..c {
        for j in i + 1..c {
            g[j * c + i] = g[i * c + j];
        }
    }
    g
}

/// The upper triangle (and diagonal blocks) of `scale · F Fᵀ` for the
/// `c x k` matrix `F` whose element `(i, p)` is `data[i * row + p * col]`;
/// the strictly lower part of whole blocks below the diagonal is left 0.
///
/// A Gram matrix is symmetric, so only the row bands' right parts are
/// multiplied: with 8 bands that is 36/64 of the full product.
fn upper_gram(c: usize, k: usize, data: &[f32], (row, col): (usize, usize), scale: f32, par: Parallelism) -> Vec<f32> {
    let band = (c / 8).max(32);
    let mut g = vec![0.0; c * c];
    for r0 in (0..c).step_by(band) {
        let (m, n) = ((c - r0).min(band), c - r0);
        // Rows r0.. of F, and the same rows seen as the columns of Fᵀ.
        let rows = &data[r0 * row..];
        matmul_into(m, n, k, &mut g[r0 * c + r0..], c, false, rows, (row, col), rows, (col, row), scale, par);
    }
    g
}

/// Backward of [`gram`]: `dL/dF = (dG + dGᵀ) F / (h·w)` for an upstream
/// gradient `grad_g` (`C x C`, row-major, not necessarily symmetric),
/// returned in `f`'s layout.
///
/// # Panics
/// If `grad_g` is not `C x C` (a programming error: it comes from [`gram`]'s output).
pub fn gram_backward(f: FeatureView<'_>, grad_g: &[f32]) -> Vec<f32> {
    let (c, p) = (f.channels, f.pixels());
    assert_eq!(grad_g.len(), c * c, "gram_backward: grad_g must be C x C");
    let mut sym = vec![0.0; c * c];
    for i in 0..c {
        for j in 0..c {
            sym[i * c + j] = grad_g[i * c + j] + grad_g[j * c + i];
        }
    }
    if p > 0 && f.layout == Layout::ChannelsLast {
        if let Some(k) = precision::path().kernel() {
            return gram_bf16::gram_backward_channels_last(k, f, &sym, 1.0 / p as f32);
        }
    }
    let mut out = vec![0.0; c * p];
    if p > 0 {
        let par = parallelism(c, p, c);
        let scale = 1.0 / p as f32;
        match f.layout {
            // dF (C x P) = sym F.
            Layout::Planar => matmul(c, p, c, &mut out, &sym, (c, 1), f.data, (p, 1), scale, par),
            // dFᵀ (P x C) = Fᵀ symᵀ = Fᵀ sym.
            Layout::ChannelsLast => matmul(p, c, c, &mut out, f.data, (c, 1), &sym, (c, 1), scale, par),
        }
    }
    out
}

/// `mean((a - b)²)`, PyTorch's `F.mse_loss` with the default mean reduction
/// (0 for empty inputs).
///
/// The sum is accumulated in `f64`, over 8 interleaved lanes added in a
/// fixed order (8 independent chains, the same bits on every run); PyTorch's
/// vectorised `f32` reduction agrees to float rounding.
///
/// # Panics
/// If the lengths differ (a programming error).
pub fn mse(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len(), "mse: operand lengths differ");
    if a.is_empty() {
        return 0.0;
    }
    let sq = |x: f32, y: f32| ((x - y) as f64).powi(2);
    let mut lanes = [0.0f64; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let rest: f64 = ca.remainder().iter().zip(cb.remainder()).map(|(&x, &y)| sq(x, y)).sum();
    for (x, y) in ca.zip(cb) {
        for l in 0..8 {
            lanes[l] += sq(x[l], y[l]);
        }
    }
    ((lanes.iter().sum::<f64>() + rest) / a.len() as f64) as f32
}

/// Gradient of [`mse`] with respect to `a`: `2 (a - b) / n`.
///
/// # Panics
/// If the lengths differ (a programming error).
pub fn mse_backward(a: &[f32], b: &[f32]) -> Vec<f32> {
    assert_eq!(a.len(), b.len(), "mse_backward: operand lengths differ");
    let scale = 2.0 / a.len().max(1) as f32;
    a.iter().zip(b).map(|(x, y)| scale * (x - y)).collect()
}

/// The style image's statistics the stylized renders must match: one Gram
/// matrix per VGG layer (relu1_1 .. relu4_1 in the paper) and its weight.
#[derive(Clone, Debug, PartialEq)]
pub struct StyleTarget {
    grams: Vec<Vec<f32>>,
    channels: Vec<usize>,
    weights: Vec<f32>,
}

impl StyleTarget {
    /// Grams of the style image's features `feats`, one per layer, weighted by
    /// `weights` (one per layer; an empty slice means weight 1 everywhere, as
    /// in the reference).
    pub fn from_features(feats: &[FeatureView<'_>], weights: &[f32]) -> Result<Self, LossError> {
        let weights = if weights.is_empty() {
            vec![1.0; feats.len()]
        } else if weights.len() == feats.len() {
            weights.to_vec()
        } else {
            return Err(LossError::WeightCount { weights: weights.len(), layers: feats.len() });
        };
        if let Some((layer, &value)) = weights.iter().enumerate().find(|(_, w)| !w.is_finite()) {
            return Err(LossError::NonFiniteWeight { layer, value });
        }
        for (layer, f) in feats.iter().enumerate() {
            check_not_empty(layer, f)?;
        }
        Ok(Self {
            grams: feats.iter().map(|f| gram(*f)).collect(),
            channels: feats.iter().map(|f| f.channels).collect(),
            weights,
        })
    }

    /// Number of layers.
    pub fn layers(&self) -> usize {
        self.grams.len()
    }

    /// Target Gram of layer `l` (`C x C`, row-major).
    pub fn gram(&self, l: usize) -> &[f32] {
        &self.grams[l]
    }

    /// Channel count `C` of layer `l`.
    pub fn channels(&self, l: usize) -> usize {
        self.channels[l]
    }

    /// Per-layer weights.
    pub fn weights(&self) -> &[f32] {
        &self.weights
    }
}

fn check_not_empty(layer: usize, f: &FeatureView<'_>) -> Result<(), LossError> {
    if f.pixels() == 0 {
        return Err(LossError::EmptyLayer { layer, channels: f.channels, height: f.height, width: f.width });
    }
    Ok(())
}

/// Style loss `Σ_l w_l · mse(gram(F_l), G_l)` of the render's features `feats`
/// against `target`; returns the loss and `dL/dF_l` for every layer (each in
/// its layer's layout and shape), ready for the feature network's backward pass.
pub fn style_loss(feats: &[FeatureView<'_>], target: &StyleTarget) -> Result<(f32, Vec<Vec<f32>>), LossError> {
    if feats.len() != target.layers() {
        return Err(LossError::LayerCount { got: feats.len(), expected: target.layers() });
    }
    for (layer, f) in feats.iter().enumerate() {
        if f.channels != target.channels[layer] {
            return Err(LossError::ChannelCount { layer, got: f.channels, expected: target.channels[layer] });
        }
        check_not_empty(layer, f)?;
    }
    let mut loss = 0.0f64;
    let mut grads = Vec::with_capacity(feats.len());
    for (l, f) in feats.iter().enumerate() {
        let w = target.weights[l];
        let g = gram(*f);
        loss += w as f64 * mse(&g, &target.grams[l]) as f64;
        let mut grad_g = mse_backward(&g, &target.grams[l]);
        grad_g.iter_mut().for_each(|v| *v *= w);
        grads.push(gram_backward(*f, &grad_g));
    }
    Ok((loss as f32, grads))
}

/// Cells of a `height x width` feature map that hold a marked pixel of a
/// `mask_height x mask_width` picture (row-major both): a picture pixel
/// counts for the cell it falls in.
pub fn cell_mask(pixels: &[bool], mask_height: usize, mask_width: usize, height: usize, width: usize) -> Vec<bool> {
    assert_eq!(pixels.len(), mask_height * mask_width, "one mark per picture pixel");
    let mut cells = vec![false; height * width];
    if height == 0 || width == 0 {
        return cells;
    }
    for y in 0..mask_height {
        let r = (y * height / mask_height).min(height - 1);
        for x in 0..mask_width {
            if pixels[y * mask_width + x] {
                cells[r * width + (x * width / mask_width).min(width - 1)] = true;
            }
        }
    }
    cells
}

/// Cell weights of a `height x width` feature map from per-pixel weights of
/// a `mask_height x mask_width` picture (row-major both): each cell gets the
/// mean weight of the picture pixels that fall in it, the guide downsampled
/// to the layer as Gatys et al. (2017) do for guided Gram matrices.
pub fn cell_weights(pixels: &[f32], mask_height: usize, mask_width: usize, height: usize, width: usize) -> Vec<f32> {
    assert_eq!(pixels.len(), mask_height * mask_width, "one weight per picture pixel");
    let mut sum = vec![0.0f32; height * width];
    let mut count = vec![0u32; height * width];
    if height == 0 || width == 0 {
        return sum;
    }
    for y in 0..mask_height {
        let r = (y * height / mask_height).min(height - 1);
        for x in 0..mask_width {
            let cell = r * width + (x * width / mask_width).min(width - 1);
            sum[cell] += pixels[y * mask_width + x];
            count[cell] += 1;
        }
    }
    sum.iter().zip(&count).map(|(s, &n)| if n > 0 { s / n as f32 } else { 0.0 }).collect()
}

/// [`style_loss`] of the marked cells only: [`style_loss_guided`] with
/// weight 1 on the cells `masks[l]` marks and 0 elsewhere, so a picture's
/// empty background (a groom on black) neither counts nor dilutes the
/// statistics of what is drawn.
pub fn style_loss_masked(
    feats: &[FeatureView<'_>],
    masks: &[Vec<bool>],
    target: &StyleTarget,
) -> Result<(f32, Vec<Vec<f32>>), LossError> {
    let guides: Vec<Vec<f32>> = masks.iter().map(|m| m.iter().map(|&v| if v { 1.0 } else { 0.0 }).collect()).collect();
    style_loss_guided(feats, &guides, target)
}

/// The guided Gram loss of Gatys et al. (2017, "Controlling Perceptual
/// Factors"): each layer's features are multiplied by the region's guide
/// `t_p` (one weight in [0, 1] per cell, row-major over the layer's map)
/// and the Gram matrix is normalised by the region's area `Σ_p t_p²`,
/// `G = Σ_p t_p² f_p f_pᵀ / Σ_p t_p²`, so a region's statistics do not
/// depend on its size. It is [`style_loss`] of the features scaled by
/// `t_p √(P / Σ t²)`, and the backward is the same scale applied to that
/// loss's gradient (the guide is fixed: no gradient flows into it). A layer
/// whose guide is all zero is an error ([`LossError::EmptyLayer`]); with a
/// 0/1 guide it is the loss over the marked cells.
pub fn style_loss_guided(
    feats: &[FeatureView<'_>],
    guides: &[Vec<f32>],
    target: &StyleTarget,
) -> Result<(f32, Vec<Vec<f32>>), LossError> {
    if guides.len() != feats.len() {
        return Err(LossError::LayerCount { got: guides.len(), expected: feats.len() });
    }
    // Per layer: the scale of each cell, `t_p √(P / Σ t²)`.
    let mut scales = Vec::with_capacity(feats.len());
    for (layer, (f, t)) in feats.iter().zip(guides).enumerate() {
        let area: f64 = t.iter().map(|&v| v as f64 * v as f64).sum();
        if t.len() != f.pixels() || !(area > 0.0) {
            return Err(LossError::EmptyLayer { layer, channels: f.channels, height: f.height, width: f.width });
        }
        let s = (f.pixels() as f64 / area).sqrt() as f32;
        scales.push(t.iter().map(|v| v * s).collect::<Vec<f32>>());
    }
    let guided: Vec<Vec<f32>> = feats
        .iter()
        .zip(&scales)
        .map(|(f, s)| {
            let mut v = f.data.to_vec();
            scale_cells(f, s, &mut v);
            v
        })
        .collect();
    let views: Vec<FeatureView<'_>> = feats.iter().zip(&guided).map(|(f, d)| FeatureView { data: d, ..*f }).collect();
    let (loss, mut grads) = style_loss(&views, target)?;
    for ((f, s), g) in feats.iter().zip(&scales).zip(&mut grads) {
        scale_cells(f, s, g);
    }
    Ok((loss, grads))
}

/// Multiplies `values` (laid out as `f`'s features) cell by cell by
/// `scale`, in place and in parallel: no scale per value, which cost an
/// allocation and a pass the size of the features for every region.
fn scale_cells(f: &FeatureView<'_>, scale: &[f32], values: &mut [f32]) {
    use rayon::prelude::*;
    match f.strides() {
        // Planar: each channel's plane is one row of cells.
        (_, 1) => values.par_chunks_mut(f.pixels()).for_each(|v| v.iter_mut().zip(scale).for_each(|(v, s)| *v *= s)),
        // Channels last: each cell's channels are contiguous.
        (_, c) => values.par_chunks_mut(c).zip(scale.par_iter()).for_each(|(v, s)| v.iter_mut().for_each(|v| *v *= s)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::{check_gradient, dot, pseudo_random};
    use nst3d_core::Image;

    fn views(images: &[Image]) -> Vec<FeatureView<'_>> {
        images.iter().map(FeatureView::from).collect()
    }

    /// The same values transposed to channels-last `(H, W, C)`.
    fn channels_last(f: &Image) -> Vec<f32> {
        let p = f.plane();
        (0..p * f.channels).map(|k| f.data[(k % f.channels) * p + k / f.channels]).collect()
    }

    fn image(c: usize, h: usize, w: usize, seed: u64) -> Image {
        Image::from_vec(c, h, w, pseudo_random(c * h * w, seed))
    }

    /// Plain triple loop in f64: the definition, to check the gemm call's strides.
    fn gram_naive(f: &Image) -> Vec<f64> {
        let (c, p) = (f.channels, f.plane());
        let mut g = vec![0.0; c * c];
        for i in 0..c {
            for j in 0..c {
                let s: f64 = f.channel(i).iter().zip(f.channel(j)).map(|(a, b)| *a as f64 * *b as f64).sum();
                g[i * c + j] = s / p as f64;
            }
        }
        g
    }

    #[test]
    fn gram_matches_definition_and_is_symmetric() {
        nst3d_core::precision::fp32(|| {
            // One small (single-threaded path) and one above the parallel threshold.
            for (c, h, w) in [(5, 3, 7), (40, 30, 33)] {
                let f = image(c, h, w, 3);
                let g = gram((&f).into());
                let want = gram_naive(&f);
                for (a, b) in g.iter().zip(&want) {
                    assert!((*a as f64 - b).abs() < 1e-5, "{a} vs {b}");
                }
                for i in 0..c {
                    for j in 0..c {
                        assert_eq!(g[i * c + j], g[j * c + i]);
                    }
                }
            }
        })
    }

    #[test]
    fn gram_backward_gradcheck_nonsymmetric_upstream() {
        nst3d_core::precision::fp32(|| {
            let f = image(6, 4, 5, 11);
            let wgt = pseudo_random(36, 12); // not symmetric: exercises dG + dGᵀ
            let analytic = gram_backward((&f).into(), &wgt);
            let probe = |x: &[f32]| dot(&wgt, &gram((&Image::from_vec(6, 4, 5, x.to_vec())).into()));
            let r = check_gradient(&f.data, &analytic, probe, 1e-2, 120, 1e-3);
            assert!(r.max_rel_err < 1e-2, "{r:?}");
        })
    }

    /// Channels-last features give the planar Gram and the planar gradient
    /// transposed (the forward is checked against the definition above and
    /// the backward by finite differences, so this covers both layouts).
    #[test]
    fn channels_last_matches_planar() {
        nst3d_core::precision::fp32(|| {
            // Small, and chunked over pixels with several row bands.
            for (c, h, w) in [(6, 4, 5), (96, 40, 33)] {
                let f = image(c, h, w, 21);
                let cl = channels_last(&f);
                let view = FeatureView { channels: c, height: h, width: w, layout: Layout::ChannelsLast, data: &cl };
                let (gp, gc) = (gram((&f).into()), gram(view));
                for (a, b) in gp.iter().zip(&gc) {
                    assert!((a - b).abs() <= 1e-5 * (1.0 + a.abs()), "gram {a} vs {b}");
                }
                let wgt = pseudo_random(c * c, 22);
                let planar = Image::from_vec(c, h, w, gram_backward((&f).into(), &wgt));
                for (a, b) in channels_last(&planar).iter().zip(&gram_backward(view, &wgt)) {
                    assert!((a - b).abs() <= 1e-5 * (1.0 + a.abs()), "gram_backward {a} vs {b}");
                }
            }
        })
    }

    /// The masked loss's gradient by finite differences (planar and
    /// channels-last), and with every cell marked it is the plain loss.
    #[test]
    fn style_loss_masked_gradcheck_and_full_mask() {
        nst3d_core::precision::fp32(|| {
            let shapes = [(4, 5, 6), (8, 3, 4)];
            let style: Vec<Image> =
                shapes.iter().enumerate().map(|(i, &(c, h, w))| image(c, h, w, 300 + i as u64)).collect();
            let target = StyleTarget::from_features(&views(&style), &[1.0, 2.0]).unwrap();
            let feats: Vec<Image> =
                shapes.iter().enumerate().map(|(i, &(c, h, w))| image(c, h, w, 400 + i as u64)).collect();
            let pixels: Vec<bool> = (0..10 * 12).map(|i| i / 12 < 8 && i % 12 < 7 && i % 5 != 0).collect();
            let masks: Vec<Vec<bool>> = shapes.iter().map(|&(_, h, w)| cell_mask(&pixels, 10, 12, h, w)).collect();
            assert!(masks.iter().all(|m| m.iter().any(|&v| !v)), "some cells unmarked");
            let (_, grads) = style_loss_masked(&views(&feats), &masks, &target).unwrap();
            for l in 0..shapes.len() {
                let (c, h, w) = shapes[l];
                let probe = |x: &[f32]| {
                    let mut fs = feats.clone();
                    fs[l] = Image::from_vec(c, h, w, x.to_vec());
                    style_loss_masked(&views(&fs), &masks, &target).unwrap().0 as f64
                };
                let r = check_gradient(&feats[l].data, &grads[l], probe, 1e-2, 60, 1e-4);
                assert!(r.max_rel_err < 2e-2, "layer {l}: {r:?}");
                // Unmarked cells get no gradient.
                let p = h * w;
                for (i, &m) in masks[l].iter().enumerate() {
                    if !m {
                        assert!((0..c).all(|ch| grads[l][ch * p + i] == 0.0));
                    }
                }
            }
            // Channels-last: the same loss and the gradient transposed.
            let cl: Vec<Vec<f32>> = feats.iter().map(channels_last).collect();
            let cl_views: Vec<FeatureView<'_>> = feats
                .iter()
                .zip(&cl)
                .map(|(f, d)| FeatureView {
                    channels: f.channels,
                    height: f.height,
                    width: f.width,
                    layout: Layout::ChannelsLast,
                    data: d,
                })
                .collect();
            let (a, _) = style_loss_masked(&views(&feats), &masks, &target).unwrap();
            let (b, gb) = style_loss_masked(&cl_views, &masks, &target).unwrap();
            assert!((a - b).abs() <= 1e-5 * a.abs(), "{a} vs {b}");
            for (l, f) in feats.iter().enumerate() {
                let planar = Image::from_vec(f.channels, f.height, f.width, grads[l].clone());
                for (x, y) in channels_last(&planar).iter().zip(&gb[l]) {
                    assert!((x - y).abs() <= 1e-5 * (1.0 + x.abs()));
                }
            }
            let full: Vec<Vec<bool>> = shapes.iter().map(|&(_, h, w)| vec![true; h * w]).collect();
            let plain = style_loss(&views(&feats), &target).unwrap().0;
            let all = style_loss_masked(&views(&feats), &full, &target).unwrap().0;
            assert!((plain - all).abs() <= 1e-6 * plain.abs(), "{plain} vs {all}");
        })
    }

    /// The guided loss with soft weights: its gradient by finite
    /// differences, and its Gram against the definition
    /// `Σ t² f fᵀ / Σ t²` computed in f64 (no reference framework needed).
    #[test]
    fn style_loss_guided_gradcheck_and_definition() {
        nst3d_core::precision::fp32(|| {
            let shapes = [(4, 5, 6), (8, 3, 4)];
            let style: Vec<Image> =
                shapes.iter().enumerate().map(|(i, &(c, h, w))| image(c, h, w, 500 + i as u64)).collect();
            let target = StyleTarget::from_features(&views(&style), &[1.0, 2.0]).unwrap();
            let feats: Vec<Image> =
                shapes.iter().enumerate().map(|(i, &(c, h, w))| image(c, h, w, 600 + i as u64)).collect();
            // A soft ramp across the picture, 0 on its left quarter.
            let pixels: Vec<f32> = (0..10 * 12).map(|i| ((i % 12) as f32 / 11.0 - 0.25).max(0.0)).collect();
            let guides: Vec<Vec<f32>> = shapes.iter().map(|&(_, h, w)| cell_weights(&pixels, 10, 12, h, w)).collect();
            let (loss, grads) = style_loss_guided(&views(&feats), &guides, &target).unwrap();
            for l in 0..shapes.len() {
                let (c, h, w) = shapes[l];
                let probe = |x: &[f32]| {
                    let mut fs = feats.clone();
                    fs[l] = Image::from_vec(c, h, w, x.to_vec());
                    style_loss_guided(&views(&fs), &guides, &target).unwrap().0 as f64
                };
                let r = check_gradient(&feats[l].data, &grads[l], probe, 1e-2, 60, 1e-4);
                assert!(r.max_rel_err < 2e-2, "layer {l}: {r:?}");
            }
            // The definition: weighted Gram, mse against the target, weighted sum.
            let mut want = 0.0f64;
            for (l, f) in feats.iter().enumerate() {
                let (c, t) = (f.channels, &guides[l]);
                let area: f64 = t.iter().map(|&v| (v as f64).powi(2)).sum();
                let mut sq = 0.0;
                for i in 0..c {
                    for j in 0..c {
                        let g: f64 = (0..f.plane())
                            .map(|p| (t[p] as f64).powi(2) * f.channel(i)[p] as f64 * f.channel(j)[p] as f64)
                            .sum::<f64>()
                            / area;
                        sq += (g - target.gram(l)[i * c + j] as f64).powi(2);
                    }
                }
                want += target.weights()[l] as f64 * sq / (c * c) as f64;
            }
            assert!((loss as f64 - want).abs() <= 1e-4 * want, "{loss} vs {want}");
            // A uniform guide is the plain loss, whatever its level.
            let half: Vec<Vec<f32>> = shapes.iter().map(|&(_, h, w)| vec![0.5; h * w]).collect();
            let plain = style_loss(&views(&feats), &target).unwrap().0;
            let guided = style_loss_guided(&views(&feats), &half, &target).unwrap().0;
            assert!((plain - guided).abs() <= 1e-5 * plain, "{plain} vs {guided}");
            let zero: Vec<Vec<f32>> = shapes.iter().map(|&(_, h, w)| vec![0.0; h * w]).collect();
            assert!(matches!(style_loss_guided(&views(&feats), &zero, &target), Err(LossError::EmptyLayer { .. })));
        })
    }

    #[test]
    fn mse_backward_gradcheck() {
        nst3d_core::precision::fp32(|| {
            let a = pseudo_random(30, 1);
            let b = pseudo_random(30, 2);
            let analytic = mse_backward(&a, &b);
            let r = check_gradient(&a, &analytic, |x| mse(x, &b) as f64, 1e-2, 30, 1e-3);
            assert!(r.max_rel_err < 1e-2, "{r:?}");
        })
    }

    #[test]
    fn style_loss_gradcheck_several_layers() {
        nst3d_core::precision::fp32(|| {
            let shapes = [(4, 5, 6), (8, 3, 4), (3, 2, 9)];
            let style: Vec<Image> =
                shapes.iter().enumerate().map(|(i, &(c, h, w))| image(c, h, w, 100 + i as u64)).collect();
            let target = StyleTarget::from_features(&views(&style), &[1.0, 0.5, 3.0]).unwrap();
            let feats: Vec<Image> =
                shapes.iter().enumerate().map(|(i, &(c, h, w))| image(c, h, w, 200 + i as u64)).collect();
            let (_, grads) = style_loss(&views(&feats), &target).unwrap();
            // Perturb one layer at a time, the others held fixed.
            for l in 0..shapes.len() {
                let (c, h, w) = shapes[l];
                let probe = |x: &[f32]| {
                    let mut fs = feats.clone();
                    fs[l] = Image::from_vec(c, h, w, x.to_vec());
                    style_loss(&views(&fs), &target).unwrap().0 as f64
                };
                let r = check_gradient(&feats[l].data, &grads[l], probe, 1e-2, 60, 1e-4);
                assert!(r.max_rel_err < 2e-2, "layer {l}: {r:?}");
            }
        })
    }

    #[test]
    fn style_loss_is_zero_at_target() {
        nst3d_core::precision::fp32(|| {
            let style = vec![image(4, 3, 3, 1), image(2, 5, 2, 2)];
            let target = StyleTarget::from_features(&views(&style), &[]).unwrap();
            let (loss, grads) = style_loss(&views(&style), &target).unwrap();
            assert_eq!(loss, 0.0);
            assert!(grads.iter().all(|g| g.iter().all(|v| *v == 0.0)));
        })
    }

    #[test]
    fn bad_inputs_are_errors() {
        nst3d_core::precision::fp32(|| {
            let style = vec![image(4, 3, 3, 1), image(2, 5, 2, 2)];
            assert_eq!(
                StyleTarget::from_features(&views(&style), &[1.0]),
                Err(LossError::WeightCount { weights: 1, layers: 2 })
            );
            assert!(matches!(
                StyleTarget::from_features(&views(&style), &[1.0, f32::NAN]),
                Err(LossError::NonFiniteWeight { layer: 1, .. })
            ));
            assert!(matches!(
                StyleTarget::from_features(&views(&[Image::zeros(3, 0, 4)]), &[]),
                Err(LossError::EmptyLayer { layer: 0, .. })
            ));
            let target = StyleTarget::from_features(&views(&style), &[]).unwrap();
            assert_eq!(
                style_loss(&views(&style[..1]), &target).unwrap_err(),
                LossError::LayerCount { got: 1, expected: 2 }
            );
            let wrong = vec![style[0].clone(), image(3, 5, 2, 2)];
            assert_eq!(
                style_loss(&views(&wrong), &target).unwrap_err(),
                LossError::ChannelCount { layer: 1, got: 3, expected: 2 }
            );
            // Error messages are one line and name the problem.
            let msg = LossError::WeightCount { weights: 1, layers: 2 }.to_string();
            assert!(!msg.contains('\n') && msg.contains("weights"));
        })
    }

    /// bf16 Gram and its backward, every kernel here, both layouts, channel
    /// counts and pixel counts off the block sizes: within bf16's tolerance
    /// of the fp32 reference (0.5 % of the largest value: operands rounded to
    /// 8 mantissa bits, sums in fp32), exactly symmetric, and the same on
    /// every kernel up to summation order.
    #[test]
    fn bf16_gram_and_backward_match_fp32() {
        use nst3d_core::bf16::Kernel;
        let max_rel = |a: &[f32], b: &[f32]| {
            let m = b.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            a.iter().zip(b).fold(0.0f32, |e, (x, y)| e.max((x - y).abs())) / m
        };
        for (c, h, w) in [(64, 17, 19), (40, 9, 7), (128, 32, 32)] {
            let f = Image::from_vec(c, h, w, pseudo_random(c * h * w, 5).iter().map(|v| v.max(0.0)).collect());
            let cl = channels_last(&f);
            let grad_g = pseudo_random(c * c, 6);
            let layouts =
                [FeatureView::from(&f), FeatureView { layout: Layout::ChannelsLast, data: &cl, ..(&f).into() }];
            for v in layouts {
                let (g32, d32) = nst3d_core::precision::fp32(|| (gram(v), gram_backward(v, &grad_g)));
                for k in Kernel::all_here() {
                    let scale = 1.0 / v.pixels() as f32;
                    let g16 = gram_bf16::gram(k, v, scale);
                    assert!(
                        max_rel(&g16, &g32) < 5e-3,
                        "{k:?} {c}x{h}x{w} {:?}: gram {}",
                        v.layout,
                        max_rel(&g16, &g32)
                    );
                    assert!((0..c).all(|i| (0..c).all(|j| g16[i * c + j] == g16[j * c + i])));
                    if v.layout == Layout::ChannelsLast {
                        let mut sym = vec![0.0; c * c];
                        for i in 0..c {
                            for j in 0..c {
                                sym[i * c + j] = grad_g[i * c + j] + grad_g[j * c + i];
                            }
                        }
                        let d16 = gram_bf16::gram_backward_channels_last(k, v, &sym, scale);
                        assert!(max_rel(&d16, &d32) < 5e-3, "{k:?} {c}x{h}x{w}: backward {}", max_rel(&d16, &d32));
                    }
                }
                let via_setting = nst3d_core::precision::scoped(nst3d_core::precision::Precision::Bf16, || gram(v));
                assert_ne!(via_setting, g32, "gram under bf16 did not take the bf16 path");
            }
        }
    }
}
