//! Colour with a style map: each painting's colour Gram matrices matched
//! over its own region of the colour picture, as the grey look's guided
//! Gram loss ([`crate::guided`]) matches its luminance. The regions are the
//! grey look's guides (each pixel's share of its light from each region,
//! rendered with the smoke's transmittance), so a pixel's colour is pulled
//! toward each painting by that painting's share of it.
//!
//! With one painting the terms are exactly the single painting's
//! ([`ViewLoss::loss_and_grad_color_guarded`]): the whole picture, plus the
//! smoke term over the cells that show smoke. With several, painting `r`'s
//! smoke term covers the smoke cells by its share, and its whole-picture
//! term adds the black around the smoke at the weight `√(S_r / S)` (`S_r`:
//! its share of the smoke cells, `S`: all of them), so each painting sees
//! black and smoke in the proportion the whole picture has.

use nst3d_core::{FeatureView, Grid3, Image};
use nst3d_loss::{cell_mask, cell_weights, style_loss_guided};
use nst3d_render as render;

use crate::guided::{region_guides, MapLoss};
use crate::view::{color_backward, rgb, smoke_pixels, ViewError, ViewLoss, ViewSpec};

/// One view's guides at the resolution VGG-19 sees (the render upsampled
/// 2x): each region's share of every pixel's light and the pixels that
/// show smoke.
struct PixelGuides {
    shares: Image,
    smoke: Vec<bool>,
}

/// The cell weights of one layer for every painting: the whole-picture
/// term's and the smoke term's.
struct LayerGuides {
    whole: Vec<Vec<f32>>,
    smoke: Vec<Vec<f32>>,
}

impl PixelGuides {
    fn new(d: &Grid3, regions: &[Grid3], view: &ViewSpec) -> Result<Self, ViewError> {
        let shares = render::upsample2x(&region_guides(d, regions, view)?);
        Ok(Self { shares, smoke: smoke_pixels(d, view)? })
    }

    /// The guides of a `fh x fw` feature map.
    fn layer(&self, fh: usize, fw: usize) -> LayerGuides {
        let (h, w, n) = (self.shares.height, self.shares.width, self.shares.channels);
        let mask = cell_mask(&self.smoke, h, w, fh, fw);
        let mut share: Vec<Vec<f32>> = (0..n).map(|r| cell_weights(self.shares.channel(r), h, w, fh, fw)).collect();
        // Each smoke cell split between the paintings by their light (evenly
        // where no region's light reaches it).
        for c in 0..fh * fw {
            let sum: f32 = share.iter().map(|s| s[c]).sum();
            share.iter_mut().for_each(|s| s[c] = if sum > 0.0 { s[c] / sum } else { 1.0 / n as f32 });
        }
        let smoke_cells = mask.iter().filter(|m| **m).count();
        let mut whole = Vec::with_capacity(n);
        let mut smoke = Vec::with_capacity(n);
        for s in &share {
            let on_smoke: Vec<f32> = s.iter().zip(&mask).map(|(v, m)| if *m { *v } else { 0.0 }).collect();
            let area: f32 = on_smoke.iter().map(|v| v * v).sum();
            let black = if smoke_cells > 0 { (area / smoke_cells as f32).sqrt() } else { (1.0 / n as f32).sqrt() };
            whole.push(s.iter().zip(&mask).map(|(v, m)| if *m { *v } else { black }).collect());
            smoke.push(on_smoke);
        }
        LayerGuides { whole, smoke }
    }
}

