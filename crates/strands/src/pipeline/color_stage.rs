//! Colour from every side: the groom's colour stylized in a
//! stage of its own, after the shape, as the volume pipeline's colour
//! stage does for smoke (`nst3d_stylize::color_stage`).
//!
//! Why a stage of its own. Stepped beside the velocities, the colour had
//! the shape's views (a few cached cameras per scale around the front) and
//! NNST targets matched on grey renders; from held-out views all around the
//! monkey its hair-only colour loss fell only 10–20 % (docs/design/strands.md).
//! Here the strands are fixed (the shape run exactly as without colour, so
//! the grey result is the same), and only the colour offsets `δ` of the
//! [`StrandColorLayer`](crate::StrandColorLayer) move:
//! - from [`COLOR_VIEWS`] cameras evenly around the up axis, at alternating
//!   elevations ([`COLOR_ELEVATIONS`]), one view per iteration in turn;
//! - against the painting's RGB Gram matrices (relu1_1 … relu4_1, equal
//!   weights, [`COLOR_LAYERS`]) over the hair only
//!   ([`nst3d_loss::style_loss_masked`]): the black background, the same in
//!   every picture and out of the colour's reach, neither counts nor
//!   dilutes the hair's statistics. Gram statistics say which colours and
//!   textures, not where, which is what a colour seen from every side can
//!   agree on; NNST's per-view targets pulled each view's strands towards
//!   another hue;
//! - the painting at the render's height times [`StylizeParams::style_scale`]
//!   (a palette taken from the whole canvas, as the canvas fills its frame);
//! - drawing the strands as the written file holds them ([`WrittenGroom`]:
//!   the groom's own points, neither the proxies nor the re-sampled guides);
//! - with Adam at [`COLOR_LEARNING_RATE`] for [`COLOR_PASSES`] passes;
//! - with a grey guard ([`GREY_GUARD`]): the colour may change the hair's
//!   brightness, so the loss adds the Gram loss of the picture's luminance
//!   to the painting's luminance, over the whole picture as the grey judge
//!   sees it, which keeps the grey look the shape gave.
//!
//! The schedule (views in turn, one step each), the view count and the
//! guard's weight are the smoke's too ([`nst3d_optim::color_stage`]); this
//! module is the hair's step, through the splat renderer.
//!
//! The chain: offsets → layer (clamped) → splat render in colour → VGG-19
//! → masked Gram loss, and beside it render → luminance → VGG-19 → Gram
//! loss, and back; each link has its own finite-difference check, and
//! `tests/chain_gradient.rs` checks the whole of [`color_view_loss`].

use nst3d_core::{FeatureView, Image};
use nst3d_features::{Vgg19, VggLayer};
use nst3d_io::image::resize_to_height;
use nst3d_loss::{cell_mask, cell_weights, style_loss, style_loss_guided, StyleTarget};
use nst3d_optim::{optimise_in_turn, Adam};
use nst3d_splat::{render, render_backward_all, SplatCamera, Strands};

use super::step::{flatten, unflatten};
use super::style_map::StrandShares;
use super::views::hair_pixels;
use super::{ColorCarry, PipelineError, StrandScene, StylizeParams};
use crate::color::COLOR_LEARNING_RATE;
use crate::strands::FlatStrands;

/// Cameras of the colour stage, evenly spaced in azimuth around the up
/// axis, and the grey guard's weight: the smoke's colour stage's
/// ([`nst3d_optim::color_stage`], where the guard's measurements are).
pub use nst3d_optim::color_stage::{COLOR_VIEWS, GREY_GUARD};

/// Elevations (polar angles, degrees) the colour cameras alternate between:
/// level with the groom and from above, where a head of hair is seen.
pub const COLOR_ELEVATIONS: [f32; 2] = [0.0, 30.0];

/// VGG-19 taps of the colour loss (Gatys et al.'s, as the volume's).
pub const COLOR_LAYERS: [VggLayer; 4] = [VggLayer::Relu1_1, VggLayer::Relu2_1, VggLayer::Relu3_1, VggLayer::Relu4_1];

/// Passes over the [`COLOR_VIEWS`] cameras the stage makes by default.
pub const COLOR_PASSES: u32 = 4;

/// `(elevation, azimuth)` in degrees of each colour camera; the azimuths are
/// offset half a step from the front so no camera sits on the turntable
/// views `nst3d preview --turntable` judges from.
pub fn color_view_angles() -> Vec<(f32, f32)> {
    (0..COLOR_VIEWS)
        .map(|k| {
            let azimuth = 360.0 * (k as f32 + 0.5) / COLOR_VIEWS as f32;
            (COLOR_ELEVATIONS[k % COLOR_ELEVATIONS.len()], azimuth)
        })
        .collect()
}

