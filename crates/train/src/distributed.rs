//! Data-parallel training: one run over several processes (ranks, started
//! by `mpirun` or `srun`), each on its own share of every step's batch.
//!
//! `--batch B` is the *global* batch: B patches a step however many ranks
//! there are, patch `j` on rank `j mod N`. Every rank draws all B patches'
//! numbers (frame, corner, rotation, mirror, view axis) from the one stream
//! the seed starts, in batch order, and cuts only its own; so the same
//! patches are drawn whatever N is, the generator stays the same on every
//! rank (its state is in the checkpoint), and a run resumes on another N.
//!
//! The step's gradient is the mean of the B patches' gradients, summed
//! *exactly*: each is put in 64-bit fixed point on a scale every rank
//! agrees on (from the batch's largest magnitude) and the integers are
//! summed with an allreduce. Integer sums do not depend on their order, so
//! the result is the same bits for any N and any reduction algorithm the
//! MPI library picks: N ranks and one rank with the same `--batch` train
//! the same model (with the same `--threads` per rank, which the patch
//! gradients themselves depend on). A batch of one on one rank is the
//! plain step of [`TrainStep::step`], as before batches existed.
//!
//! Rank 0 alone takes the job lock, resumes the checkpoint, paces the
//! schedule by its clock, decides when the time budget is spent and writes
//! the checkpoint, the model, the loss log and its curve; the others get
//! its state and its decisions by broadcast. A stop asked of any rank (a
//! signal) stops them all after the same step, rank 0 checkpointing first.
//! A failure on any rank ends every rank at the next point they meet
//! ([`agree`]): the lowest failing rank says why, the others end quietly
//! with [`RankFailed`].
//!
//! The communication is behind [`Team`]: [`Solo`] is one process and needs
//! nothing; the MPI team (the `mpi` cargo feature, `mpi_team`) is a thin
//! layer over an installed MPI library, so the default build has no MPI
//! dependency at all.

use anyhow::{bail, Result};
use nst3d_core::{math::SplitMix64, Grid3};
use nst3d_stylize::{ViewLoss, ViewSpec};

use crate::axes::{Sight, ViewAxes};
use crate::patch::PatchDraw;
use crate::step::{PatchGradient, TrainStep};

pub mod launch;
#[cfg(feature = "mpi")]
pub mod mpi_team;

/// The processes of one training run and their collective operations.
/// Every rank calls each operation in the same order with buffers of the
/// same length.
pub trait Team {
    /// This process's rank, `0..size()`.
    fn rank(&self) -> usize;
    /// How many processes train together.
    fn size(&self) -> usize;
    /// Element-wise sum over the ranks, in place.
    fn sum_i64(&self, values: &mut [i64]);
    /// Element-wise sum over the ranks, in place (used where at most one
    /// rank's value is non-zero, so the order cannot change the bits).
    fn sum_f64(&self, values: &mut [f64]);
    /// Element-wise maximum over the ranks, in place.
    fn max_f64(&self, values: &mut [f64]);
    /// Rank 0's values to every rank.
    fn broadcast_u64(&self, values: &mut [u64]);
    /// Rank 0's values to every rank.
    fn broadcast_f32(&self, values: &mut [f32]);
}

/// One process: every collective is the identity.
#[derive(Clone, Copy, Debug, Default)]
pub struct Solo;

impl Team for Solo {
    fn rank(&self) -> usize {
        0
    }
    fn size(&self) -> usize {
        1
    }
    fn sum_i64(&self, _: &mut [i64]) {}
    fn sum_f64(&self, _: &mut [f64]) {}
    fn max_f64(&self, _: &mut [f64]) {}
    fn broadcast_u64(&self, _: &mut [u64]) {}
    fn broadcast_f32(&self, _: &mut [f32]) {}
}

/// How a rank ends when another rank failed: the failing rank (the lowest,
/// if several did) reports the cause, so a user reads it once.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RankFailed {
    /// The rank that reports the cause.
    pub rank: usize,
}

impl std::fmt::Display for RankFailed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "rank {} failed (its own message says why)", self.rank)
    }
}

impl std::error::Error for RankFailed {}

