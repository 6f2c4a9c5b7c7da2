//! Several paintings on one volume, split by a style map (Gatys et al.
//! 2017, "Controlling Perceptual Factors in Neural Style Transfer", spatial
//! control): each painting owns a region, given as a weight per voxel (the
//! regions sum to 1 in every voxel). The regions are rendered with the
//! smoke's own camera and transmittance, so every pixel gets the share of
//! its light that comes from each region; those shares are the guides of
//! the guided Gram loss ([`nst3d_loss::style_loss_guided`]), one term per
//! painting, summed. The guides are fixed: no gradient flows through them.

use nst3d_core::{FeatureView, Grid3, Image};
use nst3d_loss::{cell_weights, style_loss_guided};
use nst3d_render as render;

use crate::field::Field;
use crate::view::{grey_to_rgb, ViewError, ViewLoss, ViewSpec, SMOKE_PIXEL};

/// The paintings of a style map: one [`ViewLoss`] per region, all with the
/// same network and layers.
pub struct MapLoss<'a> {
    pub(crate) paintings: Vec<ViewLoss<'a>>,
}

impl<'a> MapLoss<'a> {
    /// One loss per painting, in the order of the map's regions.
    pub fn new(paintings: Vec<ViewLoss<'a>>) -> Self {
        assert!(!paintings.is_empty(), "a style map needs paintings");
        Self { paintings }
    }

    /// Number of paintings (regions).
    pub fn regions(&self) -> usize {
        self.paintings.len()
    }

    /// Guided style loss of one view, without gradient.
    pub fn loss(&self, d: &Grid3, regions: &[Grid3], view: &ViewSpec) -> Result<f32, ViewError> {
        let guides = region_guides(d, regions, view)?;
        let grey = crate::view::view_image(d, view)?;
        let rgb = grey_to_rgb(&render::upsample2x(&grey));
        let p = &self.paintings[0];
        let fwd = p.vgg.forward(&rgb, &p.layers, false);
        Ok(self.gram_terms(&fwd.features(), &guides, (rgb.height, rgb.width))?.0)
    }

    /// The judge's table for one view: `[r][p]` is the guided Gram loss of
    /// region `r` (its guide rendered from `guide_density`, the input, so
    /// every result is judged over the same pixels) of `d`'s picture against
    /// painting `p`; `None` for a region this view does not show.
    pub fn region_table(
        &self,
        d: &Grid3,
        guide_density: &Grid3,
        regions: &[Grid3],
        view: &ViewSpec,
    ) -> Result<Vec<Option<Vec<f32>>>, ViewError> {
        let guides = render::upsample2x(&region_guides(guide_density, regions, view)?);
        let rgb = grey_to_rgb(&render::upsample2x(&crate::view::view_image(d, view)?));
        let p0 = &self.paintings[0];
        let fwd = p0.vgg.forward(&rgb, &p0.layers, false);
        let feats = fwd.features();
        let mut table = Vec::new();
        for r in 0..regions.len() {
            let t: Vec<Vec<f32>> = feats
                .iter()
                .map(|f| cell_weights(guides.channel(r), rgb.height, rgb.width, f.height, f.width))
                .collect();
            if t.iter().any(|t| t.iter().all(|v| *v <= 0.0)) {
                table.push(None);
                continue;
            }
            let row: Result<Vec<f32>, ViewError> =
                self.paintings.iter().map(|p| Ok(style_loss_guided(&feats, &t, &p.target)?.0)).collect();
            table.push(Some(row?));
        }
        Ok(table)
    }

    /// Guided style loss of one view and its gradient w.r.t. `d`.
    pub fn loss_and_grad(&self, d: &Grid3, regions: &[Grid3], view: &ViewSpec) -> Result<(f32, Grid3), ViewError> {
        let p = &self.paintings[0];
        crate::view::grey_loss_and_grad(p.vgg, &p.layers, d, view, &|feats, lattice| {
            let guides = region_guides_on(d, regions, view, lattice)?;
            self.gram_terms(feats, &guides, (2 * guides.height, 2 * guides.width))
        })
    }

    /// The guided Gram loss of every painting over its region's guide (the
    /// pixel guide `guides.channel(r)`, upsampled 2x as the render is),
    /// summed; a region no pixel of this view shows adds nothing.
    fn gram_terms(
        &self,
        feats: &[FeatureView],
        guides: &Image,
        (h, w): (usize, usize),
    ) -> Result<(f32, Vec<Vec<f32>>), ViewError> {
        let up = render::upsample2x(guides);
        debug_assert_eq!((up.height, up.width), (h, w));
        let mut loss = 0.0;
        // The first region's gradients are the sum's start: no zeroed copy.
        let mut grads: Option<Vec<Vec<f32>>> = None;
        for (r, painting) in self.paintings.iter().enumerate() {
            let t: Vec<Vec<f32>> = feats.iter().map(|f| cell_weights(up.channel(r), h, w, f.height, f.width)).collect();
            if t.iter().any(|t| t.iter().all(|v| *v <= 0.0)) {
                continue;
            }
            let (l, g) = style_loss_guided(feats, &t, &painting.target)?;
            loss += l;
            match &mut grads {
                None => grads = Some(g),
                Some(sum) => sum.iter_mut().zip(&g).for_each(|(a, b)| a.iter_mut().zip(b).for_each(|(x, y)| *x += y)),
            }
        }
        let grads = grads.unwrap_or_else(|| feats.iter().map(|f| vec![0.0; f.data.len()]).collect());
        Ok((loss, grads))
    }
}

