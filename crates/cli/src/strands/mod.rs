//! `nst3d strands`: the arguments of a groom job, turned once into
//! [`StrandSettings`], run by [`nst3d_groom`], and its report printed; and
//! `nst3d strands generate` for the procedural grooms of Table 1.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand, ValueEnum};
use nst3d_groom::{GenerateKind, GenerateSettings, StrandSettings, Temporal, UpAxis};
use nst3d_strands::{EmaClock, Preset, Wind};

use crate::console::Console;

/// Arguments of `nst3d strands`.
#[derive(Args, Clone, Debug)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct StrandsArgs {
    #[command(subcommand)]
    command: Option<StrandsCommand>,
    /// Input groom (.hair, .data, .ply, .abc, or USD: .usda, .usdc, .usd,
    /// .usdz, with their sublayers and references); with --frames a pattern
    /// such as `anim/fur_####.ply` or `fur_%04d.ply`.
    #[arg(long, required = true)]
    groom: Option<PathBuf>,
    /// Head or body mesh the strands grow from (.ply or .obj); with --frames
    /// it may be a pattern too (a moving head), else one mesh for all frames.
    /// Without it strands are neither kept out of the head nor culled.
    #[arg(long)]
    mesh: Option<PathBuf>,
    /// Style painting (PNG or JPEG); its luminance is matched. Give it
    /// several times with --style-map: each painting owns its strands.
    #[arg(long, required = true)]
    style: Vec<PathBuf>,
    /// Which strands take which --style: `@height` (each root's height, 0
    /// at the lowest root and 1 at the highest), a .txt file of one number
    /// per strand, the name of a strand (or root vertex) property of a
    /// .ply groom, or of a primvar of a USD groom (per curve, or its root
    /// point's); 0 the first painting, 1 the second, blended between.
    #[arg(long)]
    style_map: Option<String>,
    /// The --style-map's values are labels: 0 the first --style, 1 the
    /// second, and so on (one painting per strand, any number of them).
    #[arg(long, requires = "style_map")]
    style_map_labels: bool,
    /// Table 1 preset.
    #[arg(long, default_value = "short-hair", value_parser = crate::named::<Preset>(Preset::ALL.map(Preset::key)))]
    preset: Preset,
    /// Output groom: USD (.usda text, .usdc or .usd binary, .usdz package)
    /// or .ply (written atomically); with --frames a pattern.
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
    #[arg(long, default_value = "ema-one-euro", value_parser = crate::named::<Temporal>(Temporal::NAMES.iter().copied()))]
    temporal: Temporal,
    /// EMA coefficient σ (default: the preset's, Table 1).
    #[arg(long)]
    ema_sigma: Option<f32>,
    /// EMA decaying period ν, as a fraction of the iterations (default: the preset's, held
    /// longer with the orientation term).
    #[arg(long)]
    ema_nu: Option<f32>,
    /// What the EMA's iteration count m runs over: each `scale` (Alg. 1's
    /// inner counter: every scale restarts from the previous frame's field),
    /// or the whole `frame` (measured to flicker more, docs/design/strands.md).
    #[arg(long, default_value = "scale", value_parser = crate::named::<EmaClock>(EmaClock::NAMES.iter().copied()))]
    ema_clock: EmaClock,
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
    /// Which axis of the groom and mesh points up: the cameras circle it and the
    /// output keeps it (default: a USD groom's upAxis, else y; Blender grooms are z-up).
    #[arg(long, value_parser = crate::named::<UpAxis>(UpAxis::NAMES.iter().copied()))]
    up: Option<UpAxis>,
    /// Seed of densification and camera sampling.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Multiplier on the preset's learning rates (scaled by the groom's radius).
    #[arg(long, default_value_t = 1.0)]
    lr_scale: f32,
    /// The painting's scale on the hair: multiplies the preset's style sizes and the size the orientation term lays the painting at (2: strokes twice as large; default: the preset's).
    #[arg(long)]
    style_scale: Option<f32>,
    /// Cameras per scale whose matches are cached (0: a new camera every iteration).
    #[arg(long, default_value_t = 8)]
    views_per_scale: usize,
    /// Evaluation views: the first N of the finest scale's cameras (with --views-per-scale 0, N drawn afresh).
    #[arg(long, default_value_t = 4)]
    eval_views: usize,
    /// Iterations of the three scales, e.g. 0,0,30 (overrides --iters).
    #[arg(long, value_delimiter = ',')]
    scale_iters: Option<Vec<u32>>,
    /// Strand cross-section sigma in pixels at the groom centre's depth (default: the pipeline's).
    #[arg(long)]
    strand_width: Option<f32>,
    /// Match each scale's NNST targets on the groom as the coarser scales left it
    /// (true), or every scale on the rest groom as the paper writes eq. 2 (false, the
    /// default: re-matched targets gave every style the same clumps).
    #[arg(long, action = clap::ArgAction::Set)]
    rematch: Option<bool>,
    /// Velocity samples blended per control point (eq. 5's neighbourhood; default: the
    /// preset's): more spreads each sample's pull over neighbouring strands.
    #[arg(long)]
    field_neighbors: Option<usize>,
    /// Weight of the orientation term: the painting's stroke directions as targets for
    /// the strands' directions, relative to the NNST loss (0: the paper's NNST alone;
    /// default: the preset's, 0 for the presets not yet cross-tested; with --frames it
    /// makes the EMA hold on to the previous frame's field longer, see --ema-nu).
    #[arg(long)]
    orientation: Option<f32>,
    /// VGG-19 weights file (default: $NST3D_VGG19, else the user cache).
    #[arg(long)]
    weights: Option<PathBuf>,
    /// Stylize the strands' colour too: after the shape (the same as without
    /// --color), a colour stage starting from the input's colours (white without)
    /// matches the painting's colours from cameras all around the groom; written as
    /// the output's colours (USD displayColor, .ply red/green/blue).
    #[arg(long)]
    color: bool,
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
    kind: GenerateKindArg,
    /// Output groom (.ply, .usda, .usdc, .usd or .usdz); with --frames a pattern such as `anim/fur_####.ply`.
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
enum GenerateKindArg {
    /// Straight fur along the normals of a sphere (Fig. 8).
    FurBall,
    /// Near-vertical blades on a plane (Fig. 12).
    Grass,
}

