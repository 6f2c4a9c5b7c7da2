//! `nst3d strands`: stylize a hair or fur groom (strand style transfer
//! paper, Alg. 1 for one frame) with [`nst3d_strands::pipeline`], or an
//! animated groom frame by frame with the temporal coherency of Sec. 3.3
//! ([`nst3d_strands::sequence`]: `--frames` with `####` patterns); and
//! `nst3d strands generate` for the procedural fur ball / grass patch of
//! Table 1, optionally animated by wind.
//!
//! The groom and its head mesh are read and checked, the output format is
//! picked from `--out`'s extension, all before the slow part (for a
//! sequence every frame's groom is read once up front and its topology
//! checked against the first, so a bad frame 200 fails in seconds, not
//! after hours). The stylized guides are written atomically through the io
//! writers (proxies are render-only and not written), one file per frame as
//! soon as it is done; the preview is before | after | painting from the
//! front camera (the direction the groom's roots face).

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand, ValueEnum};
use nst3d_io::groom::{read_groom, write_ply_strands, write_usda_curves, Groom};
use nst3d_io::image::{luminance_rgb, resize_to_height, side_by_side, write_png};
use nst3d_io::mesh::{read_mesh, TriMesh};
use nst3d_sequence::frames::{expand_pattern, FrameSpec};
use nst3d_strands::pipeline::{max_length_change, polyline_length, stylize, StrandScene, StylizeParams};
use nst3d_strands::{
    check_topology, fur_ball, grass_patch, EmaClock, FlatStrands, Flow, FurBallParams, GrassParams, MeshBvh, Preset,
    SequenceParams, SequenceStylizer, TemporalParams, Wind,
};

use crate::progress::Progress;
use crate::sequence::job_fingerprint;
use crate::volume::{load_vgg, PREVIEW_HEIGHT};

/// Arguments of `nst3d strands`.
#[derive(Args, Clone, Debug)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct StrandsArgs {
    #[command(subcommand)]
    command: Option<StrandsCommand>,
    /// Input groom (.hair, .data, .ply, .usda, .abc); with --frames a
    /// pattern such as `anim/fur_####.ply` or `fur_%04d.ply`.
    #[arg(long, required = true)]
    groom: Option<PathBuf>,
    /// Head or body mesh the strands grow from (.ply or .obj); with --frames
    /// it may be a pattern too (a moving head), else one mesh for all frames.
    #[arg(long, required = true)]
    mesh: Option<PathBuf>,
    /// Style painting (PNG or JPEG); its luminance is matched.
    #[arg(long, required = true)]
    style: Option<PathBuf>,
    /// Table 1 preset.
    #[arg(long, value_enum, default_value = "short-hair")]
    preset: PresetArg,
    /// Output groom, .usda or .ply (written atomically); with --frames a pattern.
    #[arg(long, required = true)]
    out: Option<PathBuf>,
    /// Before | after | painting preview PNG; with --frames a pattern.
    #[arg(long)]
    preview: Option<PathBuf>,
    /// Frames of an animated groom (e.g. `1-24` or `1-3,5,7-20:2`), stylized
    /// in order with the EMA and 1€ filter of the paper's Sec. 3.3; then
    /// --groom, --out and --preview are patterns with `####` or `%04d`.
    #[arg(long)]
    frames: Option<String>,
    /// With --frames: start over, ignoring the state a killed run of the
    /// same job left (otherwise the run resumes after its last finished frame).
    #[arg(long, requires = "frames")]
    force: bool,
    /// With --frames: folder for the state saved after every frame (default:
    /// `<out dir>/.nst3d-work/<hash of the job's inputs and settings>`).
    #[arg(long, requires = "frames")]
    work_dir: Option<PathBuf>,
    /// Temporal coherency of a sequence: `ema-one-euro` (the paper),
    /// `ema`, `one-euro`, or `off` (every frame stylized on its own).
    #[arg(long, value_enum, default_value = "ema-one-euro")]
    temporal: TemporalArg,
    /// EMA coefficient σ (default: the preset's, Table 1).
    #[arg(long)]
    ema_sigma: Option<f32>,
    /// EMA decaying period ν, as a fraction of the iterations (default: the preset's).
    #[arg(long)]
    ema_nu: Option<f32>,
    /// What the EMA's iteration count m runs over: each `scale` (Alg. 1's
    /// inner counter: every scale restarts from the previous frame's field),
    /// or the whole `frame` (measured to flicker more, docs/STRANDS.md).
    #[arg(long, value_enum, default_value = "scale")]
    ema_clock: EmaClockArg,
    /// 1€ blending parameter α (default: the preset's).
    #[arg(long)]
    one_euro_alpha: Option<f32>,
    /// 1€ scaling coefficient β (default: the preset's).
    #[arg(long)]
    one_euro_beta: Option<f32>,
    /// 1€ minimum cutoff frequency f_min in Hz (default: the preset's).
    #[arg(long)]
    one_euro_fmin: Option<f32>,
    /// Frame rate of the animation (1€ filter time step; default: the preset's, 24).
    #[arg(long)]
    fps: Option<f32>,
    /// Style flow s*: a world-space velocity `X,Y,Z` in groom units per
    /// frame that carries the stylization instead of the groom's own motion.
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    style_flow: Option<Vec<f32>>,
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
    #[arg(long, default_value_t = 0.3)]
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

