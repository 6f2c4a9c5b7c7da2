//! The multi-scale loop of one stylization (cached views per scale, the
//! scale's style size and learning rate) and the evaluation of its result;
//! see the module notes of [`crate::pipeline`].

use std::collections::HashMap;

use nst3d_core::Image;
use nst3d_features::{Vgg19, VggLayer};
use nst3d_loss::nnst::{nnst_loss_matched, nnst_loss_over, NnstMatch};
use nst3d_optim::Adam;
use nst3d_splat::SplatCamera;

use crate::strands::FlatStrands;
use crate::StrandError;

use super::color_stage::{color_iterations, stylize_color_mapped};
use super::orientation::OrientationView;
use super::step::{flatten, iteration_with, loss_and_gradient_with, unflatten, OrientationTerm};
use super::style_map::{PaintingTargets, StrandShares};
use super::views::{hair_columns, hair_pixels, poisson_view_angles};
use super::{PipelineError, StrandScene, StylizeParams, NNST_LAYERS};

/// What one optimization iteration reports.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IterationReport {
    /// Scale index (0-based).
    pub scale: usize,
    /// Iteration within the scale (1-based).
    pub iteration: u32,
    /// Iterations of this scale.
    pub iterations: u32,
    /// NNST loss of this iteration's view.
    pub loss: f32,
    /// Control points the collision pass found inside the mesh.
    pub inside: usize,
    /// An iteration of the colour stage ([`stylize_color`]; `loss` is its
    /// colour loss, `scale` the finest) rather than of the shape.
    pub color: bool,
}

/// Result of [`stylize`].
#[derive(Clone, Debug)]
pub struct StylizeResult {
    /// Stylized guides (the groom to write), same layout as the rest guides.
    pub guides: FlatStrands,
    /// Stylized proxies (empty when none were grown).
    pub proxies: FlatStrands,
    /// Final strands, guides then proxies (layout of [`StrandScene::rest`]).
    pub strands: FlatStrands,
    /// Optimized velocities at the field's samples.
    pub velocities: Vec<[f32; 3]>,
    /// With [`StylizeParams::color`]: the stylized colour of every point of
    /// [`StylizeResult::strands`] (guides, then proxies).
    pub colors: Option<Vec<[f32; 3]>>,
    /// Loss of every iteration, in order.
    pub loss_history: Vec<f32>,
    /// Mean NNST loss of the rest groom over the evaluation views.
    pub eval_before: f32,
    /// Mean loss of the stylized groom against the same targets (the
    /// optimized objective).
    pub eval_after: f32,
    /// Mean NNST loss of the stylized groom re-matched on its own renders.
    pub eval_after_rematched: f32,
    /// Evaluation view angles `(ψ, δ)`, degrees.
    pub eval_angles: Vec<(f32, f32)>,
    /// The stylization measured where the optimizer did not look: the NNST
    /// loss over the hair's hyper-columns from held-out views.
    pub held_out: HeldOut,
}

/// NNST loss over the hyper-columns that cover hair (in the rest or the
/// stylized render; the empty background, which every view shares and no
/// deformation changes, is left out), mean over views the optimizer never
/// used, drawn from the preset's angle ranges by another seed.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct HeldOut {
    /// View angles `(ψ, δ)`, degrees.
    pub angles: Vec<(f32, f32)>,
    /// The rest groom against targets matched on itself.
    pub before: f32,
    /// The stylized groom against the same targets (the paper's objective).
    pub after: f32,
    /// The stylized groom against targets matched on its own render.
    pub after_rematched: f32,
}

impl HeldOut {
    /// Relative drop `1 − after / before`.
    pub fn drop(&self) -> f32 {
        1.0 - self.after / self.before
    }
}

/// Seed offset of the held-out views (see [`HeldOut`]).
const HELD_OUT_SEED: u64 = 0x4E1D_0075;

