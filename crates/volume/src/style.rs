//! The painting as the loss sees it, and the network that sees it.

use anyhow::Result;
use nst3d_core::Image;
use nst3d_features::Vgg19;
use nst3d_stylize::ViewLoss;

use crate::settings::VolumeSettings;

/// The painting at `style_scale` (its luminance, unless `style_color` or
/// `color`: without `color` the renderer draws grey smoke, which cannot
/// reach colour Grams) and VGG-19.
pub fn load_style_and_vgg(s: &VolumeSettings) -> Result<(Image, Vgg19)> {
    let style = nst3d_io::image::load_style(&s.style, s.style_scale)?;
    let style = if s.style_color || s.color { style } else { nst3d_io::image::luminance_rgb(&style) };
    Ok((style, Vgg19::load(s.weights.as_deref())?))
}

/// A style map's paintings in the map's order (`style`, then
/// `more_styles`), each at `style_scale`, with the loss that matches it:
/// in colour where `in_color` (the colour stage's), else in luminance
/// (in colour with `style_color`, unless `color` asks for a colour stage:
/// then the density follows the luminance, as with one painting).
pub fn load_paintings<'a>(
    s: &VolumeSettings,
    vgg: &'a Vgg19,
    in_color: bool,
) -> Result<(Vec<Image>, Vec<ViewLoss<'a>>)> {
    let keep_color = in_color || (s.style_color && !s.color);
    let mut pictures = Vec::new();
    let mut losses = Vec::new();
    for p in &s.styles() {
        let picture = nst3d_io::image::load_style(p, s.style_scale)?;
        let picture = if keep_color { picture } else { nst3d_io::image::luminance_rgb(&picture) };
        losses.push(ViewLoss::new(vgg, &picture, &s.style_spec())?);
        pictures.push(picture);
    }
    Ok((pictures, losses))
}
