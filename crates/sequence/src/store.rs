//! Per-frame optimisation state on disk, so a long simulation needs memory
//! for a few frames rather than for the whole sequence, and a killed farm
//! task resumes from its last completed sweep.
//!
//! # Layout of the work folder
//! Every file is a state file of the job ([`nst3d_job::State`]: safetensors
//! with the job's kind and fingerprint), so a folder of another job or of
//! an older nst3d is refused rather than resumed.
//! * `frame_TTTTTT.gGGGGGGGG.bin`: the [`FrameState`] of frame `T` (index in
//!   the run, not the frame number) as written during generation `G`
//!   (one generation per [`SweepMark`]): the arrays `field` (`[n, 3]`
//!   velocities or `[n]` scales), `adam.m`, `adam.v`, with colour
//!   `color.raw` (`[channels, n]`), `color.m`, `color.v`; the metadata
//!   `step` and `field` (`velocity` or `scale`).
//! * `checkpoint`: the metadata `generation`, `octave`, `octaves`,
//!   `sweeps_done`: the last generation whose states are complete.
//!
//! A sweep rewrites every frame, so while it runs some frames are one
//! generation ahead of the others. Files of the committed generation are
//! only deleted after the next one is committed, and on opening, files of an
//! uncommitted generation are discarded: a kill at any moment leaves a
//! consistent set of states, the ones of the checkpoint. Every file is
//! written to a temporary name and renamed, so none is ever half-written.

use std::fs;
use std::path::{Path, PathBuf};

use nst3d_job::state::Problem;
use nst3d_job::{State, StateFiles};
use nst3d_stylize::Field;

use crate::ema::{ColorState, FrameState, SequenceError, StateStore, SweepMark};

/// Name of the checkpoint file inside the work folder.
const CHECKPOINT: &str = "checkpoint";

/// A [`StateStore`] keeping every frame's field and Adam moments in a work
/// folder; memory holds only the frame being worked on.
pub struct DiskStore {
    dir: PathBuf,
    files: StateFiles,
    /// Generation that `save` writes: one past the committed one.
    generation: u64,
    /// Newest generation on disk per frame.
    latest: Vec<Option<u64>>,
    /// Committed generation per frame (kept until the next commit).
    committed: Vec<Option<u64>>,
    mark: Option<SweepMark>,
}

fn io_err(path: &Path, e: impl std::fmt::Display) -> SequenceError {
    SequenceError::Checkpoint(format!("{}: {e}", path.display()))
}

fn state_err(e: nst3d_job::StateError) -> SequenceError {
    SequenceError::Checkpoint(e.to_string())
}

/// `frame_TTTTTT.gGGGGGGGG.bin` → `(T, G)`.
fn parse_name(name: &str) -> Option<(usize, u64)> {
    let rest = name.strip_prefix("frame_")?.strip_suffix(".bin")?;
    let (t, g) = rest.split_once(".g")?;
    Some((t.parse().ok()?, g.parse().ok()?))
}

impl DiskStore {
    /// Opens (creating it if needed) a work folder whose states `files`
    /// reads and writes. A checkpoint of this job found there becomes the
    /// [`StateStore::resume_point`]; states written after it by a run that
    /// was killed mid-sweep are discarded. Without a checkpoint any old
    /// state files are removed and the run starts afresh. A checkpoint of
    /// another job or of an older nst3d is an error that says how to start
    /// over.
    pub fn open(dir: &Path, files: StateFiles) -> Result<Self, SequenceError> {
        fs::create_dir_all(dir).map_err(|e| io_err(dir, e))?;
        let cp_path = dir.join(CHECKPOINT);
        let (committed_gen, mark) = match files.load(&cp_path).map_err(state_err)? {
            Some(state) => {
                let (g, m) = checkpoint_mark(&state).map_err(|p| state_err(files.unusable(&cp_path, p)))?;
                (Some(g), Some(m))
            }
            None => (None, None),
        };
        let mut store = Self {
            dir: dir.to_path_buf(),
            files,
            generation: committed_gen.map_or(1, |g| g + 1),
            latest: Vec::new(),
            committed: Vec::new(),
            mark,
        };
        let mut files: Vec<(usize, u64, PathBuf)> = Vec::new();
        for entry in fs::read_dir(dir).map_err(|e| io_err(dir, e))? {
            let entry = entry.map_err(|e| io_err(dir, e))?;
            let name = entry.file_name().to_string_lossy().to_string();
            if name.contains(".tmp") {
                let _ = fs::remove_file(entry.path());
            } else if let Some((t, g)) = parse_name(&name) {
                files.push((t, g, entry.path()));
            }
        }
        // Newest committed file per frame survives; the rest is stale or uncommitted.
        files.sort();
        for (t, g, path) in files.iter().rev() {
            let keep = committed_gen.is_some_and(|c| *g <= c) && store.slot(*t).is_none();
            if keep {
                store.latest[*t] = Some(*g);
                store.committed[*t] = Some(*g);
            } else {
                fs::remove_file(path).map_err(|e| io_err(path, e))?;
            }
        }
        Ok(store)
    }