/// Each region's share of every pixel's light (one channel per region, the
/// picture before upsampling): the regions rendered as emission with the
/// density's transmittance, divided by their sum; 0 in every channel where
/// the pixel shows no smoke (its grey level under [`SMOKE_PIXEL`]), so the
/// black background belongs to no painting.
pub fn region_guides(d: &Grid3, regions: &[Grid3], view: &ViewSpec) -> Result<Image, ViewError> {
    region_guides_on(d, regions, view, None)
}

/// [`region_guides`] on the lattice the view's grey render already made
/// (`lattice`, where the view has a camera): the density is not resampled
/// again, and the last region's light is the grey picture's less the
/// others' (the regions sum to 1 per voxel), so two regions cost one
/// emission resampled instead of three grids (docs/design/volumes.md).
pub fn region_guides_on(
    d: &Grid3,
    regions: &[Grid3],
    view: &ViewSpec,
    lattice: Option<&render::RenderCache>,
) -> Result<Image, ViewError> {
    let mut img = match lattice {
        Some(cache) if regions.len() >= 2 => {
            let n = regions.len();
            let mut img = render::march_color_on(cache, d, &regions[..n - 1]);
            let mut rest = render::march(&cache.lattice, cache.gamma).data;
            let plane = rest.len();
            for r in 0..n - 1 {
                rest.iter_mut().zip(&img.data[r * plane..(r + 1) * plane]).for_each(|(a, b)| *a -= b);
            }
            img.data.extend(rest.into_iter().map(|v| v.max(0.0)));
            img.channels = n;
            img.data.iter_mut().for_each(|v| *v *= view.exposure);
            img
        }
        _ => crate::view::rgb_picture(d, regions, view)?,
    };
    let (n, plane) = (regions.len(), img.plane());
    for p in 0..plane {
        let sum: f32 = (0..n).map(|r| img.data[r * plane + p]).sum();
        for r in 0..n {
            let v = &mut img.data[r * plane + p];
            *v = if sum > SMOKE_PIXEL { (*v / sum).clamp(0.0, 1.0) } else { 0.0 };
        }
    }
    Ok(img)
}

/// The regions as the transported density `field.transport(d)` carries
/// them: moved with the smoke in velocity mode (each region a density of
/// its own, so they still sum to 1 wherever smoke arrives), unchanged by a
/// density scale.
pub fn carried_regions(field: &Field, regions: &[Grid3]) -> Vec<Grid3> {
    match field {
        Field::Velocity(_) => regions.iter().map(|r| field.transport(r)).collect(),
        Field::Scale(_) => regions.to_vec(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bench::synthetic_smoke;

    /// A region that holds every voxel owns every smoke pixel; two halves of
    /// a blend share each pixel, and the background belongs to neither.
    #[test]
    fn guides_are_each_regions_share_of_the_light() {
        let d = synthetic_smoke(16, 3);
        let cam = render::Camera::front(d.dims);
        let (sums, _) = render::render(&d, &cam, 0.0).unwrap();
        let gamma = 3.0 / sums.data.iter().fold(0f32, |m, v| m.max(*v));
        let view = ViewSpec { camera: Some(cam), gamma, exposure: gamma, equalize: false };
        let ones = Grid3::from_vec(d.dims, vec![1.0; d.len()]);
        let zeros = Grid3::zeros(d.dims);
        let g = region_guides(&d, &[ones.clone(), zeros.clone()], &view).unwrap();
        let plane = g.plane();
        let smoke = crate::view::view_image(&d, &view).unwrap();
        for p in 0..plane {
            let want = if smoke.data[p] > SMOKE_PIXEL { 1.0 } else { 0.0 };
            assert!((g.data[p] - want).abs() < 1e-4, "pixel {p}: {} vs {want}", g.data[p]);
            assert_eq!(g.data[plane + p], 0.0);
        }
        let half = Grid3::from_vec(d.dims, vec![0.5; d.len()]);
        let g = region_guides(&d, &[half.clone(), half], &view).unwrap();
        for p in 0..plane {
            assert!((g.data[p] - g.data[plane + p]).abs() < 1e-5);
        }
    }

    /// The guides made on the grey render's lattice, the last region as the
    /// rest of the light, are the guides rendered on their own, for a soft
    /// blend of three regions (summing to 1 per voxel) from a tilted camera.
    #[test]
    fn guides_on_the_grey_lattice_are_the_guides_rendered_alone() {
        let d = synthetic_smoke(20, 5);
        let cam = render::Camera::orbit(d.dims, 30.0, 20.0);
        let (sums, _) = render::render(&d, &cam, 0.0).unwrap();
        let gamma = 3.0 / sums.data.iter().fold(0f32, |m, v| m.max(*v));
        let view = ViewSpec { camera: Some(cam), gamma, exposure: gamma, equalize: false };
        let [nx, ny, _] = d.dims;
        let ramp = |f: fn(f32) -> f32| {
            Grid3::from_vec(d.dims, (0..d.len()).map(|i| f(((i / nx) % ny) as f32 / (ny - 1) as f32)).collect())
        };
        let regions = [ramp(|h| (1.0 - h) * 0.5), ramp(|h| h * 0.7), ramp(|h| 1.0 - (1.0 - h) * 0.5 - h * 0.7)];
        let (_, cache) = render::render(&d, &cam, gamma).unwrap();
        let alone = region_guides(&d, &regions, &view).unwrap();
        let on = region_guides_on(&d, &regions, &view, Some(&cache)).unwrap();
        assert_eq!((on.channels, on.height, on.width), (alone.channels, alone.height, alone.width));
        let worst = on.data.iter().zip(&alone.data).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
        assert!(worst < 1e-4, "largest difference {worst}");
        assert!(alone.data.iter().any(|v| *v > 0.2), "the regions are seen");
    }
}