/// [`HeldOut`] of `strands` (layout of [`StrandScene::rest`]) from
/// `params.held_out_views` views against the paintings `finest`.
pub fn held_out_loss(
    scene: &StrandScene,
    vgg: &Vgg19,
    finest: &PaintingTargets<'_>,
    strands: &FlatStrands,
    params: &StylizeParams,
) -> Result<HeldOut, PipelineError> {
    let p = params.preset;
    let angles = poisson_view_angles(
        &scene.frame,
        p.polar_deg,
        p.azimuth_deg,
        params.held_out_views,
        params.seed ^ HELD_OUT_SEED,
    );
    let (mut before, mut after, mut rematched) = (0.0f64, 0.0f64, 0.0f64);
    for &(psi, delta) in &angles {
        let cam = scene.camera(psi, delta)?;
        let (img0, img1) = (scene.render(&scene.undeformed, &cam)?, scene.render(strands, &cam)?);
        let (f0, f1) = (vgg.forward(&img0, &NNST_LAYERS, false), vgg.forward(&img1, &NNST_LAYERS, false));
        let matched = finest.match_on(scene, &scene.undeformed, f0.taps(), &cam)?;
        let mask = hair_columns(&[&img0, &img1], scene.style.background, matched.grid());
        before += nnst_loss_over(f0.taps(), &matched, &mask)? as f64;
        after += nnst_loss_over(f1.taps(), &matched, &mask)? as f64;
        let again = finest.match_on(scene, strands, f1.taps(), &cam)?;
        rematched += nnst_loss_over(f1.taps(), &again, &mask)? as f64;
    }
    let k = angles.len().max(1) as f64;
    Ok(HeldOut {
        angles,
        before: (before / k) as f32,
        after: (after / k) as f32,
        after_rematched: (rematched / k) as f32,
    })
}

impl StylizeResult {
    /// Relative drop of the evaluation loss, `1 − after / before`.
    pub fn loss_drop(&self) -> f32 {
        1.0 - self.eval_after / self.eval_before
    }
}

/// AdamW's learning rate at scale `l`: the preset's `η` times
/// [`StylizeParams::lr_scale`], in units of the groom radius (module notes).
pub fn scale_learning_rate(scene: &StrandScene, params: &StylizeParams, l: usize) -> f32 {
    params.preset.learning_rates[l] * params.lr_scale * scene.frame.radius
}

/// Stylizes the scene's groom with `style` (RGB in `[0, 1]`; its luminance
/// is matched) through `vgg`, reporting every iteration to `progress`.
pub fn stylize(
    scene: &StrandScene,
    style: &Image,
    vgg: &Vgg19,
    params: &StylizeParams,
    progress: &mut dyn FnMut(&IterationReport),
) -> Result<StylizeResult, PipelineError> {
    stylize_with(scene, style, vgg, params, FrameHooks::default(), progress)
}

/// The orientation terms of a view, one per painting (none without a
/// stroke field or with no hair in sight), each weighed `λ · strength`:
/// `λ` is `params.orientation` times [`orientation_scale`] measured at the
/// first iteration (kept in `lambda`), and a field's
/// [`StrokeField::strength`](super::StrokeField::strength) scales its own
/// term, so a field with few strokes pulls little however its gradient
/// compares.
#[allow(clippy::too_many_arguments)]
fn orientation_terms<'a>(
    lambda: &mut Option<f32>,
    scene: &StrandScene,
    vgg: &Vgg19,
    cam: &SplatCamera,
    matched: &NnstMatch,
    units: Vec<OrientationTerm<'a>>,
    params: &StylizeParams,
    v: &[f32],
) -> Result<Vec<OrientationTerm<'a>>, PipelineError> {
    if units.is_empty() {
        return Ok(units);
    }
    let ratio = match *lambda {
        Some(r) => r,
        None => *lambda.insert(params.orientation * orientation_scale(scene, vgg, cam, matched, &units, v)?),
    };
    Ok(units.into_iter().map(|u| OrientationTerm { weight: ratio * u.field.strength(), ..u }).collect())
}

/// `|∇ NNST| / |∇ orientation|` at `v` (both through the whole chain to
/// the velocities): the orientation weight that makes the two gradients
/// equal in norm.
fn orientation_scale(
    scene: &StrandScene,
    vgg: &Vgg19,
    cam: &SplatCamera,
    matched: &NnstMatch,
    units: &[OrientationTerm<'_>],
    v: &[f32],
) -> Result<f32, PipelineError> {
    let (_, g_nnst) = loss_and_gradient_with(scene, vgg, cam, matched, &[], v)?;
    let (_, g_both) = loss_and_gradient_with(scene, vgg, cam, matched, units, v)?;
    let norm = |it: &mut dyn Iterator<Item = f64>| it.map(|x| x * x).sum::<f64>().sqrt();
    let n = norm(&mut g_nnst.iter().map(|&x| x as f64));
    let o = norm(&mut g_both.iter().zip(&g_nnst).map(|(&b, &a)| (b - a) as f64));
    Ok(if o > 0.0 { (n / o) as f32 } else { 0.0 })
}

/// Where an iteration of [`stylize_with`] stands, before it runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct IterationClock {
    /// Scale index (0-based).
    pub scale: usize,
    /// Iteration within the scale (0-based).
    pub iteration: u32,
    /// Iterations of this scale.
    pub iterations: u32,
    /// Iterations of the whole frame already run (0-based index of this one).
    pub done: u32,
    /// Iterations of the whole frame.
    pub total: u32,
}

