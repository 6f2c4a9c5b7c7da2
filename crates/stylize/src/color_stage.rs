//! The colour stage of a frame (issue 29): the chroma layer
//! ([`crate::color`]) optimised on the stylized density, which it leaves
//! alone, from many views around the smoke.
//!
//! Why a stage of its own, after the density, measured on smoke_000003 with
//! Woman with a Hat (docs/VOLUME_LOOK.md, "Colour from every side"):
//! - **Held-out views need colour placed from every side.** Optimised
//!   together with the density from the job's camera, the colour reached
//!   0.61 of the grey result's colour loss from that camera but 0.77 from
//!   held-out views: a colour field placed for one view is averaged along
//!   other rays. Optimised from 16 omniview cameras on the fixed density it
//!   reaches 0.65 from the same held-out views smoothed as in sequences,
//!   0.57 unsmoothed ([`SMOOTH_PASSES`]).
//! - **The grey result stays the grey result.** The density follows the
//!   grey loss exactly as without colour, and the layer keeps luminance 1,
//!   so the colour render's luminance is the grey result's render, bit for
//!   bit: colour cannot make the grey look worse.
//! - **One view per step.** Each iteration renders one view, in turn: an
//!   iteration costs one colour render and one VGG pass; 160 such
//!   iterations measured as strong (0.65–0.66) as 40 steps that summed all
//!   16 views (640 passes, 0.65).
//!
//! The layer works at the density's full resolution with the layer's range,
//! without the sequences' smoothing ([`SMOOTH_PASSES`]).

use nst3d_core::Grid3;
use nst3d_optim::Adam;

use crate::color;
use crate::view::{ViewError, ViewLoss, ViewSpec};

/// Cameras the colour stage looks from: an omniview set of this many
/// (Sec. 4's Poisson-disk cameras on a sphere), built by the caller at the
/// job's lens and absorption.
pub const COLOR_VIEWS: usize = 16;

/// Tent passes over the raw channels (sequences: [`color::SMOOTH_PASSES`]).
/// None: measured from 16 views, the held-out colour loss is lowest without
/// smoothing (smoke_000003, 160 iterations: Woman with a Hat 0.583 with
/// none, 0.673 with one pass; Starry Night 0.742 and 0.771), and the
/// painting's colour texture at a small render's size is about a voxel.
pub const SMOOTH_PASSES: usize = 0;

/// How long and how fast the stage runs.
#[derive(Clone, Copy, Debug)]
pub struct ColorStageParams {
    /// Iterations, each rendering the next view of the list (the volume job
    /// runs [`COLOR_VIEWS`] times the density's iterations per octave).
    pub iterations: usize,
    /// Adam's step on the raw channels: the volume job passes the layer's
    /// [`color::LEARNING_RATE`] (0.2 measured the same on smoke_000003:
    /// 0.583 / 0.742 against 0.574 / 0.741, with more speckle).
    pub learning_rate: f32,
}

/// Reported after every colour iteration.
#[derive(Clone, Copy, Debug)]
pub struct ColorProgress {
    /// Iteration, 1-based.
    pub iteration: usize,
    /// Iterations in the stage.
    pub iterations: usize,
    /// Colour loss of this iteration's view (before the step).
    pub loss: f32,
}

/// Outcome of [`stylize_color`].
#[derive(Clone, Debug)]
pub struct ColorResult {
    /// The colour, one grid per RGB channel of the density's dims, of
    /// luminance 1 in every voxel.
    pub color: Vec<Grid3>,
    /// Colour loss summed over the first sweep: as many iterations as there
    /// are views, starting from white smoke (the grey result's colour loss).
    pub loss_first_sweep: f32,
    /// The same sum over the last as many iterations.
    pub loss_last_sweep: f32,
}

/// Optimises the colour of the fixed density `d` against `loss` (built with
/// the colour painting) from `views`, one view per iteration in turn, for
/// `params.iterations` iterations (with fewer than there are views, each
/// sum covers all of them).
///
/// # Panics
/// If `views` is empty.
pub fn stylize_color(
    d: &Grid3,
    loss: &ViewLoss,
    views: &[ViewSpec],
    params: &ColorStageParams,
    progress: &mut dyn FnMut(&ColorProgress),
) -> Result<ColorResult, ViewError> {
    assert!(!views.is_empty(), "the colour stage needs at least one view");
    let n = views.len();
    let iterations = params.iterations.max(1);
    let (lo, hi) = color::RAW_RANGE;
    // Raw channels start at 1: white, the grey result.
    let mut raw: Vec<Vec<f32>> = vec![vec![1.0; d.len()]; 3];
    let mut adam: Vec<Adam> = (0..3).map(|_| Adam::new(d.len(), params.learning_rate)).collect();
    let (mut first, mut last) = (0.0, 0.0);
    for it in 0..iterations {
        let refs: Vec<&[f32]> = raw.iter().map(Vec::as_slice).collect();
        let (grids, tape) = color::chroma(&refs, d.dims, SMOOTH_PASSES);
        let (l, _, grad_color) = loss.loss_and_grad_color(d, &grids, &views[it % n])?;
        if it < n {
            first += l;
        }
        if it + n >= iterations {
            last += l;
        }
        for ((r, a), g) in raw.iter_mut().zip(&mut adam).zip(color::chroma_backward(&tape, &grad_color)) {
            a.step(r, &g);
            r.iter_mut().for_each(|x| *x = x.clamp(lo, hi));
        }
        progress(&ColorProgress { iteration: it + 1, iterations, loss: l });
        nst3d_core::stop::check()?;
    }
    let refs: Vec<&[f32]> = raw.iter().map(Vec::as_slice).collect();
    let (color, _) = color::chroma(&refs, d.dims, SMOOTH_PASSES);
    Ok(ColorResult { color, loss_first_sweep: first, loss_last_sweep: last })
}
