//! Feed-forward stylization (paper Sec. 4 and 5.2): a trained network
//! (`nst3d train`) stylizes each frame on its own, from every viewpoint at
//! once, with no optimisation and no temporal machinery, so frames can run
//! in any order on any blade. Large grids run in tiles
//! ([`nst3d_network::infer_tiled`]), so memory follows the tile size.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use nst3d_core::{Grid3, Reporter};
use nst3d_io::vdb::read_vdb;
use nst3d_network::{infer_tiled, Model, Volume};
use nst3d_sequence::{expand_pattern, FrameSpec};
use nst3d_stylize::Mode;
use nst3d_train::step::{apply, Stylization};

use crate::dense::{pad, paste};
use crate::output::write_stylized;
use crate::settings::VolumeSettings;

/// A trained model and how to run it.
#[derive(Clone, Debug)]
pub struct ModelSettings {
    /// The model file written by `nst3d train`.
    pub path: PathBuf,
    /// Tile side in voxels (rounded up to a multiple of 4).
    pub tile: usize,
    /// Context around each tile, in voxels (rounded up to a multiple of 4).
    pub margin: usize,
    /// The mode the user asked for, if any: a model of the other mode is refused.
    pub mode: Option<Mode>,
}

/// What a feed-forward job did.
#[derive(Clone, Debug)]
pub struct ModelReport {
    /// Frames stylized.
    pub frames: usize,
    /// Frames skipped because their output exists, or copied because empty.
    pub skipped: usize,
    /// The model's mode.
    pub mode: Mode,
    /// Voxels run through the network.
    pub voxels: u64,
    /// Seconds spent in the network and transport (not reading or writing).
    pub seconds: f64,
    /// For a sequence, the flicker of the written frames by the metric the
    /// optimised sequences report ([`crate::flicker_of_outputs`]).
    pub flicker: Option<f64>,
    /// The output (pattern).
    pub out: String,
}

/// The model file, checked against what the user asked for.
fn load_model(m: &ModelSettings) -> Result<(Model, Mode, f32)> {
    let bytes = std::fs::read(&m.path).with_context(|| format!("cannot read the model {}", m.path.display()))?;
    let model = Model::from_bytes(&bytes, &m.path)?;
    let mode = match model.info.get("mode").map(String::as_str) {
        Some("density") => Mode::Density,
        Some("velocity") => Mode::Velocity,
        _ => bail!("{}: the model does not say its mode (density or velocity)", m.path.display()),
    };
    if let Some(asked) = m.mode.filter(|&a| a != mode) {
        bail!("{}: a {mode:?}-mode model, but --mode {asked:?} was asked for", m.path.display());
    }
    let want = if mode == Mode::Density { 1 } else { 3 };
    if model.net.out_channels() != want {
        bail!(
            "{}: a {mode:?}-mode model needs {want} output channels, it has {}",
            m.path.display(),
            model.net.out_channels()
        );
    }
    // Velocity models move smoke by up to vmax voxels, as in training.
    let vmax = match mode {
        Mode::Velocity => {
            let f: f32 = model.info.get("vmax_fraction").and_then(|v| v.parse().ok()).unwrap_or(0.04);
            let p: f32 = model.info.get("patch").and_then(|v| v.parse().ok()).unwrap_or(32.0);
            f * p
        }
        Mode::Density => 0.0,
    };
    if m.tile < m.margin || m.tile == 0 {
        bail!("--tile ({}) must be at least --tile-margin ({})", m.tile, m.margin);
    }
    Ok((model, mode, vmax))
}

/// Stylizes `d` (the file's densities) with the network: normalised to
/// `[0, 1]` as in training, run in tiles, then applied as a scale or a
/// velocity and scaled back.
fn stylize_density(model: &Model, mode: Mode, vmax: f32, d: &Grid3, m: &ModelSettings) -> Grid3 {
    let max = d.max();
    if !(max > 0.0) {
        return d.clone();
    }
    // The network maps sides that are multiples of 4 onto themselves: the
    // frame goes into the corner of such a box, normalised, and comes back out.
    let mut xg = Grid3::zeros(d.dims.map(|n| n.next_multiple_of(4)));
    paste(d, [0; 3], &mut xg, [0; 3]);
    xg.data.iter_mut().for_each(|v| *v /= max);
    let o = infer_tiled(&model.net, &Volume::from_grid(&xg), m.tile, m.margin);
    let how = match mode {
        Mode::Density => Stylization::Density,
        Mode::Velocity => Stylization::Velocity { vmax },
    };
    let mut styled = apply(&xg, &o, how);
    styled.data.iter_mut().for_each(|v| *v *= max);
    let mut out = Grid3::zeros(d.dims);
    paste(&styled, [0; 3], &mut out, [0; 3]);
    out
}