/// The painting's Gram matrices the colour stage matches: in colour for the
/// hair, in luminance for the grey guard.
pub struct ColorTargets {
    /// RGB Gram matrices at [`COLOR_LAYERS`].
    pub color: StyleTarget,
    /// The painting's luminance ([`Image::luminance3`]), same layers.
    pub grey: StyleTarget,
}

impl ColorTargets {
    /// The targets of `style` at `height` rows.
    pub fn new(vgg: &Vgg19, style: &Image, height: usize) -> Result<Self, PipelineError> {
        let painting = resize_to_height(style, height.max(16));
        let target = |img: &Image| -> Result<StyleTarget, PipelineError> {
            let fwd = vgg.forward(img, &COLOR_LAYERS, false);
            Ok(StyleTarget::from_features(&fwd.features(), &[1.0; COLOR_LAYERS.len()])?)
        };
        Ok(Self { color: target(&painting)?, grey: target(&painting.luminance3())? })
    }
}

/// One colour camera and which cells of each tap hold hair (the strands
/// are fixed, so the mask is too), per painting.
pub struct ColorView {
    /// The camera.
    pub camera: SplatCamera,
    /// Per painting, per [`COLOR_LAYERS`] tap, row-major over its map: each
    /// cell's weight in the painting's Gram matrix. One painting: 1 on the
    /// cells with hair, 0 elsewhere; a style map: the mean over the cell's
    /// pixels of the painting's share of the hair there (Gatys et al.'s
    /// guide).
    pub guides: Vec<Vec<Vec<f32>>>,
    /// Each painting's share of the hair in the picture, the weight of its
    /// grey guard.
    pub shares: Vec<f32>,
}

impl ColorView {
    /// The view of `strands` through `camera`; `None` when no hair is in
    /// sight (nothing to colour from there).
    pub fn new(
        scene: &StrandScene,
        vgg: &Vgg19,
        groom: &WrittenGroom,
        camera: SplatCamera,
        shares: &StrandShares,
    ) -> Result<Option<Self>, PipelineError> {
        let white = render(&groom.drawn(scene, None), &camera, &scene.style)?.0;
        let pixels = hair_pixels(&white, scene.style.background);
        if !pixels.iter().any(|&p| p) {
            return Ok(None);
        }
        // The taps' map sizes, from a forward of the render itself.
        let fwd = vgg.forward(&white, &COLOR_LAYERS, false);
        let sizes: Vec<(usize, usize)> = fwd.taps().iter().map(|t| (t.height, t.width)).collect();
        let masks: Vec<Vec<bool>> =
            sizes.iter().map(|&(h, w)| cell_mask(&pixels, white.height, white.width, h, w)).collect();
        if masks.iter().any(|m| !m.iter().any(|&v| v)) {
            return Ok(None);
        }
        if shares.paintings() == 1 {
            let guides = vec![masks.iter().map(|m| m.iter().map(|&v| if v { 1.0 } else { 0.0 }).collect()).collect()];
            return Ok(Some(Self { camera, guides, shares: vec![1.0] }));
        }
        let (guides, shares) = map_guides(scene, groom, &camera, shares, &pixels, &sizes)?;
        Ok(Some(Self { camera, guides, shares }))
    }
}

/// Each painting's guide per tap (cell means of its share of the hair at
/// each pixel) and its share of the hair in the picture: the map drawn on
/// the written strands from `camera`, on black.
fn map_guides(
    scene: &StrandScene,
    groom: &WrittenGroom,
    camera: &SplatCamera,
    shares: &StrandShares,
    hair: &[bool],
    sizes: &[(usize, usize)],
) -> Result<(Vec<Vec<Vec<f32>>>, Vec<f32>), PipelineError> {
    let style = nst3d_splat::StrandStyle { background: [0.0; 3], ..scene.style };
    let drawn = |k: Option<usize>| -> Result<Image, PipelineError> {
        let colors: Vec<[f32; 3]> = (0..groom.strands.strand_count())
            .flat_map(|s| {
                let v = k.map_or(1.0, |k| shares.strand_share(k, s));
                std::iter::repeat_n([v; 3], groom.strands.offsets[s + 1] - groom.strands.offsets[s])
            })
            .collect();
        Ok(render(&groom.drawn(scene, Some(&colors)), camera, &style)?.0)
    };
    let coverage = drawn(None)?;
    let plane = coverage.plane();
    let total: f64 = (0..plane).filter(|&i| hair[i]).map(|i| coverage.data[i] as f64).sum();
    let (mut guides, mut parts) = (Vec::new(), Vec::new());
    for k in 0..shares.paintings() {
        let share = drawn(Some(k))?;
        let px: Vec<f32> = (0..plane)
            .map(|i| {
                if hair[i] && coverage.data[i] > 1e-6 {
                    (share.data[i] / coverage.data[i]).clamp(0.0, 1.0)
                } else {
                    0.0
                }
            })
            .collect();
        let part: f64 = (0..plane).filter(|&i| hair[i]).map(|i| share.data[i] as f64).sum();
        parts.push(if total > 0.0 { (part / total) as f32 } else { 0.0 });
        guides.push(sizes.iter().map(|&(h, w)| cell_weights(&px, coverage.height, coverage.width, h, w)).collect());
    }
    Ok((guides, parts))
}

