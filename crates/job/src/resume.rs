//! How every resumable job starts: lock the job, then resume from its
//! saved state if there is one of this very job, else start afresh. The
//! volume sequence, the groom sequence and the training run all go through
//! [`Resume::begin`] and [`StateFiles`]; what differs is only which files
//! they keep and what is in them.
//!
//! A state file that is missing means a fresh start. One that is there but
//! cannot be used (an older nst3d's format, truncated, another job's) stops
//! the job with one line naming the file and how to start over: a job
//! never silently throws away hours of someone's work, nor resumes from
//! work that is not its own.

use std::path::{Path, PathBuf};

use crate::state::{Problem, State};
use crate::{JobId, WorkLock};

/// Why a state file could not be read, written or used; the message names
/// the file and, when it is unusable, how to start over.
#[derive(Debug, thiserror::Error)]
pub enum StateError {
    /// The file system said no.
    #[error("cannot {what} {}: {source}", path.display())]
    Io {
        /// `read` or `write`.
        what: &'static str,
        /// The state file.
        path: PathBuf,
        /// What the OS said.
        source: std::io::Error,
    },
    /// The file is there but is not a state this job can resume from.
    #[error("{}: the saved state {problem}; {restart}", path.display())]
    Unusable {
        /// The state file.
        path: PathBuf,
        /// What is wrong with it.
        problem: Problem,
        /// How the user starts over.
        restart: String,
    },
}

/// Reads and writes the state files of one job: stamps what it writes with
/// the job's identity and checks what it reads against it.
#[derive(Clone, Debug)]
pub struct StateFiles {
    id: JobId,
    restart: String,
}

impl StateFiles {
    /// The state files of the job `id`; `restart` tells a user how to start
    /// over when a state cannot be used (`"rerun with --force"`).
    pub fn new(id: JobId, restart: impl Into<String>) -> Self {
        Self { id, restart: restart.into() }
    }

    /// The job whose states these are.
    pub fn id(&self) -> &JobId {
        &self.id
    }

    /// An empty state stamped with the job's identity.
    pub fn fresh<'a>(&self) -> State<'a> {
        State::new(&self.id)
    }

    /// The error for a state at `path` that cannot be used.
    pub fn unusable(&self, path: &Path, problem: Problem) -> StateError {
        StateError::Unusable { path: path.to_path_buf(), problem, restart: self.restart.clone() }
    }

    /// The state saved at `path`: `None` when there is none (start afresh),
    /// an error when there is one this job cannot resume from.
    pub fn load(&self, path: &Path) -> Result<Option<State<'static>>, StateError> {
        let bytes = match std::fs::read(path) {
            Ok(b) => b,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(source) => return Err(StateError::Io { what: "read", path: path.to_path_buf(), source }),
        };
        let state = State::from_bytes(&bytes).map_err(|p| self.unusable(path, p))?;
        state.check(&self.id).map_err(|p| self.unusable(path, p))?;
        Ok(Some(state))
    }

    /// Writes `state` to `path` atomically: a reader (or a kill) sees the
    /// old file or the new one, never a part.
    pub fn save(&self, path: &Path, state: &State<'_>) -> Result<(), StateError> {
        nst3d_io::atomic::write_atomic(path, |w| state.write(w)).map_err(|source| StateError::Io {
            what: "write",
            path: path.to_path_buf(),
            source,
        })
    }
}

/// A running resumable job: it holds the job's lock (one process per job)
/// until dropped, and its [`StateFiles`].
#[derive(Debug)]
pub struct Resume {
    _lock: WorkLock,
    files: StateFiles,
}

impl Resume {
    /// Locks the job whose state lives at `target` (a work folder or a
    /// checkpoint file; the lock is `<target>.lock`), or says which process
    /// runs it already.
    pub fn begin(target: &Path, files: StateFiles) -> Result<Self, String> {
        Ok(Self { _lock: WorkLock::acquire(target)?, files })
    }

    /// The job's state files.
    pub fn files(&self) -> &StateFiles {
        &self.files
    }

    /// A job kept in one state file: with `force` the file is deleted
    /// first; then its state if there is one of this job (see
    /// [`StateFiles::load`]).
    pub fn load_or_fresh(&self, path: &Path, force: bool) -> Result<Option<State<'static>>, StateError> {
        if force {
            match std::fs::remove_file(path) {
                Ok(()) => {}
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(source) => return Err(StateError::Io { what: "remove", path: path.to_path_buf(), source }),
            }
        }
        self.files.load(path)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn files(hash: u64) -> StateFiles {
        StateFiles::new(JobId { kind: "test job".into(), hash, settings: "s".into() }, "rerun with --force")
    }

    /// Nothing saved: a fresh start. Saved: this job's state comes back.
    /// Another job's, a cut one and an older nst3d's are refused in one
    /// line that names the file and how to start over; `force` starts over.
    #[test]
    fn a_job_resumes_only_from_its_own_state() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("work/job.state");
        let job = Resume::begin(&dir.path().join("work"), files(7)).unwrap();
        assert!(job.load_or_fresh(&path, false).unwrap().is_none());
        let mut st = job.files().fresh();
        st.set("frames_done", 3);
        st.put_f32("x", &[2], vec![1.0, 2.0]);
        job.files().save(&path, &st).unwrap();
        let back = job.load_or_fresh(&path, false).unwrap().unwrap();
        assert_eq!(back.get::<usize>("frames_done"), Ok(3));

        let e = files(8).load(&path).unwrap_err().to_string();
        assert!(
            e.contains("job.state") && e.contains("different test job") && e.ends_with("rerun with --force"),
            "{e}"
        );
        assert_eq!(e.lines().count(), 1);
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() - 3]).unwrap();
        let e = job.files().load(&path).unwrap_err().to_string();
        assert!(e.contains("truncated or corrupt"), "{e}");
        std::fs::write(&path, b"NST3DSQ1\x01\x00").unwrap();
        let e = job.files().load(&path).unwrap_err().to_string();
        assert!(e.contains("older nst3d") && e.ends_with("rerun with --force"), "{e}");
        assert!(job.load_or_fresh(&path, true).unwrap().is_none());
        assert!(!path.exists());
    }

    /// A second process on the same job is refused while the first holds it.
    #[test]
    fn one_process_per_job() {
        let dir = tempfile::tempdir().unwrap();
        let first = Resume::begin(&dir.path().join("w"), files(1)).unwrap();
        assert!(Resume::begin(&dir.path().join("w"), files(1)).unwrap_err().contains("another nst3d"));
        drop(first);
        Resume::begin(&dir.path().join("w"), files(1)).unwrap();
    }
}
