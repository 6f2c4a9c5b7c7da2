//! One OpenVDB frame stylized (paper Sec. 3): the grid is read, densified
//! over its active box plus a margin (a velocity may carry smoke a little
//! outside its original shape, Sec. 3.3), stylized by
//! [`nst3d_stylize::stylize_frame_views`], and written back sparse into the
//! same index space with the same transform; a grid too small for strokes
//! is refined first and written `k` times finer ([`crate::upsample`]). With
//! `color`, the colour stage ([`nst3d_stylize::stylize_color`]) then colours
//! the stylized density from [`nst3d_stylize::COLOR_VIEWS`] omniview cameras,
//! scaling it with the colour, and the file gets that density.
//! A before | after | painting preview is rendered from the first camera
//! (with a style map: input | map | result | paintings, [`crate::map_preview`]).

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use nst3d_core::Reporter;
use nst3d_core::{Grid3, Image};
use nst3d_io::image::{resize_to_height, side_by_side, write_png};
use nst3d_io::vdb::{read_vdb, Transform, VdbFile};
use nst3d_stylize::{
    stylize_color, stylize_frame_map, stylize_frame_views, ColorStageParams, FrameParams, JointDensity, MapLoss, Mode,
    ViewLoss, ViewSpec, COLOR_VIEWS,
};

use crate::cameras::{CameraSet, Cameras, Lens};
use crate::dense::pad;
use crate::look::{absorption_for, display, views_of, HeldOut, PREVIEW_HEIGHT};
use crate::map_preview::write_map_preview;
use crate::output::write_stylized;
use crate::settings::VolumeSettings;
use crate::style::{load_paintings, load_style_and_vgg};
use crate::style_map::{self, MapBox};
use crate::upsample::{refine_density, refine_origin, refine_transform};

/// What a single-frame job did.
#[derive(Clone, Debug)]
pub struct FrameReport {
    /// The input file.
    pub input: PathBuf,
    /// The stylized grid's name.
    pub grid: String,
    /// The active box stylized, in voxels (after any refinement).
    pub dims: [usize; 3],
    /// How many times finer than the file it was stylized and written.
    pub upsample: usize,
    /// The optimised quantity.
    pub mode: Mode,
    /// Cameras in Θ.
    pub cameras: usize,
    /// Style loss summed over Θ before optimisation.
    pub loss_before: f32,
    /// And after.
    pub loss_after: f32,
    /// Style loss from each evaluation camera before and after, when asked for.
    pub held_out: Option<HeldOut>,
    /// The written file.
    pub out: PathBuf,
}

impl FrameReport {
    /// Relative drop of the style loss, `1 − after / before`.
    pub fn loss_drop(&self) -> f32 {
        if self.loss_before > 0.0 {
            1.0 - self.loss_after / self.loss_before
        } else {
            0.0
        }
    }
}

/// A dense grid stylized in memory: the result of [`stylize_grid`].
#[derive(Clone, Debug)]
pub struct StylizedGrid {
    /// The stylized density over the (refined) box plus `margin` voxels on
    /// every side, so smoke a velocity carried outwards is kept.
    pub density: Grid3,
    /// Empty voxels added on every side before stylizing.
    pub margin: usize,
    /// With `color`: the RGB colour over the same box as `density`, one grid
    /// per channel (a multiplier of the grey emission, 1 = white).
    pub color: Option<Vec<Grid3>>,
    /// How many times finer than the input it was stylized.
    pub upsample: usize,
    /// The (refined) input box's size in voxels, without the margin.
    pub dims: [usize; 3],
    /// Index of the input's voxel (0,0,0) after refinement.
    pub origin: [i32; 3],
    /// The transform of the refined index space.
    pub transform: Transform,
    /// Cameras in Θ.
    pub cameras: usize,
    /// Style loss summed over Θ before optimisation.
    pub loss_before: f32,
    /// And after.
    pub loss_after: f32,
    /// Style loss from each evaluation camera before and after, when asked for.
    pub held_out: Option<HeldOut>,
}

impl StylizedGrid {
    /// The result over the (refined) input box only, without the margin:
    /// the array a caller that passed a box gets back in the same place.
    pub fn cropped(&self) -> Grid3 {
        crop(&self.density, [self.margin; 3], self.dims)
    }
}

