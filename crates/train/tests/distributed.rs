//! Distributed training without MPI: two ranks as two threads of this test,
//! their collectives done through shared memory in rank order (what an MPI
//! library does between processes). Two ranks train the model one process
//! trains with the same global batch, byte for byte; a run stopped on two
//! ranks (a stop asked of one of them) resumes on one and ends as an
//! uninterrupted run; a failure on one rank is reported by that rank alone.
//! `farm/tests/test_mpi.py` runs the same through `mpirun` and Slurm.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Barrier, Mutex};

// fp32 throughout: what is tested is how ranks share the work, not the
// arithmetic (the emulated bf16 pass of CI would triple the time).
use nst3d_core::precision::fp32;
use nst3d_core::Silent;
use nst3d_train::distributed::{RankFailed, Team};
use nst3d_train::{train, train_on, TrainReport, TrainSettings};

fn shared(rel: &str) -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data").join(rel);
    assert!(p.exists(), "shared test data missing: {} (the repo expects ../shared beside it)", p.display());
    p
}

fn settings(out: &Path) -> TrainSettings {
    let frames = (20..=22).map(|f| shared(&format!("volumes/plume48/fluid_data_{f:04}.vdb"))).collect();
    let mut s = TrainSettings::new(frames, shared("styles/starry_night.jpg"), out);
    (s.style_scale, s.channels, s.patch, s.steps, s.seed, s.checkpoint_every) = (0.25, 2, 16, Some(4), 3, 2);
    s.batch = 3;
    s
}

/// Ranks in threads: each collective puts every rank's buffer (as bits)
/// on a shared board and reduces the board in rank order.
struct Threads {
    rank: usize,
    size: usize,
    board: Arc<(Barrier, Mutex<Vec<Vec<u64>>>)>,
}

impl Threads {
    fn team(size: usize) -> Vec<Threads> {
        let board = Arc::new((Barrier::new(size), Mutex::new(vec![Vec::new(); size])));
        (0..size).map(|rank| Threads { rank, size, board: board.clone() }).collect()
    }

    /// Every rank's `mine`, in rank order.
    fn exchange(&self, mine: Vec<u64>) -> Vec<Vec<u64>> {
        let (barrier, board) = &*self.board;
        board.lock().unwrap()[self.rank] = mine;
        barrier.wait();
        let all = board.lock().unwrap().clone();
        barrier.wait();
        all
    }

    fn reduce<T: Copy>(&self, values: &mut [T], bits: fn(T) -> u64, back: fn(u64) -> T, op: fn(T, T) -> T) {
        let all = self.exchange(values.iter().map(|v| bits(*v)).collect());
        for (i, v) in values.iter_mut().enumerate() {
            *v = all.iter().map(|b| back(b[i])).reduce(op).unwrap();
        }
    }
}

impl Team for Threads {
    fn rank(&self) -> usize {
        self.rank
    }
    fn size(&self) -> usize {
        self.size
    }
    fn sum_i64(&self, values: &mut [i64]) {
        self.reduce(values, |v| v as u64, |b| b as i64, |a, b| a + b);
    }
    fn sum_f64(&self, values: &mut [f64]) {
        self.reduce(values, f64::to_bits, f64::from_bits, |a, b| a + b);
    }
    fn max_f64(&self, values: &mut [f64]) {
        self.reduce(values, f64::to_bits, f64::from_bits, f64::max);
    }
    fn broadcast_u64(&self, values: &mut [u64]) {
        let all = self.exchange(values.to_vec());
        values.copy_from_slice(&all[0]);
    }
    fn broadcast_f32(&self, values: &mut [f32]) {
        let all = self.exchange(values.iter().map(|v| v.to_bits() as u64).collect());
        values.iter_mut().zip(&all[0]).for_each(|(v, b)| *v = f32::from_bits(*b as u32));
    }
}

/// Every rank's outcome of training `s` on `size` ranks in threads; `before`
/// runs first on each rank's thread (given its rank).
fn on_ranks(size: usize, s: &TrainSettings, before: fn(usize)) -> Vec<anyhow::Result<TrainReport>> {
    std::thread::scope(|scope| {
        let runs: Vec<_> = Threads::team(size)
            .into_iter()
            .map(|team| {
                scope.spawn(move || {
                    before(team.rank);
                    fp32(|| train_on(&team, s, &mut Silent))
                })
            })
            .collect();
        runs.into_iter().map(|r| r.join().unwrap()).collect()
    })
}

