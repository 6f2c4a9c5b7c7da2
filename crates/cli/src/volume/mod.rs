//! `nst3d volume`: the arguments of a volume job, turned once into
//! [`VolumeSettings`], run by [`nst3d_volume::stylize`], and its report printed.

pub mod preview;

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use nst3d_features::VggLayer;
use nst3d_render::Projection;
use nst3d_stylize::Mode;
use nst3d_volume::{ModelSettings, SequenceSettings, UpAxis, Upsample, VolumeSettings};

use crate::console::Console;

/// Arguments of `nst3d volume`.
#[derive(Args)]
pub struct VolumeArgs {
    /// Input OpenVDB file.
    #[arg(long)]
    pub input: PathBuf,
    /// Style painting (PNG or JPEG); not needed with --model. Give it
    /// several times with --style-map: each painting owns a region of the smoke.
    #[arg(long, required_unless_present = "model")]
    pub style: Vec<PathBuf>,
    /// Where each --style goes: a float grid of the input (`NAME`) or of
    /// another file (`FILE.vdb:NAME`), 0 the first painting and 1 the
    /// second, blended between; or `@height` (0 at the smoke's bottom, 1 at
    /// its top) or `@height-split` (labels: the lower half the first, the
    /// upper half the second). Sampled in world space.
    #[arg(long)]
    pub style_map: Option<String>,
    /// The --style-map's values are labels: 0 the first --style, 1 the
    /// second, and so on (one painting per region, any number of them).
    #[arg(long, requires = "style_map")]
    pub style_map_labels: bool,
    /// Output OpenVDB file (written atomically).
    #[arg(long)]
    pub out: PathBuf,
    /// Before/after preview PNG.
    #[arg(long)]
    pub preview: Option<PathBuf>,
    /// Frames to stylize as a sequence (e.g. `1-120` or `1-3,5,7-20:2`);
    /// then --input and --out are patterns with `####` or `%04d`.
    #[arg(long)]
    pub frames: Option<String>,
    /// EMA weight α of the temporal coherence (eq. 4), sequences only; 0
    /// stylizes every frame on its own (docs/design/volumes.md says why 0.8).
    #[arg(long, default_value_t = 0.8)]
    pub ema: f32,
    /// Let each octave's first sweep run without EMA blending (on by
    /// default: it makes farm chunks meet at their seams and cuts flicker
    /// further at the same style loss; docs/guide/farm.md, docs/design/volumes.md).
    /// `--ema-settle false` runs Algorithm 1 exactly as printed.
    #[arg(long, value_name = "BOOL", num_args = 0..=1, default_value_t = true, default_missing_value = "true",
          action = clap::ArgAction::Set)]
    pub ema_settle: bool,
    /// Simulation velocity grid for the EMA (default: the first of velocity, vel, v).
    #[arg(long)]
    pub velocity_grid: Option<String>,
    /// Voxels per frame per unit of the velocity grid (default: fitted to the data).
    #[arg(long)]
    pub velocity_scale: Option<f32>,
    /// Name of the float grid to stylize.
    #[arg(long, default_value = "density")]
    pub grid: String,
    /// velocity (transport by an optimised velocity, eq. 2) or density (scale
    /// field, eq. 5); default velocity (with --model: the model's mode).
    #[arg(long)]
    pub mode: Option<Mode>,
    /// A feed-forward model from `nst3d train`: stylize each frame with it in
    /// one pass, from every viewpoint, no optimisation (paper Sec. 4). Give
    /// it once per painting with --style-map: the results are blended by the map.
    #[arg(long)]
    pub model: Vec<PathBuf>,
    /// --model: tile side in voxels (memory follows it; Sec. 5.2).
    #[arg(long, default_value_t = ModelSettings::DEFAULT_TILE)]
    pub tile: usize,
    /// --model: context around each tile, in voxels (32 covers the network's reach).
    #[arg(long, default_value_t = ModelSettings::DEFAULT_MARGIN)]
    pub tile_margin: usize,
    /// Octaves (coarse-to-fine levels; default 2 in velocity mode, 3 in density mode).
    #[arg(long)]
    pub octaves: Option<usize>,
    /// Adam iterations per octave.
    #[arg(long, default_value_t = 20)]
    pub iters: usize,
    /// Adam learning rate (default: 0.5 voxels per step in velocity mode, 0.2 in density mode).
    #[arg(long)]
    pub lr: Option<f32>,
    /// Largest stylization velocity, in voxels (velocity mode; default 4% of
    /// the grid's largest side, at least 1 voxel, so small grids keep their shape).
    #[arg(long)]
    pub vmax: Option<f32>,
    /// Smallest density scale (density mode).
    #[arg(long, default_value_t = 0.0)]
    pub smin: f32,
    /// Largest density scale (density mode).
    #[arg(long, default_value_t = 2.0)]
    pub smax: f32,
    /// Style image scale factor (smaller = larger patterns).
    #[arg(long, default_value_t = 0.5)]
    pub style_scale: f32,
    /// Strength of the look: `subtle` (0.5), `default` (1), `strong` (1.5) or
    /// a number. Below 1 it shrinks --vmax and the density range around 1 by
    /// that factor (the smoke keeps its shape); above 1 it runs that many
    /// times the iterations (docs/design/volumes.md).
    /// With --model it raises the network's density scale to that power (a
    /// velocity model moves the smoke that many times as far).
    #[arg(long, default_value = "default", value_parser = nst3d_volume::settings::parse_strength)]
    pub strength: f32,
    /// Match the painting's colour statistics too (by default only its
    /// luminance: the renderer draws grey smoke, which cannot reach colour Grams).
    #[arg(long)]
    pub style_color: bool,
    /// Stylize an RGB colour per voxel (rendered in colour, matched to the
    /// painting's colours) and write it as a vec3 grid beside the density, in
    /// every frame of a sequence. A single frame is coloured after its smoke,
    /// from 16 cameras around it, free in brightness with its grey look
    /// guarded, the smoke's density scaled with the colour within
    /// --smin/--smax (docs/design/color.md); a sequence colours with the
    /// smoke in its sweeps. Optimisation only for now.
    #[arg(long, conflicts_with = "model")]
    pub color: bool,
    /// Name of the written colour grid (default: the input's colour grid, else
    /// `Cd` for Houdini-style files or y up, `color` for Blender's or z up).
    #[arg(long, requires = "color")]
    pub color_grid: Option<String>,
    /// VGG-19 layers whose Gram matrices are matched.
    #[arg(long, value_delimiter = ',', default_value = "relu1_1,relu2_1,relu3_1,relu4_1")]
    pub layers: Vec<VggLayer>,
    /// Absorption γ per unit density and voxel (default: chosen so the densest ray has optical depth 3).
    #[arg(long)]
    pub absorption: Option<f32>,
    /// Apply the differentiable histogram equalization of eq. 7 (helps dense, flat-white smoke).
    #[arg(long)]
    pub equalize: bool,
    /// Camera projection.
    #[arg(long, default_value = "perspective", value_parser = crate::named::<Projection>(Projection::NAMES.iter().copied()))]
    pub camera: Projection,
    /// Vertical field of view of the perspective camera, degrees.
    #[arg(long, default_value_t = 30.0)]
    pub fov: f32,
    /// Which index axis points up in the file (Blender caches are z-up, Houdini y-up).
    #[arg(long, default_value = "z", value_parser = crate::named::<UpAxis>(UpAxis::NAMES.iter().copied()))]
    pub up: UpAxis,
    /// VGG-19 weights file (default: $NST3D_VGG19, else the user cache; see tools/fetch_weights.sh).
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// Camera set Θ whose style losses are summed each iteration: `front`,
    /// `omniview:N` (N Poisson-disk cameras on a sphere, Sec. 4) or
    /// `ring:N[:ELEV]` (a turntable of N cameras at ELEV degrees).
    #[arg(long, default_value = "front", conflicts_with = "camera_file")]
    pub cameras: String,
    /// Shot camera or camera path (JSON, world space; see docs/guide/volumes.md).
    #[arg(long)]
    pub camera_file: Option<PathBuf>,
    /// Seed of the omniview camera placement.
    #[arg(long, default_value_t = 0)]
    pub camera_seed: u64,
    /// Also report the style loss seen from this camera set (same syntax as
    /// --cameras), before and after: views the optimiser never saw.
    #[arg(long)]
    pub eval_cameras: Option<String>,
    /// Stylize (and write) the grid this many times finer than the file:
    /// `auto` refines grids under 32 voxels along their largest side until it
    /// reaches 64 (at most 4x), `1` keeps the file's resolution.
    #[arg(long, default_value = "auto")]
    pub upsample: Upsample,
    /// Farm chunk: stylize and write only frames START-END of --frames.
    #[arg(long, requires = "frames")]
    pub chunk: Option<String>,
    /// Frames of overlap a chunk also optimises on each side (not written),
    /// so its EMA sees the same neighbours as one whole run (docs/guide/farm.md).
    #[arg(long, default_value_t = 0)]
    pub warmup: i64,
    /// Redo frames whose output file already exists.
    #[arg(long)]
    pub force: bool,
    /// Folder for per-frame optimisation state and the checkpoint (default:
    /// `<out dir>/.nst3d-work/<hash of the job's inputs and settings>`).
    #[arg(long)]
    pub work_dir: Option<PathBuf>,
}

