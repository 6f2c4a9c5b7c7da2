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
    #[arg(long, conflicts_with = "style_map")]
    color: bool,
    /// volume-iter: two paintings split at mid-height, the iteration of `nst3d volume --style-map`.
    #[arg(long)]
    style_map: bool,
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
    /// Each layer of the network at a --patch^3 patch, each product
    /// (forward, weight and input gradient) on each 3D-convolution kernel
    /// this CPU has, and the kernel --precision picks: the measurements the
    /// kernel choice was read from.
    Conv3d,
}

/// Runs the benchmark; the last line is `ms_per_iter <median>`.
pub fn run(args: BenchArgs) -> Result<()> {
    match args.which {
        Which::VolumeIter => volume_iter(&args),
        Which::StrandsIter => strands_iter(&args),
        Which::Infer => infer(&args),
        Which::TrainStep => train_step(&args),
        Which::Conv3d => conv3d(&args),
    }
}

/// Refuses `value` outside `lo..=hi` or not a multiple of `multiple`.
fn check(name: &str, value: usize, lo: usize, hi: usize, multiple: usize) -> Result<()> {
    if !(lo..=hi).contains(&value) || !value.is_multiple_of(multiple) {
        let m = if multiple > 1 { format!("a multiple of {multiple} ") } else { String::new() };
        bail!("--{name} must be {m}between {lo} and {hi}, got {value}");
    }
    Ok(())
}

/// The lines every benchmark ends with: each timed iteration, the peak
/// memory and, last, `NAME <median>`.
fn print_times(times: &[f64], last: &str) {
    let shown: Vec<String> = times.iter().map(|t| format!("{t:.1}")).collect();
    println!("iteration_ms {}", shown.join(" "));
    println!("peak_rss_mb {:.0}", nst3d_core::memory::peak_rss_mb());
    println!("{last} {:.1}", bench::median(times));
}

fn mode_name(mode: Mode) -> &'static str {
    match mode {
        Mode::Velocity => "velocity",
        Mode::Density => "density",
    }
}

fn volume_iter(args: &BenchArgs) -> Result<()> {
    check("n", args.n, 16, 512, 1)?;
    eprintln!(
        "volume-iter: N={} mode={}{} threads={} iters={} precision={}",
        args.n,
        mode_name(args.mode),
        if args.color {
            " color"
        } else if args.style_map {
            " style-map"
        } else {
            ""
        },
        rayon::current_num_threads(),
        args.iters.max(1),
        nst3d_core::precision::path().describe()
    );
    let look = match (args.color, args.style_map) {
        (true, _) => bench::Look::Color,
        (_, true) => bench::Look::StyleMap,
        _ => bench::Look::Grey,
    };
    let report = bench::volume_iter_with(args.n, args.mode, args.iters.max(1), look);
    print_times(&report.iteration_ms, "ms_per_iter");
    Ok(())
}

/// Checks the network's width and prints the first line of a network
/// benchmark: its name, its size, the width, threads and the convolutions'
/// precision.
fn network_header(name: &str, size: &str, args: &BenchArgs) -> Result<()> {
    check("channels", args.channels, 1, 256, 1)?;
    eprintln!(
        "{name}: {size} channels={} threads={} precision={}",
        args.channels,
        rayon::current_num_threads(),
        nst3d_core::precision::path_for(nst3d_core::precision::Product::Conv3d).describe()
    );
    Ok(())
}

/// `infer`: the feed-forward network's forward pass; the last line is `ms_infer`.
fn infer(args: &BenchArgs) -> Result<()> {
    check("n", args.n, 16, 512, 4)?;
    network_header("infer", &format!("N={}", args.n), args)?;
    print_times(&nst3d_network::bench::infer(args.n, args.channels, args.iters.max(1)), "ms_infer");
    Ok(())
}

/// `conv3d`: the kernel table, a line per layer and product, median ms per
/// kernel (`-` where it does not run), the picked kernel marked `*`.
fn conv3d(args: &BenchArgs) -> Result<()> {
    use nst3d_network::conv3d::Kernel3d;
    check("patch", args.patch, 16, 256, 4)?;
    network_header("conv3d", &format!("patch={}", args.patch), args)?;
    let names: Vec<&str> = Kernel3d::ALL.iter().map(|k| k.name()).collect();
    println!("{:<34} {:<12} {}", "layer", "product", names.join(" | "));
    for row in nst3d_network::bench::conv3d_table(args.patch, args.channels, args.iters.max(1)) {
        let cells: Vec<String> = Kernel3d::ALL
            .iter()
            .zip(row.ms)
            .map(|(k, ms)| {
                let mark = if row.chosen == Some(*k) { "*" } else { " " };
                ms.map_or(format!("{:>10}{mark}", "-"), |t| format!("{t:>10.2}{mark}"))
            })
            .collect();
        println!("{:<34} {:<12} {}", row.layer, format!("{:?}", row.product), cells.join(" | "));
    }
    Ok(())
}

/// `train-step`: one feed-forward training step; the last line is `ms_per_step`.
fn train_step(args: &BenchArgs) -> Result<()> {
    check("patch", args.patch, 16, 256, 4)?;
    check("channels", args.channels, 1, 256, 1)?;
    eprintln!(
        "train-step: patch={} mode={} channels={} threads={} precision: VGG-19 {}, 3D network {}",
        args.patch,
        mode_name(args.mode),
        args.channels,
        rayon::current_num_threads(),
        nst3d_core::precision::path().describe(),
        nst3d_core::precision::path_for(nst3d_core::precision::Product::Conv3d).describe()
    );
    let velocity = matches!(args.mode, Mode::Velocity);
    let (times, last) = nst3d_train::bench::train_step(args.patch, velocity, args.channels, args.iters.max(1));
    println!("loss_last {last:.6}");
    print_times(&times, "ms_per_step");
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
    println!("cpu_ms_per_iter {:.0}", r.cpu_ms_per_iter);
    print_times(&r.iteration_ms, "ms_per_iter");
    Ok(())
}
