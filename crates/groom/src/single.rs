//! One groom stylized (strand style transfer paper, Alg. 1 for one frame)
//! by [`nst3d_strands::pipeline::stylize`]. The groom and its head mesh are
//! read and checked and the output format picked from the output's
//! extension before the slow part. The stylized guides are written
//! atomically in the input's topology (proxies are render-only and not
//! written); the preview is before | after | painting from the front camera
//! (the direction the groom's roots face).

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use nst3d_core::{Groom, Reporter, TriMesh, UpAxis};
use nst3d_features::Vgg19;
use nst3d_io::groom::{read_groom_file, GroomFile};
use nst3d_io::mesh::read_mesh;
use nst3d_strands::pipeline::{
    color_iterations, stylize_mapped, FrameHooks, HeldOut, IterationReport, StrandScene, StrandShares,
};
use nst3d_strands::FlatStrands;

use crate::axis;
use crate::checks::Checks;
use crate::output::{attribute_notes, write_groom};
use crate::preview::{write_map_preview, write_preview};
use crate::settings::{OutFormat, StrandSettings, Temporal};
use crate::NO_MESH;

/// What a single-groom job did.
#[derive(Clone, Debug)]
pub struct GroomReport {
    /// The input groom.
    pub groom: PathBuf,
    /// Strands written (the input's).
    pub strands: usize,
    /// Control points written (the input's).
    pub points: usize,
    /// The preset's name.
    pub preset: &'static str,
    /// Proxy strands grown for rendering.
    pub proxies: usize,
    /// Iterations over all scales.
    pub iterations: u32,
    /// Square render size.
    pub render_size: usize,
    /// NNST loss over the evaluation views before and after.
    pub eval_before: f32,
    /// After.
    pub eval_after: f32,
    /// After, with the NNST targets matched again on the result.
    pub eval_after_rematched: f32,
    /// The hair-only loss from views the optimizer did not use.
    pub held_out: HeldOut,
    /// Lengths and collisions of what was written.
    pub checks: Checks,
    /// The written file.
    pub out: PathBuf,
}

impl GroomReport {
    /// Relative drop of the evaluation loss, `1 − after / before`.
    pub fn loss_drop(&self) -> f32 {
        1.0 - self.eval_after / self.eval_before
    }
}

/// Stylizes the groom `s.groom` into `s.out` (and `s.preview`).
pub fn stylize_groom_file(s: &StrandSettings, reporter: &mut dyn Reporter) -> Result<GroomReport> {
    let format = OutFormat::of(&s.out)?;
    s.check()?;
    s.check_outputs(None)?;
    if s.frames.is_some() {
        bail!("{} names frames: run it as a sequence", s.groom.display());
    }
    if s.temporal != Temporal::EmaOneEuro || s.style_flow.is_some() {
        bail!("--temporal and --style-flow apply to sequences; add --frames");
    }
    let input = read_groom_file(&s.groom)?;
    let groom = &input.groom;
    // A bad style map is one line before anything else is said.
    crate::style_map::map_values(s, &s.groom, groom)?;
    // After the read, not before it, so that a bad file is still one line on stderr.
    reporter.status(&format!(
        "read {}: {} strands, {} points",
        s.groom.display(),
        groom.strand_count(),
        groom.point_count()
    ));
    for note in attribute_notes(&input, format) {
        reporter.note(&format!("{}: {note}", s.groom.display()));
    }
    let (up, note) = axis::resolve(s.up, &input);
    if let Some(note) = note {
        reporter.note(&format!("{}: {note}", s.groom.display()));
    }
    let head = s.mesh.as_deref().map(read_mesh).transpose()?;
    let s = StrandSettings { up: Some(up), ..s.clone() };
    let r = stylize_groom(&s, groom, head.as_ref(), reporter)?;
    write_groom(&s.out, format, &r.strands, Some(&with_axis(input, up)), r.colors.as_deref())?;
    Ok(r.report)
}

/// A groom stylized in memory: what [`stylize_groom`] returns.
#[derive(Clone, Debug)]
pub struct StylizedGroom {
    /// The stylized guides in the input's topology (same strands, same
    /// point counts, in the same order).
    pub strands: FlatStrands,
    /// With `--color`: the stylized colour of every point of `strands`,
    /// one list per strand.
    pub colors: Option<Vec<Vec<[f32; 3]>>>,
    /// What the job did (`groom` and `out` are the settings' paths).
    pub report: GroomReport,
}

