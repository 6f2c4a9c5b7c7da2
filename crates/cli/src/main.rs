//! `nst3d`: the command line over the nst3d crates. Each command parses its
//! arguments into the settings of one library job (`nst3d_volume`,
//! `nst3d_groom`), runs it with a [`console::Console`] for progress, prints
//! the report, and turns every failure into one line on stderr and a
//! non-zero exit code; the work itself lives in the library crates.

mod bench;
mod console;
mod judge;
mod strands;
mod train;
mod volume;

/// mimalloc keeps freed pages for reuse. With the system allocator every
/// iteration's large buffers (feature maps, gradients, fields) went back to
/// the kernel and were faulted in again: about 13,000 page faults per
/// `volume-iter` iteration at N = 128, 10 % of its time (docs/design/performance.md).
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// Keeps freed pages for [`nst3d_core::memory::ALLOCATOR_PURGE_DELAY_MS`]
/// instead of mimalloc's default second (see there).
fn keep_freed_pages() {
    use nst3d_core::memory::{ALLOCATOR_PURGE_DELAY_MS, MIMALLOC_OPTION_PURGE_DELAY};
    // SAFETY: sets one integer option; mimalloc allows it at any time.
    unsafe { libmimalloc_sys::mi_option_set(MIMALLOC_OPTION_PURGE_DELAY, ALLOCATOR_PURGE_DELAY_MS as _) }
}

use clap::{Parser, Subcommand};

/// Neural style transfer for smoke volumes (OpenVDB) on the CPU.
#[derive(Parser)]
#[command(name = "nst3d", version, about)]
struct Cli {
    /// Worker threads (default: all cores).
    #[arg(long, global = true)]
    threads: Option<usize>,
    /// Arithmetic of the heavy products: auto (bf16 where the CPU has AMX
    /// tiles, fp32 otherwise; the 3D network's convolutions in bf16 on
    /// AVX512-BF16 too), bf16 (on AMX, AVX512-BF16 or emulated) or fp32
    /// (the reference). Default: $NST3D_PRECISION, else auto.
    #[arg(long, global = true, value_name = "auto|bf16|fp32", value_parser = parse_precision)]
    precision: Option<nst3d_core::precision::Precision>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Stylize the density grid of an OpenVDB file with a painting.
    Volume(volume::VolumeArgs),
    /// Run a benchmark (see docs/design/performance.md).
    Bench(bench::BenchArgs),
    /// Draw smoke as PNGs: a front view, a turntable, original | stylized, or a sequence.
    Preview(volume::preview::PreviewArgs),
    /// Stylize a hair or fur groom (strand style transfer, one frame).
    Strands(strands::StrandsArgs),
    /// Train the feed-forward network (volumetric paper Sec. 4) for one painting.
    Train(train::TrainArgs),
    /// Score stylized files against a baseline from held-out cameras (grey and colour style loss).
    Judge(judge::JudgeArgs),
}

/// A clap parser for a library settings enum: its names (`named_enum!`'s
/// `NAMES`) as the possible values --help lists, its `FromStr` for the
/// value. The CLI keeps no copy of the enum.
pub(crate) fn named<T>(names: impl IntoIterator<Item = &'static str>) -> impl clap::builder::TypedValueParser<Value = T>
where
    T: std::str::FromStr<Err = String> + Clone + Send + Sync + 'static,
{
    clap::builder::TypedValueParser::try_map(clap::builder::PossibleValuesParser::new(names), |s: String| {
        s.parse::<T>()
    })
}

fn parse_precision(s: &str) -> Result<nst3d_core::precision::Precision, String> {
    s.parse()
}

fn main() {
    nst3d_core::report::one_line_panics();
    keep_freed_pages();
    let cli = Cli::parse();
    // The docs test (crates/cli/tests/docs.rs) checks that every command
    // line the docs show still parses, without running any of them.
    if std::env::var_os("NST3D_PARSE_ONLY").is_some() {
        return;
    }
    nst3d_job::signals::install();
    if let Some(n) = cli.threads {
        if let Err(e) = rayon::ThreadPoolBuilder::new().num_threads(n.max(1)).build_global() {
            eprintln!("nst3d: error: cannot start {n} threads: {e}");
            std::process::exit(2);
        }
    }
    match cli.precision {
        Some(p) => nst3d_core::precision::set(p),
        None => {
            if let Err(e) = nst3d_core::precision::check_env() {
                eprintln!("nst3d: error: {e}");
                std::process::exit(2);
            }
        }
    }
    let result = match cli.command {
        Command::Volume(args) => volume::run(args),
        Command::Bench(args) => bench::run(args),
        Command::Preview(args) => volume::preview::run(args),
        Command::Strands(args) => strands::run(args),
        Command::Train(args) => train::run(args),
        Command::Judge(args) => judge::run(args),
    };
    // A rank of an MPI job whose message another rank gives.
    if let Some(q) = result.as_ref().err().and_then(|e| e.downcast_ref::<nst3d_train::distributed::launch::Quiet>()) {
        std::process::exit(q.0);
    }
    // A job stopped by a signal ends with 128 + the signal whatever it
    // returned, so a farm manager tells a cancelled task from a failed one.
    if let Some(sig) = nst3d_job::signals::received() {
        eprintln!(
            "nst3d: stopped by {}; outputs written so far are complete, rerun to resume",
            nst3d_job::signals::name(sig)
        );
        std::process::exit(128 + sig);
    }
    if let Err(e) = result {
        eprintln!("nst3d: error: {}", nst3d_core::report::one_line(e.as_ref()));
        std::process::exit(1);
    }
}

#[cfg(test)]
mod tests {
    use nst3d_core::memory::{ALLOCATOR_PURGE_DELAY_MS, MIMALLOC_OPTION_PURGE_DELAY};

    /// The raw option index names mimalloc's purge delay: it starts at that
    /// option's documented default (1000 ms in v3) and reads back what
    /// [`super::keep_freed_pages`] sets.
    #[test]
    fn the_purge_delay_option_is_the_one_we_set() {
        assert!(std::env::var_os("MIMALLOC_PURGE_DELAY").is_none(), "unset MIMALLOC_PURGE_DELAY to run this test");
        // SAFETY: reads and sets one integer option.
        let before = unsafe { libmimalloc_sys::mi_option_get(MIMALLOC_OPTION_PURGE_DELAY) };
        assert_eq!(before, 1000, "option {MIMALLOC_OPTION_PURGE_DELAY} is not mimalloc's purge delay");
        super::keep_freed_pages();
        let after = unsafe { libmimalloc_sys::mi_option_get(MIMALLOC_OPTION_PURGE_DELAY) };
        assert_eq!(after as i64, ALLOCATOR_PURGE_DELAY_MS);
    }
}