/// The box of `dims` voxels starting at voxel `from` of `g`.
fn crop(g: &Grid3, from: [usize; 3], dims: [usize; 3]) -> Grid3 {
    let mut out = Grid3::zeros(dims);
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            let src = g.index(from[0], from[1] + y, from[2] + z);
            let dst = out.index(0, y, z);
            out.data[dst..dst + dims[0]].copy_from_slice(&g.data[src..src + dims[0]]);
        }
    }
    out
}

/// Stylizes the single frame `s.input` into `s.out` (and `s.preview`).
pub fn stylize_frame_file(s: &VolumeSettings, reporter: &mut dyn Reporter) -> Result<FrameReport> {
    s.check()?;
    // Read and check everything before the slow part, so a bad input fails in a second.
    let file = read_vdb(&s.input)?;
    let grid = file.grid(&s.grid).with_context(|| {
        let names: Vec<&str> = file.grids.iter().map(|g| g.name.as_str()).collect();
        format!("{}: no grid named '{}' (grids: {})", s.input.display(), s.grid, names.join(", "))
    })?;
    let (bx, dense) = grid.to_dense()?;
    let r = stylize_grid_in(s, dense, &grid.transform, bx.origin, &grid.name, Some((&file, &s.input)), reporter)?;
    let origin = r.origin.map(|o| o - r.margin as i32);
    let color_name = s.color_grid.clone().unwrap_or_else(|| crate::output::color_grid_name(&file, s.up).to_string());
    let color = r.color.as_ref().map(|c| (color_name.as_str(), &c[..]));
    if color.is_some() && color_name == grid.name {
        bail!("--color-grid '{color_name}' is the stylized grid's own name");
    }
    for dropped in write_stylized(&s.out, &file, &grid.name, &r.transform, origin, &r.density, color)? {
        reporter.note(&format!("{dropped} is not copied to the output"));
    }
    Ok(FrameReport {
        input: s.input.clone(),
        grid: grid.name.clone(),
        dims: r.dims,
        upsample: r.upsample,
        mode: s.mode,
        cameras: r.cameras,
        loss_before: r.loss_before,
        loss_after: r.loss_after,
        held_out: r.held_out,
        out: s.out.clone(),
    })
}

/// A grid too small for strokes stylized `k` times finer (its transform and
/// origin refined with it); with `k` = 1 the grid as it is.
fn refine(
    dense: Grid3,
    k: usize,
    transform: &Transform,
    origin: [i32; 3],
    name: &str,
    reporter: &mut dyn Reporter,
) -> Result<(Grid3, Transform, [i32; 3])> {
    let dims = dense.dims;
    Ok(match k {
        1 => (dense, transform.clone(), origin),
        _ => {
            let refined = refine_density(&dense, k);
            reporter.note(&format!(
                "grid '{name}' is {}x{}x{} voxels, too few for strokes; it is stylized and written {k}x finer ({}x{}x{}; --upsample 1 keeps the file's resolution)",
                dims[0], dims[1], dims[2], refined.dims[0], refined.dims[1], refined.dims[2]
            ));
            (refined, refine_transform(transform, k), refine_origin(origin, k)?)
        }
    })
}

/// The colour stage of a frame: [`COLOR_VIEWS`] times the density's
/// iterations per octave, at the colour layer's rate, guarded.
fn color_stage_params(s: &VolumeSettings, params: &FrameParams) -> ColorStageParams {
    ColorStageParams {
        iterations: COLOR_VIEWS * s.iterations(),
        learning_rate: nst3d_stylize::color::LEARNING_RATE,
        grey_guard: nst3d_stylize::color_stage::GREY_GUARD,
        smoke_term: nst3d_stylize::color_stage::SMOKE_TERM,
        // The density moves with the colour within the job's own scale
        // limits (its --smin/--smax and strength), whatever the mode.
        density: Some(JointDensity {
            learning_rate: nst3d_stylize::color_stage::JOINT_DENSITY_RATE,
            smin: params.limits.smin,
            smax: params.limits.smax,
        }),
    }
}

