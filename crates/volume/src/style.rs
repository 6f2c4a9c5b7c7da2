//! The painting as the loss sees it, and the network that sees it.

use anyhow::Result;
use nst3d_core::Image;
use nst3d_features::Vgg19;

use crate::settings::VolumeSettings;

/// The painting at `style_scale` (its luminance, unless `style_color` or
/// `color`: without `color` the renderer draws grey smoke, which cannot
/// reach colour Grams) and VGG-19.
pub fn load_style_and_vgg(s: &VolumeSettings) -> Result<(Image, Vgg19)> {
    let style = nst3d_io::image::load_style(&s.style, s.style_scale)?;
    let style = if s.style_color || s.color { style } else { nst3d_io::image::luminance_rgb(&style) };
    Ok((style, Vgg19::load(s.weights.as_deref())?))
}