/// `nst3d strands` subcommands.
#[derive(Subcommand, Clone, Debug)]
enum StrandsCommand {
    /// Write a procedural groom (fur ball or grass patch, Table 1) and its
    /// mesh, optionally animated by a time-varying wind.
    Generate(GenerateArgs),
}

/// Arguments of `nst3d strands generate`.
#[derive(Args, Clone, Debug)]
struct GenerateArgs {
    /// Which groom.
    #[arg(value_enum)]
    kind: GenerateKind,
    /// Output groom (.ply or .usda); with --frames a pattern such as `anim/fur_####.ply`.
    #[arg(long)]
    out: PathBuf,
    /// The mesh the strands grow from (.ply), for `nst3d strands --mesh`.
    #[arg(long)]
    mesh_out: Option<PathBuf>,
    /// Frames to write (e.g. `1-24`); frame f is the wind at time f / fps.
    /// Without it the groom is written once, at rest.
    #[arg(long)]
    frames: Option<String>,
    /// Strands (default: Table 1's, 8000 fur / 3000 grass).
    #[arg(long)]
    strands: Option<usize>,
    /// Control points per strand.
    #[arg(long, default_value_t = 9)]
    points: usize,
    /// Strand length (default: 0.25 fur / 0.3 grass).
    #[arg(long)]
    length: Option<f32>,
    /// Fur ball radius.
    #[arg(long, default_value_t = 1.0)]
    radius: f32,
    /// Seed of the root sampler.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Frame rate of the animation.
    #[arg(long, default_value_t = 24.0)]
    fps: f32,
    /// Wind push at the tips, in strand lengths (0: no wind).
    #[arg(long, default_value_t = Wind::default().strength)]
    wind: f32,
    /// Wind azimuth at time 0, degrees in the XZ plane (0 = +X).
    #[arg(long, default_value_t = Wind::default().direction_deg, allow_hyphen_values = true)]
    wind_direction: f32,
    /// How fast the wind turns, degrees per second.
    #[arg(long, default_value_t = Wind::default().turn_deg_per_s, allow_hyphen_values = true)]
    wind_turn: f32,
    /// Gust wavelength along the wind, scene units.
    #[arg(long, default_value_t = Wind::default().wavelength)]
    wind_wavelength: f32,
    /// Gust frequency, Hz.
    #[arg(long, default_value_t = Wind::default().frequency_hz)]
    wind_frequency: f32,
}

/// Procedural grooms.
#[derive(Clone, Copy, Debug, ValueEnum)]
enum GenerateKind {
    /// Straight fur along the normals of a sphere (Fig. 8).
    FurBall,
    /// Near-vertical blades on a plane (Fig. 12).
    Grass,
}

/// `--temporal` choices.
#[derive(Clone, Copy, Debug, PartialEq, ValueEnum)]
enum TemporalArg {
    #[value(name = "ema-one-euro")]
    EmaOneEuro,
    Ema,
    #[value(name = "one-euro")]
    OneEuro,
    Off,
}

