//! The held-out judge: how much closer to a painting a stylized file is than
//! a baseline file, seen from cameras no optimisation used, by the real
//! VGG-19 Gram style loss. It reads files only, so it does not matter which
//! method made them (per-frame optimisation, a sequence, a network).
//!
//! Every file is placed in one shared box (their union, so the cameras and
//! the absorption are the same for all) and scored twice per view:
//! - **grey**: the transmittance render against the painting's luminance,
//!   the loss the grey pipeline optimises;
//! - **colour** (with [`JudgeSettings::color`]): the emission–absorption
//!   render with the file's colour grid (`Cd` or `color`; white where a file
//!   has none) against the colour painting, over the whole
//!   picture and over the smoke only (the pixels the file's density shows;
//!   the background is out of any colour's reach).
//!
//! A verdict is the per-view ratio loss(result) / loss(baseline): below 1
//! is closer to the painting; its worst (largest) view is the side from
//! which the result moved least.

use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Result};
use nst3d_core::{Grid3, Reporter, UpAxis};
use nst3d_features::Vgg19;
use nst3d_io::vdb::{read_vdb, DenseBox, Transform};
use nst3d_stylize::{StyleSpec, ViewLoss, ViewSpec};

use crate::cameras::{CameraSet, Lens};
use crate::dense::{color_grid, color_in_box, in_box, pad, union_box, DenseColor};
use crate::look::{absorption_for, views_of};
use crate::upsample::{refine_density, refine_origin, refine_transform};

/// Empty voxels around the shared box, so no camera clips the smoke.
const MARGIN: usize = 4;

/// What to judge and how.
#[derive(Clone, Debug)]
pub struct JudgeSettings {
    /// The painting.
    pub style: PathBuf,
    /// Further paintings, for a style map's judge ([`crate::judge_map`]).
    pub more_styles: Vec<PathBuf>,
    /// Every result is compared with this file (the input, or another result).
    pub baseline: PathBuf,
    /// The files judged.
    pub results: Vec<PathBuf>,
    /// Held-out cameras (`ring:N[:ELEV]`, `omniview:N`, `front`).
    pub cameras: String,
    /// The density grid's name.
    pub grid: String,
    /// The files' up axis (the ring goes around it).
    pub up: UpAxis,
    /// Also score in colour.
    pub color: bool,
    /// VGG-19 weights (default: the bundled ones).
    pub weights: Option<PathBuf>,
    /// The Gram layers and their weights (default: the paper's relu1_1..relu4_1,
    /// equal). One layer alone shows where a change acts: colour moves the
    /// shallow layers most.
    pub spec: StyleSpec,
    /// The painting's scale, as `nst3d volume --style-scale` takes it
    /// (default: the volume job's own default). A Gram matrix depends on the
    /// painting's size in pixels against the picture's: judged at another
    /// scale than the job painted at, a result is measured against strokes
    /// of another size than it was asked for (a judge reading the painting
    /// at its full size while the job ran at 0.5 misjudged colour results;
    /// docs/design/color.md).
    pub style_scale: f32,
    /// Absorption γ of every picture (default: the smallest automatic one
    /// over the baseline's views, so none saturates).
    pub absorption: Option<f32>,
}

impl JudgeSettings {
    /// The judge of docs/design/feedforward.md: 8 azimuths at 30° elevation.
    pub fn new(style: impl Into<PathBuf>, baseline: impl Into<PathBuf>, results: Vec<PathBuf>) -> Self {
        Self {
            style: style.into(),
            more_styles: Vec::new(),
            baseline: baseline.into(),
            results,
            cameras: "ring:8:30".into(),
            grid: "density".into(),
            up: UpAxis::Z,
            color: false,
            weights: None,
            spec: StyleSpec::default(),
            style_scale: crate::VolumeSettings::new("", "", "").style_scale,
            absorption: None,
        }
    }

    /// `style`, then `more_styles`.
    pub fn styles(&self) -> Vec<PathBuf> {
        std::iter::once(self.style.clone()).chain(self.more_styles.iter().cloned()).collect()
    }
}

/// Per view, loss(result) / loss(baseline).
#[derive(Clone, Debug, PartialEq)]
pub struct Ratios(pub Vec<f32>);

