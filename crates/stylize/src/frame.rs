//! Multi-octave optimisation of one frame (paper Sec. 3.1/3.3, the inner
//! loop of Algorithm 1 for a single frame).
//!
//! Octaves run coarse to fine: at octave `k` the density is box-downsampled
//! `2^(octaves-1-k)` times while the painting keeps its size, so coarse
//! octaves place large patterns and fine octaves add detail; the field is
//! carried up to the next octave by trilinear resampling.

use nst3d_core::Grid3;
use nst3d_optim::Adam;
use nst3d_render::Camera;
use nst3d_transport as transport;

use crate::field::{Field, Limits, Mode};
use crate::guided::{carried_regions, MapLoss};
use crate::view::{ViewError, ViewLoss, ViewSpec};

/// Settings of a single-frame stylisation.
#[derive(Clone, Debug)]
pub struct FrameParams {
    /// Velocity or density mode.
    pub mode: Mode,
    /// Number of octaves (1 = full resolution only).
    pub octaves: usize,
    /// Adam iterations per octave.
    pub iterations: usize,
    /// Adam learning rate: voxels per step (velocity) or scale units (density).
    pub learning_rate: f32,
    /// Hard limits of Sec. 3.3.
    pub limits: Limits,
    /// The view at full resolution.
    pub view: ViewSpec,
}

/// Reported after every iteration.
#[derive(Clone, Copy, Debug)]
pub struct Progress {
    /// Current octave, 0-based, coarse first.
    pub octave: usize,
    /// Number of octaves.
    pub octaves: usize,
    /// Iteration within the octave, 1-based.
    pub iteration: usize,
    /// Iterations per octave.
    pub iterations: usize,
    /// Loss at this iteration (before the step).
    pub loss: f32,
}

/// Outcome of [`stylize_frame`].
#[derive(Clone, Debug)]
pub struct FrameResult {
    /// The stylised density `d* = T(d, field)` at full resolution.
    pub density: Grid3,
    /// The optimised field at full resolution.
    pub field: Field,
    /// Style loss of the input seen from the view (full resolution).
    pub loss_before: f32,
    /// Style loss of the result seen from the same view.
    pub loss_after: f32,
}

impl FrameResult {
    /// Fractional drop of the style loss, `1 - after/before`.
    pub fn loss_drop(&self) -> f32 {
        if self.loss_before > 0.0 {
            1.0 - self.loss_after / self.loss_before
        } else {
            0.0
        }
    }
}

/// The density pyramid, finest first.
fn pyramid(d: &Grid3, octaves: usize) -> Vec<Grid3> {
    let mut levels = vec![d.clone()];
    for _ in 1..octaves {
        let next = transport::downsample2(levels.last().unwrap());
        if next.dims.iter().any(|&n| n < 4) {
            break; // coarser than this carries no pattern
        }
        levels.push(next);
    }
    levels
}

/// The view adapted to a grid `factor` times coarser: each voxel holds the
/// average of `factor` voxels along a ray, so absorption scales by `factor`
/// to keep the picture's opacity, and the camera moves into coarse index space.
///
/// Exposure scales *up* by `factor` too: a ray crosses `factor` times fewer
/// voxels, so the march's light `I = Σ d τ` is `factor` times smaller, and the
/// grey level `exposure · I` only matches the fine picture with the larger
/// exposure (it is `γ · I` ≈ opacity at every octave). Dividing instead made
/// every coarse octave `factor²` too dark; the coarse optimisation then fought
/// the brightness rather than placing patterns (docs/design/volumes.md).
pub fn view_at(view: &ViewSpec, factor: f32) -> ViewSpec {
    ViewSpec {
        camera: view.camera.map(|c| coarse_camera(c, factor)),
        gamma: view.gamma * factor,
        exposure: view.exposure * factor,
        equalize: view.equalize,
    }
}

/// The camera in the index space of a grid `factor` times coarser: voxel
/// centre `i` of the fine grid sits at `(i + 0.5) / factor - 0.5` there.
fn coarse_camera(mut cam: Camera, factor: f32) -> Camera {
    let map = |p: [f32; 3]| p.map(|x| (x + 0.5) / factor - 0.5);
    cam.eye = map(cam.eye);
    cam.target = map(cam.target);
    cam
}

