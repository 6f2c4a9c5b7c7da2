//! `nst3d strands`: stylize a hair or fur groom (strand style transfer
//! paper, Alg. 1 for one frame) with [`nst3d_strands::pipeline`].
//!
//! The groom and its head mesh are read and checked, the output format is
//! picked from `--out`'s extension, all before the slow part. The stylized
//! guides are written atomically through the io writers (proxies are
//! render-only and not written); the preview is before | after | painting
//! from the front camera (the direction the groom's roots face).

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use nst3d_io::groom::{read_groom, write_ply_strands, write_usda_curves};
use nst3d_io::image::{luminance_rgb, resize_to_height, side_by_side, write_png};
use nst3d_io::mesh::read_mesh;
use nst3d_strands::pipeline::{max_length_change, polyline_length, stylize, StrandScene, StylizeParams};
use nst3d_strands::{FlatStrands, MeshBvh, Preset};

use crate::progress::Progress;
use crate::volume::{load_vgg, PREVIEW_HEIGHT};

/// Arguments of `nst3d strands`.
#[derive(Args)]
pub struct StrandsArgs {
    /// Input groom (.hair, .data, .ply, .usda, .abc).
    #[arg(long)]
    groom: PathBuf,
    /// Head or body mesh the strands grow from (.ply or .obj).
    #[arg(long)]
    mesh: PathBuf,
    /// Style painting (PNG or JPEG); its luminance is matched.
    #[arg(long)]
    style: PathBuf,
    /// Table 1 preset.
    #[arg(long, value_enum, default_value = "short-hair")]
    preset: PresetArg,
    /// Output groom, .usda or .ply (written atomically).
    #[arg(long)]
    out: PathBuf,
    /// Before | after | painting preview PNG.
    #[arg(long)]
    preview: Option<PathBuf>,
    /// Total iterations over the three scales (default: the preset's),
    /// split in the preset's proportions.
    #[arg(long)]
    iters: Option<u32>,
    /// Square render size (default: the preset's; style sizes follow it).
    #[arg(long)]
    render_size: Option<usize>,
    /// Proxy strands to grow (default: the preset's proxy/guide ratio).
    #[arg(long)]
    proxies: Option<usize>,
    /// Seed of densification and camera sampling.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Multiplier on the preset's learning rates (scaled by the groom's radius).
    #[arg(long, default_value_t = 0.1)]
    lr_scale: f32,
    /// Cameras per scale whose matches are cached (0: a new camera every iteration).
    #[arg(long, default_value_t = 8)]
    views_per_scale: usize,
    /// Evaluation views with --views-per-scale 0 (otherwise the finest scale's views).
    #[arg(long, default_value_t = 4)]
    eval_views: usize,
    /// Iterations of the three scales, e.g. 0,0,30 (overrides --iters).
    #[arg(long, value_delimiter = ',')]
    scale_iters: Option<Vec<u32>>,
    /// Strand cross-section sigma in pixels at the groom centre's depth (default: the pipeline's).
    #[arg(long)]
    strand_width: Option<f32>,
    /// VGG-19 weights file (default: $NST3D_VGG19, else the user cache).
    #[arg(long)]
    weights: Option<PathBuf>,
}

/// The presets by command-line name.
#[derive(Clone, Copy, ValueEnum)]
enum PresetArg {
    ShortHair,
    #[value(name = "short-hair-360")]
    ShortHair360,
    LongHair,
    Cat,
    FurBall,
    Grass,
}

impl PresetArg {
    fn preset(self) -> Preset {
        match self {
            PresetArg::ShortHair => Preset::ShortHair,
            PresetArg::ShortHair360 => Preset::ShortHair360,
            PresetArg::LongHair => Preset::LongHair,
            PresetArg::Cat => Preset::Cat,
            PresetArg::FurBall => Preset::FurBall,
            PresetArg::Grass => Preset::Grass,
        }
    }
}

#[derive(Clone, Copy)]
enum OutFormat {
    Usda,
    Ply,
}

fn out_format(path: &Path) -> Result<OutFormat> {
    match path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
        Some("usda") => Ok(OutFormat::Usda),
        Some("ply") => Ok(OutFormat::Ply),
        _ => bail!("--out {}: the output groom must end in .usda or .ply", path.display()),
    }
}