/// Per view, `a / b`; 1 where the baseline scores 0 (a view with no smoke).
pub(crate) fn ratio(a: &[f32], b: &[f32]) -> Ratios {
    Ratios(a.iter().zip(b).map(|(a, b)| if *b > 0.0 { a / b } else { 1.0 }).collect())
}

impl Ratios {
    /// The largest ratio: the view that moved least towards the painting.
    pub fn worst(&self) -> f32 {
        self.0.iter().copied().fold(f32::NEG_INFINITY, f32::max)
    }

    /// The mean ratio.
    pub fn mean(&self) -> f32 {
        self.0.iter().sum::<f32>() / self.0.len().max(1) as f32
    }

    /// The median ratio (the upper one of an even count).
    pub fn median(&self) -> f32 {
        let mut v = self.0.clone();
        v.sort_by(f32::total_cmp);
        v[v.len() / 2]
    }
}

/// One result's verdict.
#[derive(Clone, Debug)]
pub struct Verdict {
    /// The file judged.
    pub file: PathBuf,
    /// Grey loss ratios.
    pub grey: Ratios,
    /// Colour loss ratios, with [`JudgeSettings::color`].
    pub color: Option<Ratios>,
    /// The same over the smoke only
    /// ([`nst3d_stylize::ViewLoss::loss_color_on_smoke`]).
    pub color_smoke: Option<Ratios>,
}

/// One file's density and (white if absent) colour, before boxing.
struct Loaded {
    density: (DenseBox, Grid3),
    color: Option<DenseColor>,
    transform: Transform,
}

fn load(path: &Path, grid: &str) -> Result<Loaded> {
    let file = read_vdb(path).map_err(|e| anyhow!("{e}"))?;
    let g = crate::dense::density_grid(&file, path, grid)?;
    Ok(Loaded { density: g.to_dense()?, color: color_grid(&file)?, transform: g.transform.clone() })
}

/// `f` made `k` times finer (trilinear, as `nst3d volume --upsample` refines).
fn refine(f: Loaded, k: usize) -> Result<Loaded> {
    if k == 1 {
        return Ok(f);
    }
    let up = |bx: DenseBox, g: &Grid3| -> Result<(DenseBox, Grid3)> {
        let g = refine_density(g, k);
        Ok((DenseBox { origin: refine_origin(bx.origin, k)?, dims: g.dims }, g))
    };
    let density = up(f.density.0, &f.density.1)?;
    let color = match f.color {
        None => None,
        Some((bx, ch)) => {
            let [r, g, b] = ch;
            let (bx2, r) = up(bx, &r)?;
            Some((bx2, [r, up(bx, &g)?.1, up(bx, &b)?.1]))
        }
    };
    Ok(Loaded { density, color, transform: refine_transform(&f.transform, k) })
}

/// Every file (the baseline first) in one shared box, padded, with the
/// cameras and absorption every file is seen with.
pub(crate) struct Scene {
    /// Density, and colour where the file has it, per file.
    pub files: Vec<(Grid3, Option<Vec<Grid3>>)>,
    /// Index of the padded box's voxel (0,0,0) under `transform`.
    pub origin: [i32; 3],
    /// The finest file's index-to-world transform.
    pub transform: Transform,
    /// The union of the files' boxes inside the padded box: offset, size.
    pub inner: ([usize; 3], [usize; 3]),
    /// The held-out views.
    pub views: Vec<ViewSpec>,
}