/// Every rank's `result`, agreed: `Ok` where every rank succeeded; where
/// any failed, the lowest failing rank gets its own error (naming its rank
/// when there are several) and every other rank [`RankFailed`]. A
/// collective: every rank calls it at the same point.
pub fn agree<T>(team: &dyn Team, result: Result<T>) -> Result<T> {
    let n = team.size();
    // The lowest failing rank r as n − r, the largest such value.
    let mut lowest = [if result.is_err() { (n - team.rank()) as f64 } else { 0.0 }];
    team.max_f64(&mut lowest);
    if lowest[0] == 0.0 {
        return result;
    }
    let failed = n - lowest[0] as usize;
    match result {
        // Rank 0's failures are the job's; another rank's may be its node's.
        Err(e) if failed == team.rank() && failed > 0 => Err(e.context(format!("rank {failed} of {n}"))),
        Err(e) if failed == team.rank() => Err(e),
        _ => Err(RankFailed { rank: failed }.into()),
    }
}

/// An error every rank meets at the same point (the batch's loss or
/// gradient): rank 0 reports it, the others end with [`RankFailed`].
pub fn everywhere(team: &dyn Team, e: anyhow::Error) -> anyhow::Error {
    match team.rank() {
        0 => e,
        _ => RankFailed { rank: 0 }.into(),
    }
}

/// Runs `f` on rank 0 alone and agrees on its result ([`agree`]): its
/// value on rank 0, `None` on the others.
pub fn on_rank0<T>(team: &dyn Team, f: impl FnOnce() -> Result<T>) -> Result<Option<T>> {
    let result = if team.rank() == 0 { f().map(Some) } else { Ok(None) };
    agree(team, result)
}

/// The batch's limits against the ranks: every rank needs a patch a step.
pub fn check_batch(team: &dyn Team, batch: usize) -> Result<()> {
    if batch == 0 {
        bail!("--batch must be at least 1");
    }
    if batch < team.size() {
        bail!(
            "--batch {batch} is fewer patches than the {} ranks: give --batch {} or more (the batch is the whole \
             step's, spread over the ranks)",
            team.size(),
            team.size()
        );
    }
    Ok(())
}

/// Rank 0's trainer and generator (fresh or resumed) to every rank, so all
/// start from the same state whatever their disks hold.
pub fn share_start(team: &dyn Team, trainer: &mut TrainStep, rng: &mut SplitMix64) -> Result<()> {
    if team.size() == 1 {
        return Ok(());
    }
    let (m, v, adam_step) = trainer.adam_state();
    let mut floats = [trainer.params(), m.to_vec(), v.to_vec()].concat();
    let mut words =
        [adam_step, trainer.position().to_bits(), trainer.schedule.total_steps, trainer.pace.to_bits(), rng.state()];
    team.broadcast_f32(&mut floats);
    team.broadcast_u64(&mut words);
    if team.rank() != 0 {
        let n = floats.len() / 3;
        trainer.set_params(&floats[..n]);
        trainer.set_adam_state(&floats[n..2 * n], &floats[2 * n..], words[0])?;
        trainer.set_position(f64::from_bits(words[1]));
        trainer.schedule.total_steps = words[2];
        trainer.pace = f64::from_bits(words[3]);
        *rng = SplitMix64::new(words[4]);
    }
    Ok(())
}

/// After a step: rank 0's pacing of the schedule and its `out_of_time`
/// to every rank; returns whether any rank was asked to stop, the same on
/// every rank, so all of them stop after this step. (A rank must act on
/// this answer, not on its own flag again: a signal can arrive in between.)
pub fn follow_rank0(team: &dyn Team, trainer: &mut TrainStep, out_of_time: &mut bool) -> bool {
    if team.size() == 1 {
        return nst3d_core::stop::requested();
    }
    let mut words = [trainer.schedule.total_steps, trainer.pace.to_bits(), *out_of_time as u64];
    team.broadcast_u64(&mut words);
    trainer.schedule.total_steps = words[0];
    trainer.pace = f64::from_bits(words[1]);
    *out_of_time = words[2] != 0;
    let mut stop = [nst3d_core::stop::requested() as u8 as f64];
    team.max_f64(&mut stop);
    stop[0] > 0.0
}

/// What a step draws, from the training settings.
#[derive(Clone, Copy, Debug)]
pub struct Batch {
    /// Patches a step, over all ranks.
    pub size: usize,
    /// Patch side.
    pub patch: usize,
    /// Rotation range about x, degrees (±).
    pub theta_deg: f32,
    /// Rotation range about y, degrees (±).
    pub phi_deg: f32,
    /// How each patch is seen.
    pub view_axes: ViewAxes,
    /// The solid texture's period, if one is trained.
    pub texture_period: Option<usize>,
}