/// The sum over `parts` of each target's Gram loss of `img` at
/// [`COLOR_LAYERS`] (guided by its cell weights, or over the whole
/// picture), and its gradient w.r.t. `img`: one VGG-19 pass for all.
fn gram_loss(
    vgg: &Vgg19,
    img: &Image,
    parts: &[(&StyleTarget, Option<&[Vec<f32>]>)],
) -> Result<(f32, Image), PipelineError> {
    let fwd = vgg.forward(img, &COLOR_LAYERS, true);
    let taps: Vec<FeatureView<'_>> = fwd.taps().iter().map(FeatureView::from).collect();
    let (mut loss, mut grads) = (0.0f32, Vec::<Vec<f32>>::new());
    for (target, guides) in parts {
        let (l, g) = match guides {
            Some(guides) => style_loss_guided(&taps, guides, target)?,
            None => style_loss(&taps, target)?,
        };
        loss += l;
        match grads.is_empty() {
            true => grads = g,
            false => grads.iter_mut().zip(&g).for_each(|(a, b)| a.iter_mut().zip(b).for_each(|(a, b)| *a += b)),
        }
    }
    let grads: Vec<FeatureView<'_>> = taps.iter().zip(&grads).map(|(f, g)| FeatureView { data: g, ..*f }).collect();
    Ok((loss, vgg.backward(&fwd, &grads)))
}

/// What the colour stage draws: the strands as the written file holds them
/// (the groom's own control points, the stylized shape carried to them as
/// the output is), coloured through the [`ColorCarry`] from the guides'
/// points. The re-sampled guides (100 points a strand at Short Hair) draw
/// brighter than the file's own points (17 on monkey_curly), and the grey
/// guard fitted on them did not see the grey look the file shows: with
/// them, monkey_curly × Starry Night at the defaults scored 1.240 of the
/// grey result's grey loss, drawing the written points 1.078
/// (docs/design/strands.md, "At full size"); the proxies
/// are the optimisation's densification and are not written (drawn, the
/// hair was denser than any picture of the file: hair-only judge 0.921 of
/// the grey result's with proxies, 0.818 without).
pub struct WrittenGroom {
    /// The written control points (layout of [`StrandScene::input`]).
    pub strands: FlatStrands,
    /// Guide colours to the written points.
    pub carry: ColorCarry,
}

impl WrittenGroom {
    /// The file `strands` (layout of [`StrandScene::rest`]) would be
    /// written as.
    pub fn new(scene: &StrandScene, strands: &FlatStrands) -> Result<Self, PipelineError> {
        let g = scene.guide_count;
        let split = strands.offsets[g];
        let guides = FlatStrands { points: strands.points[..split].to_vec(), offsets: strands.offsets[..=g].to_vec() };
        Ok(Self {
            strands: scene.to_input_topology(&scene.input, &guides)?,
            carry: ColorCarry::new(scene, &scene.input)?,
        })
    }

    /// The written strands for the renderer, in `colors` (one per written point).
    fn drawn<'a>(&'a self, scene: &'a StrandScene, colors: Option<&'a [[f32; 3]]>) -> Strands<'a> {
        Strands {
            points: &self.strands.points,
            offsets: &self.strands.offsets,
            colors,
            root_normals: scene.root_normals.as_deref().map(|n| &n[..scene.guide_count]),
        }
    }
}