/// What an animated sequence adds to one frame's optimization (Alg. 1 lines
/// 5 and 7); the default is the static case.
#[derive(Default)]
pub struct FrameHooks<'a> {
    /// Velocities `v_t` at the field's samples to start from instead of
    /// zero (Alg. 1 line 5 starts from zero).
    pub initial: Option<&'a [[f32; 3]]>,
    /// Called before every iteration's transport with `v_t`, which it may
    /// change in place: the EMA of eq. 8 towards the previous frame's field.
    #[allow(clippy::type_complexity)]
    pub before_iteration: Option<&'a mut dyn FnMut(IterationClock, &mut [[f32; 3]]) -> Result<(), PipelineError>>,
}

impl FrameHooks<'_> {
    /// Runs [`FrameHooks::before_iteration`], if any, on the flat velocities `v`.
    fn before(&mut self, clock: IterationClock, v: &mut Vec<f32>) -> Result<(), PipelineError> {
        if let Some(hook) = self.before_iteration.as_mut() {
            let mut vv = unflatten(v);
            hook(clock, &mut vv)?;
            *v = flatten(&vv);
        }
        Ok(())
    }
}

/// [`stylize`] with a sequence's per-frame [`FrameHooks`].
pub fn stylize_with(
    scene: &StrandScene,
    style: &Image,
    vgg: &Vgg19,
    params: &StylizeParams,
    hooks: FrameHooks<'_>,
    progress: &mut dyn FnMut(&IterationReport),
) -> Result<StylizeResult, PipelineError> {
    let one = StrandShares::single(scene.rest.strand_count());
    stylize_mapped(scene, &[style], &one, vgg, params, hooks, progress)
}