/// The input file as the output should describe it: the job's up axis in
/// the layer (a z-up `.ply` written as `.usda` says `upAxis = "Z"`).
pub(crate) fn with_axis(mut input: GroomFile, up: UpAxis) -> GroomFile {
    input.usd_primvars.up_axis = Some(up.usd_name().to_string());
    input
}

/// Stylizes `groom` grown on `head` (if any) with the settings of a single
/// groom; `s.groom`, `s.mesh` and `s.out` are not read or written (a front
/// end with the groom in memory passes it here), `s.preview` is written
/// when set. Both are in the axes `s.up` names (`None`: y-up), and so are
/// the returned strands.
pub fn stylize_groom(
    s: &StrandSettings,
    groom: &Groom,
    head: Option<&TriMesh>,
    reporter: &mut dyn Reporter,
) -> Result<StylizedGroom> {
    s.check()?;
    let up = s.up.unwrap_or(UpAxis::Y);
    let groom = &*axis::groom_to_y_up(groom, up);
    let head_y_up = head.map(|h| axis::mesh_to_y_up(h, up));
    let head = head_y_up.as_deref();
    if head.is_none() {
        reporter.note(NO_MESH);
    }
    let paintings = s.paintings().iter().map(|p| nst3d_io::image::load_style(p, 1.0)).collect::<Result<Vec<_>, _>>()?;
    let map = crate::style_map::map_values(s, &s.groom, groom)?;
    let vgg = Vgg19::load(s.weights.as_deref())?;
    let params = s.stylize_params(groom.strand_count());
    StrandSettings::check_memory(&params, groom.strand_count())?;
    reporter.status(&params.look_line());

    let scene =
        StrandScene::build(groom, head, &params, &mut |m| reporter.status(m)).with_context(|| match &s.mesh {
            Some(m) => format!("{} on {}", s.groom.display(), m.display()),
            None => s.groom.display().to_string(),
        })?;
    let shares = match &map {
        Some(values) => crate::style_map::shares(s, &scene, values)?,
        None => StrandShares::single(scene.rest.strand_count()),
    };
    let total: u32 = params.iterations.iter().sum();
    let color_total = if params.color { color_iterations() } else { 0 };
    reporter.begin((total + color_total) as u64);
    let refs: Vec<&nst3d_core::Image> = paintings.iter().collect();
    let result = stylize_mapped(&scene, &refs, &shares, &vgg, &params, FrameHooks::default(), &mut |r| {
        report_iteration(reporter, r, params.held_out_views)
    })?;
    reporter.end();

    let input = FlatStrands::from_groom(groom)?;
    let written = scene.to_input_topology(&input, &result.guides)?;
    let colors = match &result.colors {
        Some(c) => Some(scene.colors_to_input_topology(&input, &c[..scene.raw_guides.points.len()])?),
        None => None,
    };
    match &s.preview {
        Some(preview) if map.is_some() => {
            write_map_preview(preview, &scene, (&result.strands, result.colors.as_deref()), &shares, &refs)?
        }
        Some(preview) => write_preview(preview, &scene, &result.strands, result.colors.as_deref(), &paintings[0])?,
        None => {}
    }
    let checks = Checks::new(groom, &scene, &result.guides, &written, head)?;
    let written = axis::strands_from_y_up(written, up);
    let report = GroomReport {
        groom: s.groom.clone(),
        strands: written.strand_count(),
        points: written.points.len(),
        preset: params.preset.name,
        proxies: scene.rest.strand_count() - scene.guide_count,
        iterations: total,
        render_size: params.render_size,
        eval_before: result.eval_before,
        eval_after: result.eval_after,
        eval_after_rematched: result.eval_after_rematched,
        held_out: result.held_out.clone(),
        checks,
        out: s.out.clone(),
    };
    Ok(StylizedGroom { strands: written, colors, report })
}

/// One iteration on the progress bar; after the last of the shape, the
/// measurement that follows (a minute at Short Hair size with nothing else
/// on the bar).
fn report_iteration(reporter: &mut dyn Reporter, r: &IterationReport, held_out_views: usize) {
    reporter.step(&if r.color {
        format!("colour iteration {}/{} loss {:.4e}", r.iteration, r.iterations, r.loss)
    } else {
        format!("scale {}/3 iteration {}/{} loss {:.4e}", r.scale + 1, r.iteration, r.iterations, r.loss)
    });
    if !r.color && r.scale == 2 && r.iteration == r.iterations {
        reporter.status(&format!(
            "measuring the result: NNST loss from the optimised views and {held_out_views} held-out views"
        ));
    }
}