/// The colour stage's loss of `strands` drawn in the colours offsets
/// `delta` make, seen from `view`, and its gradient w.r.t. `delta`: the RGB
/// Gram loss over the hair plus [`GREY_GUARD`] times the luminance Gram loss
/// of the whole picture; with a style map, each painting's (`targets`, in
/// the map's order) over its region, and its grey guard weighed by its
/// share of the hair in sight.
pub fn color_view_loss(
    scene: &StrandScene,
    vgg: &Vgg19,
    targets: &[ColorTargets],
    groom: &WrittenGroom,
    view: &ColorView,
    delta: &[[f32; 3]],
) -> Result<(f32, Vec<[f32; 3]>), PipelineError> {
    let layer = scene.color_layer()?;
    let colors = layer.forward(delta);
    let carried = groom.carry.forward(&colors[..scene.raw_guides.points.len()]);
    let s = groom.drawn(scene, Some(&carried));
    let (img, cache) = render(&s, &view.camera, &scene.style)?;
    // The hair's colour, and the grey guard over the whole picture.
    let colour: Vec<_> = targets.iter().zip(&view.guides).map(|(t, g)| (&t.color, Some(&g[..]))).collect();
    let (color_loss, mut grad_img) = gram_loss(vgg, &img, &colour)?;
    let mut loss = color_loss;
    for (t, &share) in targets.iter().zip(&view.shares).filter(|(_, &s)| s > 0.0) {
        let (grey, grad_grey) = gram_loss(vgg, &img.luminance3(), &[(&t.grey, None)])?;
        let grad_grey = Image::luminance3_backward(&grad_grey);
        for (a, b) in grad_img.data.iter_mut().zip(&grad_grey.data) {
            *a += GREY_GUARD * share * b;
        }
        loss += GREY_GUARD * share * grey;
    }
    if !loss.is_finite() {
        return Err(PipelineError::Diverged(format!("colour loss is {loss}")));
    }
    // Back through the carry to the guides' points; the proxies are not
    // drawn, so their colours get no gradient.
    let grad_written = render_backward_all(&s, &view.camera, &scene.style, &cache, &grad_img)?.colors;
    let mut grad_colors = groom.carry.backward(&grad_written);
    grad_colors.resize(colors.len(), [0.0; 3]);
    Ok((loss, layer.backward(delta, &grad_colors)))
}

/// What [`stylize_color`] reached.
#[derive(Clone, Debug)]
pub struct ColorStageResult {
    /// The colour offsets at the layer's sites.
    pub delta: Vec<[f32; 3]>,
    /// The colour of every point of the strands (guides, then proxies).
    pub colors: Vec<[f32; 3]>,
    /// Mean colour loss over the first pass over the views.
    pub loss_first_pass: f32,
    /// The same over the last as many iterations.
    pub loss_last_pass: f32,
}

/// Iterations of the colour stage: [`COLOR_PASSES`] passes over the views.
pub fn color_iterations() -> u32 {
    COLOR_PASSES * COLOR_VIEWS as u32
}

/// Stylizes the colour of the fixed `strands` (layout of
/// [`StrandScene::rest`]) with `style` from the colour cameras, starting
/// from the input's colours; `progress(i, loss)` after each of the
/// [`color_iterations`].
pub fn stylize_color(
    scene: &StrandScene,
    style: &Image,
    vgg: &Vgg19,
    strands: &FlatStrands,
    params: &StylizeParams,
    progress: &mut dyn FnMut(u32, f32) -> Result<(), PipelineError>,
) -> Result<ColorStageResult, PipelineError> {
    let one = StrandShares::single(scene.rest.strand_count());
    stylize_color_mapped(scene, &[style], &one, vgg, strands, params, progress)
}

/// [`stylize_color`] toward several `paintings` shared by a style map:
/// each painting's colour Gram matrices over its region of each picture.
pub fn stylize_color_mapped(
    scene: &StrandScene,
    paintings: &[&Image],
    shares: &StrandShares,
    vgg: &Vgg19,
    strands: &FlatStrands,
    params: &StylizeParams,
    progress: &mut dyn FnMut(u32, f32) -> Result<(), PipelineError>,
) -> Result<ColorStageResult, PipelineError> {
    let height = (params.style_scale * params.render_size as f32).round() as usize;
    let targets = paintings.iter().map(|p| ColorTargets::new(vgg, p, height)).collect::<Result<Vec<_>, _>>()?;
    let groom = WrittenGroom::new(scene, strands)?;
    let mut views = Vec::with_capacity(COLOR_VIEWS);
    for (elevation, azimuth) in color_view_angles() {
        if let Some(v) = ColorView::new(scene, vgg, &groom, scene.camera(elevation, azimuth)?, shares)? {
            views.push(v);
        }
    }
    let layer = scene.color_layer()?;
    let mut raw = flatten(&layer.start());
    if views.is_empty() {
        // No hair in sight from anywhere: the input's colours stand.
        let colors = layer.forward(&unflatten(&raw));
        return Ok(ColorStageResult { delta: unflatten(&raw), colors, loss_first_pass: 0.0, loss_last_pass: 0.0 });
    }
    let mut adam = Adam::new(raw.len(), COLOR_LEARNING_RATE);
    let sweeps = optimise_in_turn(&views, color_iterations() as usize, |i, view: &ColorView| {
        let (loss, grad) = color_view_loss(scene, vgg, &targets, &groom, view, &unflatten(&raw))?;
        adam.step(&mut raw, &flatten(&grad));
        progress(i as u32 + 1, loss)?;
        Ok::<f32, PipelineError>(loss)
    })?;
    let delta = unflatten(&raw);
    let colors = layer.forward(&delta);
    Ok(ColorStageResult { delta, colors, loss_first_pass: sweeps.first, loss_last_pass: sweeps.last })
}
