//! `nst3d bench ...`: benchmarks whose medians docs/design/performance.md divides by
//! the PyTorch peer's.

use std::path::PathBuf;

use anyhow::{bail, Result};
use clap::{Args, ValueEnum};
use nst3d_groom::bench::StrandsIterSettings;
use nst3d_stylize::{bench, Mode};

use crate::console::Console;

/// Arguments of `nst3d bench`.
#[derive(Args)]
pub struct BenchArgs {
    /// Which benchmark.
    #[arg(value_enum)]
    which: Which,
    /// Grid resolution N (N^3 voxels, N x N render).
    #[arg(long, default_value_t = 128)]
    n: usize,
    /// velocity or density.
    #[arg(long, default_value = "velocity")]
    mode: Mode,
    /// Timed iterations after one warm-up (the peer's default is 6).
    #[arg(long, default_value_t = 6)]
    iters: usize,
    /// train-step: patch size P (a multiple of 4).
    #[arg(long, default_value_t = 64)]
    patch: usize,
    /// infer, train-step: the network's width C (2C at the low resolution), as the peer's --channels.
    #[arg(long, default_value_t = 16)]
    channels: usize,
    /// volume-iter: with colour, the iteration `nst3d volume --color` runs.
    #[arg(long)]
    color: bool,
    #[command(flatten)]
    strands: StrandInputs,
}

#[derive(Clone, Copy, ValueEnum)]
enum Which {
    /// One iteration of volumetric style transfer, as shared/bench/README.md defines it.
    VolumeIter,
    /// One iteration of strand stylization (transport, constraints, splat
    /// render, VGG-19, NNST, backward, AdamW) on the Bangs groom.
    StrandsIter,
    /// One forward pass of the feed-forward network (Fig. 9) on an N^3 grid,
    /// as `torch_ff_ref.py --infer N` times it.
    Infer,
    /// One training step of the feed-forward network on a --patch^3 patch,
    /// as `torch_ff_ref.py --patch P --mode M` times it.
    TrainStep,
}

/// Runs the benchmark; the last line is `ms_per_iter <median>`.
pub fn run(args: BenchArgs) -> Result<()> {
    match args.which {
        Which::VolumeIter => volume_iter(&args),
        Which::StrandsIter => strands_iter(&args),
        Which::Infer => infer(&args),
        Which::TrainStep => train_step(&args),
    }
}

fn volume_iter(args: &BenchArgs) -> Result<()> {
    if !(16..=512).contains(&args.n) {
        bail!("--n must be between 16 and 512, got {}", args.n);
    }
    let threads = rayon::current_num_threads();
    let mode = match args.mode {
        Mode::Velocity => "velocity",
        Mode::Density => "density",
    };
    eprintln!(
        "volume-iter: N={} mode={mode}{} threads={threads} iters={} precision={}",
        args.n,
        if args.color { " color" } else { "" },
        args.iters.max(1),
        nst3d_core::precision::path().describe()
    );
    let report = bench::volume_iter_with(args.n, args.mode, args.iters.max(1), args.color);
    let times: Vec<String> = report.iteration_ms.iter().map(|t| format!("{t:.1}")).collect();
    println!("iteration_ms {}", times.join(" "));
    println!("peak_rss_mb {:.0}", peak_rss_mb());
    println!("ms_per_iter {:.1}", report.median_ms);
    Ok(())
}

/// `infer`: the feed-forward network's forward pass; the last line is `ms_infer`.
fn infer(args: &BenchArgs) -> Result<()> {
    if !(16..=512).contains(&args.n) || !args.n.is_multiple_of(4) {
        bail!("--n must be a multiple of 4 between 16 and 512, got {}", args.n);
    }
    if !(1..=256).contains(&args.channels) {
        bail!("--channels must be between 1 and 256, got {}", args.channels);
    }
    eprintln!(
        "infer: N={} channels={} threads={} precision={}",
        args.n,
        args.channels,
        rayon::current_num_threads(),
        nst3d_core::precision::path_for(nst3d_core::precision::Product::Conv3d).describe()
    );
    let times = nst3d_network::bench::infer(args.n, args.channels, args.iters.max(1));
    let shown: Vec<String> = times.iter().map(|t| format!("{t:.1}")).collect();
    println!("iteration_ms {}", shown.join(" "));
    println!("peak_rss_mb {:.0}", peak_rss_mb());
    println!("ms_infer {:.1}", bench::median(&times));
    Ok(())
}