/// The guided Gram loss of `picture` (before the 2x upsampling every view
/// gets) against every painting, over its whole-picture guide plus
/// `smoke_w` times over its smoke guide, and with `grad` the gradient
/// w.r.t. the picture. A term whose guide is empty in a layer (a painting
/// this view does not show) adds nothing.
fn guided_loss(
    paintings: &[ViewLoss],
    picture: &Image,
    guides: &PixelGuides,
    smoke_w: f32,
    grad: bool,
) -> Result<(f32, Option<Image>), ViewError> {
    let up = render::upsample2x(picture);
    let p0 = &paintings[0];
    let fwd = p0.vgg.forward(&up, &p0.layers, grad);
    let feats = fwd.features();
    let layers: Vec<LayerGuides> = feats.iter().map(|f| guides.layer(f.height, f.width)).collect();
    let mut loss = 0.0;
    let mut grads: Option<Vec<Vec<f32>>> = None;
    for (r, painting) in paintings.iter().enumerate() {
        let whole: Vec<Vec<f32>> = layers.iter().map(|l| l.whole[r].clone()).collect();
        let smoke: Vec<Vec<f32>> = layers.iter().map(|l| l.smoke[r].clone()).collect();
        for (t, w) in [(whole, 1.0), (smoke, smoke_w)] {
            if w == 0.0 || t.iter().any(|t| t.iter().all(|v| *v <= 0.0)) {
                continue;
            }
            let (l, g) = style_loss_guided(&feats, &t, &painting.target)?;
            loss += w * l;
            match &mut grads {
                None => grads = Some(g.into_iter().map(|g| g.into_iter().map(|y| w * y).collect()).collect()),
                Some(sum) => {
                    sum.iter_mut().zip(&g).for_each(|(a, b)| a.iter_mut().zip(b).for_each(|(x, y)| *x += w * y))
                }
            }
        }
    }
    if !grad {
        return Ok((loss, None));
    }
    let grads = grads.unwrap_or_else(|| feats.iter().map(|f| vec![0.0; f.data.len()]).collect());
    let views: Vec<FeatureView> = feats.iter().zip(&grads).map(|(f, g)| FeatureView { data: g, ..*f }).collect();
    Ok((loss, Some(render::upsample2x_backward(&p0.vgg.backward(&fwd, &views)))))
}