impl StrandsArgs {
    /// The library's settings: the arguments as they are, typed.
    fn settings(self) -> Result<StrandSettings> {
        // clap enforces these unless a subcommand is given.
        let need = |p: Option<PathBuf>, name: &str| p.with_context(|| format!("{name} is required"));
        let style_flow = match self.style_flow {
            None => None,
            Some(v) if v.len() == 3 => Some([v[0], v[1], v[2]]),
            Some(v) => bail!("--style-flow needs three finite numbers X,Y,Z, got {v:?}"),
        };
        let scale_iters = match self.scale_iters {
            None => None,
            Some(n) if n.len() == 3 => Some([n[0], n[1], n[2]]),
            Some(n) => bail!("--scale-iters needs three comma-separated counts, got {}", n.len()),
        };
        Ok(StrandSettings {
            groom: need(self.groom, "--groom")?,
            mesh: self.mesh,
            style: self.style.first().cloned().context("--style is required")?,
            more_styles: self.style.iter().skip(1).cloned().collect(),
            style_map: self.style_map,
            style_map_labels: self.style_map_labels,
            style_map_values: None,
            out: need(self.out, "--out")?,
            preview: self.preview,
            preset: self.preset,
            frames: self.frames,
            force: self.force,
            work_dir: self.work_dir,
            temporal: self.temporal,
            ema_sigma: self.ema_sigma,
            ema_nu: self.ema_nu,
            ema_clock: self.ema_clock,
            one_euro_alpha: self.one_euro_alpha,
            one_euro_beta: self.one_euro_beta,
            one_euro_fmin: self.one_euro_fmin,
            fps: self.fps,
            style_flow,
            iters: self.iters,
            render_size: self.render_size,
            proxies: self.proxies,
            up: self.up,
            seed: self.seed,
            lr_scale: self.lr_scale,
            style_scale: self.style_scale,
            views_per_scale: self.views_per_scale,
            eval_views: self.eval_views,
            scale_iters,
            strand_width: self.strand_width,
            rematch: self.rematch,
            field_neighbors: self.field_neighbors,
            orientation: self.orientation,
            weights: self.weights,
            color: self.color,
        })
    }
}

/// Runs `nst3d strands`.
pub fn run(args: StrandsArgs) -> Result<()> {
    if let Some(StrandsCommand::Generate(g)) = args.command {
        return generate(g);
    }
    let s = args.settings()?;
    nst3d_groom::OutFormat::of(&s.out)?;
    if s.frames.is_some() {
        return run_sequence(&s);
    }
    let r = nst3d_groom::stylize_groom_file(&s, &mut Console::default())?;
    println!("{}", r.summary(s.mesh.is_some()));
    Ok(())
}

/// `nst3d strands --frames`: the animated groom, then the sequence's mean
/// losses and flicker.
fn run_sequence(s: &StrandSettings) -> Result<()> {
    let r = nst3d_groom::stylize_groom_sequence(s, &mut Console::default())?;
    println!("{}", r.summary(s.mesh.is_some()));
    Ok(())
}

/// `nst3d strands generate`: the procedural groom at rest, or one file per
/// frame of its wind animation, and its mesh.
fn generate(g: GenerateArgs) -> Result<()> {
    let settings = GenerateSettings {
        kind: match g.kind {
            GenerateKindArg::FurBall => GenerateKind::FurBall,
            GenerateKindArg::Grass => GenerateKind::Grass,
        },
        out: g.out,
        mesh_out: g.mesh_out,
        frames: g.frames,
        strands: g.strands,
        points: g.points,
        length: g.length,
        radius: g.radius,
        seed: g.seed,
        fps: g.fps,
        wind: Wind {
            direction_deg: g.wind_direction,
            turn_deg_per_s: g.wind_turn,
            strength: g.wind,
            wavelength: g.wind_wavelength,
            frequency_hz: g.wind_frequency,
        },
    };
    println!("{}", nst3d_groom::generate(&settings)?.summary());
    Ok(())
}

#[cfg(test)]
mod defaults {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        args: StrandsArgs,
    }

    /// Every default of `nst3d strands` is the library's (the Python
    /// package's): the parsed settings print exactly as `StrandSettings::new`'s.
    #[test]
    fn library_defaults_are_the_command_lines() {
        let argv = ["nst3d", "--groom", "g.ply", "--mesh", "m.ply", "--style", "p.jpg", "--out", "o.usda"];
        let a = Cli::parse_from(argv).args.settings().unwrap();
        let d = StrandSettings::new("g.ply", "m.ply", "p.jpg", "o.usda");
        assert_eq!(format!("{a:#?}"), format!("{d:#?}"));
    }
}
