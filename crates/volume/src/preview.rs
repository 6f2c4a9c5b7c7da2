//! Pictures of OpenVDB smoke for judging a result without a DCC
//! (`nst3d preview`): one front view, a turntable, an original | stylized
//! sheet, or a whole sequence, all drawn by the transmittance renderer the
//! optimiser sees (paper eq. 6), so what the artist judges is what the
//! style loss judged; with `color`, by the emission–absorption renderer in
//! each file's colour grid.
//!
//! Everything shown together shares one dense box (the union of the active
//! boxes), one camera set and one absorption γ: a compared file or a later
//! frame must not shift, zoom or change brightness, or the artist would be
//! judging the preview instead of the smoke.

use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Context, Result};
use nst3d_core::{Grid3, Image};
use nst3d_io::image::{resize_to_height, side_by_side, write_png};
use nst3d_io::vdb::{read_vdb, DenseBox};
use nst3d_job::{expand_pattern, FrameSpec};
use nst3d_render::{Camera, Projection};

use crate::cameras::{front_camera, turntable};
use crate::dense::{in_box, union_box};
use crate::look::{auto_absorption, color_image, transmittance_image, PREVIEW_HEIGHT};
use crate::settings::UpAxis;

/// Field of view of the preview cameras: the `nst3d volume` default, so a
/// preview frames the smoke as the optimiser saw it.
const FOV_DEG: f32 = 30.0;

/// Most pictures one turntable may have: beyond one per degree nobody looks.
const MAX_TURNTABLE: usize = 360;

/// Largest picture height accepted, so a typo cannot allocate gigabytes.
const MAX_HEIGHT: usize = 8192;

/// Width in pixels of the grey bar between original and stylized.
const GAP: usize = 4;

/// What to draw: the settings of `nst3d preview`.
#[derive(Clone, Debug)]
pub struct PreviewSettings {
    /// OpenVDB file to draw (with `frames`, a pattern with `####` or `%04d`).
    pub input: PathBuf,
    /// A second file (e.g. the stylized result) drawn to the right of
    /// `input` with the same camera and absorption; a pattern with `frames`.
    pub compare: Option<PathBuf>,
    /// Output PNG (written atomically); with `turntable` or `frames` a
    /// pattern (turntable pictures are numbered from 1).
    pub out: PathBuf,
    /// Name of the float grid to draw.
    pub grid: String,
    /// Frames of a sequence (e.g. `1-40`), one PNG each.
    pub frames: Option<String>,
    /// Number of pictures around the volume, at evenly spaced azimuths from the front.
    pub turntable: Option<usize>,
    /// Turntable camera elevation in degrees above the horizon.
    pub elevation: f32,
    /// Camera projection.
    pub projection: Projection,
    /// The file's up axis.
    pub up: UpAxis,
    /// Absorption γ; `None`: the densest ray of `input`, or of its densest
    /// frame, gets optical depth 3, and the same γ is used for `compare`
    /// and every frame, so brightness does not pump.
    pub absorption: Option<f32>,
    /// Picture height in pixels (a compare sheet is two pictures wide).
    pub height: usize,
    /// Draw each file in its colour grid (`Cd` or `color`, white where it has
    /// none), as `nst3d volume --color` renders it.
    pub color: bool,
}

impl PreviewSettings {
    /// The defaults of `nst3d preview` for drawing `input` into `out`.
    pub fn new(input: impl Into<PathBuf>, out: impl Into<PathBuf>) -> Self {
        Self {
            input: input.into(),
            compare: None,
            out: out.into(),
            grid: "density".into(),
            frames: None,
            turntable: None,
            elevation: 0.0,
            projection: Projection::Perspective,
            up: UpAxis::Z,
            absorption: None,
            height: PREVIEW_HEIGHT,
            color: false,
        }
    }
}

/// What a preview job wrote.
#[derive(Clone, Copy, Debug)]
pub struct PreviewReport {
    /// Pictures written.
    pub pictures: usize,
    /// The absorption they share.
    pub absorption: f32,
}

