//! `nst3d preview`: pictures of OpenVDB smoke drawn by the transmittance
//! renderer the optimiser sees ([`nst3d_volume::preview`]), or of a groom
//! drawn by the strand splatting renderer from the strand stylization's
//! cameras ([`nst3d_groom::preview_groom`]).

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use nst3d_render::Projection;
use nst3d_strands::Preset;
use nst3d_volume::{PreviewSettings, UpAxis, PREVIEW_HEIGHT};

use crate::console::plural;

/// Arguments of `nst3d preview`.
#[derive(Args)]
pub struct PreviewArgs {
    /// OpenVDB file to draw (with --frames, a pattern with `####` or `%04d`),
    /// or a groom (.hair, .data, .ply, .abc, .usda, .usdc, .usd, .usdz).
    #[arg(long)]
    pub input: PathBuf,
    /// For a groom: the mesh it grows from (front direction and culling).
    #[arg(long)]
    pub mesh: Option<PathBuf>,
    /// A second file (e.g. the stylized result) drawn to the right of --input
    /// with the same camera and absorption; a pattern with --frames.
    #[arg(long)]
    pub compare: Option<PathBuf>,
    /// Output PNG (written atomically); with --turntable or --frames a pattern
    /// with `####` or `%04d` (turntable pictures are numbered from 1).
    #[arg(long)]
    pub out: PathBuf,
    /// Name of the float grid to draw.
    #[arg(long, default_value = "density")]
    pub grid: String,
    /// Frames of a sequence (e.g. `1-40` or `1-3,5,7-20:2`), one PNG each.
    #[arg(long)]
    pub frames: Option<String>,
    /// Number of pictures around the volume, at evenly spaced azimuths from the front.
    #[arg(long)]
    pub turntable: Option<usize>,
    /// Turntable camera elevation in degrees above the horizon.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub elevation: f32,
    /// Camera projection.
    #[arg(long, default_value = "perspective", value_parser = crate::named::<Projection>(Projection::NAMES.iter().copied()))]
    pub camera: Projection,
    /// Which axis points up in the file (default: z for a volume, as Blender caches are;
    /// for a groom a USD groom's upAxis, else y)
    #[arg(long, value_parser = crate::named::<UpAxis>(UpAxis::NAMES.iter().copied()))]
    pub up: Option<UpAxis>,
    /// Absorption γ per unit density and voxel (default: the densest ray of
    /// --input, or of its densest frame, gets optical depth 3; the same γ is
    /// then used for --compare and every frame, so brightness does not pump).
    #[arg(long, allow_negative_numbers = true)]
    pub absorption: Option<f32>,
    /// Picture height in pixels (a compare sheet is two pictures wide).
    #[arg(long, default_value_t = PREVIEW_HEIGHT)]
    pub height: usize,
    /// For a groom: judge every picture against this painting (VGG-19 Gram style
    /// loss of the picture to the painting's luminance; with --compare the ratio
    /// compare/input per picture, and the median and worst, over the whole picture
    /// and over the hair only).
    #[arg(long)]
    pub style: Option<PathBuf>,
    /// Draw in colour: a volume in its colour grid (`Cd` or `color`), a groom in its
    /// per-point colours (white where there are none); for a groom with --style,
    /// judge in colour (the painting's RGB Gram matrices) and report the grey
    /// judge of the pictures' luminance beside it.
    #[arg(long)]
    pub color: bool,
    /// For a groom: draw it with this preset's strand look and culling, as
    /// `nst3d strands --preset` renders it (grass on its ground is culled
    /// away by a head's threshold).
    #[arg(long, value_parser = crate::named::<Preset>(Preset::ALL.map(Preset::key)))]
    pub preset: Option<Preset>,
}

/// Runs `nst3d preview`.
pub fn run(args: PreviewArgs) -> Result<()> {
    if nst3d_groom::is_groom_file(&args.input) {
        if args.frames.is_some() || args.absorption.is_some() || args.grid != "density" {
            anyhow::bail!("--frames, --absorption and --grid apply to volumes; {} is a groom", args.input.display());
        }
        if let Some(s) = &args.style {
            if !s.is_file() {
                anyhow::bail!("--style {}: no such painting", s.display());
            }
        }
        let settings = nst3d_groom::GroomPreviewSettings {
            input: args.input,
            compare: args.compare,
            mesh: args.mesh,
            out: args.out,
            turntable: args.turntable,
            elevation: args.elevation,
            height: args.height,
            up: args.up,
            style: args.style,
            color: args.color,
            preset: args.preset.unwrap_or(Preset::ShortHair),
        };
        let r = nst3d_groom::preview_groom(&settings)?;
        let n = r.pictures;
        println!("wrote {n} preview picture{} of the groom ({})", plural(n), settings.out.display());
        for line in r.judgement() {
            println!("{line}");
        }
        return Ok(());
    }
    if args.mesh.is_some() || args.style.is_some() || args.preset.is_some() {
        anyhow::bail!(
            "--mesh, --style and --preset apply to grooms; {} is a volume (nst3d judge judges volumes)",
            args.input.display()
        );
    }
    let settings = PreviewSettings {
        input: args.input,
        compare: args.compare,
        out: args.out,
        grid: args.grid,
        frames: args.frames,
        turntable: args.turntable,
        elevation: args.elevation,
        projection: args.camera,
        up: args.up.unwrap_or(UpAxis::Z),
        absorption: args.absorption,
        height: args.height,
        color: args.color,
    };
    let r = nst3d_volume::preview(&settings)?;
    println!(
        "wrote {} preview picture{} ({}), absorption {:.6}",
        r.pictures,
        plural(r.pictures),
        settings.out.display(),
        r.absorption
    );
    Ok(())
}