    /// Deletes the state files a [`DiskStore`] keeps in `dir` (frame
    /// states, the checkpoint, their temporary names), then `dir` itself if
    /// nothing else is in it. Anything else there is left alone: `dir` may
    /// be a user's `--work-dir` that holds other files. A missing `dir` is
    /// not an error.
    pub fn remove(dir: &Path) -> Result<(), SequenceError> {
        let entries = match fs::read_dir(dir) {
            Ok(e) => e,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
            Err(e) => return Err(io_err(dir, e)),
        };
        for entry in entries {
            let entry = entry.map_err(|e| io_err(dir, e))?;
            let name = entry.file_name().to_string_lossy().to_string();
            let ours = name == CHECKPOINT
                || parse_name(&name).is_some()
                || ((name.starts_with("frame_") || name.starts_with(CHECKPOINT)) && name.contains(".tmp"))
                || (name.starts_with(".nst3d-") && name.ends_with(".tmp"));
            if ours {
                fs::remove_file(entry.path()).map_err(|e| io_err(&entry.path(), e))?;
            }
        }
        // Fails, and is meant to, when other files remain.
        let _ = fs::remove_dir(dir);
        Ok(())
    }

    /// The work folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Newest generation of frame `t`, growing the tables as needed.
    fn slot(&mut self, t: usize) -> Option<u64> {
        if self.latest.len() <= t {
            self.latest.resize(t + 1, None);
            self.committed.resize(t + 1, None);
        }
        self.latest[t]
    }

    fn path(&self, t: usize, g: u64) -> PathBuf {
        self.dir.join(format!("frame_{t:06}.g{g:08}.bin"))
    }
}

/// The generation and sweep mark of a `checkpoint` state. Public for the
/// fuzz harness.
pub fn checkpoint_mark(state: &State<'_>) -> Result<(u64, SweepMark), Problem> {
    let mark = SweepMark {
        octave: state.get("octave")?,
        octaves: state.get("octaves")?,
        sweeps_done: state.get("sweeps_done")?,
    };
    Ok((state.get("generation")?, mark))
}

/// A frame's state as a state file of the job `files` names; the arrays
/// are borrowed from `st`.
pub fn encode<'a>(st: &'a FrameState, files: &StateFiles) -> State<'a> {
    let mut out = files.fresh();
    let n = st.field.len();
    match &st.field {
        Field::Velocity(_) => out.put_f32("field", &[n / 3, 3], st.field.params()),
        Field::Scale(_) => out.put_f32("field", &[n], st.field.params()),
    }
    out.set("field", if matches!(st.field, Field::Scale(_)) { "scale" } else { "velocity" });
    out.set("step", st.step);
    out.put_f32("adam.m", &[st.m.len()], &st.m[..]);
    out.put_f32("adam.v", &[st.v.len()], &st.v[..]);
    if let Some(c) = &st.color {
        let voxels = c.raw.first().map_or(0, |f| f.len());
        let raw: Vec<f32> = c.raw.iter().flat_map(|f| f.params()).copied().collect();
        out.put_f32("color.raw", &[c.raw.len(), voxels], raw);
        out.put_f32("color.m", &[c.m.len()], &c.m[..]);
        out.put_f32("color.v", &[c.v.len()], &c.v[..]);
    }
    out
}

