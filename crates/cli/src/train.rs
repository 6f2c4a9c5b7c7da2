//! `nst3d train`: arguments → [`nst3d_train::TrainSettings`] → one library
//! call → the printed report.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use nst3d_stylize::Mode;
use nst3d_train::distributed::launch::train_as_launched;
use nst3d_train::{TrainSettings, ViewAxes};

/// Arguments of `nst3d train`.
#[derive(Args)]
pub struct TrainArgs {
    /// Simulation frames: an OpenVDB file, or a pattern with `####` / `%04d`
    /// together with --frames. Repeat for several simulations.
    #[arg(long, required = true)]
    input: Vec<String>,
    /// Frames of each --input pattern, in the same order (e.g. `1-40`).
    #[arg(long)]
    frames: Vec<String>,
    /// The painting.
    #[arg(long)]
    style: PathBuf,
    /// The model file to write (`.safetensors`); a checkpoint `<out>.ckpt`,
    /// the loss log `<out>.csv` and its plot `<out>.loss.png` go beside it.
    #[arg(long)]
    out: PathBuf,
    /// density (a scale in [0, 2]; the example model's mode) or velocity
    /// (moves smoke by up to vmax = 4 % of the patch); both keep each
    /// frame's total density (docs/design/feedforward.md).
    #[arg(long, default_value = "density")]
    mode: Mode,
    /// Name of the density grid.
    #[arg(long, default_value = "density")]
    grid: String,
    /// Network width C (2C at the low resolution).
    #[arg(long, default_value_t = 16)]
    channels: usize,
    /// Patch side in voxels (a multiple of 4; the paper used 128 and 256 on a GPU).
    #[arg(long, default_value_t = 32)]
    patch: usize,
    /// Steps of the OneCycle schedule [default: 2000; with --minutes alone, as
    /// many as the measured step time fits in the budget].
    #[arg(long)]
    steps: Option<u64>,
    /// Train for this many minutes: alone, the schedule is sized to fill them;
    /// with --steps, the run stops after them (a checkpoint is written; rerun to continue).
    #[arg(long)]
    minutes: Option<f64>,
    /// Random rotation about x, ± degrees.
    #[arg(long, default_value_t = 180.0)]
    theta: f32,
    /// Random rotation about y, ± degrees (the paper narrows it to 20 for some styles).
    #[arg(long, default_value_t = 90.0)]
    phi: f32,
    /// How each step sees its patch: random (along one of its x, y, z per
    /// step), all (along all three, 3x the rendering work), sphere (a
    /// perspective camera from a random direction, as the omniview
    /// cameras are placed) or z (the paper's peer and the first models,
    /// which learn to stretch their strokes along z;
    /// docs/design/feedforward.md).
    #[arg(long, default_value = "random")]
    view_axes: ViewAxes,
    /// How opaque the training pictures are: patch (γ = 8/P for every
    /// patch, the paper's peer) or frame (each patch as its whole frame is
    /// drawn: its densest column at optical depth 3).
    #[arg(long, default_value = "patch")]
    absorption: nst3d_train::Absorption,
    /// Style image scale factor (smaller = larger patterns).
    #[arg(long, default_value_t = 0.5)]
    style_scale: f32,
    /// Octaves of the loss: the stylized patch is also scored box-filtered
    /// 2x (and 4x) smaller, matching strokes at several sizes (the paper used 2).
    #[arg(long, default_value_t = 2)]
    octaves: usize,
    /// Learn a periodic solid texture of this period (voxels) beside the
    /// network, multiplied into its result: strokes where the smoke is
    /// smooth, which the network alone leaves flat. Not in the paper
    /// (docs/design/feedforward.md); the shipped models use 32.
    #[arg(long)]
    texture: Option<usize>,
    /// Seed of the initial weights and the patch sampling.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Steps between checkpoints.
    #[arg(long, default_value_t = 50)]
    checkpoint_every: u64,
    /// Patches a step, over all ranks of an MPI run (`mpirun -n N nst3d
    /// train`): each rank takes B/N of them and the step follows their mean
    /// gradient; the same B on any N trains the same model.
    #[arg(long, default_value_t = 1)]
    batch: usize,
    /// VGG-19 weights file (default: $NST3D_VGG19, else the user cache).
    #[arg(long)]
    weights: Option<PathBuf>,
}

/// The library's settings from the command line.
fn settings(args: TrainArgs) -> Result<TrainSettings> {
    Ok(TrainSettings {
        frames: nst3d_train::job::training_frames(&args.input, &args.frames)?,
        grid: args.grid,
        style: args.style,
        style_scale: args.style_scale,
        weights: args.weights,
        velocity: matches!(args.mode, Mode::Velocity),
        channels: args.channels,
        patch: args.patch,
        octaves: args.octaves,
        steps: args.steps,
        minutes: args.minutes,
        theta_deg: args.theta,
        phi_deg: args.phi,
        view_axes: args.view_axes,
        absorption: args.absorption,
        texture: args.texture,
        seed: args.seed,
        out: args.out,
        checkpoint_every: args.checkpoint_every,
        batch: args.batch,
    })
}

/// Runs `nst3d train`, alone or as one rank of an MPI job (rank 0 prints
/// the report).
pub fn run(args: TrainArgs) -> Result<()> {
    let started = std::time::Instant::now();
    let console = &mut crate::console::Console::default();
    let Some(r) = train_as_launched(|| settings(args), console, nst3d_job::signals::received)? else {
        return Ok(());
    };
    let minutes = started.elapsed().as_secs_f64() / 60.0;
    let how = if r.resumed_at > 0 { format!(" (resumed at step {})", r.resumed_at + 1) } else { String::new() };
    let left = if r.schedule_done { "" } else { "; time budget reached, rerun to continue" };
    let steps = match r.sized {
        true => format!("{} steps, a {}-step OneCycle schedule paced to the time budget", r.steps, r.planned_steps),
        false => format!("{} of {} steps", r.steps, r.planned_steps),
    };
    println!(
        "trained {steps}{how} in {minutes:.1} min; loss {:.4e} (first 10 %) -> {:.4e} (last 10 %){left}; wrote {}",
        r.loss_first,
        r.loss_last,
        r.out.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        args: TrainArgs,
    }

    /// The library's defaults (what the Python package uses) are the command line's.
    #[test]
    fn library_defaults_are_the_command_lines() {
        let a = Cli::parse_from(["nst3d", "--input", "a.vdb", "--style", "p.jpg", "--out", "m.safetensors"]).args;
        let d = TrainSettings::new(vec![], "p.jpg", "m.safetensors");
        assert_eq!(
            (a.grid, a.style_scale, a.channels, a.patch, a.octaves, a.steps, a.minutes, a.theta, a.phi, a.seed),
            (d.grid, d.style_scale, d.channels, d.patch, d.octaves, d.steps, d.minutes, d.theta_deg, d.phi_deg, d.seed)
        );
        assert_eq!((a.checkpoint_every, matches!(a.mode, Mode::Velocity)), (d.checkpoint_every, d.velocity));
        assert_eq!((a.view_axes, a.batch), (d.view_axes, d.batch));
    }
}