/// The preview: before | after | the painting, all scaled to one readable
/// height (`grids`: the input, the stylized density and its colour).
fn write_preview(
    path: &Path,
    loss: &ViewLoss,
    view: &ViewSpec,
    (input, density, color): (&Grid3, &Grid3, Option<&[Grid3]>),
    style: &Image,
) -> Result<()> {
    // Before | after | the painting, all scaled to one readable height.
    let h = PREVIEW_HEIGHT;
    let before = resize_to_height(&display(loss, input, view)?, h);
    let after = match color {
        None => display(loss, density, view)?,
        Some(c) => nst3d_render::upsample2x(&nst3d_stylize::color_view_image(density, c, view)?),
    };
    let after = resize_to_height(&after, h);
    let painting = resize_to_height(style, h);
    write_png(path, &side_by_side(&[&before, &after, &painting]))?;
    Ok(())
}

/// What a style map's job made: the density (scaled by the colour stage
/// with `color`) and its colour.
struct Mapped {
    result: nst3d_stylize::FrameResult,
    density: Grid3,
    color: Option<Vec<Grid3>>,
}

/// The single-frame job with a style map: every painting's loss over its
/// region (`nst3d_stylize::guided`), the map sampled on the padded box `at`;
/// with `--color` the colour stage then gives each region its own
/// painting's colour (`nst3d_stylize::guided_color`) over the regions as
/// the density's field carried them. The preview shows input | map |
/// result | the paintings.
fn stylize_mapped(
    s: &VolumeSettings,
    vgg: &nst3d_features::Vgg19,
    (padded, gamma): (&Grid3, f32),
    at: &MapBox,
    input: Option<(&VdbFile, &Path)>,
    (params, views): (&FrameParams, &[ViewSpec]),
    reporter: &mut dyn Reporter,
) -> Result<Mapped> {
    let source = s.map_source()?.context("a style map's job needs a map")?;
    let labels = source.labels(s.style_map_labels);
    let map = style_map::sample(&source, input, at, labels)?;
    let regions = style_map::regions(&map, padded, s.styles().len(), labels)?;
    let (grey_pictures, losses) = load_paintings(s, vgg, false)?;
    let loss = MapLoss::new(losses);
    let (color_pictures, color_loss) = match s.color {
        true => load_paintings(s, vgg, true).map(|(p, l)| (Some(p), Some(MapLoss::new(l))))?,
        false => (None, None),
    };
    let color_params = color_stage_params(s, params);
    let color_iterations = if s.color { color_params.iterations } else { 0 };
    reporter.begin((s.octaves() * s.iterations() + color_iterations) as u64);
    let result = stylize_frame_map(padded, &loss, &regions, params, views, &mut |p| reporter.step(&progress_line(p)))?;
    if result.density.data.iter().any(|v| !v.is_finite()) {
        bail!("stylization produced non-finite densities (try a smaller --lr)");
    }
    let (density, color) = match &color_loss {
        None => (result.density.clone(), None),
        Some(color_loss) => {
            let moved = nst3d_stylize::guided::carried_regions(&result.field, &regions);
            let c = nst3d_stylize::stylize_color_map(
                &result.density,
                (color_loss, &loss, &moved),
                &color_views(s, padded.dims, gamma),
                &color_params,
                &mut |p| reporter.step(&color_line(p)),
            )?;
            (c.density, Some(c.color))
        }
    };
    reporter.end();
    if let Some(path) = &s.preview {
        let pictures = color_pictures.as_ref().unwrap_or(&grey_pictures);
        let plain = ViewLoss::new(vgg, &grey_pictures[0], &s.style_spec())?;
        let grids = (padded, &regions[..], &density, color.as_deref());
        write_map_preview(path, &plain, &views[0], grids, pictures)?;
    }
    Ok(Mapped { result, density, color })
}

/// The views of `--eval-cameras` around the padded grid (none without).
fn held_out_views(s: &VolumeSettings, padded: &Grid3) -> Result<Vec<ViewSpec>> {
    Ok(match &s.eval_cameras {
        Some(e) => {
            let cams = CameraSet::parse(e)?.cameras(&Lens::of(s), padded.dims);
            let g = absorption_for(s.absorption, cams.iter().map(|c| (padded, c)))?;
            views_of(&cams, g, s.equalize)
        }
        None => Vec::new(),
    })
}