/// Runs `nst3d strands`.
pub fn run(args: StrandsArgs) -> Result<()> {
    let format = out_format(&args.out)?;
    if args.iters == Some(0) {
        bail!("--iters must be at least 1");
    }
    if !(args.lr_scale.is_finite() && args.lr_scale > 0.0) {
        bail!("--lr-scale must be a positive number, got {}", args.lr_scale);
    }
    let groom = read_groom(&args.groom)?;
    let head = read_mesh(&args.mesh)?;
    let painting = nst3d_io::image::load_style(&args.style, 1.0)?;
    let vgg = load_vgg(args.weights.as_deref())?;

    let mut params = StylizeParams::from_preset(args.preset.preset().params(), groom.strand_count());
    if let Some(n) = args.iters {
        params = params.with_total_iterations(n);
    }
    if let Some(r) = args.render_size {
        params.render_size = r;
    }
    if let Some(m) = args.proxies {
        params.proxies = m;
    }
    params.seed = args.seed;
    params.lr_scale = args.lr_scale;
    params.views_per_scale = args.views_per_scale;
    params.eval_views = args.eval_views;
    if let Some(n) = &args.scale_iters {
        if n.len() != 3 {
            bail!("--scale-iters needs three comma-separated counts, got {}", n.len());
        }
        params.iterations = [n[0], n[1], n[2]];
    }
    if let Some(w) = args.strand_width {
        if !(w.is_finite() && w > 0.0) {
            bail!("--strand-width must be a positive number of pixels, got {w}");
        }
        params.strand_width_px = w;
    }

    let scene = StrandScene::new(&groom, &head, &params)
        .with_context(|| format!("{} on {}", args.groom.display(), args.mesh.display()))?;
    let total: u32 = params.iterations.iter().sum();
    let mut progress = Progress::new(total as u64);
    let result = stylize(&scene, &painting, &vgg, &params, &mut |r| {
        progress.step(format!("scale {}/3 iteration {}/{} loss {:.4e}", r.scale + 1, r.iteration, r.iterations, r.loss))
    })?;
    progress.finish();

    let out_groom = result.guides.to_groom();
    match format {
        OutFormat::Usda => write_usda_curves(&args.out, &out_groom)?,
        OutFormat::Ply => write_ply_strands(&args.out, &out_groom)?,
    }

    if let Some(preview) = &args.preview {
        let h = PREVIEW_HEIGHT;
        let cam = scene.front_camera(h)?;
        let before = scene.render(&scene.undeformed, &cam)?;
        let after = scene.render(&result.strands, &cam)?;
        let paint = resize_to_height(&luminance_rgb(&painting), h);
        write_png(preview, &side_by_side(&[&before, &after, &paint]))?;
    }

    // Lengths against the input groom's own polylines (what an artist
    // measures), and against the resampled rest guides (what the
    // constraint holds).
    let input_lengths: Vec<f64> = groom.strands.iter().map(|s| polyline_length(&s.points)).collect();
    let vs_input = (0..result.guides.strand_count())
        .map(|s| ((polyline_length(result.guides.strand(s)) - input_lengths[s]) / input_lengths[s].max(1e-30)).abs())
        .fold(0.0f64, f64::max);
    let rest_guides = FlatStrands {
        points: scene.rest.points[..result.guides.points.len()].to_vec(),
        offsets: result.guides.offsets.clone(),
    };
    let vs_rest = max_length_change(&rest_guides, &result.guides);
    let bvh = MeshBvh::new(&head)?;
    let inside = result.guides.points.iter().filter(|&&p| bvh.is_inside(p)).count();
    println!(
        "{}: {} strands x {} points stylized ({}, {} proxies, {} iterations at {}px); \
         NNST loss {:.4e} -> {:.4e} ({:+.1}%; re-matched on the result {:.4e}); \
         max length change {:.3}% vs input ({:.4}% vs rest); {} control points inside the mesh; wrote {}",
        args.groom.display(),
        result.guides.strand_count(),
        result.guides.strand(0).len(),
        params.preset.name,
        scene.rest.strand_count() - scene.guide_count,
        total,
        params.render_size,
        result.eval_before,
        result.eval_after,
        -100.0 * result.loss_drop(),
        result.eval_after_rematched,
        100.0 * vs_input,
        100.0 * vs_rest,
        inside,
        args.out.display()
    );
    Ok(())
}