/// One frame file in, one out.
fn one_frame(
    s: &VolumeSettings,
    model: &Model,
    mode: Mode,
    vmax: f32,
    m: &ModelSettings,
    input: &Path,
    out: &Path,
) -> Result<Option<(u64, f64)>> {
    let file = read_vdb(input)?;
    let grid = file.grid(&s.grid).with_context(|| format!("{}: no grid named '{}'", input.display(), s.grid))?;
    if grid.active_voxel_count() == 0 {
        return Ok(None);
    }
    let (bx, dense) = grid.to_dense()?;
    // Room for the velocity to move smoke outwards.
    let margin = if mode == Mode::Velocity { vmax.ceil() as usize + 1 } else { 0 };
    let padded = pad(&dense, margin);
    let origin = bx.origin.map(|o| o - margin as i32);
    let t0 = Instant::now();
    let styled = stylize_density(model, mode, vmax, &padded, m);
    let secs = t0.elapsed().as_secs_f64();
    if styled.data.iter().any(|v| !v.is_finite()) {
        bail!("{}: the network produced non-finite densities", input.display());
    }
    write_stylized(out, &file, &grid.name, &grid.transform, origin, &styled)?;
    Ok(Some((padded.len() as u64, secs)))
}

/// Stylizes `s.input` (one frame, or the frames of `s.sequence`) with the
/// model `m`, each frame on its own.
pub fn stylize_with_model(s: &VolumeSettings, m: &ModelSettings, reporter: &mut dyn Reporter) -> Result<ModelReport> {
    let (model, mode, vmax) = load_model(m)?;
    let input = s.input.to_string_lossy().to_string();
    let output = s.out.to_string_lossy().to_string();
    let jobs: Vec<(PathBuf, PathBuf, bool)> = match &s.sequence {
        None => vec![(s.input.clone(), s.out.clone(), true)],
        Some(seq) => {
            let spec = FrameSpec::parse(&seq.frames)?;
            let frames: Vec<i64> = match &seq.chunk {
                Some(c) => {
                    // The same chunk syntax and checks as optimised sequences.
                    let (a, b) = crate::sequence::parse_chunk(c)?;
                    spec.within(a, b)
                }
                None => spec.frames().to_vec(),
            };
            let mut v = Vec::new();
            for f in frames {
                let o = PathBuf::from(expand_pattern(&output, f)?);
                let todo = seq.force || !o.exists();
                v.push((PathBuf::from(expand_pattern(&input, f)?), o, todo));
            }
            v
        }
    };
    let (mut frames, mut skipped, mut voxels, mut seconds) = (0, 0, 0u64, 0.0);
    reporter.begin(jobs.len() as u64);
    for (inp, out, todo) in &jobs {
        if !todo {
            skipped += 1;
            reporter.step(&format!("{} exists, kept", out.display()));
            continue;
        }
        match one_frame(s, &model, mode, vmax, m, inp, out)? {
            Some((n, t)) => {
                frames += 1;
                voxels += n;
                seconds += t;
            }
            None if s.sequence.is_none() => bail!("{}: grid '{}' is empty: nothing to stylize", inp.display(), s.grid),
            None => {
                // An empty frame of a sequence: the input, byte for byte.
                let bytes = std::fs::read(inp).with_context(|| format!("cannot read {}", inp.display()))?;
                nst3d_io::atomic::write_atomic(out, |w| w.write_all(&bytes))
                    .with_context(|| format!("cannot write {}", out.display()))?;
                skipped += 1;
            }
        }
        reporter.step(&format!("{}", out.display()));
    }
    reporter.end();
    let flicker = match s.sequence {
        // Scored as an optimised sequence of the model's mode would be.
        Some(_) => crate::flicker_of_outputs(&VolumeSettings { mode, ..s.clone() }, reporter)?,
        None => None,
    };
    Ok(ModelReport { frames, skipped, mode, voxels, seconds, flicker, out: output })
}