/// Stylizes one dense grid in memory with the settings of a single frame
/// (`s.input` and `s.out` are not used; `s.preview` is written when set):
/// `dense` is a box whose voxel (0,0,0) is index `origin` of a grid with
/// `transform` (camera files are placed with it; an array with no file
/// behind it passes [`Transform::uniform`]`(1.0)` and the origin 0).
/// `name` is the grid's name in messages.
pub fn stylize_grid(
    s: &VolumeSettings,
    dense: Grid3,
    transform: &Transform,
    origin: [i32; 3],
    name: &str,
    reporter: &mut dyn Reporter,
) -> Result<StylizedGrid> {
    stylize_grid_in(s, dense, transform, origin, name, None, reporter)
}

/// The progress bar's line for one optimisation iteration.
fn progress_line(p: &nst3d_stylize::Progress) -> String {
    format!("octave {}/{} iteration {}/{} loss {:.4e}", p.octave + 1, p.octaves, p.iteration, p.iterations, p.loss)
}

/// A frame's grid made ready to stylize: refined, padded, with its cameras.
struct Prepared {
    /// The refined density plus `margin` empty voxels on every side.
    padded: Grid3,
    padded_origin: [i32; 3],
    transform: Transform,
    origin: [i32; 3],
    /// The refined box's size without the margin.
    dims: [usize; 3],
    margin: usize,
    upsample: usize,
    vmax: f32,
    gamma: f32,
    views: Vec<ViewSpec>,
}

/// Checks `dense`, refines and pads it and places the cameras on it.
fn prepare(
    s: &VolumeSettings,
    dense: Grid3,
    transform: &Transform,
    origin: [i32; 3],
    name: &str,
    reporter: &mut dyn Reporter,
) -> Result<Prepared> {
    s.check()?;
    if dense.is_empty() || dense.data.iter().all(|v| *v == 0.0) {
        bail!("grid '{name}' is empty: there is no smoke to stylize");
    }
    if let Some(v) = dense.data.iter().find(|v| !v.is_finite()) {
        bail!("grid '{name}' holds a non-finite density ({v})");
    }
    let upsample = s.upsample.factor(dense.dims);
    VolumeSettings::check_memory(dense.dims.map(|d| d * upsample), false)?;
    let (dense, transform, origin) = refine(dense, upsample, transform, origin, name, reporter)?;
    let dims = dense.dims;
    let vmax = s.vmax_for(*dims.iter().max().unwrap_or(&1));
    let margin = s.margin(vmax);
    let padded = pad(&dense, margin);
    let padded_origin = origin.map(|o| o - margin as i32);
    let cameras = Cameras::of(s)?.at(0.0, padded.dims, &transform, padded_origin);
    let gamma = absorption_for(s.absorption, cameras.iter().map(|c| (&padded, c)))?;
    let views = views_of(&cameras, gamma, s.equalize);
    Ok(Prepared { padded, padded_origin, transform, origin, dims, margin, upsample, vmax, gamma, views })
}

/// [`stylize_grid_in`] with several paintings, each where the style map
/// puts it.
fn stylize_grid_mapped(
    s: &VolumeSettings,
    vgg: &nst3d_features::Vgg19,
    p: Prepared,
    input: Option<(&VdbFile, &Path)>,
    reporter: &mut dyn Reporter,
) -> Result<StylizedGrid> {
    let params = s.frame_params(p.vmax, &p.views[0]);
    let at = MapBox {
        dims: p.padded.dims,
        origin: p.padded_origin,
        transform: &p.transform,
        inner: ([p.margin; 3], p.dims),
        up: s.up,
    };
    let m = stylize_mapped(s, vgg, (&p.padded, p.gamma), &at, input, (&params, &p.views), reporter)?;
    Ok(StylizedGrid {
        cameras: p.views.len(),
        loss_before: m.result.loss_before,
        loss_after: m.result.loss_after,
        density: m.density,
        color: m.color,
        margin: p.margin,
        upsample: p.upsample,
        dims: p.dims,
        origin: p.origin,
        transform: p.transform,
        held_out: None,
    })
}

