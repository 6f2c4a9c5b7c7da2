//! Per-frame optimisation state on disk, so a long simulation needs memory
//! for a few frames rather than for the whole sequence, and a killed farm
//! task resumes from its last completed sweep.
//!
//! # Layout of the work folder
//! * `frame_TTTTTT.gGGGGGGGG.bin`: the [`FrameState`] of frame `T` (index in
//!   the run, not the frame number) as written during generation `G`
//!   (one generation per [`SweepMark`]).
//! * `checkpoint`: one line, `nst3d-checkpoint generation G octave K octaves N sweeps S`,
//!   the last generation whose states are complete.
//!
//! A sweep rewrites every frame, so while it runs some frames are one
//! generation ahead of the others. Files of the committed generation are
//! only deleted after the next one is committed, and on opening, files of an
//! uncommitted generation are discarded: a kill at any moment leaves a
//! consistent set of states, the ones of the checkpoint. Every file is
//! written to a temporary name and renamed, so none is ever half-written.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use nst3d_stylize::Field;

use crate::ema::{ColorState, FrameState, SequenceError, StateStore, SweepMark};

/// First bytes of a state file (format version 1).
const MAGIC: &[u8; 8] = b"NST3DFS1";
/// Name of the checkpoint file inside the work folder.
const CHECKPOINT: &str = "checkpoint";

/// A [`StateStore`] keeping every frame's field and Adam moments in a work
/// folder; memory holds only the frame being worked on.
pub struct DiskStore {
    dir: PathBuf,
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

/// Writes `bytes` to `path` through a temporary file in the same folder and
/// a rename, so readers see the old content or the new, never a part.
fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), SequenceError> {
    let tmp = path.with_extension(format!("tmp{}", std::process::id()));
    let result = (|| {
        let mut f = fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        fs::rename(&tmp, path)
    })();
    if let Err(e) = result {
        let _ = fs::remove_file(&tmp);
        return Err(io_err(path, e));
    }
    Ok(())
}

/// `frame_TTTTTT.gGGGGGGGG.bin` → `(T, G)`.
fn parse_name(name: &str) -> Option<(usize, u64)> {
    let rest = name.strip_prefix("frame_")?.strip_suffix(".bin")?;
    let (t, g) = rest.split_once(".g")?;
    Some((t.parse().ok()?, g.parse().ok()?))
}