/// `--ema-clock` choices.
#[derive(Clone, Copy, Debug, ValueEnum)]
enum EmaClockArg {
    Frame,
    Scale,
}

/// The presets by command-line name.
#[derive(Clone, Copy, Debug, ValueEnum)]
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
    if let Some(StrandsCommand::Generate(g)) = args.command {
        return generate(g);
    }
    // clap enforces these unless a subcommand is given.
    let need = |p: &Option<PathBuf>, name: &str| p.clone().with_context(|| format!("{name} is required"));
    let paths = Paths {
        groom: need(&args.groom, "--groom")?,
        mesh: need(&args.mesh, "--mesh")?,
        style: need(&args.style, "--style")?,
        out: need(&args.out, "--out")?,
    };
    let format = out_format(&paths.out)?;
    check_args(&args)?;
    if let Some(spec) = &args.frames {
        return run_sequence(&args, &paths, spec, format);
    }
    if args.temporal != TemporalArg::EmaOneEuro || args.style_flow.is_some() {
        bail!("--temporal and --style-flow apply to sequences; add --frames");
    }
    let groom = read_groom(&paths.groom)?;
    let head = read_mesh(&paths.mesh)?;
    let painting = nst3d_io::image::load_style(&paths.style, 1.0)?;
    let vgg = load_vgg(args.weights.as_deref())?;
    let params = stylize_params(&args, groom.strand_count());

    let scene = StrandScene::new(&groom, &head, &params)
        .with_context(|| format!("{} on {}", paths.groom.display(), paths.mesh.display()))?;
    let total: u32 = params.iterations.iter().sum();
    let mut progress = Progress::new(total as u64);
    let result = stylize(&scene, &painting, &vgg, &params, &mut |r| {
        progress.step(format!("scale {}/3 iteration {}/{} loss {:.4e}", r.scale + 1, r.iteration, r.iterations, r.loss))
    })?;
    progress.finish();

    let written = scene.to_input_topology(&FlatStrands::from_groom(&groom)?, &result.guides)?;
    write_groom(&paths.out, format, &written)?;
    if let Some(preview) = &args.preview {
        write_preview(preview, &scene, &result.strands, &painting)?;
    }
    let checks = Checks::new(&groom, &scene, &result.guides, &written, &head)?;
    println!(
        "{}: {} strands ({} control points, as in the input) stylized ({}, {} proxies, {} iterations at {}px); \
         NNST loss {:.4e} -> {:.4e} ({:+.1}%; re-matched on the result {:.4e}); \
         max length change {:.3}% vs input ({:.4}% vs rest); {} control points inside the mesh; wrote {}",
        paths.groom.display(),
        written.strand_count(),
        written.points.len(),
        params.preset.name,
        scene.rest.strand_count() - scene.guide_count,
        total,
        params.render_size,
        result.eval_before,
        result.eval_after,
        -100.0 * result.loss_drop(),
        result.eval_after_rematched,
        100.0 * checks.vs_input,
        100.0 * checks.vs_rest,
        checks.inside,
        paths.out.display()
    );
    Ok(())
}

/// The four path arguments, present.
struct Paths {
    groom: PathBuf,
    mesh: PathBuf,
    style: PathBuf,
    out: PathBuf,
}

/// Checks the numeric arguments before any slow work.
fn check_args(args: &StrandsArgs) -> Result<()> {
    if args.iters == Some(0) {
        bail!("--iters must be at least 1");
    }
    if !(args.lr_scale.is_finite() && args.lr_scale > 0.0) {
        bail!("--lr-scale must be a positive number, got {}", args.lr_scale);
    }
    if let Some(n) = &args.scale_iters {
        if n.len() != 3 {
            bail!("--scale-iters needs three comma-separated counts, got {}", n.len());
        }
        if n.iter().all(|&k| k == 0) {
            bail!("--scale-iters must run at least one iteration");
        }
    }
    if let Some(w) = args.strand_width {
        if !(w.is_finite() && w > 0.0) {
            bail!("--strand-width must be a positive number of pixels, got {w}");
        }
    }
    Ok(())
}

