//! Pictures of grooms: the before | after | painting preview of a job, and
//! `nst3d preview` of groom files.

use std::path::{Path, PathBuf};

use anyhow::Result;
use nst3d_core::{Image, UpAxis};
use nst3d_io::image::{luminance_rgb, resize_to_height, side_by_side, write_png};
use nst3d_strands::pipeline::{GroomView, StrandScene, StrandShares};
use nst3d_strands::FlatStrands;

use crate::axis;
use crate::judge::GramJudge;
use crate::settings::frame_path;

pub use nst3d_io::image::PREVIEW_HEIGHT;

/// Before | after | painting from the front camera; with `colors` (a
/// stylization with colour: every point of `after`, guides then proxies)
/// the before is drawn in the colours it started from, the after in
/// `colors` and the painting in colour, else all three grey.
pub fn write_preview(
    path: &Path,
    scene: &StrandScene,
    after: &FlatStrands,
    colors: Option<&[[f32; 3]]>,
    painting: &Image,
) -> Result<()> {
    let h = PREVIEW_HEIGHT;
    let cam = scene.front_camera(h)?;
    let start = match colors {
        Some(_) => {
            let layer = scene.color_layer()?;
            Some(layer.forward(&layer.start()))
        }
        None => None,
    };
    let before = scene.render_colored(&scene.undeformed, start.as_deref(), &cam)?;
    let after = scene.render_colored(after, colors, &cam)?;
    let paint = resize_to_height(&if colors.is_some() { painting.clone() } else { luminance_rgb(painting) }, h);
    write_png(path, &side_by_side(&[&before, &after, &paint]))?;
    Ok(())
}

/// The tint each painting's strands take in a style map's preview: orange,
/// blue, green, magenta, then round again.
const MAP_TINTS: [[f32; 3]; 4] = [[1.0, 0.55, 0.15], [0.2, 0.55, 1.0], [0.3, 0.85, 0.3], [0.9, 0.3, 0.8]];

/// A style map's preview from the front camera: the rest groom in each
/// painting's tint by its strands' shares (the map) | the result (in
/// `colors` when the colour was stylized, as [`write_preview`]) | each
/// painting, framed in its tint.
pub fn write_map_preview(
    path: &Path,
    scene: &StrandScene,
    (after, colors): (&FlatStrands, Option<&[[f32; 3]]>),
    shares: &StrandShares,
    paintings: &[&Image],
) -> Result<()> {
    let h = PREVIEW_HEIGHT;
    let cam = scene.front_camera(h)?;
    let mut tint = vec![[0.0f32; 3]; scene.undeformed.points.len()];
    for k in 0..shares.paintings() {
        let c = MAP_TINTS[k % MAP_TINTS.len()];
        for (t, s) in tint.iter_mut().zip(shares.point_shares(k, &scene.undeformed)) {
            (0..3).for_each(|j| t[j] += s * c[j]);
        }
    }
    let map = scene.render_colored(&scene.undeformed, Some(&tint), &cam)?;
    let after = scene.render_colored(after, colors, &cam)?;
    let shown = |p: &Image| if colors.is_some() { p.clone() } else { luminance_rgb(p) };
    let framed: Vec<Image> = paintings
        .iter()
        .enumerate()
        .map(|(k, p)| framed(&resize_to_height(&shown(p), h), MAP_TINTS[k % MAP_TINTS.len()]))
        .collect();
    let mut panels = vec![&map, &after];
    panels.extend(framed.iter());
    write_png(path, &side_by_side(&panels))?;
    Ok(())
}

/// `img` (RGB) with a border of `color`, 4 pixels wide.
fn framed(img: &Image, color: [f32; 3]) -> Image {
    let mut out = img.clone();
    let (h, w) = (img.height, img.width);
    for y in 0..h {
        for x in 0..w {
            if x < 4 || y < 4 || x + 4 >= w || y + 4 >= h {
                (0..3).for_each(|c| out.data[c * h * w + y * w + x] = color[c]);
            }
        }
    }
    out
}