/// [`stylize_with`] toward several `paintings` at once, each strand toward
/// its `shares` of them (a style map, [`super::style_map`]).
pub fn stylize_mapped(
    scene: &StrandScene,
    paintings: &[&Image],
    shares: &StrandShares,
    vgg: &Vgg19,
    params: &StylizeParams,
    mut hooks: FrameHooks<'_>,
    progress: &mut dyn FnMut(&IterationReport),
) -> Result<StylizeResult, PipelineError> {
    check_inputs(params, paintings)?;
    let p = params.preset;
    vgg.prepare(VggLayer::Relu4_1);

    let n = scene.field.sample_count();
    let mut v = initial_velocities(hooks.initial, n)?;
    let (mut done, total) = (0u32, params.iterations.iter().sum::<u32>());
    let mut adam = Adam::adamw(3 * n, 0.0, params.weight_decay);
    let mut history = Vec::new();

    // Camera angles for all scales from one Poisson sequence, so the
    // scales see different views.
    let per_scale = views_per_scale(params);
    let angles = poisson_view_angles(&scene.frame, p.polar_deg, p.azimuth_deg, per_scale.iter().sum(), params.seed);
    let (mut first, mut finest, mut rest_matches) = (0, None, None);
    let mut lambda: Option<f32> = None; // the orientation term's λ, set at its first iteration
    for (l, &iters) in params.iterations.iter().enumerate() {
        let views = &angles[first..first + per_scale[l]];
        first += per_scale[l];
        // The shape follows the paintings' luminance, with or without
        // colour (the colour has a stage of its own, after the shape).
        let looks = PaintingTargets::new(vgg, paintings, shares, params, l)?;
        // Where this scale's targets are matched: the rest groom (eq. 2), or
        // with `rematch` the groom as the coarser scales left it.
        let base = if params.rematch && l > 0 && iters > 0 { Some(scene.deform(&unflatten(&v))?.0) } else { None };
        if iters > 0 {
            adam.lr = scale_learning_rate(scene, params, l);
            let strands = base.as_ref().unwrap_or(&scene.undeformed);
            let projected = projected_views(scene, &looks, strands, p.orientation_projector())?;
            let mut cache: HashMap<usize, ScaleView> = HashMap::new();
            for m in 0..iters {
                let k = m as usize % views.len();
                if let std::collections::hash_map::Entry::Vacant(e) = cache.entry(k) {
                    e.insert(scale_view(scene, vgg, &looks, strands, views[k], projected.is_none())?);
                }
                let (cam, matched, oriented) = &cache[&k];
                let units = orientation_units(&looks, projected.as_deref().unwrap_or(oriented));
                let terms = orientation_terms(&mut lambda, scene, vgg, cam, matched, units, params, &v)?;
                hooks.before(IterationClock { scale: l, iteration: m, iterations: iters, done, total }, &mut v)?;
                done += 1;
                let step = iteration_with(scene, vgg, cam, matched, &terms, &mut v, &mut adam)
                    .map_err(|e| at_iteration(e, l, m))?;
                history.push(step.loss);
                progress(&IterationReport {
                    scale: l,
                    iteration: m + 1,
                    iterations: iters,
                    loss: step.loss,
                    inside: step.stats.inside,
                    color: false,
                });
                nst3d_core::stop::check()?;
            }
            // The finest scale's views matched on the rest groom are the
            // evaluation's "before" matches.
            rest_matches = base.is_none().then(|| evaluation_matches(cache, params.eval_views));
        }
        finest = Some(looks);
    }
    let finest = finest.expect("three scales");

    let (strands, _) = scene.deform(&unflatten(&v))?;
    if strands.points.iter().any(|p| p.iter().any(|c| !c.is_finite())) {
        return Err(PipelineError::Diverged("non-finite control points".into()));
    }
    let views = Views { angles: &angles, per_scale: &per_scale, rest_matches: rest_matches.as_ref() };
    let eval = evaluate(scene, vgg, params, views, &finest, &strands)?;
    let held_out = (params.held_out_views > 0)
        .then(|| held_out_loss(scene, vgg, &finest, &strands, params))
        .transpose()?
        .unwrap_or_default();
    // Colour: a stage of its own on the finished strands.
    let colors = match params.color {
        true => Some(color_stage(scene, (paintings, shares), vgg, &strands, params, progress)?),
        false => None,
    };
    let (guides, proxies) = split_guides(scene, &strands);
    Ok(StylizeResult {
        guides,
        proxies,
        strands,
        velocities: unflatten(&v),
        colors,
        loss_history: history,
        eval_before: eval.before,
        eval_after: eval.after,
        eval_after_rematched: eval.after_rematched,
        eval_angles: eval.angles,
        held_out,
    })
}

/// The targets of the cached views `evaluate` measures (the first
/// `eval_views`), by view index.
fn evaluation_matches(cache: HashMap<usize, ScaleView>, eval_views: usize) -> HashMap<usize, NnstMatch> {
    cache.into_iter().filter(|(k, _)| *k < eval_views).map(|(k, view)| (k, view.1)).collect()
}

/// The settings are sound and every painting usable.
fn check_inputs(params: &StylizeParams, paintings: &[&Image]) -> Result<(), PipelineError> {
    params.validate()?;
    paintings.iter().try_for_each(|p| check_style(p))?;
    Ok(())
}

/// The orientation terms of a cached view at unit weight: each painting's
/// stroke field with its view, where its region is in sight.
fn orientation_units<'a>(
    looks: &'a PaintingTargets<'_>,
    oriented: &'a [Option<OrientationView>],
) -> Vec<OrientationTerm<'a>> {
    looks
        .strokes
        .iter()
        .zip(oriented)
        .filter_map(|(field, view)| view.as_ref().map(|view| OrientationTerm { field, view, weight: 1.0 }))
        .collect()
}

/// The painting must be RGB and at least 16 pixels a side (VGG's taps).
fn check_style(style: &Image) -> Result<(), PipelineError> {
    if style.channels != 3 || style.height < 16 || style.width < 16 {
        return Err(PipelineError::Parameter(format!(
            "style image is {}x{}x{}, need 3 channels and at least 16x16",
            style.channels, style.height, style.width
        )));
    }
    Ok(())
}

/// The flat velocities a frame starts from: the hook's (a sequence's
/// previous frame) or zero (Alg. 1 line 5).
fn initial_velocities(initial: Option<&[[f32; 3]]>, n: usize) -> Result<Vec<f32>, PipelineError> {
    Ok(match initial {
        Some(v0) if v0.len() != n => {
            return Err(StrandError::Mismatch { what: "initial velocities", expected: n, got: v0.len() }.into())
        }
        Some(v0) => flatten(v0),
        None => vec![0.0f32; 3 * n],
    })
}