/// The stylization settings for a groom of `guides` strands (proxies
/// default to the preset's proxy/guide ratio).
fn stylize_params(args: &StrandsArgs, guides: usize) -> StylizeParams {
    let mut params = StylizeParams::from_preset(args.preset.preset().params(), guides);
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
        params.iterations = [n[0], n[1], n[2]];
    }
    if let Some(w) = args.strand_width {
        params.strand_width_px = w;
    }
    params
}

fn write_groom(path: &Path, format: OutFormat, strands: &FlatStrands) -> Result<()> {
    let g = strands.to_groom();
    match format {
        OutFormat::Usda => write_usda_curves(path, &g)?,
        OutFormat::Ply => write_ply_strands(path, &g)?,
    }
    Ok(())
}

/// Before | after | painting from the front camera.
fn write_preview(path: &Path, scene: &StrandScene, after: &FlatStrands, painting: &nst3d_core::Image) -> Result<()> {
    let h = PREVIEW_HEIGHT;
    let cam = scene.front_camera(h)?;
    let before = scene.render(&scene.undeformed, &cam)?;
    let after = scene.render(after, &cam)?;
    let paint = resize_to_height(&luminance_rgb(painting), h);
    write_png(path, &side_by_side(&[&before, &after, &paint]))?;
    Ok(())
}

/// Lengths and collisions of a stylized groom.
struct Checks {
    /// Largest relative length change of the written strands against the
    /// input groom's own polylines (what an artist measures).
    vs_input: f64,
    /// Against the resampled rest guides (what the constraint holds).
    vs_rest: f32,
    /// Written control points inside the mesh.
    inside: usize,
}

impl Checks {
    /// `guides`: the optimized (re-sampled) guides; `written`: what goes to
    /// the file, in the input's topology.
    fn new(
        groom: &Groom,
        scene: &StrandScene,
        guides: &FlatStrands,
        written: &FlatStrands,
        head: &TriMesh,
    ) -> Result<Self> {
        let input_lengths: Vec<f64> = groom.strands.iter().map(|s| polyline_length(&s.points)).collect();
        let vs_input = (0..written.strand_count())
            .map(|s| ((polyline_length(written.strand(s)) - input_lengths[s]) / input_lengths[s].max(1e-30)).abs())
            .fold(0.0f64, f64::max);
        let rest_guides =
            FlatStrands { points: scene.rest.points[..guides.points.len()].to_vec(), offsets: guides.offsets.clone() };
        let vs_rest = max_length_change(&rest_guides, guides);
        // The scene's collider is this mesh's BVH already.
        let built;
        let bvh = match &scene.constraints.collider {
            Some(b) => b,
            None => {
                built = MeshBvh::new(head)?;
                &built
            }
        };
        let inside = written.points.iter().filter(|&&p| bvh.is_inside(p)).count();
        Ok(Checks { vs_input, vs_rest, inside })
    }
}

/// Path `pattern` at `frame` (clear error without a placeholder).
fn frame_path(pattern: &Path, frame: i64, what: &str) -> Result<PathBuf> {
    let text = pattern.to_str().with_context(|| format!("{what} {} is not valid UTF-8", pattern.display()))?;
    Ok(PathBuf::from(expand_pattern(text, frame).with_context(|| format!("{what} with --frames"))?))
}

/// Whether `path` names a frame pattern rather than one file.
fn is_pattern(path: &Path) -> bool {
    path.to_str().is_some_and(|p| expand_pattern(p, 0).is_ok())
}

/// The temporal settings of a sequence: the preset's (Table 1) with any
/// overrides. Static presets have none in the table; they borrow the Long
/// Hair preset's, the animated hair example.
fn temporal_params(args: &StrandsArgs) -> TemporalParams {
    let preset = args.preset.preset().params();
    let mut t = preset.temporal.unwrap_or_else(|| {
        eprintln!(
            "nst3d: note: preset {} has no temporal parameters in Table 1; using Long Hair's (override with \
             --ema-sigma, --ema-nu, --one-euro-*)",
            preset.name
        );
        Preset::LongHair.params().temporal.expect("Long Hair is animated")
    });
    let set = |dst: &mut f32, v: Option<f32>| {
        if let Some(v) = v {
            *dst = v;
        }
    };
    set(&mut t.ema_sigma, args.ema_sigma);
    set(&mut t.ema_nu, args.ema_nu);
    set(&mut t.blend_alpha, args.one_euro_alpha);
    set(&mut t.beta, args.one_euro_beta);
    set(&mut t.min_cutoff_hz, args.one_euro_fmin);
    set(&mut t.fps, args.fps);
    t
}