/// What `nst3d preview` draws of a groom.
#[derive(Clone, Debug)]
pub struct GroomPreviewSettings {
    /// The groom (.hair, .data, .ply, .abc, or USD: .usda, .usdc, .usd, .usdz).
    pub input: PathBuf,
    /// A second groom with the same strands (e.g. the stylized result),
    /// drawn to the right of `input` from the same cameras.
    pub compare: Option<PathBuf>,
    /// The mesh the strands grow from (front direction and culling).
    pub mesh: Option<PathBuf>,
    /// Output PNG; with `turntable` a pattern (`####` or `%04d`, from 1).
    pub out: PathBuf,
    /// Pictures at evenly spaced azimuths from the front.
    pub turntable: Option<usize>,
    /// Camera elevation in degrees.
    pub elevation: f32,
    /// Picture height in pixels.
    pub height: usize,
    /// Which axis points up (`--up`); `None`: a USD groom's `upAxis`,
    /// else y. The turntable circles it.
    pub up: Option<UpAxis>,
    /// A painting to judge every picture against ([`GramJudge`]).
    pub style: Option<PathBuf>,
    /// Draw each groom in its own per-point colours (white where it has
    /// none) and judge in colour; the grey judge then scores the pictures'
    /// luminance ([`GroomPreviewReport::input_grey_loss`]).
    pub color: bool,
    /// The preset whose strand look and culling the pictures take.
    pub preset: nst3d_strands::Preset,
}

/// What [`preview_groom`] drew, and with a painting its judgement.
#[derive(Clone, Debug, Default)]
pub struct GroomPreviewReport {
    /// Pictures written.
    pub pictures: usize,
    /// Per picture, the Gram style loss of `input` to the painting.
    pub input_loss: Vec<f32>,
    /// Per picture, that of `compare`.
    pub compare_loss: Vec<f32>,
    /// With colour and a painting: per picture, the grey Gram loss of the
    /// luminance of `input`'s picture to the painting's luminance.
    pub input_grey_loss: Vec<f32>,
    /// That of `compare`.
    pub compare_grey_loss: Vec<f32>,
    /// With a painting: per picture, the Gram loss over the hair only
    /// ([`GramJudge::hair_loss`]) of `input` (in colour with `color`).
    pub input_hair_loss: Vec<f32>,
    /// That of `compare`.
    pub compare_hair_loss: Vec<f32>,
    /// Grey only, with a painting: per picture, the hair-only loss with the
    /// hair at the painting's tone ([`GramJudge::toned_hair_loss`]) of `input`.
    pub input_toned_loss: Vec<f32>,
    /// That of `compare`.
    pub compare_toned_loss: Vec<f32>,
}

impl GroomPreviewReport {
    /// Per picture, `compare`'s loss over `input`'s: below 1, the compared
    /// groom is nearer the painting from that side.
    pub fn ratios(&self) -> Vec<f32> {
        self.compare_loss.iter().zip(&self.input_loss).map(|(c, i)| c / i).collect()
    }

    /// [`GroomPreviewReport::ratios`] of the hair-only losses.
    pub fn hair_ratios(&self) -> Vec<f32> {
        self.compare_hair_loss.iter().zip(&self.input_hair_loss).map(|(c, i)| c / i).collect()
    }

    /// [`GroomPreviewReport::ratios`] of the tone-matched hair-only losses
    /// (grey pictures only; empty in colour).
    pub fn toned_ratios(&self) -> Vec<f32> {
        self.compare_toned_loss.iter().zip(&self.input_toned_loss).map(|(c, i)| c / i).collect()
    }

    /// With colour: [`GroomPreviewReport::ratios`] of the grey losses.
    pub fn grey_ratios(&self) -> Vec<f32> {
        self.compare_grey_loss.iter().zip(&self.input_grey_loss).map(|(c, i)| c / i).collect()
    }
}

