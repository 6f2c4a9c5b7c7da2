//! `nst3d bench ...`: benchmarks whose medians docs/PERFORMANCE.md divides by
//! the PyTorch peer's.

use anyhow::{bail, Result};
use clap::{Args, ValueEnum};
use nst3d_stylize::{bench, Mode};

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
}

#[derive(Clone, Copy, ValueEnum)]
enum Which {
    /// One iteration of volumetric style transfer, as shared/bench/README.md defines it.
    VolumeIter,
}

/// Runs the benchmark; the last line is `ms_per_iter <median>`.
pub fn run(args: BenchArgs) -> Result<()> {
    if !(16..=512).contains(&args.n) {
        bail!("--n must be between 16 and 512, got {}", args.n);
    }
    match args.which {
        Which::VolumeIter => {
            let threads = rayon::current_num_threads();
            let mode = match args.mode {
                Mode::Velocity => "velocity",
                Mode::Density => "density",
            };
            eprintln!("volume-iter: N={} mode={mode} threads={threads} iters={}", args.n, args.iters.max(1));
            let report = bench::volume_iter(args.n, args.mode, args.iters.max(1));
            let times: Vec<String> = report.iteration_ms.iter().map(|t| format!("{t:.1}")).collect();
            println!("iteration_ms {}", times.join(" "));
            println!("peak_rss_mb {:.0}", peak_rss_mb());
            println!("ms_per_iter {:.1}", report.median_ms);
        }
    }
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
