//! How a volume looks to the loss and to the artist: the absorption γ that
//! keeps renders between flat and saturated, the views of a camera set, and
//! the pictures of a density.

use anyhow::{bail, Result};
use nst3d_core::{Grid3, Image};
use nst3d_render::Camera;
use nst3d_stylize::{ViewLoss, ViewSpec};

pub use nst3d_io::image::PREVIEW_HEIGHT;

/// Absorption giving the densest ray an optical depth of 3: dense enough to
/// show shape, thin enough that the image does not flatten to white.
pub fn auto_absorption(d: &Grid3, camera: &Camera) -> Result<f32> {
    match absorption_in_view(d, camera)? {
        Some(g) => Ok(g),
        None => bail!("the density is zero everywhere in view: nothing to stylize"),
    }
}

/// The smallest [`auto_absorption`] over `pairs`; `None` when no smoke is
/// in any view. A camera the renderer refuses is an error.
pub fn smallest_absorption<'a>(pairs: impl Iterator<Item = (&'a Grid3, &'a Camera)>) -> Result<Option<f32>> {
    let mut best: Option<f32> = None;
    for (d, c) in pairs {
        if let Some(g) = absorption_in_view(d, c)? {
            best = Some(best.map_or(g, |b| b.min(g)));
        }
    }
    Ok(best)
}

/// [`auto_absorption`], `None` when no smoke is in view; a camera the
/// renderer refuses is an error (it once read as "zero everywhere").
fn absorption_in_view(d: &Grid3, camera: &Camera) -> Result<Option<f32>> {
    // With γ = 0 the render is the plain column sum of density along each ray.
    let (sums, _) = nst3d_render::render(d, camera, 0.0)?;
    let max = sums.data.iter().copied().fold(0.0f32, f32::max);
    Ok((max > 0.0).then(|| 3.0 / max))
}

/// Absorption from `explicit`, or the smallest [`auto_absorption`] over
/// every density and camera given, so no view of any frame saturates.
pub fn absorption_for<'a>(explicit: Option<f32>, pairs: impl Iterator<Item = (&'a Grid3, &'a Camera)>) -> Result<f32> {
    match explicit {
        Some(g) if g.is_finite() && g > 0.0 => Ok(g),
        Some(g) => bail!("--absorption must be a positive number, got {g}"),
        None => match smallest_absorption(pairs)? {
            Some(g) => Ok(g),
            None => bail!("the density is zero everywhere in view: nothing to stylize"),
        },
    }
}

/// Views for `cameras` with absorption `gamma`.
pub fn views_of(cameras: &[Camera], gamma: f32, equalize: bool) -> Vec<ViewSpec> {
    cameras.iter().map(|c| ViewSpec { camera: Some(*c), gamma, exposure: gamma, equalize }).collect()
}

/// The style loss of a result from each held-out view (`--eval-cameras`),
/// before and after: the judge of docs/design/feedforward.md reads its mean and
/// its worst view.
#[derive(Clone, Debug, PartialEq)]
pub struct HeldOut {
    /// Per view, the input's loss.
    pub before: Vec<f32>,
    /// Per view, the result's loss.
    pub after: Vec<f32>,
}

impl HeldOut {
    /// Per-view losses of `before` and `after` from `views`.
    pub fn measure(loss: &ViewLoss, before: &Grid3, after: &Grid3, views: &[ViewSpec]) -> Result<Self> {
        let each = |d: &Grid3| views.iter().map(|v| Ok(loss.loss(d, v)?)).collect::<Result<Vec<f32>>>();
        Ok(Self { before: each(before)?, after: each(after)? })
    }

    /// [`HeldOut::measure`] in colour: `before` seen white (the grey
    /// picture), `after` with its colour, both by the RGB Gram loss.
    pub fn measure_color(
        loss: &ViewLoss,
        before: &Grid3,
        after: &Grid3,
        color: &[Grid3],
        views: &[ViewSpec],
    ) -> Result<Self> {
        let white = vec![Grid3::from_vec(before.dims, vec![1.0; before.len()]); 3];
        let each =
            |d: &Grid3, c: &[Grid3]| views.iter().map(|v| Ok(loss.loss_color(d, c, v)?)).collect::<Result<Vec<f32>>>();
        Ok(Self { before: each(before, &white)?, after: each(after, color)? })
    }

    /// Mean loss over the views, before and after.
    pub fn means(&self) -> (f32, f32) {
        let mean = |v: &[f32]| v.iter().sum::<f32>() / v.len().max(1) as f32;
        (mean(&self.before), mean(&self.after))
    }

    /// The largest after / before ratio over the views, and its view: the
    /// side from which the result moved least towards the painting.
    pub fn worst(&self) -> (f32, usize) {
        self.before
            .iter()
            .zip(&self.after)
            .map(|(b, a)| if *b > 0.0 { a / b } else { 1.0 })
            .enumerate()
            .fold((f32::NEG_INFINITY, 0), |best, (i, r)| if r > best.0 { (r, i) } else { best })
    }
}

/// The picture an artist sees of a density: the network's grey image, 2x.
pub fn display(loss: &ViewLoss, d: &Grid3, view: &ViewSpec) -> Result<Image> {
    Ok(nst3d_render::upsample2x(&loss.image(d, view)?))
}

/// The picture an artist sees: the rendered light `Σ d·τ` scaled by γ (as
/// `ViewLoss::image` with exposure γ), about `1 − exp(−γ Σ d)`: white smoke
/// on black that saturates gracefully instead of clipping.
pub fn transmittance_image(d: &Grid3, cam: &Camera, gamma: f32) -> Result<Image> {
    let (mut img, _) = nst3d_render::render(d, cam, gamma)?;
    img.data.iter_mut().for_each(|v| *v *= gamma);
    Ok(img)
}

/// [`transmittance_image`] in colour: each voxel's emission tinted by its
/// colour `color` (three grids of `d`'s dims, white = the grey picture), the
/// emission–absorption render `nst3d volume --color` optimises.
pub fn color_image(d: &Grid3, color: &[Grid3], cam: &Camera, gamma: f32) -> Result<Image> {
    let (mut img, _) = nst3d_render::render_color_view(d, color, cam.view(d.dims)?, gamma)?;
    img.data.iter_mut().for_each(|v| *v *= gamma);
    Ok(img)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_render::Projection;

    /// A camera the renderer refuses is reported as such, not as empty smoke.
    #[test]
    fn a_bad_camera_is_not_called_empty_smoke() {
        let mut d = Grid3::zeros([8, 8, 8]);
        d.data.iter_mut().for_each(|v| *v = 0.5);
        // The view direction is parallel to the up vector: no image plane.
        let bad = Camera {
            projection: Projection::Orthographic,
            eye: [3.5, 20.0, 3.5],
            target: [3.5, 3.5, 3.5],
            up: [0.0, 1.0, 0.0],
            fov_y_deg: 30.0,
            aspect: 1.0,
        };
        let e = absorption_for(None, [(&d, &bad)].into_iter()).unwrap_err().to_string();
        assert!(!e.contains("zero everywhere"), "{e}");
        let empty = Grid3::zeros([8, 8, 8]);
        let good = Camera { eye: [3.5, 3.5, 30.0], ..bad };
        let e = absorption_for(None, [(&empty, &good)].into_iter()).unwrap_err().to_string();
        assert!(e.contains("zero everywhere"), "{e}");
    }
}