/// `nst3d strands --frames`: every frame in order through a
/// [`SequenceStylizer`], one output (and preview) per frame, then the
/// sequence's mean losses and flicker.
fn run_sequence(args: &StrandsArgs, paths: &Paths, spec: &str, format: OutFormat) -> Result<()> {
    let frames = FrameSpec::parse(spec)?;
    let frames = frames.frames();
    let groom_at = |f| frame_path(&paths.groom, f, "--groom");
    let out_at = |f| frame_path(&paths.out, f, "--out");
    out_at(frames[0])?;
    if let Some(p) = &args.preview {
        frame_path(p, frames[0], "--preview")?;
    }
    let mesh_varies = is_pattern(&paths.mesh);
    let mesh_at = |f| if mesh_varies { frame_path(&paths.mesh, f, "--mesh") } else { Ok(paths.mesh.clone()) };
    let flow = match &args.style_flow {
        None => Flow::Animation,
        Some(v) if v.len() == 3 && v.iter().all(|c| c.is_finite()) => Flow::Style([v[0], v[1], v[2]]),
        Some(v) => bail!("--style-flow needs three finite numbers X,Y,Z, got {v:?}"),
    };

    // Every frame's groom up front: present, readable, same topology.
    let first = read_groom(&groom_at(frames[0])?)?;
    for &f in &frames[1..] {
        let path = groom_at(f)?;
        let g = read_groom(&path)?;
        check_topology(&first, f, &g).with_context(|| path.display().to_string())?;
    }
    let fixed_mesh = if mesh_varies { None } else { Some(read_mesh(&paths.mesh)?) };
    if mesh_varies {
        for &f in frames {
            let p = mesh_at(f)?;
            if !p.exists() {
                bail!("{}: mesh of frame {f} not found", p.display());
            }
        }
    }
    let painting = nst3d_io::image::load_style(&paths.style, 1.0)?;
    let vgg = load_vgg(args.weights.as_deref())?;
    let stylize = stylize_params(args, first.strand_count());
    let mut params = SequenceParams::new(stylize, temporal_params(args));
    (params.ema, params.one_euro) = match args.temporal {
        TemporalArg::EmaOneEuro => (true, true),
        TemporalArg::Ema => (true, false),
        TemporalArg::OneEuro => (false, true),
        TemporalArg::Off => (false, false),
    };
    params.ema_clock = match args.ema_clock {
        EmaClockArg::Frame => EmaClock::Frame,
        EmaClockArg::Scale => EmaClock::Scale,
    };
    params.flow = flow;
    let t = params.temporal;
    let mut seq = SequenceStylizer::new(&vgg, &painting, params)?;

    // Resume: the state saved after the last finished frame of this job.
    let work = match &args.work_dir {
        Some(w) => w.clone(),
        None => {
            let first_out = out_at(frames[0])?;
            let dir = first_out.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
            dir.join(".nst3d-work").join(format!("{:016x}", strands_job_hash(args, frames, &groom_at, &mesh_at)?))
        }
    };
    let state_path = work.join(STATE_FILE);
    // Only our own file goes: --work-dir may name a folder that holds more.
    if args.force && state_path.exists() {
        std::fs::remove_file(&state_path).with_context(|| format!("cannot remove {}", state_path.display()))?;
    }
    let mut done = 0usize;
    let mut worst = (0.0f64, 0.0f32, 0usize);
    if state_path.exists() {
        let bytes = std::fs::read(&state_path).with_context(|| state_path.display().to_string())?;
        let extra =
            seq.restore_state(&bytes).with_context(|| format!("{} (--force starts over)", state_path.display()))?;
        let &[n, w0, w1, w2] = extra.as_slice() else {
            bail!("{}: saved state has no frame count (--force starts over)", state_path.display());
        };
        done = n as usize;
        if done > frames.len() {
            bail!(
                "{}: saved state has {done} frames done, the job has {} (--force starts over)",
                state_path.display(),
                frames.len()
            );
        }
        for &f in &frames[..done] {
            let out = out_at(f)?;
            if !out.exists() {
                bail!(
                    "{}: output of frame {f} is missing but the saved state in {} has it done; --force starts over",
                    out.display(),
                    work.display()
                );
            }
        }
        worst = (w0, w1 as f32, w2 as usize);
        if done == frames.len() {
            eprintln!("all {done} frames already done (state in {}; --force redoes them)", work.display());
        } else if let Some(last) = done.checked_sub(1).map(|i| frames[i]) {
            eprintln!("resuming after frame {last} ({done} of {} done) from {}", frames.len(), work.display());
        }
    }
    let per_frame: u32 = seq.params().stylize.iterations.iter().sum();
    let mut progress = Progress::new(per_frame as u64 * (frames.len() - done) as u64);
    for (i, &f) in frames.iter().enumerate().skip(done) {
        let groom_path = groom_at(f)?;
        let groom = read_groom(&groom_path)?;
        let frame_mesh;
        let mesh = match &fixed_mesh {
            Some(m) => m,
            None => {
                frame_mesh = read_mesh(&mesh_at(f)?)?;
                &frame_mesh
            }
        };
        let r = seq.stylize_frame(f, &groom, mesh, &mut |r| {
            progress.step(format!(
                "frame {f} scale {}/3 iteration {}/{} loss {:.4e}",
                r.scale + 1,
                r.iteration,
                r.iterations,
                r.loss
            ))
        })?;
        let out = out_at(f)?;
        let written = r.scene.to_input_topology(&FlatStrands::from_groom(&groom)?, &r.guides)?;
        write_groom(&out, format, &written)?;
        if let Some(p) = &args.preview {
            write_preview(&frame_path(p, f, "--preview")?, &r.scene, &r.strands, &painting)?;
        }
        let c = Checks::new(&groom, &r.scene, &r.guides, &written, mesh)?;
        worst = (worst.0.max(c.vs_input), worst.1.max(c.vs_rest), worst.2.max(c.inside));
        println!(
            "frame {f}: NNST loss {:.4e} -> {:.4e} (output {:.4e}){}; wrote {}",
            r.eval_before,
            r.optimized.eval_after,
            r.eval_output,
            r.flicker.map_or(String::new(), |k| format!(
                "; flicker {:.5} (raw {:.5}, input {:.5})",
                k.compensated, k.raw, k.input_raw
            )),
            out.display()
        );
        // Outputs first, then the state: a kill in between redoes this frame.
        std::fs::create_dir_all(&work).with_context(|| format!("cannot create the work folder {}", work.display()))?;
        let state = seq.save_state(&[(i + 1) as f64, worst.0, worst.1 as f64, worst.2 as f64]);
        nst3d_io::atomic::write_atomic(&state_path, |w| w.write_all(&state))
            .with_context(|| format!("cannot write {}", state_path.display()))?;
    }
    progress.finish();
    let s = seq.report();
    let p = &seq.params().stylize;
    let mode = match args.temporal {
        TemporalArg::EmaOneEuro => format!(
            "EMA sigma {} nu {} + 1-euro alpha {} beta {} f_min {} Hz at {} fps",
            t.ema_sigma, t.ema_nu, t.blend_alpha, t.beta, t.min_cutoff_hz, t.fps
        ),
        TemporalArg::Ema => format!("EMA sigma {} nu {}", t.ema_sigma, t.ema_nu),
        TemporalArg::OneEuro => {
            format!("1-euro alpha {} beta {} f_min {} Hz at {} fps", t.blend_alpha, t.beta, t.min_cutoff_hz, t.fps)
        }
        TemporalArg::Off => "per-frame, no temporal filtering".into(),
    };
    println!(
        "sequence: {} frames ({}; {}, {} iterations/frame at {}px); mean NNST loss {:.4e} -> {:.4e} \
         (output {:.4e}, re-matched {:.4e}); flicker {:.5} (motion-compensated), raw frame difference {:.5} \
         (input {:.5}); max length change {:.3}% vs input ({:.4}% vs rest); {} control points inside the mesh",
        s.frames,
        mode,
        p.preset.name,
        per_frame,
        p.render_size,
        s.eval_before,
        s.eval_optimized,
        s.eval_output,
        s.eval_output_rematched,
        s.flicker,
        s.flicker_raw,
        s.flicker_input_raw,
        100.0 * worst.0,
        100.0 * worst.1,
        worst.2
    );
    Ok(())
}