/// Reads what [`encode`] wrote: arrays of the wrong shape or sizes that
/// disagree are corruption. Public for the fuzz harness.
pub fn decode(mut state: State<'_>) -> Result<FrameState, Problem> {
    let bad = |what: &str| Problem::Corrupt(what.to_string());
    let (shape, params) = state.take_f32s("field")?;
    let field = match (state.text("field"), shape.as_slice()) {
        (Some("velocity"), &[n, 3]) if params.len() == 3 * n => {
            Field::Velocity(params.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
        }
        (Some("scale"), &[n]) if params.len() == n => Field::Scale(params),
        _ => return Err(bad("field")),
    };
    let (_, m) = state.take_f32s("adam.m")?;
    let (_, v) = state.take_f32s("adam.v")?;
    if m.len() != field.len() || v.len() != field.len() {
        return Err(bad("moments vs field"));
    }
    let color = match state.has("color.raw") {
        false => None,
        true => {
            let (shape, raw) = state.take_f32s("color.raw")?;
            let (_, m) = state.take_f32s("color.m")?;
            let (_, v) = state.take_f32s("color.v")?;
            let &[channels, voxels] = shape.as_slice() else { return Err(bad("colour")) };
            if m.len() != raw.len() || v.len() != raw.len() || channels > 3 {
                return Err(bad("colour moments"));
            }
            let raw = (0..channels).map(|c| Field::Scale(raw[c * voxels..(c + 1) * voxels].to_vec())).collect();
            Some(ColorState { raw, m, v })
        }
    };
    Ok(FrameState { field, m, v, step: state.get("step")?, color })
}

impl StateStore for DiskStore {
    fn load(&mut self, t: usize) -> Result<Option<FrameState>, SequenceError> {
        let Some(g) = self.slot(t) else { return Ok(None) };
        let path = self.path(t, g);
        let state = self.files.load(&path).map_err(state_err)?;
        let state = state.ok_or_else(|| io_err(&path, "state file missing"))?;
        decode(state).map(Some).map_err(|p| state_err(self.files.unusable(&path, p)))
    }

    fn save(&mut self, t: usize, state: FrameState) -> Result<(), SequenceError> {
        self.slot(t);
        let g = self.generation;
        self.files.save(&self.path(t, g), &encode(&state, &self.files)).map_err(state_err)?;
        // A second save in one generation replaces the first; anything older
        // than the committed file is already gone.
        self.latest[t] = Some(g);
        Ok(())
    }

    fn commit(&mut self, mark: SweepMark) -> Result<(), SequenceError> {
        let g = self.generation;
        let mut checkpoint = self.files.fresh();
        checkpoint.set("generation", g);
        checkpoint.set("octave", mark.octave);
        checkpoint.set("octaves", mark.octaves);
        checkpoint.set("sweeps_done", mark.sweeps_done);
        self.files.save(&self.dir.join(CHECKPOINT), &checkpoint).map_err(state_err)?;
        for t in 0..self.latest.len() {
            if let (Some(new), Some(old)) = (self.latest[t], self.committed[t]) {
                if old < new {
                    let path = self.path(t, old);
                    fs::remove_file(&path).map_err(|e| io_err(&path, e))?;
                }
            }
            self.committed[t] = self.latest[t];
        }
        self.generation += 1;
        self.mark = Some(mark);
        Ok(())
    }

    fn resume_point(&self) -> Option<SweepMark> {
        self.mark
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_job::JobId;

    fn files(hash: u64) -> StateFiles {
        StateFiles::new(JobId { kind: "volume sequence".into(), hash, settings: String::new() }, "rerun with --force")
    }

    fn state(x: f32) -> FrameState {
        FrameState {
            field: Field::Velocity(vec![[x, 2.0 * x, -x]; 4]),
            m: vec![x; 12],
            v: vec![0.5; 12],
            step: 7,
            color: None,
        }
    }

    fn round_trip(st: &FrameState) -> Result<FrameState, Problem> {
        decode(State::from_bytes(&encode(st, &files(1)).to_bytes())?)
    }

    /// A state with colour comes back with it, bit for bit; cut short, it is refused.
    #[test]
    fn colour_round_trips_and_a_cut_file_is_refused() {
        let color = ColorState {
            raw: (0..3).map(|c| Field::Scale(vec![0.5 + c as f32, 1.5])).collect(),
            m: (0..6).map(|i| i as f32).collect(),
            v: vec![0.25; 6],
        };
        let st = FrameState {
            field: Field::Scale(vec![1.0, 2.0]),
            m: vec![0.0; 2],
            v: vec![-0.0; 2],
            step: 3,
            color: Some(color),
        };
        let back = round_trip(&st).unwrap();
        assert_eq!((back.field.params(), back.step), (st.field.params(), 3));
        let c = back.color.unwrap();
        assert_eq!(c.raw.iter().map(|f| f.params().to_vec()).collect::<Vec<_>>(), [[0.5, 1.5], [1.5, 1.5], [2.5, 1.5]]);
        assert_eq!((c.m, c.v), ((0..6).map(|i| i as f32).collect(), vec![0.25; 6]));
        let velocity = round_trip(&state(1.5)).unwrap();
        assert_eq!((velocity.field.params(), &velocity.m[..]), (state(1.5).field.params(), &state(1.5).m[..]));
        assert!(matches!(velocity.field, Field::Velocity(_)) && velocity.color.is_none());
        let bytes = encode(&st, &files(1)).to_bytes();
        for len in 0..bytes.len() {
            assert!(State::from_bytes(&bytes[..len]).is_err(), "cut to {len} bytes read");
        }
    }

    /// Arrays whose shapes disagree with each other are refused, not a panic.
    #[test]
    fn arrays_that_disagree_are_refused() {
        let st = state(1.0);
        let mut short = encode(&st, &files(1));
        short.put_f32("adam.m", &[11], vec![0.0; 11]);
        assert!(decode(short).is_err());
        let mut flat = encode(&st, &files(1));
        flat.put_f32("field", &[12], vec![0.0; 12]);
        assert!(decode(flat).is_err(), "a velocity field must be [n, 3]");
        let mut odd = encode(&st, &files(1));
        odd.set("field", "pressure");
        assert!(decode(odd).is_err());
        let mut four = encode(&st, &files(1));
        four.put_f32("color.raw", &[4, 1], vec![1.0; 4]);
        four.put_f32("color.m", &[4], vec![0.0; 4]);
        four.put_f32("color.v", &[4], vec![0.0; 4]);
        assert!(decode(four).is_err(), "four colour channels");
    }

    fn first(st: &FrameState) -> f32 {
        st.field.params()[0]
    }

    #[test]
    fn states_round_trip_and_commit_is_what_a_restart_sees() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("work");
        let mark = |s| SweepMark { octave: 0, octaves: 1, sweeps_done: s };
        {
            let mut store = DiskStore::open(&dir, files(1)).unwrap();
            assert_eq!(store.resume_point(), None);
            for t in 0..3 {
                store.save(t, state(t as f32)).unwrap();
            }
            store.commit(mark(1)).unwrap();
            let back = store.load(2).unwrap().unwrap();
            assert_eq!(back.field.params(), state(2.0).field.params());
            assert_eq!((back.m, back.step), (state(2.0).m, 7));
            // A sweep that is killed after one frame.
            store.save(0, state(10.0)).unwrap();
            assert_eq!(first(&store.load(0).unwrap().unwrap()), 10.0);
        }
        let mut store = DiskStore::open(&dir, files(1)).unwrap();
        assert_eq!(store.resume_point(), Some(mark(1)));
        assert_eq!(first(&store.load(0).unwrap().unwrap()), 0.0, "the uncommitted save is discarded");
        assert_eq!(first(&store.load(1).unwrap().unwrap()), 1.0);
        for t in 0..3 {
            store.save(t, state(20.0 + t as f32)).unwrap();
        }
        store.commit(mark(2)).unwrap();
        let files_left = fs::read_dir(&dir).unwrap().count();
        assert_eq!(files_left, 4, "one file per frame plus the checkpoint");
        let mut store = DiskStore::open(&dir, files(1)).unwrap();
        assert_eq!(first(&store.load(2).unwrap().unwrap()), 22.0);
        // Another job's folder is refused, not resumed.
        let e = DiskStore::open(&dir, files(2)).err().expect("refused").to_string();
        assert!(e.contains("different volume sequence") && e.contains("--force"), "{e}");
        fs::write(dir.join(CHECKPOINT), "garbage").unwrap();
        assert!(DiskStore::open(&dir, files(1)).is_err());

        // Removing the store deletes its files only; a folder with nothing
        // else goes too.
        fs::write(dir.join("frame_000001.g00000003.tmp42"), "half").unwrap();
        fs::write(dir.join(".nst3d-Ab12.tmp"), "half").unwrap();
        fs::write(dir.join("notes.txt"), "the user's").unwrap();
        DiskStore::remove(&dir).unwrap();
        let left: Vec<_> = fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(left, vec![std::ffi::OsString::from("notes.txt")]);
        fs::remove_file(dir.join("notes.txt")).unwrap();
        DiskStore::remove(&dir).unwrap();
        assert!(!dir.exists());
        DiskStore::remove(&dir).unwrap();
    }

    /// A work folder an older nst3d left mid-run: one line that says to
    /// start over, and `remove` (what `--force` runs) clears it.
    #[test]
    fn an_older_nst3d_work_folder_is_refused_in_one_line() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("work");
        fs::create_dir_all(&dir).unwrap();
        fs::write(dir.join(CHECKPOINT), "nst3d-checkpoint generation 4 octave 1 octaves 3 sweeps 2\n").unwrap();
        let mut old = b"NST3DFS1".to_vec();
        old.extend([0u8; 24]);
        fs::write(dir.join("frame_000000.g00000004.bin"), old).unwrap();
        let e = DiskStore::open(&dir, files(1)).err().expect("refused").to_string();
        assert!(e.contains("checkpoint") && e.contains("older nst3d") && e.ends_with("rerun with --force"), "{e}");
        assert_eq!(e.lines().count(), 1);
        DiskStore::remove(&dir).unwrap();
        assert!(!dir.exists());
        assert_eq!(DiskStore::open(&dir, files(1)).unwrap().resume_point(), None);
    }
}