impl VolumeArgs {
    /// The library's settings: the arguments as they are, typed.
    fn settings(self) -> VolumeSettings {
        let sequence = self.frames.map(|frames| SequenceSettings {
            frames,
            ema: self.ema,
            ema_settle: self.ema_settle,
            velocity_grid: self.velocity_grid,
            velocity_scale: self.velocity_scale,
            chunk: self.chunk,
            warmup: self.warmup,
            force: self.force,
            work_dir: self.work_dir,
        });
        VolumeSettings {
            input: self.input,
            style: self.style.first().cloned().unwrap_or_default(),
            more_styles: self.style.iter().skip(1).cloned().collect(),
            style_map: self.style_map,
            style_map_labels: self.style_map_labels,
            style_map_array: None,
            out: self.out,
            preview: self.preview,
            grid: self.grid,
            mode: self.mode.unwrap_or(Mode::Velocity),
            octaves: self.octaves,
            iters: self.iters,
            lr: self.lr,
            vmax: self.vmax,
            smin: self.smin,
            smax: self.smax,
            style_scale: self.style_scale,
            strength: self.strength,
            style_color: self.style_color,
            color: self.color,
            color_grid: self.color_grid,
            layers: self.layers,
            absorption: self.absorption,
            equalize: self.equalize,
            projection: self.camera,
            fov: self.fov,
            up: self.up,
            weights: self.weights,
            cameras: self.cameras,
            camera_file: self.camera_file,
            camera_seed: self.camera_seed,
            eval_cameras: self.eval_cameras,
            upsample: self.upsample,
            sequence,
            model: self.model.first().cloned().map(|path| ModelSettings {
                path,
                more: self.model.iter().skip(1).cloned().collect(),
                tile: self.tile,
                margin: self.tile_margin,
                mode: self.mode,
                strength: self.strength,
            }),
        }
    }
}