impl MapLoss<'_> {
    /// [`ViewLoss::loss_and_grad_color_guarded`] with a style map: `self`
    /// built with the colour paintings, `guard` (if any) with their
    /// luminance, each painting over its region of `regions` (as the grey
    /// look's carried regions). Returns the colour loss (whole picture plus
    /// the weighted smoke term), the guard's loss (0 without one) and the
    /// gradients w.r.t. `d` and each colour channel.
    pub fn loss_and_grad_color_guarded(
        &self,
        d: &Grid3,
        color: &[Grid3],
        regions: &[Grid3],
        view: &ViewSpec,
        smoke: f32,
        guard: Option<(&MapLoss, f32)>,
    ) -> Result<(f32, f32, Grid3, Vec<Grid3>), ViewError> {
        let (picture, cache) = rgb(d, color, view)?;
        let guides = PixelGuides::new(d, regions, view)?;
        let (loss, grad) = guided_loss(&self.paintings, &picture, &guides, smoke, true)?;
        let mut grad = grad.expect("asked for the gradient");
        let mut guard_loss = 0.0;
        if let Some((g, w)) = guard {
            let (l, grad_lum) = guided_loss(&g.paintings, &picture.luminance3(), &guides, 0.0, true)?;
            guard_loss = l;
            let back = Image::luminance3_backward(&grad_lum.expect("asked for the gradient"));
            grad.data.iter_mut().zip(&back.data).for_each(|(a, b)| *a += w * b);
        }
        let (grad_d, grad_c) = color_backward(d, color, view, &cache, grad);
        Ok((loss, guard_loss, grad_d, grad_c))
    }

    /// The colour loss of one view (each painting over its region, whole
    /// picture), without gradient.
    pub fn loss_color(&self, d: &Grid3, color: &[Grid3], regions: &[Grid3], view: &ViewSpec) -> Result<f32, ViewError> {
        let (picture, _) = rgb(d, color, view)?;
        Ok(guided_loss(&self.paintings, &picture, &PixelGuides::new(d, regions, view)?, 0.0, false)?.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bench::synthetic_smoke;
    use crate::view::StyleSpec;
    use nst3d_core::gradcheck::pseudo_random;
    use nst3d_features::{Vgg19, VggFlavor};

    fn painting(seed: u64) -> Image {
        let v = pseudo_random(3 * 24 * 24, seed).iter().map(|x| 0.5 + 0.4 * x).collect();
        Image::from_vec(3, 24, 24, v)
    }

    fn setup(n: usize) -> (Grid3, Vec<Grid3>, ViewSpec) {
        let d = synthetic_smoke(n, 4);
        let cam = render::Camera::orbit(d.dims, 20.0, 15.0);
        let view = ViewSpec { camera: Some(cam), gamma: 0.2, exposure: 0.2, equalize: false };
        let color: Vec<Grid3> = (0..3)
            .map(|c| Grid3::from_vec(d.dims, pseudo_random(d.len(), 30 + c).iter().map(|x| 1.0 + 0.5 * x).collect()))
            .collect();
        (d, color, view)
    }

    /// One painting over a map that gives it every voxel is the single
    /// painting's loss and gradients, bit for bit, guard and smoke term
    /// included.
    #[test]
    fn one_painting_is_the_single_paintings_loss() {
        let vgg = Vgg19::random(VggFlavor::Torchvision, 3);
        let spec = StyleSpec::default();
        let (d, color, view) = setup(16);
        let loss = ViewLoss::new(&vgg, &painting(1), &spec).unwrap();
        let grey = ViewLoss::new(&vgg, &painting(1).luminance3(), &spec).unwrap();
        let want = loss.loss_and_grad_color_guarded(&d, &color, &view, 0.5, Some((&grey, 1.0))).unwrap();
        let map = MapLoss::new(vec![ViewLoss::new(&vgg, &painting(1), &spec).unwrap()]);
        let map_grey = MapLoss::new(vec![ViewLoss::new(&vgg, &painting(1).luminance3(), &spec).unwrap()]);
        let all = vec![Grid3::from_vec(d.dims, vec![1.0; d.len()])];
        let got = map.loss_and_grad_color_guarded(&d, &color, &all, &view, 0.5, Some((&map_grey, 1.0))).unwrap();
        assert_eq!((got.0, got.1), (want.0, want.1));
        assert_eq!(got.2.data, want.2.data);
        assert!(got.3.iter().zip(&want.3).all(|(a, b)| a.data == b.data));
        assert_eq!(map.loss_color(&d, &color, &all, &view).unwrap(), loss.loss_color(&d, &color, &view).unwrap());
    }

    /// Two paintings split by a soft map, with the smoke term and the
    /// guard: the gradient w.r.t. the colour against central differences
    /// (the guides depend on the density only), by the rule of the single
    /// painting's colour check: most large entries agree within 5 %.
    #[test]
    fn two_paintings_color_gradient_matches_finite_differences() {
        nst3d_core::precision::fp32(|| {
            let vgg = Vgg19::random(VggFlavor::Torchvision, 3);
            let spec = StyleSpec::default();
            let (d, color, view) = setup(12);
            let map = |f: fn(&Image) -> Image| {
                MapLoss::new([1, 2].iter().map(|s| ViewLoss::new(&vgg, &f(&painting(*s)), &spec).unwrap()).collect())
            };
            let (loss, grey) = (map(|p| p.clone()), map(|p| p.luminance3()));
            let [nx, ny, nz] = d.dims;
            let up: Vec<f32> = (0..d.len()).map(|i| (i / (nx * ny)) as f32 / (nz - 1) as f32).collect();
            let regions = [up.iter().map(|v| 1.0 - v).collect(), up].map(|r| Grid3::from_vec(d.dims, r));
            let f = |c: &[Grid3]| loss.loss_and_grad_color_guarded(&d, c, &regions, &view, 0.5, Some((&grey, 2.0)));
            let (l0, g0, _, grad) = f(&color).unwrap();
            assert!(l0 > 0.0 && g0 > 0.0);
            let analytic: Vec<f32> = grad.iter().flat_map(|c| c.data.clone()).collect();
            let big = analytic.iter().fold(0f32, |m, v| m.max(v.abs()));
            let (mut agree, mut probed) = (0, 0);
            for i in (0..analytic.len()).step_by(19).filter(|i| analytic[*i].abs() >= 0.05 * big) {
                let (ch, at, h) = (i / d.len(), i % d.len(), 1e-2f32);
                let total = |dx: f32| {
                    let mut c = color.clone();
                    c[ch].data[at] += dx;
                    let (l, g, _, _) = f(&c).unwrap();
                    (l + 2.0 * g) as f64
                };
                let fd = (total(h) - total(-h)) / (2.0 * h as f64);
                probed += 1;
                agree += (((fd - analytic[i] as f64) / fd).abs() < 0.05) as usize;
            }
            assert!(probed >= 20, "only {probed} large entries probed");
            assert!(agree as f64 >= 0.7 * probed as f64, "{agree} of {probed} agree within 5%");
        })
    }
}
