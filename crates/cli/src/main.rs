//! `nst3d`: the command line over the nst3d crates. It parses arguments,
//! reports progress and turns every failure into one line on stderr and a
//! non-zero exit code; the work itself lives in the library crates.

mod bench;
mod progress;
mod sequence;
mod volume;

use clap::{Parser, Subcommand};

/// Neural style transfer for smoke volumes (OpenVDB) on the CPU.
#[derive(Parser)]
#[command(name = "nst3d", version, about)]
struct Cli {
    /// Worker threads (default: all cores).
    #[arg(long, global = true)]
    threads: Option<usize>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Stylize the density grid of an OpenVDB file with a painting.
    Volume(volume::VolumeArgs),
    /// Run a benchmark (see docs/PERFORMANCE.md).
    Bench(bench::BenchArgs),
}

fn main() {
    // A bug must still read as one line, not a backtrace, for an artist.
    std::panic::set_hook(Box::new(|info| {
        let msg = info
            .payload()
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| info.payload().downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "unknown".into());
        let at = info.location().map(|l| format!(" at {}:{}", l.file(), l.line())).unwrap_or_default();
        eprintln!("nst3d: internal error: {msg}{at} (please report this)");
    }));
    let cli = Cli::parse();
    if let Some(n) = cli.threads {
        if let Err(e) = rayon::ThreadPoolBuilder::new().num_threads(n.max(1)).build_global() {
            eprintln!("nst3d: error: cannot start {n} threads: {e}");
            std::process::exit(2);
        }
    }
    let result = match cli.command {
        Command::Volume(args) => volume::run(args),
        Command::Bench(args) => bench::run(args),
    };
    if let Err(e) = result {
        // `{:#}` joins the context chain into a single line.
        eprintln!("nst3d: error: {e:#}");
        std::process::exit(1);
    }
}
