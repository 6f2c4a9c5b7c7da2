//! A judge of how far a groom went towards a painting, apart
//! from the optimised loss: the real VGG-19 Gram style loss (relu1_1 …
//! relu4_1, equal weights, as Gatys et al. and the volume pipeline's
//! judge) of each picture `nst3d preview` draws, to the painting's
//! luminance at the picture's height. It reads files only, so it scores any
//! groom the same way, from views no optimisation used (a turntable around
//! the up axis at an elevation of your choosing). With colour, pictures in
//! the grooms' own colours are judged against the painting in colour.

use std::path::Path;

use anyhow::Result;
use nst3d_core::{FeatureView, Image};
use nst3d_features::{Vgg19, VggLayer};
use nst3d_io::image::{luminance_rgb, resize_to_height};
use nst3d_loss::{cell_mask, style_loss, style_loss_masked, StyleTarget};

/// Median as the judges report it (the mean of the middle two for an even count).
pub use nst3d_core::stats::median;

/// Gram matrices of a painting, for scoring pictures of one height.
pub struct GramJudge {
    vgg: Vgg19,
    target: StyleTarget,
    /// The painting's mean luminance, the brightness
    /// [`GramJudge::toned_hair_loss`] gives the hair before scoring it.
    tone: f32,
}

const LAYERS: [VggLayer; 4] = [VggLayer::Relu1_1, VggLayer::Relu2_1, VggLayer::Relu3_1, VggLayer::Relu4_1];

impl GramJudge {
    /// The painting at `style`, as grey, resized to `height` rows (the
    /// pictures' height: its strokes keep their size relative to the frame).
    pub fn new(style: &Path, height: usize, weights: Option<&Path>) -> Result<Self> {
        Self::with_color(style, height, weights, false)
    }

    /// [`GramJudge::new`], with `color` the painting in its colours (issue
    /// 29's colour judge: pictures drawn in the grooms' colours against the
    /// painting's RGB Gram matrices).
    pub fn with_color(style: &Path, height: usize, weights: Option<&Path>, color: bool) -> Result<Self> {
        let painting = nst3d_io::image::load_style(style, 1.0)?;
        let vgg = Vgg19::load(weights)?;
        let src = if color { painting } else { luminance_rgb(&painting) };
        let grey = resize_to_height(&src, height);
        let fwd = vgg.forward(&grey, &LAYERS, false);
        let target = StyleTarget::from_features(&fwd.features(), &[1.0; 4])?;
        let tone = mean_luma(&grey, |_| true);
        Ok(Self { vgg, target, tone })
    }

    /// The Gram style loss of a picture (RGB or grey) to the painting.
    pub fn loss(&self, picture: &Image) -> Result<f32> {
        let fwd = self.vgg.forward(&as_rgb(picture), &LAYERS, false);
        Ok(style_loss(&fwd.features(), &self.target)?.0)
    }

    /// [`GramJudge::loss`] over the hair only: each layer's Gram matrix
    /// summed over the cells that hold hair (a picture pixel off the black
    /// background by more than 0.02, as the pipeline's hair-only NNST loss
    /// counts) and divided by their count. The background, the same in
    /// every groom's picture, is where no colour can reach; it dilutes the
    /// whole-picture loss (the colour judge reports both). `None`
    /// when the picture shows no hair.
    pub fn hair_loss(&self, picture: &Image) -> Result<Option<f32>> {
        Ok(self.scores(picture)?.1)
    }

    /// [`GramJudge::loss`] and [`GramJudge::hair_loss`] of one picture from
    /// one VGG-19 forward.
    pub fn scores(&self, picture: &Image) -> Result<(f32, Option<f32>)> {
        let rgb = as_rgb(picture);
        let fwd = self.vgg.forward(&rgb, &LAYERS, false);
        let whole = style_loss(&fwd.features(), &self.target)?.0;
        let hair = nst3d_strands::pipeline::hair_pixels(&rgb, [0.0; 3]);
        let masks: Vec<Vec<bool>> =
            fwd.taps().iter().map(|t| cell_mask(&hair, rgb.height, rgb.width, t.height, t.width)).collect();
        if masks.iter().any(|m| !m.contains(&true)) {
            return Ok((whole, None));
        }
        let views: Vec<FeatureView<'_>> = fwd.taps().iter().map(FeatureView::from).collect();
        Ok((whole, Some(style_loss_masked(&views, &masks, &self.target)?.0)))
    }

    /// [`GramJudge::hair_loss`] of the picture with its hair brightened or
    /// darkened (one gain, clamped to 1) to the painting's mean luminance.
    ///
    /// Why: the Gram loss mixes tone with texture. A groom's shape cannot
    /// change its pictures' tone (the shading is fixed root to tip), yet
    /// the plain hair-only loss of the *unstylized* input darkened to half
    /// scores 0.34–0.38 of the input's with Starry Night and 0.16–0.17
    /// with Shipwreck and Woman with a Hat (docs/design/strands.md, "Judging the
    /// judge"). With every picture's hair at the painting's tone, a darker
    /// or brighter copy of the input scores near 1 (0.85–0.98 on a real
    /// picture, where faint pixels leave the hair mask and bright ones clip;
    /// exactly 1 where neither happens) and what is left is mostly the
    /// hair's structure.
    pub fn toned_hair_loss(&self, picture: &Image) -> Result<Option<f32>> {
        let rgb = as_rgb(picture);
        let hair = nst3d_strands::pipeline::hair_pixels(&rgb, [0.0; 3]);
        let mean = mean_luma(&rgb, |i| hair[i]);
        if mean <= 0.0 {
            return Ok(None);
        }
        let gain = self.tone / mean;
        let mut toned = rgb;
        toned.data.iter_mut().for_each(|v| *v = (*v * gain).min(1.0));
        self.hair_loss(&toned)
    }
}

/// Mean luminance of an RGB picture over the pixels `keep` selects (0 for none).
fn mean_luma(rgb: &Image, keep: impl Fn(usize) -> bool) -> f32 {
    let n = rgb.height * rgb.width;
    let (mut sum, mut count) = (0.0f64, 0usize);
    for i in (0..n).filter(|&i| keep(i)) {
        sum += (0..3).map(|c| nst3d_core::image::LUMA[c] * rgb.data[c * n + i]).sum::<f32>() as f64;
        count += 1;
    }
    if count == 0 {
        0.0
    } else {
        (sum / count as f64) as f32
    }
}

/// A grey picture as three equal channels; an RGB one as it is.
fn as_rgb(picture: &Image) -> Image {
    if picture.channels == 1 {
        Image::from_vec(3, picture.height, picture.width, [picture.data.as_slice(); 3].concat())
    } else {
        picture.clone()
    }
}
