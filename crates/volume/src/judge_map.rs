//! The style map's judge: each region of a stylized file scored against
//! each painting by the guided Gram loss (the loss a style map optimises,
//! `nst3d_stylize::guided`), from the held-out cameras, as the ratio to the
//! baseline's (the input's) loss of the same region against the same
//! painting. Raw losses cannot be compared across paintings (one painting's
//! are smaller than another's everywhere); ratios can: a region followed
//! its own painting when its ratio toward that painting is the lower.
//!
//! Every file is judged over the same pixels: each region's guide is
//! rendered through the baseline's smoke, with the map sampled on the
//! baseline's box as `nst3d volume` samples it. With two paintings each
//! view also measures the boundary's seam ([`crate::seam`]).

use std::path::PathBuf;

use anyhow::{bail, Result};
use nst3d_core::Grid3;
use nst3d_core::Reporter;
use nst3d_features::Vgg19;
use nst3d_io::vdb::read_vdb;
use nst3d_stylize::{region_guides, view_image, MapLoss, ViewLoss, ViewSpec};

use crate::judge::{ratio, scene, JudgeSettings, Ratios};
use crate::seam::{seam, Seam};
use crate::style_map::{regions, sample, MapBox, MapSource};

/// One result's region-by-region verdict.
#[derive(Clone, Debug)]
pub struct MapVerdict {
    /// The file judged.
    pub file: PathBuf,
    /// `[region][painting]`: loss ratios over the views that show the
    /// region (`None` where no view does).
    pub regions: Vec<Vec<Option<Ratios>>>,
    /// Per view, the seam between the two regions (`None` for a view that
    /// shows no boundary, and for maps of more than two paintings).
    pub seams: Vec<Option<Seam>>,
}

/// Judges every result region by region; `style_map` as `nst3d volume
/// --style-map` takes it, `labels` as `--style-map-labels`.
pub fn judge_map(
    s: &JudgeSettings,
    style_map: &str,
    labels: bool,
    reporter: &mut dyn Reporter,
) -> Result<Vec<MapVerdict>> {
    let paintings = s.styles();
    if paintings.len() < 2 {
        bail!("a style map is judged against two or more paintings: give --style once for each");
    }
    let scene = scene(s)?;
    let source = MapSource::parse(style_map)?;
    let labels = source.labels(labels);
    let input = read_vdb(&s.baseline)?;
    let base = &scene.files[0].0;
    let at =
        MapBox { dims: base.dims, origin: scene.origin, transform: &scene.transform, inner: scene.inner, up: s.up };
    let regions = regions(&sample(&source, Some((&input, &s.baseline)), &at, labels)?, base, paintings.len(), labels)?;
    let vgg = Vgg19::load(s.weights.as_deref())?;
    let mut losses = Vec::new();
    for p in &paintings {
        let picture = nst3d_io::image::luminance_rgb(&nst3d_io::image::load_style(p, s.style_scale)?);
        losses.push(ViewLoss::new(&vgg, &picture, &s.spec)?);
    }
    let judge = MapLoss::new(losses);
    reporter.begin(scene.files.len() as u64);
    // Per file, per view: [region] -> per painting; and the seams.
    let mut tables = Vec::new();
    let mut seams = Vec::new();
    for (d, _) in &scene.files {
        let per_view =
            scene.views.iter().map(|v| judge.region_table(d, base, &regions, v)).collect::<Result<Vec<_>, _>>()?;
        tables.push(per_view);
        seams.push(scene.views.iter().map(|v| view_seam(base, d, &regions, v)).collect::<Result<Vec<_>>>()?);
        reporter.step("judged");
    }
    reporter.end();
    let column = |t: &[Vec<Option<Vec<f32>>>], r: usize, p: usize| -> Vec<f32> {
        t.iter().filter_map(|view| view[r].as_ref().map(|row| row[p])).collect()
    };
    Ok(s.results
        .iter()
        .zip(&tables[1..])
        .zip(seams.into_iter().skip(1))
        .map(|((file, t), seams)| MapVerdict {
            file: file.clone(),
            seams,
            regions: (0..regions.len())
                .map(|r| {
                    (0..paintings.len())
                        .map(|p| {
                            let (a, b) = (column(t, r, p), column(&tables[0], r, p));
                            (!a.is_empty()).then(|| ratio(&a, &b))
                        })
                        .collect()
                })
                .collect(),
        })
        .collect())
}

/// The seam of `d` against the baseline `base` in `view`, over the
/// boundary of the baseline's two regions; `None` for other region counts.
fn view_seam(base: &Grid3, d: &Grid3, regions: &[Grid3], view: &ViewSpec) -> Result<Option<Seam>> {
    if regions.len() != 2 {
        return Ok(None);
    }
    let guides = region_guides(base, regions, view)?;
    let plane = guides.plane();
    let smoke: Vec<bool> = (0..plane).map(|p| guides.data[p] + guides.data[plane + p] > 0.0).collect();
    Ok(seam(&view_image(base, view)?, &view_image(d, view)?, &guides.data[plane..], &smoke))
}