/// Loads the baseline and the results into one [`Scene`].
pub(crate) fn scene(s: &JudgeSettings) -> Result<Scene> {
    if s.results.is_empty() {
        bail!("nothing to judge: give at least one result file after the baseline");
    }
    let files: Vec<Loaded> =
        std::iter::once(&s.baseline).chain(&s.results).map(|p| load(p, &s.grid)).collect::<Result<_>>()?;
    // Files at a coarser resolution than the finest (an input beside a
    // result `nst3d volume` wrote 2x finer) are refined to it, as the job
    // refines; other mismatches cannot be compared voxel for voxel.
    // Per axis: a file's voxels need not be cubes (smoke_000003's are not).
    let finest: [f64; 3] =
        std::array::from_fn(|a| files.iter().map(|f| f.transform.voxel_size[a]).fold(f64::INFINITY, f64::min));
    let files: Vec<Loaded> = files
        .into_iter()
        .zip(std::iter::once(&s.baseline).chain(&s.results))
        .map(|(f, path)| {
            let k = f.transform.voxel_size[0] / finest[0];
            let ki = k.round() as usize;
            let same_shape = (0..3).all(|a| ((f.transform.voxel_size[a] / finest[a]) - k).abs() < 1e-6 * k);
            if (k - ki as f64).abs() > 1e-6 * k || !same_shape || ki == 0 {
                bail!(
                    "{} has voxels of {:?}, another file {finest:?}: judge files whose resolutions differ by a whole factor",
                    path.display(),
                    f.transform.voxel_size
                );
            }
            refine(f, ki)
        })
        .collect::<Result<_>>()?;
    let bx = files.iter().map(|f| f.density.0).reduce(|a, b| union_box(&a, &b)).expect("a baseline");
    let boxed = |f: &Loaded| -> (Grid3, Option<Vec<Grid3>>) {
        let d = pad(&in_box(Some(f.density.clone()), &bx), MARGIN);
        // Outside the colour grid's voxels: white, the grey picture (the
        // margin's colour is never drawn: it has no density).
        let c = f.color.as_ref().map(|c| color_in_box(Some(c), &bx).iter().map(|g| pad(g, MARGIN)).collect::<Vec<_>>());
        (d, c)
    };
    let boxed_files: Vec<_> = files.iter().map(boxed).collect();
    let base = &boxed_files[0].0;
    // The volume job's lens (projection, field of view), around this up axis.
    let lens = Lens { up: s.up, ..Lens::of(&crate::VolumeSettings::new("", "", "")) };
    let cams = CameraSet::parse(&s.cameras)?.cameras(&lens, base.dims);
    let gamma = absorption_for(s.absorption, cams.iter().map(|c| (base, c)))?;
    Ok(Scene {
        origin: bx.origin.map(|o| o - MARGIN as i32),
        transform: files[0].transform.clone(),
        inner: ([MARGIN; 3], bx.dims),
        views: views_of(&cams, gamma, false),
        files: boxed_files,
    })
}

/// Judges every result against the baseline; `reporter` sees one step per file.
pub fn judge(s: &JudgeSettings, reporter: &mut dyn Reporter) -> Result<Vec<Verdict>> {
    let scene = scene(s)?;
    let vgg = Vgg19::load(s.weights.as_deref())?;
    let painting = nst3d_io::image::load_style(&s.style, s.style_scale)?;
    let grey_loss = ViewLoss::new(&vgg, &painting.luminance3(), &s.spec)?;
    let rgb_loss = match s.color {
        true => Some(ViewLoss::new(&vgg, &painting, &s.spec)?),
        false => None,
    };
    let views = &scene.views;
    reporter.begin(scene.files.len() as u64);
    let mut scores = Vec::new();
    for (d, c) in scene.files {
        // A coloured file's grey look is its colour render's luminance.
        let grey: Vec<f32> = views
            .iter()
            .map(|v| match &c {
                Some(c) => grey_loss.loss_color_luminance(&d, c, v),
                None => grey_loss.loss(&d, v),
            })
            .collect::<Result<_, _>>()?;
        let rgb = match &rgb_loss {
            None => None,
            Some(l) => {
                let c = c.unwrap_or_else(|| color_in_box(None, &DenseBox { origin: [0; 3], dims: d.dims }));
                let whole = views.iter().map(|v| l.loss_color(&d, &c, v)).collect::<Result<Vec<f32>, _>>()?;
                // A view with no smoke scores 0, so its ratio is 1.
                let smoke = views
                    .iter()
                    .map(|v| Ok(l.loss_color_on_smoke(&d, &c, v)?.unwrap_or(0.0)))
                    .collect::<Result<Vec<f32>, nst3d_stylize::ViewError>>()?;
                Some((whole, smoke))
            }
        };
        scores.push((grey, rgb));
        reporter.step("judged");
    }
    reporter.end();
    let (base_grey, base_rgb) = &scores[0];
    Ok(s.results
        .iter()
        .zip(&scores[1..])
        .map(|(file, (grey, rgb))| Verdict {
            file: file.clone(),
            grey: ratio(grey, base_grey),
            color: rgb.as_ref().zip(base_rgb.as_ref()).map(|(a, b)| ratio(&a.0, &b.0)),
            color_smoke: rgb.as_ref().zip(base_rgb.as_ref()).map(|(a, b)| ratio(&a.1, &b.1)),
        })
        .collect())
}
