//! The colour stage of a frame (issue 29): an RGB multiplier per voxel
//! optimised on the stylized density, which it leaves alone, from many
//! views around the smoke.
//!
//! Why a stage of its own, after the density, measured on smoke_000003 with
//! Woman with a Hat (docs/VOLUME_LOOK.md, "Colour from every side"):
//! - **Held-out views need colour placed from every side.** Optimised
//!   together with the density from the job's camera, the colour reached
//!   0.61 of the grey result's colour loss from that camera but 0.77 from
//!   held-out views: a colour field placed for one view is averaged along
//!   other rays. Optimised from 16 omniview cameras on the fixed density it
//!   reaches 0.65 from the same held-out views smoothed as in sequences,
//!   0.57 unsmoothed: the stage does not smooth.
//! - **The density stays the grey result's.** The density follows the grey
//!   loss exactly as without colour.
//! - **Free in brightness, with a grey guard** (session 21,
//!   docs/VOLUME_LOOK.md, "Colour free in brightness"): each channel moves
//!   in [`COLOR_RANGE`], so the smoke may take a painting's dark colours,
//!   and the loss adds [`GREY_GUARD`] times the grey loss of the colour
//!   render's luminance. The earlier layer held luminance 1 (the colour
//!   render's luminance was the grey render), which kept the grey look
//!   unchanged but could not darken.
//! - **One view per step.** Each iteration renders one view, in turn: an
//!   iteration costs one colour render and two VGG passes (colour and
//!   guard); 160 such iterations measured as strong (0.65–0.66) as 40
//!   steps that summed all 16 views (640 passes, 0.65).

use nst3d_core::Grid3;
use nst3d_optim::Adam;

use crate::view::{ViewError, ViewLoss, ViewSpec};

/// Cameras the colour stage looks from: an omniview set of this many
/// (Sec. 4's Poisson-disk cameras on a sphere), built by the caller at the
/// job's lens and absorption.
pub const COLOR_VIEWS: usize = 16;

/// Range of each colour channel: white is 1, so a voxel may darken to
/// black or brighten to twice its grey emission per channel.
pub const COLOR_RANGE: (f32, f32) = (0.0, 2.0);

/// Weight of the grey guard: the grey loss (Gram loss to the painting's
/// luminance) of the colour render's luminance, added to the colour loss,
/// as the strands' colour stage guards the hair (the same weight, measured
/// there). On smoke_000003 at the defaults (`nst3d judge --color` against
/// the grey result, 8 held-out views, median; docs/VOLUME_LOOK.md):
///
/// | layer | painting | colour | colour on the smoke | grey |
/// | --- | --- | --- | --- | --- |
/// | luminance 1 (before) | Woman with a Hat | 0.595 | 0.490 | 1.000 |
/// | free, guard 1 | Woman with a Hat | 0.582 | 0.367 | 0.758 |
/// | luminance 1 (before) | Starry Night | 0.845 | 0.704 | 1.000 |
/// | free, guard 1 | Starry Night | 0.827 | 0.661 | 0.903 |
/// | free, guard 1 (not tuned on) | Shipwreck | 0.658 | 0.250 | 0.770 |
///
/// The colour gets closer to the painting and the grey look too: with
/// brightness free the stage also draws the painting's light and dark.
pub const GREY_GUARD: f32 = 1.0;

/// How long and how fast the stage runs.
#[derive(Clone, Copy, Debug)]
pub struct ColorStageParams {
    /// Iterations, each rendering the next view of the list (the volume job
    /// runs [`COLOR_VIEWS`] times the density's iterations per octave).
    pub iterations: usize,
    /// Adam's step on the colour channels: the volume job passes the
    /// layer's [`crate::color::LEARNING_RATE`] (0.2 measured the same on
    /// smoke_000003: with the luminance-1 layer 0.583 / 0.742 against
    /// 0.574 / 0.741 (Woman / Starry), with more speckle; free with the
    /// guard, Starry 0.825 against 0.827).
    pub learning_rate: f32,
    /// Weight of the grey guard (the volume job passes [`GREY_GUARD`]; 0
    /// leaves the grey look unguarded).
    pub grey_guard: f32,
}

/// Reported after every colour iteration.
#[derive(Clone, Copy, Debug)]
pub struct ColorProgress {
    /// Iteration, 1-based.
    pub iteration: usize,
    /// Iterations in the stage.
    pub iterations: usize,
    /// The stage's loss (colour plus guard) of this iteration's view, before the step.
    pub loss: f32,
}

/// Outcome of [`stylize_color`].
#[derive(Clone, Debug)]
pub struct ColorResult {
    /// The colour, one grid per RGB channel of the density's dims, each
    /// value in [`COLOR_RANGE`].
    pub color: Vec<Grid3>,
    /// The stage's loss (colour plus guard) summed over the first sweep: as
    /// many iterations as there are views, starting from white smoke.
    pub loss_first_sweep: f32,
    /// The same sum over the last as many iterations.
    pub loss_last_sweep: f32,
}

/// Optimises the colour of the fixed density `d` against `loss` (built with
/// the colour painting) plus `params.grey_guard` times `grey` (built with
/// the painting's luminance) of the colour render's luminance, from
/// `views`, one view per iteration in turn, for `params.iterations`
/// iterations (with fewer than there are views, each sum covers all of
/// them).
///
/// # Panics
/// If `views` is empty.
pub fn stylize_color(
    d: &Grid3,
    loss: &ViewLoss,
    grey: &ViewLoss,
    views: &[ViewSpec],
    params: &ColorStageParams,
    progress: &mut dyn FnMut(&ColorProgress),
) -> Result<ColorResult, ViewError> {
    assert!(!views.is_empty(), "the colour stage needs at least one view");
    let n = views.len();
    let iterations = params.iterations.max(1);
    let (lo, hi) = COLOR_RANGE;
    let (guard_w, lr) = (params.grey_guard, params.learning_rate);
    // White: the grey result.
    let mut color: Vec<Grid3> = vec![Grid3::from_vec(d.dims, vec![1.0; d.len()]); 3];
    let mut adam: Vec<Adam> = (0..3).map(|_| Adam::new(d.len(), lr)).collect();
    let (mut first, mut last) = (0.0, 0.0);
    let guard = (guard_w > 0.0).then_some((grey, guard_w));
    for it in 0..iterations {
        let (l, l_grey, _, grad) = loss.loss_and_grad_color_guarded(d, &color, &views[it % n], guard)?;
        let l = l + guard_w * l_grey;
        if it < n {
            first += l;
        }
        if it + n >= iterations {
            last += l;
        }
        for ((c, a), g) in color.iter_mut().zip(&mut adam).zip(&grad) {
            a.step(&mut c.data, &g.data);
            c.data.iter_mut().for_each(|x| *x = x.clamp(lo, hi));
        }
        progress(&ColorProgress { iteration: it + 1, iterations, loss: l });
        nst3d_core::stop::check()?;
    }
    Ok(ColorResult { color, loss_first_sweep: first, loss_last_sweep: last })
}
