//! The [`Team`] of an MPI job (`mpirun`, `srun --mpi=pmix`), through the
//! `mpi` crate over the MPI library installed on the machine (Open MPI or
//! MPICH). Built only with the `mpi` cargo feature.

use anyhow::{bail, Result};
use mpi::collective::SystemOperation;
use mpi::topology::SimpleCommunicator;
use mpi::traits::{Communicator, CommunicatorCollectives, Root};

use super::Team;

/// The processes of `MPI_COMM_WORLD`. Dropping it ends MPI
/// (`MPI_Finalize`), which every rank must reach.
pub struct MpiTeam {
    world: SimpleCommunicator,
    // Declared last: dropped after the communicator.
    _universe: mpi::environment::Universe,
}

impl MpiTeam {
    /// Starts MPI. MPI functions are called from this thread alone (the
    /// worker threads never call them), the "funneled" level.
    pub fn init() -> Result<Self> {
        let Some((universe, _)) = mpi::initialize_with_threading(mpi::Threading::Funneled) else {
            bail!("MPI was already started in this process");
        };
        Ok(Self { world: universe.world(), _universe: universe })
    }

    /// The ranks on this machine (for a default thread count per rank).
    pub fn ranks_on_this_node(&self) -> usize {
        self.world.split_shared(self.world.rank()).size() as usize
    }

    /// The MPI library's name and version ("Open MPI v4.1.4"): its own
    /// description up to the first comma, spaces collapsed.
    pub fn library() -> String {
        let v = mpi::environment::library_version().unwrap_or_default();
        let name = v.lines().next().unwrap_or_default().split(',').next().unwrap_or_default();
        match name.split_whitespace().collect::<Vec<_>>().join(" ") {
            n if n.is_empty() => "an MPI library".into(),
            n => n,
        }
    }

    /// Ends every rank at once (`MPI_Abort`), for a failure the others
    /// cannot learn of at a collective.
    pub fn abort(&self, code: i32) -> ! {
        self.world.abort(code)
    }

    fn reduce<T: mpi::datatype::Equivalence + Copy>(&self, values: &mut [T], op: SystemOperation) {
        let send = values.to_vec();
        self.world.all_reduce_into(&send[..], values, op);
    }
}

impl Team for MpiTeam {
    fn rank(&self) -> usize {
        self.world.rank() as usize
    }
    fn size(&self) -> usize {
        self.world.size() as usize
    }
    fn sum_i64(&self, values: &mut [i64]) {
        self.reduce(values, SystemOperation::sum());
    }
    fn sum_f64(&self, values: &mut [f64]) {
        self.reduce(values, SystemOperation::sum());
    }
    fn max_f64(&self, values: &mut [f64]) {
        self.reduce(values, SystemOperation::max());
    }
    fn broadcast_u64(&self, values: &mut [u64]) {
        self.world.process_at_rank(0).broadcast_into(values);
    }
    fn broadcast_f32(&self, values: &mut [f32]) {
        self.world.process_at_rank(0).broadcast_into(values);
    }
}
