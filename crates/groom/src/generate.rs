//! The procedural grooms of Table 1 written to files: the fur ball (Fig. 8)
//! and the grass patch (Fig. 12) at rest, or one file per frame of their
//! wind animation, and the mesh they grow from (what a stylization job's
//! mesh input reads).

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use nst3d_job::FrameSpec;
use nst3d_strands::{fur_ball, grass_patch, FurBallParams, GrassParams, Wind};

use crate::output::write_groom;
use crate::settings::frame_path;
use crate::settings::OutFormat;

/// Which procedural groom.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GenerateKind {
    /// Straight fur along the normals of a sphere (Fig. 8).
    FurBall,
    /// Near-vertical blades on a plane (Fig. 12).
    Grass,
}

/// What to generate and where.
#[derive(Clone, Debug)]
pub struct GenerateSettings {
    /// Which groom.
    pub kind: GenerateKind,
    /// Output groom (.ply, .usda, .usdc or .usdz); with `frames` a pattern.
    pub out: PathBuf,
    /// The mesh the strands grow from (.ply).
    pub mesh_out: Option<PathBuf>,
    /// Frames to write; frame f is the wind at time f / fps. Without it the
    /// groom is written once, at rest.
    pub frames: Option<String>,
    /// Strands (default: Table 1's, 8000 fur / 3000 grass).
    pub strands: Option<usize>,
    /// Control points per strand.
    pub points: usize,
    /// Strand length (default: 0.25 fur / 0.3 grass).
    pub length: Option<f32>,
    /// Fur ball radius.
    pub radius: f32,
    /// Seed of the root sampler.
    pub seed: u64,
    /// Frame rate of the animation.
    pub fps: f32,
    /// The wind.
    pub wind: Wind,
}

/// The files a generate job wrote.
#[derive(Clone, Debug)]
pub struct GenerateReport {
    /// Strands per groom.
    pub strands: usize,
    /// Control points per strand.
    pub points: usize,
    /// Groom files, in frame order.
    pub written: Vec<PathBuf>,
    /// The mesh file, if asked for.
    pub mesh: Option<PathBuf>,
}

/// Writes the procedural groom `g` asks for.
pub fn generate(g: &GenerateSettings) -> Result<GenerateReport> {
    let format = OutFormat::of(&g.out)?;
    if !(g.fps.is_finite() && g.fps > 0.0) {
        bail!("--fps must be a positive number, got {}", g.fps);
    }
    let w = &g.wind;
    for (name, v) in [
        ("--wind", w.strength),
        ("--wind-direction", w.direction_deg),
        ("--wind-turn", w.turn_deg_per_s),
        ("--wind-wavelength", w.wavelength),
        ("--wind-frequency", w.frequency_hz),
    ] {
        if !v.is_finite() {
            bail!("{name} must be a finite number, got {v}");
        }
    }
    if !(w.strength >= 0.0 && w.wavelength > 0.0) {
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
    let mut written = Vec::new();
    match &g.frames {
        None => {
            write_groom(&g.out, format, &rest, None, None)?;
            written.push(g.out.clone());
        }
        Some(spec) => {
            let spec = FrameSpec::parse(spec)?;
            frame_path(&g.out, spec.frames()[0], "--out")?;
            for &f in spec.frames() {
                let out = frame_path(&g.out, f, "--out")?;
                write_groom(&out, format, &w.at_time(&rest, f as f32 / g.fps)?, None, None)?;
                written.push(out);
            }
        }
    }
    if let Some(m) = &g.mesh_out {
        nst3d_io::mesh::write_mesh_ply(m, &mesh).with_context(|| format!("writing {}", m.display()))?;
    }
    Ok(GenerateReport { strands: rest.strand_count(), points: g.points, written, mesh: g.mesh_out.clone() })
}