/// One patch of a step: where it is cut, how it is seen and where its
/// corner lies in the solid texture's space.
struct Draw {
    patch: PatchDraw,
    sights: Vec<Sight>,
    at: [i64; 3],
}

impl Batch {
    /// One patch's numbers from `rng`: where it is cut, its view axes, then
    /// (only with a texture, so a run without one keeps its stream) where
    /// it lies on the texture.
    fn draw(&self, rng: &mut SplitMix64, frames: &[Grid3]) -> Draw {
        let patch = PatchDraw::draw(rng, frames, self.patch, self.theta_deg, self.phi_deg);
        let sights = self.view_axes.pick(|| rng.uniform_f32());
        let at = match self.texture_period {
            Some(p) => std::array::from_fn(|_| (rng.next_u64() % p as u64) as i64),
            None => [0; 3],
        };
        Draw { patch, sights, at }
    }
}

/// One optimisation step over the global batch; returns the batch's mean
/// loss. Each patch is seen as `views[i]` says for its frame `i`. A
/// collective: every rank calls it once a step.
pub fn batch_step(
    team: &dyn Team,
    trainer: &mut TrainStep,
    rng: &mut SplitMix64,
    frames: &[Grid3],
    batch: &Batch,
    (loss, views): (&ViewLoss, &[ViewSpec]),
) -> Result<f32> {
    if batch.size == 1 && team.size() == 1 {
        let d = batch.draw(rng, frames);
        let view = &views[d.patch.frame];
        return Ok(trainer.step(&d.patch.cut(frames, batch.patch), d.at, loss, view, &d.sights)?);
    }
    let draws: Vec<_> = (0..batch.size).map(|_| batch.draw(rng, frames)).collect();
    let mut mine: Vec<(usize, PatchGradient)> = Vec::new();
    let mut failure = None;
    for j in (team.rank()..batch.size).step_by(team.size()) {
        let d = &draws[j];
        match trainer.gradient(&d.patch.cut(frames, batch.patch), d.at, loss, &views[d.patch.frame], &d.sights) {
            Ok(g) => mine.push((j, g)),
            Err(e) => {
                failure = Some(e);
                break;
            }
        }
    }
    let all = || mine.iter().flat_map(|(_, g)| &g.grads);
    let largest = all().filter(|v| v.is_finite()).fold(0.0f32, |m, v| m.max(v.abs()));
    let finite = all().all(|v| v.is_finite());
    // One collective for the fixed point's scale, a failed patch and a
    // gradient that is not a number.
    let n = team.size();
    let mut agreed =
        [largest as f64, if failure.is_some() { (n - team.rank()) as f64 } else { 0.0 }, !finite as u8 as f64];
    team.max_f64(&mut agreed);
    if agreed[1] > 0.0 {
        let failed = n - agreed[1] as usize;
        return match failure {
            Some(e) if failed == team.rank() && failed > 0 => {
                Err(anyhow::Error::from(e).context(format!("rank {failed} of {n}")))
            }
            Some(e) if failed == team.rank() => Err(e.into()),
            _ => Err(RankFailed { rank: failed }.into()),
        };
    }
    if agreed[2] > 0.0 {
        let e = anyhow::anyhow!(
            "the gradient is not a number at step {} (try a smaller learning rate)",
            trainer.steps() + 1
        );
        return Err(everywhere(team, e));
    }
    let params = trainer.adam_state().0.len();
    let (grads, l, k) = batch_mean(team, &mine, (params, batch.size), agreed[0]);
    trainer.update(grads, k);
    Ok(l)
}

/// The mean gradient (of `n` parameters), loss and mass ratio of a batch
/// of `b` from each rank's share `mine` (`(j, patch j's gradient)`),
/// `largest` the largest gradient magnitude over the batch.
fn batch_mean(
    team: &dyn Team,
    mine: &[(usize, PatchGradient)],
    (n, b): (usize, usize),
    largest: f64,
) -> (Vec<f32>, f32, f32) {
    let scale = fixed_point_scale(largest, b);
    let mut sum = vec![0i64; n];
    // Per patch: its loss and mass ratio in its own slot.
    let mut slots = vec![0.0f64; 2 * b];
    for (j, g) in mine {
        add_fixed(&mut sum, &g.grads, scale);
        (slots[2 * j], slots[2 * j + 1]) = (g.loss as f64, g.mass_ratio as f64);
    }
    team.sum_i64(&mut sum);
    team.sum_f64(&mut slots);
    let mean = |xs: &mut dyn Iterator<Item = f64>| (xs.sum::<f64>() / b as f64) as f32;
    let l = mean(&mut slots.iter().step_by(2).copied());
    let k = mean(&mut slots.iter().skip(1).step_by(2).copied());
    (from_fixed(&sum, scale, b), l, k)
}

