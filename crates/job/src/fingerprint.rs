//! A farm job's identity: which work folder its saved state lives in. A
//! rerun of the same job (same settings, same painting, same input frames)
//! finds its folder again and resumes; any change makes a new folder, so a
//! stale state is never applied to different work.

use std::path::{Path, PathBuf};

/// FNV-1a, 64 bits: a stable name for a job's work folder (the same on
/// every machine and build, unlike the standard library's hasher).
fn fnv1a(bytes: &[u8], mut h: u64) -> u64 {
    for b in bytes {
        h ^= *b as u64;
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

/// The settings part of a job's fingerprint: the `Debug` form of its
/// settings, after the caller cleared the fields that do not change what
/// the job computes (output folders, previews, `force`). Every other field,
/// including one added later, is in it: the safe side. `threads_matter`
/// adds the thread count for jobs that are reproducible bit for bit only on
/// the same count.
pub fn settings_key<S: std::fmt::Debug>(settings: &S, threads_matter: bool) -> String {
    match threads_matter {
        true => format!("{settings:?}|threads {}", rayon::current_num_threads()),
        false => format!("{settings:?}"),
    }
}

/// A stable hash of a job: its `settings` text, the contents of the files
/// in `read` (small: a painting, a camera file) and the path, size and
/// modification time of the files in `stamped` (the input frames, which may
/// be large: their contents are not read).
pub fn job_fingerprint(settings: &str, read: &[PathBuf], stamped: &[PathBuf]) -> std::io::Result<u64> {
    let named = |p: &Path, e: std::io::Error| std::io::Error::new(e.kind(), format!("{}: {e}", p.display()));
    let mut h = fnv1a(settings.as_bytes(), 0xcbf2_9ce4_8422_2325);
    for p in read {
        h = fnv1a(&std::fs::read(p).map_err(|e| named(p, e))?, h);
    }
    for p in stamped {
        let meta = std::fs::metadata(p).map_err(|e| named(p, e))?;
        let mtime =
            meta.modified().ok().and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok()).map_or(0, |d| d.as_nanos());
        h = fnv1a(format!("{}|{}|{mtime}", p.display(), meta.len()).as_bytes(), h);
    }
    Ok(h)
}

/// The default work folder of a job whose first output is `out`:
/// `<out dir>/.nst3d-work/<hash>`, beside the outputs so it lands on the
/// same (shared) disk every blade of the farm sees.
pub fn default_work_dir(out: &Path, hash: u64) -> PathBuf {
    let dir = out.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    dir.join(".nst3d-work").join(format!("{hash:016x}"))
}

/// Whose a saved state is: the kind of job (`"volume sequence"`, ...,
/// also how messages name it), the job's fingerprint and the settings text
/// it was taken over. Every state file carries all three
/// ([`crate::State::new`]) and a job resumes only from its own
/// ([`crate::State::check`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct JobId {
    /// The kind of job, in words.
    pub kind: String,
    /// [`job_fingerprint`] of the job.
    pub hash: u64,
    /// The settings text the fingerprint was taken over ([`settings_key`]).
    pub settings: String,
}

impl JobId {
    /// The identity of a job of `kind`: [`job_fingerprint`] over
    /// `settings`, the contents of `read` and the stamps of `stamped`.
    pub fn new(kind: &str, settings: String, read: &[PathBuf], stamped: &[PathBuf]) -> std::io::Result<Self> {
        let hash = job_fingerprint(&settings, read, stamped)?;
        Ok(Self { kind: kind.to_string(), hash, settings })
    }

    /// The fingerprint as a state file stores it: 16 hex digits.
    pub fn fingerprint(&self) -> String {
        format!("{:016x}", self.hash)
    }
}