/// Cached views of each scale: the scale's iterations, or
/// [`StylizeParams::views_per_scale`] when fewer.
fn views_per_scale(params: &StylizeParams) -> Vec<usize> {
    params
        .iterations
        .iter()
        .map(|&it| if params.views_per_scale == 0 { it as usize } else { params.views_per_scale.min(it as usize) })
        .collect()
}

/// A cached view of a scale: its camera, the NNST targets matched there
/// and the orientation term's view of each painting (none without the
/// term, with no hair in sight, or where the scale projects the paintings
/// from one camera: [`projected_views`]).
type ScaleView = (SplatCamera, NnstMatch, Vec<Option<OrientationView>>);

/// The view at `angle` of `strands` (where the scale's targets are
/// matched) with the scale's targets and, with `oriented`, the paintings'
/// stroke fields laid over this view.
fn scale_view(
    scene: &StrandScene,
    vgg: &Vgg19,
    looks: &PaintingTargets<'_>,
    strands: &FlatStrands,
    angle: (f32, f32),
    oriented: bool,
) -> Result<ScaleView, PipelineError> {
    let cam = scene.camera(angle.0, angle.1)?;
    let img = scene.render(strands, &cam)?;
    let feats = vgg.forward(&img, &NNST_LAYERS, false);
    let matched = looks.match_on(scene, strands, feats.taps(), &cam)?;
    let views = match oriented {
        true => orientation_views(scene, looks, strands, &cam, &img)?,
        false => Vec::new(),
    };
    Ok((cam, matched, views))
}

/// With a projector (a projected preset's
/// [`orientation_projector`](crate::preset::PresetParams::orientation_projector)),
/// the paintings' stroke fields laid over `strands` seen from it, for
/// every view of the scale: a strand then has one target direction in
/// every view, as a texture projected from the front camera has. Laid
/// over each view's own box instead, a motif slides across the hair as
/// the camera moves, and a fine one (a triangle tessellation on long
/// hair) asks each strand for different directions in different views.
fn projected_views(
    scene: &StrandScene,
    looks: &PaintingTargets<'_>,
    strands: &FlatStrands,
    projector: Option<(f32, f32)>,
) -> Result<Option<Vec<Option<OrientationView>>>, PipelineError> {
    let Some((polar, azimuth)) = projector else { return Ok(None) };
    if looks.strokes.is_empty() {
        return Ok(Some(Vec::new()));
    }
    let cam = scene.camera(polar, azimuth)?;
    let img = scene.render(strands, &cam)?;
    Ok(Some(orientation_views(scene, looks, strands, &cam, &img)?))
}

/// The orientation term's view of each painting through `cam`, whose
/// render of `strands` is `img`: each stroke field laid over the box of
/// the hair in `img` (none for a painting whose region is out of sight).
fn orientation_views(
    scene: &StrandScene,
    looks: &PaintingTargets<'_>,
    strands: &FlatStrands,
    cam: &SplatCamera,
    img: &Image,
) -> Result<Vec<Option<OrientationView>>, PipelineError> {
    let hair = hair_pixels(img, scene.style.background);
    let s = scene.strands(strands, None);
    // With a map each painting is laid over its own region's box, so a
    // region takes its painting's whole motif at the style scale.
    let map = match looks.shares.paintings() > 1 && !looks.strokes.is_empty() {
        true => Some(looks.shares.view_map(scene, strands, cam)?),
        false => None,
    };
    let mut views = Vec::with_capacity(looks.strokes.len());
    for (k, field) in looks.strokes.iter().enumerate() {
        let view = match &map {
            Some(map) => OrientationView::new(field, &s, &map.region(k, &hair), &scene.style, cam)
                .map(|v| v.shared(&looks.shares.point_shares(k, strands))),
            None => OrientationView::new(field, &s, &hair, &scene.style, cam),
        };
        views.push(view);
    }
    Ok(views)
}

/// A diverged iteration says where it diverged.
fn at_iteration(e: PipelineError, l: usize, m: u32) -> PipelineError {
    match e {
        PipelineError::Diverged(why) => {
            PipelineError::Diverged(format!("{why} at scale {} iteration {}", l + 1, m + 1))
        }
        e => e,
    }
}

