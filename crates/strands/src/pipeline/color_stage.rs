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
use nst3d_loss::{cell_mask, style_loss, style_loss_masked, StyleTarget};
use nst3d_optim::{optimise_in_turn, Adam};
use nst3d_splat::{render, render_backward_all, SplatCamera, Strands};

use super::step::{flatten, unflatten};
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
/// are fixed, so the mask is too).
pub struct ColorView {
    /// The camera.
    pub camera: SplatCamera,
    /// Per [`COLOR_LAYERS`] tap, row-major over its map: cells with hair.
    pub masks: Vec<Vec<bool>>,
}

impl ColorView {
    /// The view of `strands` through `camera`; `None` when no hair is in
    /// sight (nothing to colour from there).
    pub fn new(
        scene: &StrandScene,
        vgg: &Vgg19,
        groom: &WrittenGroom,
        camera: SplatCamera,
    ) -> Result<Option<Self>, PipelineError> {
        let white = render(&groom.drawn(scene, None), &camera, &scene.style)?.0;
        let pixels = hair_pixels(&white, scene.style.background);
        if !pixels.iter().any(|&p| p) {
            return Ok(None);
        }
        // The taps' map sizes, from a forward of the render itself.
        let fwd = vgg.forward(&white, &COLOR_LAYERS, false);
        let masks: Vec<Vec<bool>> =
            fwd.taps().iter().map(|t| cell_mask(&pixels, white.height, white.width, t.height, t.width)).collect();
        if masks.iter().any(|m| !m.iter().any(|&v| v)) {
            return Ok(None);
        }
        Ok(Some(Self { camera, masks }))
    }
}

/// The Gram loss of `img` to `target` at [`COLOR_LAYERS`] (over the cells
/// `masks` marks, or the whole picture), and its gradient w.r.t. `img`.
fn gram_loss(
    vgg: &Vgg19,
    img: &Image,
    target: &StyleTarget,
    masks: Option<&[Vec<bool>]>,
) -> Result<(f32, Image), PipelineError> {
    let fwd = vgg.forward(img, &COLOR_LAYERS, true);
    let taps: Vec<FeatureView<'_>> = fwd.taps().iter().map(FeatureView::from).collect();
    let (loss, grads) = match masks {
        Some(m) => style_loss_masked(&taps, m, target)?,
        None => style_loss(&taps, target)?,
    };
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
/// of the whole picture.
pub fn color_view_loss(
    scene: &StrandScene,
    vgg: &Vgg19,
    targets: &ColorTargets,
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
    let (color_loss, mut grad_img) = gram_loss(vgg, &img, &targets.color, Some(&view.masks))?;
    let (grey, grad_grey) = gram_loss(vgg, &img.luminance3(), &targets.grey, None)?;
    let grad_grey = Image::luminance3_backward(&grad_grey);
    for (a, b) in grad_img.data.iter_mut().zip(&grad_grey.data) {
        *a += GREY_GUARD * b;
    }
    let loss = color_loss + GREY_GUARD * grey;
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
    let height = (params.style_scale * params.render_size as f32).round() as usize;
    let targets = ColorTargets::new(vgg, style, height)?;
    let groom = WrittenGroom::new(scene, strands)?;
    let mut views = Vec::with_capacity(COLOR_VIEWS);
    for (elevation, azimuth) in color_view_angles() {
        if let Some(v) = ColorView::new(scene, vgg, &groom, scene.camera(elevation, azimuth)?)? {
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