#[test]
fn two_ranks_train_what_one_process_trains_with_the_same_batch() {
    let dir = tempfile::tempdir().unwrap();
    let one = dir.path().join("one.safetensors");
    fp32(|| train(&settings(&one), &mut Silent)).unwrap();
    let two = dir.path().join("two.safetensors");
    // A batch of 3 on 2 ranks: two patches on rank 0, one on rank 1.
    for r in on_ranks(2, &settings(&two), |_| {}) {
        assert_eq!(r.unwrap().steps, 4);
    }
    assert_eq!(std::fs::read(&one).unwrap(), std::fs::read(&two).unwrap(), "2 ranks and 1 differ");
    // With a solid texture too (its gradient rides in the same sum).
    let textured = |name: &str| {
        let mut s = settings(&dir.path().join(name));
        s.texture = Some(8);
        s
    };
    fp32(|| train(&textured("one_t.safetensors"), &mut Silent)).unwrap();
    on_ranks(2, &textured("two_t.safetensors"), |_| {}).into_iter().for_each(|r| assert_eq!(r.unwrap().steps, 4));
    let read = |name: &str| std::fs::read(dir.path().join(name)).unwrap();
    assert_eq!(read("one_t.safetensors"), read("two_t.safetensors"), "textured: 2 ranks and 1 differ");
    assert_eq!(std::fs::read(one.with_extension("csv")).unwrap(), std::fs::read(two.with_extension("csv")).unwrap());
    let m = nst3d_network::Model::from_bytes(&std::fs::read(&two).unwrap(), &two).unwrap();
    assert_eq!(m.info.get("batch").map(String::as_str), Some("3"));
}

/// With a texture and each patch seen at its own frame's absorption, two
/// ranks train what one process trains to within f32 rounding: a patch's
/// gradient on rank 1 has differed from the same patch's in one process
/// in its last bits (a source of order dependence not yet found), so this
/// pair is held to a tolerance, the others above to the bit.
#[test]
fn two_ranks_with_frame_absorption_agree_with_one_within_rounding() {
    let dir = tempfile::tempdir().unwrap();
    let framed = |name: &str| {
        let mut s = settings(&dir.path().join(name));
        (s.texture, s.absorption) = (Some(8), nst3d_train::Absorption::Frame);
        s
    };
    let (one, two) = (framed("one.safetensors"), framed("two.safetensors"));
    fp32(|| train(&one, &mut Silent)).unwrap();
    on_ranks(2, &two, |_| {}).into_iter().for_each(|r| assert_eq!(r.unwrap().steps, 4));
    let model = |s: &TrainSettings| nst3d_network::Model::from_bytes(&std::fs::read(&s.out).unwrap(), &s.out).unwrap();
    let flat = |m: nst3d_network::Model| {
        let mut p = m.net.flat();
        p.extend(m.texture.expect("a textured model").values);
        p
    };
    let (a, b) = (flat(model(&one)), flat(model(&two)));
    let largest = a.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    let worst = a.iter().zip(&b).fold(0.0f32, |m, (x, y)| m.max((x - y).abs()));
    assert!(worst <= 1e-5 * largest, "2 ranks and 1 differ by {worst} (largest parameter {largest})");
}

#[test]
fn a_run_stopped_on_two_ranks_resumes_on_one() {
    let dir = tempfile::tempdir().unwrap();
    let whole = dir.path().join("whole.safetensors");
    fp32(|| train(&settings(&whole), &mut Silent)).unwrap();
    let parts = dir.path().join("parts.safetensors");
    // A stop asked of rank 1 alone stops both after the first step; rank 0
    // checkpoints.
    let outcomes = on_ranks(2, &settings(&parts), |rank| {
        if rank == 1 {
            nst3d_core::stop::request();
        }
    });
    for r in outcomes {
        assert!(r.unwrap_err().is::<nst3d_core::stop::Interrupted>());
    }
    let r = fp32(|| train(&settings(&parts), &mut Silent)).unwrap();
    assert_eq!((r.resumed_at, r.steps), (1, 4));
    assert_eq!(std::fs::read(&whole).unwrap(), std::fs::read(&parts).unwrap(), "the resumed model differs");
}

#[test]
fn a_failure_is_reported_by_its_rank_alone() {
    let dir = tempfile::tempdir().unwrap();
    let mut s = settings(&dir.path().join("m.safetensors"));
    // Too few patches for the ranks: the same on every rank, said by rank 0.
    s.batch = 1;
    let outcomes = on_ranks(2, &s, |_| {});
    assert!(outcomes[0].as_ref().unwrap_err().to_string().contains("--batch 1 is fewer patches than the 2 ranks"));
    assert_eq!(outcomes[1].as_ref().unwrap_err().downcast_ref::<RankFailed>(), Some(&RankFailed { rank: 0 }));
    assert!(!dir.path().join("m.safetensors").exists());
}