/// The fixed point's scale, a power of two: `largest · b · scale ≤ 2⁶¹`,
/// so a sum of `b` values of magnitude at most `largest` cannot overflow
/// an `i64`, and a value is kept to `2⁻⁶¹` of the batch's largest (f32's
/// own precision is 2⁻²⁴ of each value).
pub fn fixed_point_scale(largest: f64, b: usize) -> f64 {
    if largest <= 0.0 || largest.is_nan() {
        return 1.0;
    }
    let e = 61 - (largest * b as f64).log2().ceil() as i32;
    2f64.powi(e)
}

/// Adds `values` in fixed point (`round(v · scale)`) to `sum`.
pub fn add_fixed(sum: &mut [i64], values: &[f32], scale: f64) {
    for (s, v) in sum.iter_mut().zip(values) {
        *s += (*v as f64 * scale).round() as i64;
    }
}

/// The mean of `b` fixed-point values summed in `sum`, in f32.
pub fn from_fixed(sum: &[i64], scale: f64, b: usize) -> Vec<f32> {
    let d = scale * b as f64;
    sum.iter().map(|s| (*s as f64 / d) as f32).collect()
}

/// How a process of a job of several was started ([`launched_as`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Launch {
    /// Its rank.
    pub rank: usize,
    /// How many processes the launcher started.
    pub size: usize,
    /// Whether the launcher gave them what MPI needs to find each other
    /// (`mpirun`, `mpiexec`, `srun --mpi=pmix`); a plain `srun` does not.
    pub mpi: bool,
}

/// How this process was started, from the environment an MPI launcher or
/// Slurm's `srun` gives its processes; `None` when it is one process.
pub fn launched_as() -> Option<Launch> {
    let var = |k: &str| std::env::var(k).ok().and_then(|v| v.trim().parse::<usize>().ok());
    let pairs = [
        ("OMPI_COMM_WORLD_RANK", "OMPI_COMM_WORLD_SIZE", true),
        ("PMI_RANK", "PMI_SIZE", true),
        ("PMIX_RANK", "SLURM_STEP_NUM_TASKS", true),
        ("SLURM_PROCID", "SLURM_STEP_NUM_TASKS", false),
    ];
    pairs.iter().find_map(|&(r, n, mpi)| Some(Launch { rank: var(r)?, size: var(n)?, mpi })).filter(|l| l.size > 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fixed-point sum is exact to far below f32's precision and does
    /// not depend on the order of the patches (what makes N ranks and one
    /// rank agree bit for bit).
    #[test]
    fn fixed_point_sums_are_exact_and_order_free() {
        let patches: Vec<Vec<f32>> = (0..5)
            .map(|p| {
                nst3d_core::gradcheck::pseudo_random(300, p + 1).iter().map(|v| v * 10f32.powi(p as i32 - 3)).collect()
            })
            .collect();
        let largest = patches.iter().flatten().fold(0f32, |m, v| m.max(v.abs())) as f64;
        let scale = fixed_point_scale(largest, patches.len());
        let sum_in = |order: &[usize]| {
            let mut s = vec![0i64; 300];
            order.iter().for_each(|&p| add_fixed(&mut s, &patches[p], scale));
            from_fixed(&s, scale, patches.len())
        };
        let forward = sum_in(&[0, 1, 2, 3, 4]);
        assert_eq!(forward, sum_in(&[3, 1, 4, 0, 2]));
        for (i, got) in forward.iter().enumerate() {
            let exact = patches.iter().map(|p| p[i] as f64).sum::<f64>() / 5.0;
            assert!((*got as f64 - exact).abs() <= 1e-7 * exact.abs() + 1e-18, "{got} vs {exact}");
        }
        // Nothing to scale: zeros stay zeros.
        assert_eq!(fixed_point_scale(0.0, 4), 1.0);
        assert!(fixed_point_scale(1e-30, 1000) > 1e30);
    }

    #[test]
    fn one_rank_agrees_with_itself() {
        assert_eq!(agree(&Solo, Ok(3)).unwrap(), 3);
        let e = agree::<()>(&Solo, Err(anyhow::anyhow!("bad frame"))).unwrap_err();
        assert_eq!(e.to_string(), "bad frame");
        assert!(check_batch(&Solo, 1).is_ok() && check_batch(&Solo, 0).is_err());
    }
}
