//! One optimization step of Alg. 1 on a view whose targets are already
//! matched, timed stage by stage so the `strands-iter` benchmark can report
//! where the time goes.

use std::time::{Duration, Instant};

use nst3d_core::{FeatureView, Image};
use nst3d_features::Vgg19;
use nst3d_loss::nnst::{nnst_loss_matched, NnstMatch};
use nst3d_optim::Adam;
use nst3d_splat::{render, render_backward, SplatCamera};

use crate::constraints::{CollisionStats, ConstraintTape};

use super::orientation::{orientation_loss, OrientationView, StrokeField};
use super::{PipelineError, StrandScene, NNST_LAYERS};

/// The orientation term of one view ([`super::orientation`]) and its
/// weight `λ` beside the NNST loss.
#[derive(Clone, Copy, Debug)]
pub struct OrientationTerm<'a> {
    /// The painting's stroke field at the scale's style size.
    pub field: &'a StrokeField,
    /// The field laid over this view.
    pub view: &'a OrientationView,
    /// `λ`.
    pub weight: f32,
}

/// Wall time of each stage of one [`iteration`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StageTimes {
    /// Eq. 5: `p + W v`, roots pinned.
    pub transport: Duration,
    /// Length preservation and collision projection ([`StrandScene::constrain`]).
    pub constraints: Duration,
    /// Splat render (projection, binning, compositing).
    pub render: Duration,
    /// VGG-19 forward to relu4_1, keeping what the backward needs.
    pub vgg_forward: Duration,
    /// NNST loss against the cached targets and its gradient at the taps.
    pub loss: Duration,
    /// VGG-19 backward to the image.
    pub vgg_backward: Duration,
    /// Splat backward to the control points.
    pub splat_backward: Duration,
    /// Back through the constraint projections to the transported points.
    pub constraints_backward: Duration,
    /// `Wᵀ`: point gradients to the velocities (pinned roots dropped).
    pub field_backward: Duration,
    /// The AdamW step.
    pub optimizer: Duration,
}

impl StageTimes {
    /// The stages' names and times, in pipeline order.
    pub fn stages(&self) -> [(&'static str, Duration); 10] {
        [
            ("transport", self.transport),
            ("constraints", self.constraints),
            ("render", self.render),
            ("vgg_forward", self.vgg_forward),
            ("nnst_loss", self.loss),
            ("vgg_backward", self.vgg_backward),
            ("splat_backward", self.splat_backward),
            ("constraints_backward", self.constraints_backward),
            ("field_backward", self.field_backward),
            ("adamw", self.optimizer),
        ]
    }

    /// Sum of the stages.
    pub fn total(&self) -> Duration {
        self.stages().iter().map(|s| s.1).sum()
    }
}

/// What one [`iteration`] did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepReport {
    /// NNST loss of the view before the step.
    pub loss: f32,
    /// Orientation loss of the view before the step (0 without the term).
    pub orientation: f32,
    /// The constraints' first collision pass on this iterate.
    pub stats: CollisionStats,
    /// Where the time went.
    pub times: StageTimes,
}

/// One optimization step of Alg. 1 on a view whose targets are already
/// matched: deform by `v` (flat `3 × samples`), render through `cam`, VGG-19,
/// NNST loss against `matched`, the chain backward to `v`, and one `adam`
/// step. A non-finite loss leaves `v` untouched and is an error.
/// [`stylize`](super::stylize) runs exactly this per iteration; the `strands-iter`
/// benchmark times it.
pub fn iteration(
    scene: &StrandScene,
    vgg: &Vgg19,
    cam: &SplatCamera,
    matched: &NnstMatch,
    v: &mut [f32],
    adam: &mut Adam,
) -> Result<StepReport, PipelineError> {
    iteration_with(scene, vgg, cam, matched, &[], v, adam)
}

