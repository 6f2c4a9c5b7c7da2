//! One OpenVDB frame stylized (paper Sec. 3): the grid is read, densified
//! over its active box plus a margin (a velocity may carry smoke a little
//! outside its original shape, Sec. 3.3), stylized by
//! [`nst3d_stylize::stylize_frame_views`], and written back sparse into the
//! same index space with the same transform; a grid too small for strokes
//! is refined first and written `k` times finer ([`crate::upsample`]). A
//! before | after | painting preview is rendered from the first camera.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use nst3d_core::Reporter;
use nst3d_io::image::{resize_to_height, side_by_side, write_png};
use nst3d_io::vdb::read_vdb;
use nst3d_stylize::{stylize_frame_views, Mode, ViewLoss};

use crate::cameras::{CameraSet, Cameras, Lens};
use crate::dense::pad;
use crate::look::{absorption_for, display, mean_loss, views_of, PREVIEW_HEIGHT};
use crate::output::write_stylized;
use crate::settings::VolumeSettings;
use crate::style::load_style_and_vgg;
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
    /// Mean style loss over the evaluation cameras before and after, when asked for.
    pub held_out: Option<(f32, f32)>,
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

/// Stylizes the single frame `s.input` into `s.out` (and `s.preview`).
pub fn stylize_frame_file(s: &VolumeSettings, reporter: &mut dyn Reporter) -> Result<FrameReport> {
    s.check()?;
    // Read and check everything before the slow part, so a bad input fails in a second.
    let file = read_vdb(&s.input)?;
    let grid = file.grid(&s.grid).with_context(|| {
        let names: Vec<&str> = file.grids.iter().map(|g| g.name.as_str()).collect();
        format!("{}: no grid named '{}' (grids: {})", s.input.display(), s.grid, names.join(", "))
    })?;
    let (mut bx, dense) = grid.to_dense()?;
    let k = s.upsample.factor(bx.dims);
    let (dense, transform) = match k {
        1 => (dense, grid.transform.clone()),
        _ => {
            let refined = (refine_density(&dense, k), refine_transform(&grid.transform, k));
            reporter.note(&format!(
                "grid '{}' is {}x{}x{} voxels, too few for strokes; it is stylized and written {k}x finer ({}x{}x{}; --upsample 1 keeps the file's resolution)",
                grid.name, bx.dims[0], bx.dims[1], bx.dims[2], refined.0.dims[0], refined.0.dims[1], refined.0.dims[2]
            ));
            bx.origin = refine_origin(bx.origin, k)?;
            bx.dims = refined.0.dims;
            refined
        }
    };
    let (style, vgg) = load_style_and_vgg(s)?;

    let vmax = s.vmax_for(*bx.dims.iter().max().unwrap_or(&1));
    let margin = s.margin(vmax);
    let padded = pad(&dense, margin);
    let origin = bx.origin.map(|o| o - margin as i32);
    let cameras = Cameras::of(s)?.at(0.0, padded.dims, &transform, origin);
    let gamma = absorption_for(s.absorption, cameras.iter().map(|c| (&padded, c)))?;
    let views = views_of(&cameras, gamma, s.equalize);
    let view = views[0].clone();
    let loss = ViewLoss::new(&vgg, &style, &s.style_spec())?;
    let params = s.frame_params(vmax, &view);
    let held_out = match &s.eval_cameras {
        Some(e) => {
            let cams = CameraSet::parse(e)?.cameras(&Lens::of(s), padded.dims);
            let g = absorption_for(s.absorption, cams.iter().map(|c| (&padded, c)))?;
            views_of(&cams, g, s.equalize)
        }
        None => Vec::new(),
    };
    let held_out_before = mean_loss(&loss, &padded, &held_out)?;

    reporter.begin((s.octaves * s.iterations()) as u64);
    let result = stylize_frame_views(&padded, &loss, &params, &views, &mut |p| {
        reporter.step(&format!(
            "octave {}/{} iteration {}/{} loss {:.4e}",
            p.octave + 1,
            p.octaves,
            p.iteration,
            p.iterations,
            p.loss
        ))
    })?;
    reporter.end();
    if result.density.data.iter().any(|v| !v.is_finite()) {
        bail!("stylization produced non-finite densities (try a smaller --lr)");
    }

    for dropped in write_stylized(&s.out, &file, &grid.name, &transform, origin, &result.density)? {
        reporter.note(&format!("{dropped} is not copied to the output"));
    }
    if let Some(preview) = &s.preview {
        // Before | after | the painting, all scaled to one readable height.
        let h = PREVIEW_HEIGHT;
        let before = resize_to_height(&display(&loss, &padded, &view)?, h);
        let after = resize_to_height(&display(&loss, &result.density, &view)?, h);
        let painting = resize_to_height(&style, h);
        write_png(preview, &side_by_side(&[&before, &after, &painting]))?;
    }
    let held_out = match held_out.is_empty() {
        true => None,
        false => Some((held_out_before, mean_loss(&loss, &result.density, &held_out)?)),
    };
    Ok(FrameReport {
        input: s.input.clone(),
        grid: grid.name.clone(),
        dims: bx.dims,
        upsample: k,
        mode: s.mode,
        cameras: views.len(),
        loss_before: result.loss_before,
        loss_after: result.loss_after,
        held_out,
        out: s.out.clone(),
    })
}
