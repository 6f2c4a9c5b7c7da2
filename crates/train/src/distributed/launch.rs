//! One `nst3d train` process, alone or as one rank of an MPI job
//! (`mpirun -n N`, `srun --mpi=pmix`). A build without the `mpi` feature
//! refuses to run as several copies of one job, in one line, rather than
//! train N models into one file. Under MPI every rank runs the same
//! command; rank 0 reports, and a failure or a stop is said once, by the
//! rank it concerns, while the others end quietly with the same exit
//! status ([`Quiet`]).

use anyhow::Result;
use nst3d_core::Reporter;

use super::{launched_as, Launch};
use crate::{TrainReport, TrainSettings};

/// An exit status with nothing to print: another rank says why.
#[derive(Debug)]
pub struct Quiet(pub i32);

impl std::fmt::Display for Quiet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "exit status {} (another rank reports why)", self.0)
    }
}

impl std::error::Error for Quiet {}

/// Trains with the settings `settings` builds: alone, or as one rank of
/// the MPI job that started this process. `reporter` is rank 0's (or the
/// lone process's); `stop_signal` is the stop signal this process
/// received, if any. The report on rank 0 (or alone), `None` on the other
/// ranks.
pub fn train_as_launched(
    settings: impl FnOnce() -> Result<TrainSettings>,
    reporter: &mut dyn Reporter,
    stop_signal: fn() -> Option<i32>,
) -> Result<Option<TrainReport>> {
    match launched_as() {
        None => Ok(Some(crate::train(&settings()?, reporter)?)),
        Some(launch) if launch.rank != 0 && !(cfg!(feature = "mpi") && launch.mpi) => Err(Quiet(1).into()),
        Some(launch) => as_rank(launch, settings, reporter, stop_signal),
    }
}

/// Rank 0 of several processes a launcher started, with no MPI to join
/// them (the others end quietly).
#[cfg(not(feature = "mpi"))]
fn as_rank(
    launch: Launch,
    _: impl FnOnce() -> Result<TrainSettings>,
    _: &mut dyn Reporter,
    _: fn() -> Option<i32>,
) -> Result<Option<TrainReport>> {
    anyhow::bail!(
        "this nst3d was built without MPI and was started as {} copies of one job: build it with MPI \
         (tools/build_mpi.sh, docs/guide/farm.md) or start one copy",
        launch.size
    )
}

/// One rank of an MPI job.
#[cfg(feature = "mpi")]
fn as_rank(
    launch: Launch,
    settings: impl FnOnce() -> Result<TrainSettings>,
    reporter: &mut dyn Reporter,
    stop_signal: fn() -> Option<i32>,
) -> Result<Option<TrainReport>> {
    use super::{agree, mpi_team::MpiTeam, Team};
    if !launch.mpi {
        anyhow::bail!(
            "srun started {} tasks without MPI's process manager: start them with `srun --mpi=pmix` \
             (docs/guide/farm.md)",
            launch.size
        );
    }
    let team = MpiTeam::init()?;
    if team.size() != launch.size {
        anyhow::bail!(
            "started as {} processes, but MPI sees {}: start nst3d with the mpirun of the MPI it was built with",
            launch.size,
            team.size()
        );
    }
    // Without --threads (which builds the pool first, so this is then a
    // no-op), the node's cores are shared among its ranks.
    let cores = std::thread::available_parallelism().map_or(1, usize::from);
    let _ = rayon::ThreadPoolBuilder::new().num_threads((cores / team.ranks_on_this_node()).max(1)).build_global();
    let rank = team.rank();
    let outcome = agree(&team, settings()).and_then(|s| {
        let mut silent = nst3d_core::Silent;
        let reporter: &mut dyn Reporter = if rank == 0 { reporter } else { &mut silent };
        reporter.status(&format!(
            "nst3d: training on {} MPI ranks ({}), batch {}, {} threads a rank",
            team.size(),
            MpiTeam::library(),
            s.batch,
            rayon::current_num_threads()
        ));
        crate::train_on(&team, &s, reporter)
    });
    let outcome = said_once(rank, outcome, stop_signal());
    // MPI_Finalize, which every rank reaches.
    drop(team);
    outcome.map(|r| (rank == 0).then_some(r))
}

/// A rank's outcome with the message said once: a failure by the rank that
/// failed, a stop by rank 0 (`signal`: the stop signal this rank received).
#[cfg(feature = "mpi")]
fn said_once(rank: usize, outcome: Result<TrainReport>, signal: Option<i32>) -> Result<TrainReport> {
    use nst3d_core::stop::Interrupted;
    let e = match outcome {
        Ok(r) => return Ok(r),
        Err(e) => e,
    };
    if e.is::<super::RankFailed>() {
        return Err(Quiet(1).into());
    }
    if !e.is::<Interrupted>() {
        return Err(e);
    }
    // Every rank stopped after the same step; a signal may have reached
    // only some of them.
    match (rank, signal) {
        (0, Some(_)) => Err(e),
        (0, None) => {
            eprintln!(
                "nst3d: stopped with another rank of the job, which received a stop signal; outputs written so far \
                 are complete, rerun to resume"
            );
            Err(Quiet(143).into())
        }
        (_, sig) => Err(Quiet(sig.map_or(143, |s| 128 + s)).into()),
    }
}