/// The colour stage's views: [`COLOR_VIEWS`] omniview cameras around a
/// padded grid of `dims`, at the job's absorption `gamma`.
fn color_views(s: &VolumeSettings, dims: [usize; 3], gamma: f32) -> Vec<ViewSpec> {
    views_of(&CameraSet::Omniview(COLOR_VIEWS).cameras(&Lens::of(s), dims), gamma, false)
}

/// The progress bar's line for one colour iteration.
fn color_line(p: &nst3d_stylize::ColorProgress) -> String {
    format!("colour iteration {}/{} loss {:.4e}", p.iteration, p.iterations, p.loss)
}

/// [`stylize_grid`] of a grid read from `input` (the file and its path),
/// where a `--style-map NAME` finds its grid.
fn stylize_grid_in(
    s: &VolumeSettings,
    dense: Grid3,
    transform: &Transform,
    origin: [i32; 3],
    name: &str,
    input: Option<(&VdbFile, &Path)>,
    reporter: &mut dyn Reporter,
) -> Result<StylizedGrid> {
    let p = prepare(s, dense, transform, origin, name, reporter)?;
    let (style, vgg) = load_style_and_vgg(s)?;
    if s.map_source()?.is_some() {
        return stylize_grid_mapped(s, &vgg, p, input, reporter);
    }
    let Prepared { padded, transform, origin, dims, margin, upsample: k, vmax, gamma, views, .. } = p;
    let view = views[0].clone();
    // The density follows the grey loss whether or not colour follows.
    let grey_style = match s.color {
        true => nst3d_io::image::luminance_rgb(&style),
        false => style.clone(),
    };
    let loss = ViewLoss::new(&vgg, &grey_style, &s.style_spec())?;
    let color_loss = s.color.then(|| ViewLoss::new(&vgg, &style, &s.style_spec())).transpose()?;
    let params = s.frame_params(vmax, &view);
    let color_params = color_stage_params(s, &params);
    // The colour views see the smoke at the job's absorption, as its own
    // views do. (The smallest absorption over them instead, so the colour is
    // placed as deep as any view could see, measured worse: smoke_000003,
    // Woman with a Hat 0.822 of the grey result's held-out colour loss
    // against 0.592; docs/design/color.md.)
    let color_views = match s.color {
        true => color_views(s, padded.dims, gamma),
        false => Vec::new(),
    };
    let color_iterations = if s.color { color_params.iterations } else { 0 };
    let held_out = held_out_views(s, &padded)?;

    reporter.begin((s.octaves() * s.iterations() + color_iterations) as u64);
    let result = stylize_frame_views(&padded, &loss, &params, &views, &mut |p| reporter.step(&progress_line(p)))?;
    if result.density.data.iter().any(|v| !v.is_finite()) {
        bail!("stylization produced non-finite densities (try a smaller --lr)");
    }
    // The colour stage may move the density with the colour
    // ([`ColorStageParams::density`]); the file gets the density it returns.
    let (density, color) = match &color_loss {
        None => (result.density, None),
        Some(cl) => {
            let c = stylize_color(&result.density, cl, &loss, &color_views, &color_params, &mut |p| {
                reporter.step(&color_line(p))
            })?;
            (c.density, Some(c.color))
        }
    };
    reporter.end();

    if let Some(preview) = &s.preview {
        write_preview(preview, &loss, &view, (&padded, &density, color.as_deref()), &style)?;
    }
    let held_out = match (held_out.is_empty(), &color, &color_loss) {
        (true, _, _) => None,
        (false, Some(c), Some(cl)) => Some(HeldOut::measure_color(cl, &padded, &density, c, &held_out)?),
        (false, _, _) => Some(HeldOut::measure(&loss, &padded, &density, &held_out)?),
    };
    Ok(StylizedGrid {
        cameras: views.len(),
        loss_before: result.loss_before,
        loss_after: result.loss_after,
        density,
        color,
        margin,
        upsample: k,
        dims,
        origin,
        transform,
        held_out,
    })
}