/// One output picture: the volumes drawn side by side and where it goes.
struct Shot {
    /// `--input` and, when comparing, `--compare` for this frame.
    sources: Vec<PathBuf>,
    /// The PNG (for a turntable, the pattern; expanded per camera).
    out: PathBuf,
}

/// Draws the pictures `args` asks for; nothing is left behind if any fails.
pub fn preview(args: &PreviewSettings) -> Result<PreviewReport> {
    check_args(args)?;
    nst3d_io::atomic::check_output("--out", &args.out, &["png"], &[]).map_err(anyhow::Error::msg)?;
    let shots = plan(args)?;
    let sequence = args.frames.is_some();

    // First pass: every file is read and checked before anything is written,
    // and the common box is the union over all of them so the camera never moves.
    // A single shot keeps its dense grids; a sequence reads them again per frame
    // rather than holding every frame in memory, remembering only which input
    // frame has the densest column (see `column_peak`).
    let mut union: Option<DenseBox> = None;
    let mut kept: Vec<Option<(DenseBox, Grid3)>> = Vec::new();
    let mut densest: Option<(f32, usize)> = None;
    for (i, shot) in shots.iter().enumerate() {
        for (k, path) in shot.sources.iter().enumerate() {
            let loaded = load(path, &args.grid, sequence)?;
            if let Some((bx, d)) = &loaded {
                union = Some(union.map_or(*bx, |u| union_box(&u, bx)));
                if k == 0 {
                    let peak = column_peak(d, args.up);
                    if densest.is_none_or(|(p, _)| peak > p) {
                        densest = Some((peak, i));
                    }
                }
            }
            if shots.len() == 1 {
                kept.push(loaded);
            }
        }
    }
    let Some(bx) = union else {
        bail!("grid '{}' is empty in every frame: nothing to preview", args.grid);
    };

    let front = front_camera(bx.dims, args.up, args.projection, FOV_DEG);
    let cameras = match args.turntable {
        Some(n) => turntable(n, args.elevation, bx.dims, args.up, args.projection),
        None => vec![front],
    };

    // A single shot's grids, already read, moved into the common box.
    let mut ready: Option<Vec<Grid3>> = (shots.len() == 1).then(|| kept.into_iter().map(|l| in_box(l, &bx)).collect());
    let gamma = match (args.absorption, &ready) {
        (Some(g), _) => g,
        (None, Some(d)) => auto_absorption(&d[0], &front).with_context(|| shots[0].sources[0].display().to_string())?,
        (None, None) => {
            let i = densest.map_or(0, |(_, i)| i);
            let path = &shots[i].sources[0];
            let d = in_box(load(path, &args.grid, true)?, &bx);
            auto_absorption(&d, &front).with_context(|| path.display().to_string())?
        }
    };

    let layout = Layout::new(&cameras, bx.dims, args.height)?;
    let mut written = Written::default();
    for shot in &shots {
        let d = match ready.take() {
            Some(d) => d,
            None => shot
                .sources
                .iter()
                .map(|path| Ok(in_box(load(path, &args.grid, sequence)?, &bx)))
                .collect::<Result<Vec<_>>>()?,
        };
        let colors: Option<Vec<Vec<Grid3>>> = match args.color {
            true => Some(shot.sources.iter().map(|path| load_color(path, &bx)).collect::<Result<_>>()?),
            false => None,
        };
        for (c, cam) in cameras.iter().enumerate() {
            let pictures: Vec<Image> = d
                .iter()
                .enumerate()
                .zip(&shot.sources)
                .map(|((k, d), path)| {
                    let img = match &colors {
                        Some(colors) => color_image(d, &colors[k], cam, gamma),
                        None => transmittance_image(d, cam, gamma),
                    };
                    Ok(layout.fit(&img.with_context(|| path.display().to_string())?, c))
                })
                .collect::<Result<_>>()?;
            let sheet = sheet(&pictures);
            let out = match args.turntable {
                Some(_) => PathBuf::from(expand_pattern(&lossy(&shot.out), c as i64 + 1)?),
                None => shot.out.clone(),
            };
            written.write(&out, &sheet)?;
        }
    }
    Ok(PreviewReport { pictures: written.commit(), absorption: gamma })
}

