//! Outputs are never left half-written: every file nst3d writes goes to a
//! temporary name in the destination folder and is renamed over the target
//! only once it is complete. A crash, a full disk or a killed farm task leaves
//! either the old file or the new one, never a torso.

use std::fs;
use std::io::{self, BufWriter, Write};
use std::path::Path;

/// Writes `path` atomically: `fill` streams the content into a temporary file
/// next to `path`, which is flushed, synced and renamed onto `path`. On any
/// error the temporary file is removed and `path` is untouched.
pub fn write_atomic<F>(path: &Path, fill: F) -> io::Result<()>
where
    F: FnOnce(&mut dyn Write) -> io::Result<()>,
{
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    if !dir.exists() {
        fs::create_dir_all(dir)?;
    }
    // Same folder as the target so the rename is a same-filesystem atomic move.
    let tmp = tempfile::Builder::new().prefix(".nst3d-").suffix(".tmp").tempfile_in(dir)?;
    {
        let mut w = BufWriter::new(tmp.as_file());
        fill(&mut w)?;
        w.flush()?;
    }
    // Temporary files are created private (0600); a finished output should
    // read like any other file the user writes: keep the old file's mode, or
    // rw-r--r-- for a new one.
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = fs::metadata(path).map(|m| m.permissions().mode() & 0o7777).unwrap_or(0o644);
        tmp.as_file().set_permissions(fs::Permissions::from_mode(mode))?;
    }
    tmp.as_file().sync_all()?;
    tmp.persist(path).map_err(|e| e.error)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn failed_write_leaves_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("out.bin");
        let err = write_atomic(&target, |w| {
            w.write_all(b"partial")?;
            Err(io::Error::other("boom"))
        });
        assert!(err.is_err());
        assert!(!target.exists());
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 0, "temp file left behind");
    }

    #[test]
    fn success_replaces_target() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("sub/out.bin");
        write_atomic(&target, |w| w.write_all(b"old")).unwrap();
        write_atomic(&target, |w| w.write_all(b"new")).unwrap();
        assert_eq!(fs::read(&target).unwrap(), b"new");
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            assert_eq!(fs::metadata(&target).unwrap().permissions().mode() & 0o777, 0o644);
        }
    }
}

/// Checks an output before any work is done, so a bad `--out` fails in a
/// second rather than after the optimisation: its extension is one of
/// `exts` (lower case, without the dot; empty: any), it is not one of
/// `inputs` (the same file by any path: nst3d never overwrites its source),
/// it is not a folder, and its folder can be made and takes a new file (the
/// probe file is removed at once). `flag` names the option in messages.
pub fn check_output(flag: &str, path: &Path, exts: &[&str], inputs: &[&Path]) -> Result<(), String> {
    let ext = path.extension().map(|e| e.to_string_lossy().to_lowercase()).unwrap_or_default();
    if !exts.is_empty() && !exts.contains(&ext.as_str()) {
        let want: Vec<String> = exts.iter().map(|e| format!(".{e}")).collect();
        return Err(format!(
            "{flag} {}: nst3d writes {} here, not {}",
            path.display(),
            want.join(" or "),
            if ext.is_empty() { "a file without extension".to_string() } else { format!(".{ext}") }
        ));
    }
    if path.is_dir() {
        return Err(format!("{flag} {} is a folder; name the file to write", path.display()));
    }
    for input in inputs {
        if let (Ok(a), Ok(b)) = (fs::canonicalize(path), fs::canonicalize(input)) {
            if a == b {
                return Err(format!(
                    "{flag} {} is the input {}: nst3d never overwrites its input (choose another path)",
                    path.display(),
                    input.display()
                ));
            }
        }
    }
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    // Nothing is created here: the folders the write would make are probed
    // at the nearest one that exists (a failed job leaves no empty folder).
    let existing = dir.ancestors().find(|a| a.as_os_str().is_empty() || a.exists()).unwrap_or(Path::new("."));
    let existing = if existing.as_os_str().is_empty() { Path::new(".") } else { existing };
    let probe = match existing.is_dir() {
        true => tempfile::Builder::new().prefix(".nst3d-").suffix(".tmp").tempfile_in(existing).map(drop),
        false => Err(io::Error::other(format!("{} is not a folder", existing.display()))),
    };
    probe.map_err(|e| format!("{flag} {}: cannot write in {}: {e}", path.display(), dir.display()))
}

#[cfg(test)]
mod check_tests {
    use super::check_output;

    /// Each refusal names the problem; a good path passes and leaves nothing behind.
    #[test]
    fn outputs_are_checked_before_the_work() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("in.vdb");
        std::fs::write(&input, b"x").unwrap();
        let via_dotdot = dir.path().join("sub/../in.vdb");
        std::fs::create_dir_all(dir.path().join("sub")).unwrap();
        let e = check_output("--out", &via_dotdot, &["vdb"], &[&input]).unwrap_err();
        assert!(e.contains("is the input"), "{e}");
        let e = check_output("--out", &dir.path().join("x.exr"), &["png"], &[]).unwrap_err();
        assert!(e.contains("writes .png here, not .exr"), "{e}");
        let e = check_output("--out", &dir.path().join("sub"), &[], &[]).unwrap_err();
        assert!(e.contains("is a folder"), "{e}");
        // Under a file: no folder can be made there, whoever runs the test.
        let e = check_output("--out", &input.join("o.vdb"), &["vdb"], &[]).unwrap_err();
        assert!(e.contains("cannot write in"), "{e}");
        let fresh = dir.path().join("new/deeper/out.vdb");
        check_output("--out", &fresh, &["vdb"], &[&input]).unwrap();
        assert!(!dir.path().join("new").exists(), "the check made a folder");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2, "the probe was left behind");
        // A folder that takes no new file (not checkable as root, who may write anywhere).
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let ro = dir.path().join("sub/ro");
            std::fs::create_dir(&ro).unwrap();
            std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o555)).unwrap();
            let writable = tempfile::tempfile_in(&ro).is_ok();
            let r = check_output("--out", &ro.join("o.vdb"), &["vdb"], &[]);
            assert_eq!(r.is_ok(), writable, "{r:?}");
            std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o755)).unwrap();
        }
    }
}