/// Runs `nst3d volume`.
pub fn run(args: VolumeArgs) -> Result<()> {
    let ema = args.ema;
    // A single frame still checks --ema, as it always has.
    if !(0.0..1.0).contains(&ema) {
        anyhow::bail!("--ema must be in [0, 1), got {ema}");
    }
    let settings = args.settings();
    let report = nst3d_volume::stylize(&settings, &mut Console::default())?;
    for line in report.lines(settings.eval_cameras.as_deref()) {
        println!("{line}");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        args: VolumeArgs,
    }

    fn parsed(extra: &[&str]) -> VolumeSettings {
        let mut argv = vec!["nst3d", "--input", "a.vdb", "--style", "p.jpg", "--out", "o.vdb"];
        argv.extend_from_slice(extra);
        Cli::parse_from(argv).args.settings()
    }

    /// Every default of `nst3d volume` is the library's (what the Python
    /// package runs with when an option is not given): the parsed settings
    /// print exactly as `VolumeSettings::new`'s, field by field.
    #[test]
    fn library_defaults_are_the_command_lines() {
        let d = VolumeSettings::new("a.vdb", "p.jpg", "o.vdb");
        assert_eq!(format!("{:#?}", parsed(&[])), format!("{d:#?}"));
        let mut seq = d.clone();
        seq.sequence = Some(SequenceSettings { frames: "1-3".into(), ..SequenceSettings::default() });
        assert_eq!(format!("{:#?}", parsed(&["--frames", "1-3"])), format!("{seq:#?}"));
        let mut model = d;
        model.model = Some(ModelSettings::new("m.safetensors"));
        assert_eq!(format!("{:#?}", parsed(&["--model", "m.safetensors"])), format!("{model:#?}"));
    }
}