/// Draws a groom (and its comparison) as the stylization's cameras see it,
/// without stylizing, and with `s.style` judges each picture.
pub fn preview_groom(s: &GroomPreviewSettings) -> Result<GroomPreviewReport> {
    let n = s.turntable.unwrap_or(1);
    if n == 0 || n > 3600 {
        anyhow::bail!("--turntable {n}: give 1 to 3600 pictures");
    }
    if !(16..=8192).contains(&s.height) {
        anyhow::bail!("--height {}: give 16 to 8192 pixels", s.height);
    }
    nst3d_io::atomic::check_output("--out", &s.out, &["png"], &[]).map_err(anyhow::Error::msg)?;
    if s.turntable.is_some() && !crate::settings::is_pattern(&s.out) {
        anyhow::bail!("--out {} with --turntable needs a frame placeholder (#### or %04d)", s.out.display());
    }
    let outs: Vec<PathBuf> = match s.turntable {
        Some(_) => (1..=n as i64).map(|i| frame_path(&s.out, i, "--out")).collect::<Result<_>>()?,
        None => vec![s.out.clone()],
    };
    let input = nst3d_io::groom::read_groom_file(&s.input)?;
    let (up, _) = axis::resolve(s.up, &input);
    let groom = FlatStrands::from_groom(&axis::groom_to_y_up(&input.groom, up))?;
    let input_colors = s.color.then(|| point_colors(&input.groom));
    let mut compare_colors = None;
    let compare = match &s.compare {
        Some(p) => {
            let g = nst3d_io::groom::read_groom(p)?;
            compare_colors = s.color.then(|| point_colors(&g));
            let c = FlatStrands::from_groom(&axis::groom_to_y_up(&g, up))?;
            if c.strand_count() != groom.strand_count() {
                anyhow::bail!(
                    "{}: {} strands, {} has {}: not the same groom",
                    p.display(),
                    c.strand_count(),
                    s.input.display(),
                    groom.strand_count()
                );
            }
            Some(c)
        }
        None => None,
    };
    let head = s.mesh.as_deref().map(nst3d_io::mesh::read_mesh).transpose()?;
    let head = head.as_ref().map(|h| axis::mesh_to_y_up(h, up));
    let params = nst3d_strands::pipeline::StylizeParams::from_preset(s.preset.params(), groom.strand_count());
    let view = GroomView::new(&groom, head.as_deref(), &params)?;
    let judge = s.style.as_deref().map(|p| GramJudge::with_color(p, s.height, None, s.color)).transpose()?;
    let grey_judge = match &s.style {
        Some(p) if s.color => Some(GramJudge::new(p, s.height, None)?),
        _ => None,
    };
    let mut report = GroomPreviewReport { pictures: outs.len(), ..Default::default() };
    for (i, out) in outs.iter().enumerate() {
        let azimuth = 360.0 * i as f32 / n as f32;
        let mut pictures =
            vec![view.render_colored(&groom, input_colors.as_deref(), s.elevation, azimuth, s.height)?];
        if let Some(c) = &compare {
            pictures.push(view.render_colored(c, compare_colors.as_deref(), s.elevation, azimuth, s.height)?);
        }
        if let Some(j) = &judge {
            // Whole picture and hair only from one forward per picture.
            let (whole, hair) = j.scores(&pictures[0])?;
            report.input_loss.push(whole);
            report.input_hair_loss.push(hair.unwrap_or(f32::NAN));
            if let Some(p) = pictures.get(1) {
                let (whole, hair) = j.scores(p)?;
                report.compare_loss.push(whole);
                report.compare_hair_loss.push(hair.unwrap_or(f32::NAN));
            }
            // In grey the tone is the shading's, which no shape changes:
            // the tone-matched score is the one about structure.
            if !s.color {
                report.input_toned_loss.push(j.toned_hair_loss(&pictures[0])?.unwrap_or(f32::NAN));
                if let Some(p) = pictures.get(1) {
                    report.compare_toned_loss.push(j.toned_hair_loss(p)?.unwrap_or(f32::NAN));
                }
            }
        }
        if let Some(j) = &grey_judge {
            report.input_grey_loss.push(j.loss(&luminance_rgb(&pictures[0]))?);
            if let Some(p) = pictures.get(1) {
                report.compare_grey_loss.push(j.loss(&luminance_rgb(p))?);
            }
        }
        write_png(out, &side_by_side(&pictures.iter().collect::<Vec<_>>()))?;
    }
    Ok(report)
}

/// Every point's colour in file order (white for a strand without colours).
fn point_colors(g: &nst3d_core::Groom) -> Vec<[f32; 3]> {
    g.strands
        .iter()
        .flat_map(|s| match &s.colors {
            Some(c) if c.len() == s.points.len() => c.clone(),
            _ => vec![[1.0; 3]; s.points.len()],
        })
        .collect()
}