/// Checks the numeric arguments and mode combinations before reading anything.
fn check_args(args: &PreviewSettings) -> Result<()> {
    if let Some(g) = args.absorption {
        if !(g.is_finite() && g > 0.0) {
            bail!("--absorption must be a positive number, got {g}");
        }
    }
    if !(8..=MAX_HEIGHT).contains(&args.height) {
        bail!("--height must be between 8 and {MAX_HEIGHT} pixels, got {}", args.height);
    }
    if let Some(n) = args.turntable {
        if !(1..=MAX_TURNTABLE).contains(&n) {
            bail!("--turntable must be between 1 and {MAX_TURNTABLE} pictures, got {n}");
        }
        if args.frames.is_some() {
            bail!("--turntable and --frames cannot be combined (one output pattern has one frame number)");
        }
    }
    if !(args.elevation.is_finite() && args.elevation.abs() <= 90.0) {
        bail!("--elevation must be between -90 and 90 degrees, got {}", args.elevation);
    }
    Ok(())
}

/// The pictures to make: one per frame of a sequence, else one (a turntable
/// expands its output pattern per camera later). Patterns are checked here so
/// a missing placeholder fails before any file is read.
fn plan(args: &PreviewSettings) -> Result<Vec<Shot>> {
    let Some(spec) = &args.frames else {
        if args.turntable.is_some() {
            expand_pattern(&lossy(&args.out), 1).context("--out with --turntable")?;
        }
        if !args.input.exists() && expand_pattern(&lossy(&args.input), 1).is_ok() {
            bail!("{} looks like a frame pattern: give --frames", args.input.display());
        }
        let sources = std::iter::once(args.input.clone()).chain(args.compare.clone()).collect();
        return Ok(vec![Shot { sources, out: args.out.clone() }]);
    };
    let spec = FrameSpec::parse(spec)?;
    let expand = |pattern: &Path, what: &str, frame: i64| -> Result<PathBuf> {
        Ok(PathBuf::from(expand_pattern(&lossy(pattern), frame).with_context(|| format!("{what} with --frames"))?))
    };
    spec.frames()
        .iter()
        .map(|&f| {
            let mut sources = vec![expand(&args.input, "--input", f)?];
            if let Some(c) = &args.compare {
                sources.push(expand(c, "--compare", f)?);
            }
            Ok(Shot { sources, out: expand(&args.out, "--out", f)? })
        })
        .collect()
}

/// Reads `grid` of the file at `path` densified over its active box; `None`
/// for an empty grid when `allow_empty` (a sequence often starts before the
/// smoke does), an error otherwise.
fn load(path: &Path, grid: &str, allow_empty: bool) -> Result<Option<(DenseBox, Grid3)>> {
    // Flattened to its message: the error already quotes its I/O cause, which
    // `{:#}` would otherwise print a second time.
    let file = read_vdb(path).map_err(|e| anyhow!("{e}"))?;
    let g = crate::dense::density_grid(&file, path, grid)?;
    if allow_empty && g.active_bbox().is_none() {
        return Ok(None);
    }
    Ok(Some(g.to_dense()?))
}

/// The colour grid of the file at `path` in the box `bx`, white where it
/// has none ([`crate::dense::color_in_box`]).
fn load_color(path: &Path, bx: &DenseBox) -> Result<Vec<Grid3>> {
    let file = read_vdb(path).map_err(|e| anyhow!("{e}"))?;
    let color = crate::dense::color_grid(&file).with_context(|| path.display().to_string())?;
    Ok(crate::dense::color_in_box(color.as_ref(), bx))
}