impl DiskStore {
    /// Opens (creating it if needed) a work folder. A checkpoint found there
    /// becomes the [`StateStore::resume_point`]; states written after it by
    /// a run that was killed mid-sweep are discarded. Without a checkpoint
    /// any old state files are removed and the run starts afresh.
    pub fn open(dir: &Path) -> Result<Self, SequenceError> {
        fs::create_dir_all(dir).map_err(|e| io_err(dir, e))?;
        let cp_path = dir.join(CHECKPOINT);
        let (committed_gen, mark) = match fs::read_to_string(&cp_path) {
            Ok(text) => {
                let (g, m) = parse_checkpoint(&text).ok_or_else(|| {
                    io_err(&cp_path, "unreadable checkpoint (delete the work folder to start afresh)")
                })?;
                (Some(g), Some(m))
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => (None, None),
            Err(e) => return Err(io_err(&cp_path, e)),
        };
        let mut store = Self {
            dir: dir.to_path_buf(),
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
                || ((name.starts_with("frame_") || name.starts_with(CHECKPOINT)) && name.contains(".tmp"));
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

/// Parses the `checkpoint` file: its generation and sweep mark, `None` when
/// the text is not such a line. Public for the fuzz harness.
pub fn parse_checkpoint(text: &str) -> Option<(u64, SweepMark)> {
    let w: Vec<&str> = text.split_whitespace().collect();
    match w.as_slice() {
        ["nst3d-checkpoint", "generation", g, "octave", k, "octaves", n, "sweeps", s] => Some((
            g.parse().ok()?,
            SweepMark { octave: k.parse().ok()?, octaves: n.parse().ok()?, sweeps_done: s.parse().ok()? },
        )),
        _ => None,
    }
}

/// Serialises a state: magic, mode (0 velocity, 1 scale), step, parameter
/// count, then field, first and second moments as little-endian f32; with
/// colour, then the voxel count `n` and the raw channels, first and second
/// moments (`3n` values each).
pub fn encode(st: &FrameState) -> Vec<u8> {
    let params = st.field.params();
    let mut out = Vec::with_capacity(32 + 12 * params.len());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&(matches!(st.field, Field::Scale(_)) as u64).to_le_bytes());
    out.extend_from_slice(&st.step.to_le_bytes());
    out.extend_from_slice(&(params.len() as u64).to_le_bytes());
    for v in params.iter().chain(&st.m).chain(&st.v) {
        out.extend_from_slice(&v.to_le_bytes());
    }
    if let Some(c) = &st.color {
        out.extend_from_slice(&(c.raw.first().map_or(0, |f| f.len()) as u64).to_le_bytes());
        for v in c.raw.iter().flat_map(|f| f.params()).chain(&c.m).chain(&c.v) {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out
}

/// Reads what [`encode`] wrote; `None` for anything else (another file,
/// a truncated one, a count that does not match the bytes). Public for the
/// fuzz harness.
pub fn decode(bytes: &[u8]) -> Option<FrameState> {
    let word = |i: usize| Some(u64::from_le_bytes(bytes.get(8 * i..8 * i + 8)?.try_into().ok()?));
    if bytes.get(..8)? != MAGIC {
        return None;
    }
    let (scale, step, len) = (word(1)?, word(2)?, usize::try_from(word(3)?).ok()?);
    let field_bytes = len.checked_mul(12)?;
    let body = bytes.get(32..32usize.checked_add(field_bytes)?)?;
    // The count is checked against the bytes actually there before anything is allocated.
    if scale > 1 || (scale == 0 && len % 3 != 0) {
        return None;
    }
    let floats =
        |b: &[u8]| -> Vec<f32> { b.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect() };
    let all = floats(body);
    let (p, rest) = all.split_at(len);
    let (m, v) = rest.split_at(len);
    let field = if scale == 1 {
        Field::Scale(p.to_vec())
    } else {
        Field::Velocity(p.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
    };
    let tail = &bytes[32 + field_bytes..];
    let color = match tail.len() {
        0 => None,
        _ => {
            let n = usize::try_from(u64::from_le_bytes(tail.get(..8)?.try_into().ok()?)).ok()?;
            if Some(tail.len() - 8) != n.checked_mul(36) {
                return None;
            }
            let all = floats(&tail[8..]);
            let (raw, rest) = all.split_at(3 * n);
            let (m, v) = rest.split_at(3 * n);
            Some(ColorState {
                raw: raw.chunks_exact(n.max(1)).take(3).map(|c| Field::Scale(c.to_vec())).collect(),
                m: m.to_vec(),
                v: v.to_vec(),
            })
        }
    };
    Some(FrameState { field, m: m.to_vec(), v: v.to_vec(), step, color })
}

impl StateStore for DiskStore {
    fn load(&mut self, t: usize) -> Result<Option<FrameState>, SequenceError> {
        let Some(g) = self.slot(t) else { return Ok(None) };
        let path = self.path(t, g);
        let bytes = fs::read(&path).map_err(|e| io_err(&path, e))?;
        decode(&bytes)
            .map(Some)
            .ok_or_else(|| io_err(&path, "corrupt state file (delete the work folder to start afresh)"))
    }

    fn save(&mut self, t: usize, state: FrameState) -> Result<(), SequenceError> {
        self.slot(t);
        let g = self.generation;
        write_atomic(&self.path(t, g), &encode(&state))?;
        // A second save in one generation replaces the first; anything older
        // than the committed file is already gone.
        self.latest[t] = Some(g);
        Ok(())
    }

    fn commit(&mut self, mark: SweepMark) -> Result<(), SequenceError> {
        let g = self.generation;
        let line = format!(
            "nst3d-checkpoint generation {g} octave {} octaves {} sweeps {}\n",
            mark.octave, mark.octaves, mark.sweeps_done
        );
        write_atomic(&self.dir.join(CHECKPOINT), line.as_bytes())?;
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

    fn state(x: f32) -> FrameState {
        FrameState {
            field: Field::Velocity(vec![[x, 2.0 * x, -x]; 4]),
            m: vec![x; 12],
            v: vec![0.5; 12],
            step: 7,
            color: None,
        }
    }

    /// A state with colour comes back with it; cut short, it is refused.
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
            v: vec![0.0; 2],
            step: 3,
            color: Some(color),
        };
        let bytes = encode(&st);
        let back = decode(&bytes).unwrap();
        let c = back.color.unwrap();
        assert_eq!(c.raw.iter().map(|f| f.params().to_vec()).collect::<Vec<_>>(), [[0.5, 1.5], [1.5, 1.5], [2.5, 1.5]]);
        assert_eq!((c.m, c.v), ((0..6).map(|i| i as f32).collect(), vec![0.25; 6]));
        assert!(decode(&bytes[..bytes.len() - 4]).is_none());
        assert!(decode(&bytes[..bytes.len() - 8 - 72]).unwrap().color.is_none(), "without the block: no colour");
    }

    fn first(st: &FrameState) -> f32 {
        st.field.params()[0]
    }

    #[test]
    fn states_round_trip_and_commit_is_what_a_restart_sees() {
        let dir = std::env::temp_dir().join(format!("nst3d-diskstore-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        let mark = |s| SweepMark { octave: 0, octaves: 1, sweeps_done: s };
        {
            let mut store = DiskStore::open(&dir).unwrap();
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
        let mut store = DiskStore::open(&dir).unwrap();
        assert_eq!(store.resume_point(), Some(mark(1)));
        assert_eq!(first(&store.load(0).unwrap().unwrap()), 0.0, "the uncommitted save is discarded");
        assert_eq!(first(&store.load(1).unwrap().unwrap()), 1.0);
        for t in 0..3 {
            store.save(t, state(20.0 + t as f32)).unwrap();
        }
        store.commit(mark(2)).unwrap();
        let files = fs::read_dir(&dir).unwrap().count();
        assert_eq!(files, 4, "one file per frame plus the checkpoint");
        let mut store = DiskStore::open(&dir).unwrap();
        assert_eq!(first(&store.load(2).unwrap().unwrap()), 22.0);
        fs::write(dir.join(CHECKPOINT), "garbage").unwrap();
        assert!(DiskStore::open(&dir).is_err());

        // Removing the store deletes its files only; a folder with nothing
        // else goes too.
        fs::write(dir.join("frame_000001.g00000003.tmp42"), "half").unwrap();
        fs::write(dir.join("notes.txt"), "the user's").unwrap();
        DiskStore::remove(&dir).unwrap();
        let left: Vec<_> = fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(left, vec![std::ffi::OsString::from("notes.txt")]);
        fs::remove_file(dir.join("notes.txt")).unwrap();
        DiskStore::remove(&dir).unwrap();
        assert!(!dir.exists());
        DiskStore::remove(&dir).unwrap();
    }

    #[test]
    fn a_state_whose_count_overflows_is_refused_not_a_panic() {
        // Count 2^62 + 1: `12 * count` wraps to 12, which the 12 bytes of
        // body used to match, and the split at the count then panicked.
        let mut bytes =
            encode(&FrameState { field: Field::Scale(vec![1.0]), m: vec![0.0], v: vec![0.0], step: 0, color: None });
        bytes[24..32].copy_from_slice(&((1u64 << 62) + 1).to_le_bytes());
        assert!(decode(&bytes).is_none());
        // The well-formed one still reads; a mode other than 0 or 1 does not.
        let good = encode(&state(1.0));
        assert_eq!(decode(&good).unwrap().field.params(), state(1.0).field.params());
        let mut odd = good.clone();
        odd[8] = 2;
        assert!(decode(&odd).is_none());
    }
}