/// Stylises one density grid seen from `params.view`. `progress` is called
/// after every iteration.
pub fn stylize_frame(
    d: &Grid3,
    loss: &ViewLoss,
    params: &FrameParams,
    progress: &mut dyn FnMut(&Progress),
) -> Result<FrameResult, ViewError> {
    stylize_frame_views(d, loss, params, std::slice::from_ref(&params.view), progress)
}

/// Stylises one density grid for a camera set Θ (eq. 1): every iteration
/// sums the style losses and gradients of all `views` (full resolution; an
/// empty set falls back to `params.view`). The reported losses are sums too.
pub fn stylize_frame_views(
    d: &Grid3,
    loss: &ViewLoss,
    params: &FrameParams,
    views: &[ViewSpec],
    progress: &mut dyn FnMut(&Progress),
) -> Result<FrameResult, ViewError> {
    let views = if views.is_empty() { std::slice::from_ref(&params.view) } else { views };
    let mut score = |_: usize, _: usize, _: &Field, dstar: &Grid3, view: &ViewSpec| loss.loss_and_grad(dstar, view);
    let (field, density) = optimise(d, params, views, &mut score, progress)?;
    let (mut loss_before, mut loss_after) = (0.0, 0.0);
    for view in views {
        loss_before += loss.loss(d, view)?;
        loss_after += loss.loss(&density, view)?;
    }
    Ok(FrameResult { density, field, loss_before, loss_after })
}

/// [`stylize_frame_views`] toward several paintings split by a style map:
/// `regions` holds one weight grid per painting of `loss` (over `d`'s box,
/// summing to 1 in every voxel), and every view's loss is the guided Gram
/// loss of each painting over its region ([`crate::guided`]). The regions
/// follow the octaves (box-averaged as the density is) and, in velocity
/// mode, the smoke's transport.
pub fn stylize_frame_map(
    d: &Grid3,
    loss: &MapLoss,
    regions: &[Grid3],
    params: &FrameParams,
    views: &[ViewSpec],
    progress: &mut dyn FnMut(&Progress),
) -> Result<FrameResult, ViewError> {
    let views = if views.is_empty() { std::slice::from_ref(&params.view) } else { views };
    assert_eq!(regions.len(), loss.regions(), "one region per painting");
    let octaves = pyramid(d, params.octaves.max(1)).len();
    let pyramids: Vec<Vec<Grid3>> = regions.iter().map(|r| pyramid(r, octaves)).collect();
    // The regions as this iteration's field carries them, made once for
    // all the iteration's views (keyed by octave and iteration).
    let mut carried: Option<((usize, usize), Vec<Grid3>)> = None;
    let mut score = |level: usize, step: usize, f: &Field, dstar: &Grid3, view: &ViewSpec| {
        if carried.as_ref().is_none_or(|(key, _)| *key != (level, step)) {
            let here: Vec<Grid3> = pyramids.iter().map(|p| p[level].clone()).collect();
            carried = Some(((level, step), carried_regions(f, &here)));
        }
        loss.loss_and_grad(dstar, &carried.as_ref().expect("made above").1, view)
    };
    let (field, density) = optimise(d, params, views, &mut score, progress)?;
    let moved = carried_regions(&field, regions);
    let (mut loss_before, mut loss_after) = (0.0, 0.0);
    for view in views {
        loss_before += loss.loss(d, regions, view)?;
        loss_after += loss.loss(&density, &moved, view)?;
    }
    Ok(FrameResult { density, field, loss_before, loss_after })
}

/// One view's loss and gradient w.r.t. the transported density at pyramid
/// level `level` (0 = full resolution) and iteration `step` of that level,
/// for the field that transported it.
type Score<'s> = dyn FnMut(usize, usize, &Field, &Grid3, &ViewSpec) -> Result<(f32, Grid3), ViewError> + 's;