/// The mean NNST losses of [`StylizeResult`] over the evaluation views.
struct Evaluation {
    angles: Vec<(f32, f32)>,
    before: f32,
    after: f32,
    after_rematched: f32,
}

/// The optimisation's views, for [`evaluate`].
struct Views<'a> {
    /// Every scale's camera angles, in order.
    angles: &'a [(f32, f32)],
    /// How many of them each scale has.
    per_scale: &'a [usize],
    /// The finest scale's cached views' targets where they were matched on
    /// the rest groom (by view index): those views are not matched again.
    rest_matches: Option<&'a HashMap<usize, NnstMatch>>,
}

/// The NNST loss of the rest groom and of the stylized `strands` against
/// the finest scale's targets, from the first `eval_views` of the finest
/// scale's cached views (the optimized views, whose rest-groom targets the
/// scale already matched; the result's re-match is the one new match); with
/// a fresh camera per iteration, a fixed set drawn from the same
/// distribution.
fn evaluate(
    scene: &StrandScene,
    vgg: &Vgg19,
    params: &StylizeParams,
    Views { angles, per_scale, rest_matches }: Views<'_>,
    finest: &PaintingTargets<'_>,
    strands: &FlatStrands,
) -> Result<Evaluation, PipelineError> {
    let p = params.preset;
    let cached = params.views_per_scale > 0 && params.iterations[2] > 0;
    let eval_angles = if cached {
        let finest = &angles[angles.len() - per_scale[2]..];
        finest[..params.eval_views.min(finest.len())].to_vec()
    } else {
        poisson_view_angles(&scene.frame, p.polar_deg, p.azimuth_deg, params.eval_views, params.seed ^ 0xE7A1)
    };
    let (mut before, mut after, mut rematched) = (0.0f64, 0.0f64, 0.0f64);
    for (i, &(psi, delta)) in eval_angles.iter().enumerate() {
        let cam = scene.camera(psi, delta)?;
        let img0 = scene.render(&scene.undeformed, &cam)?;
        let f0 = vgg.forward(&img0, &NNST_LAYERS, false);
        let matched_here;
        let matched = match rest_matches.filter(|_| cached).and_then(|m| m.get(&i)) {
            Some(m) => m,
            None => {
                matched_here = finest.match_on(scene, &scene.undeformed, f0.taps(), &cam)?;
                &matched_here
            }
        };
        let img = scene.render(strands, &cam)?;
        let feats = vgg.forward(&img, &NNST_LAYERS, false);
        before += nnst_loss_matched(f0.taps(), matched)?.0 as f64;
        after += nnst_loss_matched(feats.taps(), matched)?.0 as f64;
        let again = finest.match_on(scene, strands, feats.taps(), &cam)?;
        rematched += nnst_loss_matched(feats.taps(), &again)?.0 as f64;
    }
    let k = eval_angles.len() as f64;
    Ok(Evaluation {
        angles: eval_angles,
        before: (before / k) as f32,
        after: (after / k) as f32,
        after_rematched: (rematched / k) as f32,
    })
}

/// The colour stage on the finished strands, its iterations reported as
/// the finest scale's with `color` set.
fn color_stage(
    scene: &StrandScene,
    (paintings, shares): (&[&Image], &StrandShares),
    vgg: &Vgg19,
    strands: &FlatStrands,
    params: &StylizeParams,
    progress: &mut dyn FnMut(&IterationReport),
) -> Result<Vec<[f32; 3]>, PipelineError> {
    let iterations = color_iterations();
    let stage = stylize_color_mapped(scene, paintings, shares, vgg, strands, params, &mut |i, loss| {
        progress(&IterationReport { scale: 2, iteration: i, iterations, loss, inside: 0, color: true });
        Ok(nst3d_core::stop::check()?)
    })?;
    Ok(stage.colors)
}

/// The guides (the groom to write) and the proxies of `strands` (layout of
/// [`StrandScene::rest`]).
fn split_guides(scene: &StrandScene, strands: &FlatStrands) -> (FlatStrands, FlatStrands) {
    let g = scene.guide_count;
    let split = strands.offsets[g];
    let guides = FlatStrands { points: strands.points[..split].to_vec(), offsets: strands.offsets[..=g].to_vec() };
    let proxies = FlatStrands {
        points: strands.points[split..].to_vec(),
        offsets: strands.offsets[g..].iter().map(|o| o - split).collect(),
    };
    (guides, proxies)
}
