//! Two farm blades on one job: a requeued chunk can start on a second
//! machine while the first still runs it. Each resumable job holds an
//! exclusive lock on `<work folder>.lock` (an OS file lock, released by
//! the kernel when the process ends, however it ends, so a killed job
//! never leaves a stale lock); the second process exits at once naming the
//! first, and neither corrupts the other's state files.

use std::fs::{self, File, OpenOptions, TryLockError};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

/// The lock of one job, held until dropped (the lock file is then removed).
#[derive(Debug)]
pub struct WorkLock {
    _file: File,
    path: PathBuf,
}

impl WorkLock {
    /// Locks `<target>.lock` (its folder is made if missing), or explains
    /// which process holds it.
    pub fn acquire(target: &Path) -> Result<Self, String> {
        let mut name = target.as_os_str().to_owned();
        name.push(".lock");
        let path = PathBuf::from(name);
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            fs::create_dir_all(dir).map_err(|e| format!("cannot make {}: {e}", dir.display()))?;
        }
        let mut file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .map_err(|e| format!("cannot open the lock {}: {e}", path.display()))?;
        match file.try_lock() {
            Ok(()) => {}
            Err(TryLockError::WouldBlock) => {
                let mut holder = String::new();
                let _ = file.read_to_string(&mut holder);
                let who = match holder.trim() {
                    "" => "another process".to_string(),
                    h => format!("process {h}"),
                };
                return Err(format!(
                    "another nst3d is running this job: {} is locked by {who} (wait for it, or stop it; a rerun then resumes)",
                    target.display()
                ));
            }
            Err(TryLockError::Error(e)) => return Err(format!("cannot lock {}: {e}", path.display())),
        }
        // Who holds it, for the second process's message.
        let _ = file.set_len(0).and_then(|()| write!(file, "{}@{}", std::process::id(), host()));
        Ok(Self { _file: file, path })
    }
}

impl Drop for WorkLock {
    fn drop(&mut self) {
        // The lock itself goes with the file handle; the file is tidied.
        let _ = fs::remove_file(&self.path);
    }
}

fn host() -> String {
    fs::read_to_string("/etc/hostname").map(|h| h.trim().to_string()).unwrap_or_else(|_| "this machine".into())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A second lock on the same job is refused naming the holder; after the
    /// first is dropped the job can be locked again and no file is left.
    #[test]
    fn one_job_one_holder() {
        let dir = tempfile::tempdir().unwrap();
        let work = dir.path().join(".nst3d-work/abc");
        let first = WorkLock::acquire(&work).unwrap();
        let e = WorkLock::acquire(&work).unwrap_err();
        assert!(e.contains("another nst3d is running this job") && e.contains(&std::process::id().to_string()), "{e}");
        drop(first);
        let again = WorkLock::acquire(&work).unwrap();
        drop(again);
        assert_eq!(fs::read_dir(dir.path().join(".nst3d-work")).unwrap().count(), 0);
    }
}