/// The multi-octave Adam loop: returns the field at full resolution and the
/// density it transports.
fn optimise(
    d: &Grid3,
    params: &FrameParams,
    views: &[ViewSpec],
    score: &mut Score,
    progress: &mut dyn FnMut(&Progress),
) -> Result<(Field, Grid3), ViewError> {
    let levels = pyramid(d, params.octaves.max(1));
    let octaves = levels.len();
    let mut field: Option<(Field, [usize; 3])> = None;

    for (k, level) in levels.iter().rev().enumerate() {
        let factor = (1usize << (octaves - 1 - k)) as f32;
        let level_views: Vec<ViewSpec> = views.iter().map(|v| view_at(v, factor)).collect();
        let mut f = match field.take() {
            None => Field::initial(params.mode, level.len()),
            Some((f, dims)) => f.resize(dims, level.dims),
        };
        let vmax_here = params.limits.vmax / factor;
        f.constrain(&params.limits, vmax_here);
        // A fresh Adam per octave: the moments of a coarser grid do not map
        // onto the finer one, and the paper restarts the optimiser per level.
        let mut adam = Adam::new(f.len(), params.learning_rate);
        for it in 0..params.iterations {
            let (dstar, tape) = f.forward(level);
            let mut l = 0.0;
            let mut grad_dstar = Grid3::zeros(level.dims);
            let add = |acc: &mut Grid3, g: &Grid3| acc.data.iter_mut().zip(&g.data).for_each(|(a, b)| *a += b);
            for view in &level_views {
                let (lv, gv) = score(octaves - 1 - k, it, &f, &dstar, view)?;
                l += lv;
                add(&mut grad_dstar, &gv);
            }
            let grad = f.descent(f.backward(level, &tape, &grad_dstar.data), level.dims);
            adam.step(f.params_mut(), &grad);
            f.constrain(&params.limits, vmax_here);
            progress(&Progress { octave: k, octaves, iteration: it + 1, iterations: params.iterations, loss: l });
            nst3d_core::stop::check()?;
        }
        field = Some((f, level.dims));
    }

    let (field, dims) = field.expect("at least one octave");
    let field = if dims == d.dims { field } else { field.resize(dims, d.dims) };
    let density = field.transport(d);
    Ok((field, density))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bench::synthetic_smoke;
    use nst3d_render::Projection;

    /// Grey image of `d` as `ViewLoss` renders it (render, then exposure).
    fn grey(d: &Grid3, view: &ViewSpec) -> nst3d_core::Image {
        let (mut img, _) = nst3d_render::render(d, view.camera.as_ref().unwrap(), view.gamma).unwrap();
        img.data.iter_mut().for_each(|v| *v *= view.exposure);
        img
    }

    fn mean(v: &[f32]) -> f64 {
        v.iter().map(|x| *x as f64).sum::<f64>() / v.len() as f64
    }

    /// Every octave must show the optimiser the same picture, only coarser:
    /// a coarse octave that renders 1/factor² as bright (the old
    /// `exposure / factor`) is a different image whose Gram matrices the
    /// coarse loop chases, and what it learns shows up as streaks and a
    /// seam in the final result.
    #[test]
    fn coarse_octaves_render_as_bright_as_the_fine_grid() {
        let d = synthetic_smoke(32, 7);
        for projection in [Projection::Perspective, Projection::Orthographic] {
            let cam = nst3d_render::Camera::front(d.dims).with_projection(projection);
            // The CLI's look: the densest ray has optical depth 3, exposure γ.
            let (sums, _) = nst3d_render::render(&d, &cam, 0.0).unwrap();
            let gamma = 3.0 / sums.data.iter().fold(0f32, |m, v| m.max(*v));
            let view = ViewSpec { camera: Some(cam), gamma, exposure: gamma, equalize: false };
            // Box filtering blurs the silhouette a little (more at factor 4,
            // 8 voxels across), so the means agree to 25%; the old exposure
            // was off by 75% at factor 2 and 94% at factor 4.
            let fine = grey(&d, &view);
            let mut level = d.clone();
            for factor in [2.0f32, 4.0] {
                level = transport::downsample2(&level);
                let coarse = grey(&level, &view_at(&view, factor));
                let (mf, mc) = (mean(&fine.data), mean(&coarse.data));
                assert!(
                    (mc / mf - 1.0).abs() < 0.25,
                    "{projection:?} factor {factor}: coarse mean grey {mc:.4} vs fine {mf:.4}"
                );
                let (pf, pc) =
                    (fine.data.iter().fold(0f32, |m, v| m.max(*v)), coarse.data.iter().fold(0f32, |m, v| m.max(*v)));
                assert!((pc / pf - 1.0).abs() < 0.25, "{projection:?} factor {factor}: brightest {pc:.4} vs {pf:.4}");
            }
        }
    }
}