/// Name of the saved sequence state in the work folder.
const STATE_FILE: &str = "strands.state";

/// Everything a strand sequence's saved state depends on: the settings
/// (not `--force`, `--work-dir`), the painting's contents, and every frame's
/// groom and mesh by path, size and modification time. `--threads` is
/// included: results are reproducible bit for bit only on the same count.
fn strands_job_hash(
    args: &StrandsArgs,
    frames: &[i64],
    groom_at: &dyn Fn(i64) -> Result<PathBuf>,
    mesh_at: &dyn Fn(i64) -> Result<PathBuf>,
) -> Result<u64> {
    let mut a = args.clone();
    (a.force, a.work_dir) = (false, None);
    let mut stamped = Vec::with_capacity(2 * frames.len());
    for &f in frames {
        stamped.push(groom_at(f)?);
        stamped.push(mesh_at(f)?);
    }
    let style = a.style.clone().context("--style is required")?;
    job_fingerprint(&format!("{a:?}"), &[style], &stamped)
}

/// `nst3d strands generate`: the procedural groom at rest, or one file per
/// frame of its wind animation, and its mesh.
fn generate(g: GenerateArgs) -> Result<()> {
    let format = out_format(&g.out)?;
    if !(g.fps.is_finite() && g.fps > 0.0) {
        bail!("--fps must be a positive number, got {}", g.fps);
    }
    for (name, v) in [
        ("--wind", g.wind),
        ("--wind-direction", g.wind_direction),
        ("--wind-turn", g.wind_turn),
        ("--wind-wavelength", g.wind_wavelength),
        ("--wind-frequency", g.wind_frequency),
    ] {
        if !v.is_finite() {
            bail!("{name} must be a finite number, got {v}");
        }
    }
    if !(g.wind >= 0.0 && g.wind_wavelength > 0.0) {
        bail!("--wind must be >= 0 and --wind-wavelength > 0");
    }
    let (rest, mesh) = match g.kind {
        GenerateKind::FurBall => {
            let d = FurBallParams::default();
            fur_ball(&FurBallParams {
                radius: g.radius,
                strands: g.strands.unwrap_or(d.strands),
                points: g.points,
                length: g.length.unwrap_or(d.length),
                seed: g.seed,
            })?
        }
        GenerateKind::Grass => {
            let d = GrassParams::default();
            grass_patch(&GrassParams {
                strands: g.strands.unwrap_or(d.strands),
                points: g.points,
                length: g.length.unwrap_or(d.length),
                seed: g.seed,
                ..d
            })?
        }
    };
    let wind = Wind {
        direction_deg: g.wind_direction,
        turn_deg_per_s: g.wind_turn,
        strength: g.wind,
        wavelength: g.wind_wavelength,
        frequency_hz: g.wind_frequency,
    };
    let mut written = Vec::new();
    match &g.frames {
        None => {
            write_groom(&g.out, format, &rest)?;
            written.push(g.out.clone());
        }
        Some(spec) => {
            let spec = FrameSpec::parse(spec)?;
            frame_path(&g.out, spec.frames()[0], "--out")?;
            for &f in spec.frames() {
                let out = frame_path(&g.out, f, "--out")?;
                write_groom(&out, format, &wind.at_time(&rest, f as f32 / g.fps)?)?;
                written.push(out);
            }
        }
    }
    if let Some(m) = &g.mesh_out {
        nst3d_io::mesh::write_mesh_ply(m, &mesh).with_context(|| format!("writing {}", m.display()))?;
    }
    println!(
        "wrote {} strands x {} points to {}{}{}",
        rest.strand_count(),
        g.points,
        written.first().map_or(String::new(), |p| p.display().to_string()),
        if written.len() > 1 {
            format!(" .. {} ({} frames)", written[written.len() - 1].display(), written.len())
        } else {
            String::new()
        },
        g.mesh_out.as_ref().map_or(String::new(), |m| format!("; mesh {}", m.display()))
    );
    Ok(())
}