/// [`iteration`] with the orientation terms (one per painting) added to
/// the loss.
pub fn iteration_with(
    scene: &StrandScene,
    vgg: &Vgg19,
    cam: &SplatCamera,
    matched: &NnstMatch,
    orientation: &[OrientationTerm<'_>],
    v: &mut [f32],
    adam: &mut Adam,
) -> Result<StepReport, PipelineError> {
    let (mut report, grad) = loss_and_gradient_with(scene, vgg, cam, matched, orientation, v)?;
    let clock = Instant::now();
    adam.step(v, &grad);
    report.times.optimizer = clock.elapsed();
    Ok(report)
}

/// The forward and backward of one [`iteration`] without the optimizer
/// step: the view's NNST loss at `v` and its gradient with respect to `v`
/// (flat, like `v`). `report.times.optimizer` is zero. The `strands-iter`
/// benchmark's dump hands this gradient to the PyTorch peer, whose autograd
/// checks it.
pub fn loss_and_gradient(
    scene: &StrandScene,
    vgg: &Vgg19,
    cam: &SplatCamera,
    matched: &NnstMatch,
    v: &[f32],
) -> Result<(StepReport, Vec<f32>), PipelineError> {
    loss_and_gradient_with(scene, vgg, cam, matched, &[], v)
}

/// [`loss_and_gradient`] of `NNST + Σ λ · orientation` over the
/// `orientation` terms (the report keeps the two losses apart).
pub fn loss_and_gradient_with(
    scene: &StrandScene,
    vgg: &Vgg19,
    cam: &SplatCamera,
    matched: &NnstMatch,
    orientation: &[OrientationTerm<'_>],
    v: &[f32],
) -> Result<(StepReport, Vec<f32>), PipelineError> {
    let mut times = StageTimes::default();
    let mut clock = Instant::now();
    let mut lap = |slot: &mut Duration| {
        let now = Instant::now();
        *slot = now - clock;
        clock = now;
    };
    let mut strands = scene.transport(&unflatten(v))?;
    lap(&mut times.transport);
    let mut tape = ConstraintTape::default();
    let stats = scene.constrain_recorded(&mut strands, &mut tape)?;
    lap(&mut times.constraints);
    let s = scene.strands(&strands, None);
    let (img, cache) = render(&s, cam, &scene.style)?;
    lap(&mut times.render);
    let (loss, grad_img) = view_loss(vgg, &img, matched, &mut times)?;
    // `view_loss` timed its own three stages; restart the lap clock so the
    // splat backward is not charged with them.
    let mut timed_by_view_loss = Duration::ZERO;
    lap(&mut timed_by_view_loss);
    let mut grad_points = render_backward(&s, cam, &scene.style, &cache, &grad_img)?;
    let mut orientation_value = 0.0;
    for term in orientation {
        let (value, g) = orientation_loss(term.field, term.view, &strands);
        orientation_value += value;
        grad_points.iter_mut().zip(&g).for_each(|(a, b)| (0..3).for_each(|k| a[k] += term.weight * b[k]));
    }
    lap(&mut times.splat_backward);
    let grad_points = tape.backward(&scene.constraints.rest, &grad_points)?;
    lap(&mut times.constraints_backward);
    let grad = flatten(&scene.transport_backward(grad_points)?);
    lap(&mut times.field_backward);
    Ok((StepReport { loss, orientation: orientation_value, stats, times }, grad))
}

/// VGG-19 forward of `img`, the NNST loss against `matched` and the
/// backward to the image; adds to the stages' times.
fn view_loss(
    vgg: &Vgg19,
    img: &Image,
    matched: &NnstMatch,
    times: &mut StageTimes,
) -> Result<(f32, Image), PipelineError> {
    let clock = Instant::now();
    let fwd = vgg.forward(img, &NNST_LAYERS, true);
    times.vgg_forward += clock.elapsed();
    let clock = Instant::now();
    let (loss, tap_grads) = nnst_loss_matched(fwd.taps(), matched)?;
    times.loss += clock.elapsed();
    if !loss.is_finite() {
        return Err(PipelineError::Diverged(format!("loss is {loss}")));
    }
    let clock = Instant::now();
    let grad = vgg.backward(&fwd, &tap_grads.iter().map(FeatureView::from).collect::<Vec<_>>());
    times.vgg_backward += clock.elapsed();
    Ok((loss, grad))
}

pub(super) fn unflatten(v: &[f32]) -> Vec<[f32; 3]> {
    v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
}

pub(super) fn flatten(v: &[[f32; 3]]) -> Vec<f32> {
    v.iter().flatten().copied().collect()
}