/// Largest column sum of density along the front camera's axis (y for a
/// z-up file, z for y-up): a camera-free stand-in for the densest ray, to
/// pick which frame of a sequence sets γ. The densest frame, not the first,
/// sets it: a simulation usually starts as a thin puff, and its γ would turn
/// every later frame flat white.
fn column_peak(d: &Grid3, up: UpAxis) -> f32 {
    let [nx, ny, nz] = d.dims;
    let mut sums = match up {
        UpAxis::Z => vec![0f32; nx * nz],
        UpAxis::Y => vec![0f32; nx * ny],
    };
    for z in 0..nz {
        for y in 0..ny {
            let row = &d.data[d.index(0, y, z)..][..nx];
            let at = match up {
                UpAxis::Z => z * nx,
                UpAxis::Y => y * nx,
            };
            sums[at..at + nx].iter_mut().zip(row).for_each(|(s, v)| *s += v);
        }
    }
    sums.into_iter().fold(0.0, f32::max)
}

/// Common picture size for a camera set: one scale for all cameras, so a
/// turntable does not zoom as the projected box changes with azimuth, and one
/// canvas, so the pictures play as a flipbook.
struct Layout {
    /// Picture height of each camera's image after scaling.
    heights: Vec<usize>,
    /// Canvas width and height.
    canvas: [usize; 2],
}

impl Layout {
    fn new(cameras: &[Camera], dims: [usize; 3], height: usize) -> Result<Self> {
        let sizes: Vec<[usize; 2]> =
            cameras.iter().map(|c| Ok(c.view(dims).map(|v| [v.dims[0], v.dims[1]])?)).collect::<Result<_>>()?;
        let tallest = sizes.iter().map(|s| s[1]).max().unwrap_or(1).max(1);
        let scale = height as f32 / tallest as f32;
        let heights: Vec<usize> = sizes.iter().map(|s| ((s[1] as f32 * scale).round() as usize).max(1)).collect();
        let width = sizes
            .iter()
            .zip(&heights)
            .map(|(s, &h)| ((s[0] * h) as f32 / s[1].max(1) as f32).round().max(1.0) as usize)
            .max()
            .unwrap_or(1);
        Ok(Self { heights, canvas: [width, height] })
    }

    /// Camera `c`'s image scaled and centred on the common canvas.
    fn fit(&self, img: &Image, c: usize) -> Image {
        let img = resize_to_height(img, self.heights[c]);
        let [w, h] = self.canvas;
        if img.width == w && img.height == h {
            return img;
        }
        let mut out = Image::zeros(img.channels, h, w);
        let (x0, y0) = (w.saturating_sub(img.width) / 2, h.saturating_sub(img.height) / 2);
        let cols = img.width.min(w);
        for ch in 0..img.channels {
            for y in 0..img.height.min(h) {
                let src = &img.data[(ch * img.height + y) * img.width..][..cols];
                out.data[(ch * h + y + y0) * w + x0..][..cols].copy_from_slice(src);
            }
        }
        out
    }
}

/// The pictures of one shot left to right, split by a thin grey bar so the
/// smoke of two neighbours never reads as one plume.
fn sheet(pictures: &[Image]) -> Image {
    if pictures.len() == 1 {
        return pictures[0].clone();
    }
    let h = pictures[0].height;
    let bar = Image::from_vec(1, h, GAP, vec![0.3; h * GAP]);
    let mut row: Vec<&Image> = Vec::with_capacity(2 * pictures.len());
    for (i, p) in pictures.iter().enumerate() {
        if i > 0 {
            row.push(&bar);
        }
        row.push(p);
    }
    side_by_side(&row)
}

/// A path as the text a pattern is expanded in.
fn lossy(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

/// Pictures written so far by this run: removed again if the run fails, so a
/// failure never leaves half a turntable or sequence behind.
#[derive(Default)]
struct Written {
    paths: Vec<PathBuf>,
}

impl Written {
    fn write(&mut self, path: &Path, img: &Image) -> Result<()> {
        write_png(path, img)?;
        self.paths.push(path.to_path_buf());
        Ok(())
    }

    /// Keeps the files; returns how many there are.
    fn commit(mut self) -> usize {
        std::mem::take(&mut self.paths).len()
    }
}

impl Drop for Written {
    fn drop(&mut self) {
        for p in &self.paths {
            let _ = std::fs::remove_file(p);
        }
    }
}