/// `train-step`: one feed-forward training step; the last line is `ms_per_step`.
fn train_step(args: &BenchArgs) -> Result<()> {
    if !(16..=256).contains(&args.patch) || !args.patch.is_multiple_of(4) {
        bail!("--patch must be a multiple of 4 between 16 and 256, got {}", args.patch);
    }
    if !(1..=256).contains(&args.channels) {
        bail!("--channels must be between 1 and 256, got {}", args.channels);
    }
    let velocity = matches!(args.mode, Mode::Velocity);
    eprintln!(
        "train-step: patch={} mode={} channels={} threads={} precision: VGG-19 {}, 3D network {}",
        args.patch,
        if velocity { "velocity" } else { "density" },
        args.channels,
        rayon::current_num_threads(),
        nst3d_core::precision::path().describe(),
        nst3d_core::precision::path_for(nst3d_core::precision::Product::Conv3d).describe()
    );
    let (times, last) = nst3d_train::bench::train_step(args.patch, velocity, args.channels, args.iters.max(1));
    let shown: Vec<String> = times.iter().map(|t| format!("{t:.1}")).collect();
    println!("iteration_ms {}", shown.join(" "));
    println!("loss_last {last:.6}");
    println!("peak_rss_mb {:.0}", peak_rss_mb());
    println!("ms_per_step {:.1}", bench::median(&times));
    Ok(())
}

/// Where the strand benchmark's inputs live (defaults: the shared Bangs
/// groom and head, run from the repository root).
#[derive(Args)]
pub struct StrandInputs {
    /// strands-iter: groom.
    #[arg(long, default_value = "../shared/data/grooms/Bangs_100.hair")]
    groom: PathBuf,
    /// strands-iter: head mesh.
    #[arg(long, default_value = "../shared/data/grooms/Bangs_head.ply")]
    mesh: PathBuf,
    /// strands-iter: style painting (its luminance is matched).
    #[arg(long, default_value = "../shared/data/styles/starry_night.jpg")]
    style: PathBuf,
    /// strands-iter: VGG-19 weights (default: $NST3D_VGG19, else the user cache).
    #[arg(long)]
    weights: Option<PathBuf>,
    /// strands-iter: square render size.
    #[arg(long, default_value_t = 600)]
    size: usize,
    /// strands-iter: write the scene, camera, targets and style columns here
    /// for the PyTorch peer (tools/bench/strands_iter_torch.py).
    #[arg(long)]
    dump: Option<PathBuf>,
}

/// `strands-iter`: one iteration of strand stylization on the Bangs groom
/// ([`nst3d_groom::bench::strands_iter`]); the last line is `ms_per_iter`.
fn strands_iter(args: &BenchArgs) -> Result<()> {
    let a = &args.strands;
    let settings = StrandsIterSettings {
        groom: a.groom.clone(),
        mesh: a.mesh.clone(),
        style: a.style.clone(),
        weights: a.weights.clone(),
        size: a.size,
        iters: args.iters,
        dump: a.dump.clone(),
    };
    let r = nst3d_groom::bench::strands_iter(&settings, &mut Console::default())?;
    println!("match_ms {:.1}  (once per view, not in the iteration)", r.match_ms);
    println!("loss_iter0 {:.6}  (match-time loss {:.6})", r.loss_iter0, r.loss_match);
    println!("loss_last {:.6}", r.loss_last);
    for (name, ms) in &r.stages {
        println!("stage_ms {name:<15} {ms:.1}");
    }
    let times: Vec<String> = r.iteration_ms.iter().map(|t| format!("{t:.1}")).collect();
    println!("iteration_ms {}", times.join(" "));
    println!("cpu_ms_per_iter {:.0}", r.cpu_ms_per_iter);
    println!("peak_rss_mb {:.0}", peak_rss_mb());
    println!("ms_per_iter {:.1}", r.ms_per_iter);
    Ok(())
}

/// Peak resident memory of this process (Linux `VmHWM`), for the memory
/// comparison with the peer; 0 where the kernel does not say.
fn peak_rss_mb() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1).and_then(|kb| kb.parse::<f64>().ok()))
        })
        .map_or(0.0, |kb| kb / 1024.0)
}
