//! A full disk (ENOSPC) while writing an output or a checkpoint: one clear
//! line, exit 1, the temporary file removed, earlier outputs and the last
//! committed checkpoint intact (the job resumes from it elsewhere). The full
//! disk is a real one: a small tmpfs this test mounts, so it needs root, as
//! CI has; without root it fails saying so.

mod common;
use common::{s, shared};

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// A tmpfs of `kib` KiB at `dir`, unmounted on drop.
struct SmallDisk(PathBuf);

impl SmallDisk {
    fn mount(dir: &Path, kib: usize) -> Self {
        std::fs::create_dir_all(dir).unwrap();
        let o = Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={kib}k"), "tmpfs", s(dir)])
            .output()
            .expect("run mount");
        assert!(
            o.status.success(),
            "this test mounts a small tmpfs to fill it and needs root: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        Self(dir.to_path_buf())
    }
}

impl Drop for SmallDisk {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg(&self.0).status();
    }
}

fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> =
        std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().to_string()).collect();
    v.sort();
    v
}

fn nst3d(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_nst3d")).args(args).output().unwrap()
}

#[test]
fn a_full_disk_is_one_line_and_leaves_the_last_good_state() {
    let dir = tempfile::tempdir().unwrap();
    let style = shared("styles/starry_night.jpg");
    let fast = ["--iters", "4", "--octaves", "1", "--upsample", "1"];

    // An output that does not fit: the earlier file beside it survives.
    let disk = SmallDisk::mount(&dir.path().join("small"), 256);
    let earlier = disk.0.join("earlier.vdb");
    std::fs::write(&earlier, b"an earlier output").unwrap();
    let out = disk.0.join("styled.vdb");
    let input = shared("volumes/smoke_000003.vdb");
    let mut args = vec!["volume", "--input", s(&input), "--style", s(&style), "--out", s(&out)];
    args.extend_from_slice(&fast);
    let o = nst3d(&args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("nst3d: error")).collect();
    assert_eq!(lines.len(), 1, "{err}");
    assert!(lines[0].contains("styled.vdb") && lines[0].contains("No space left on device"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(names(&disk.0), ["earlier.vdb"], "a temporary or partial file was left");
    assert_eq!(std::fs::read(&earlier).unwrap(), b"an earlier output");
    drop(disk);

    // A work folder whose disk fills up (another job's file) during the
    // second sweep: the job stops with one line, no temporary state is left,
    // and the last committed sweep resumes when the folder is copied
    // somewhere with room.
    let disk = SmallDisk::mount(&dir.path().join("work"), 8000);
    let plume = shared("volumes/plume48").join("fluid_data_####.vdb");
    let outs = dir.path().join("seq/s_####.vdb");
    let seq = |work: &Path| {
        let mut c = Command::new(env!("CARGO_BIN_EXE_nst3d"));
        c.args(["volume", "--input", s(&plume), "--frames", "20-23", "--style", s(&style)])
            .args(["--out", s(&outs), "--work-dir", s(work)])
            .args(fast);
        c
    };
    let mut child = seq(&disk.0).stderr(Stdio::piped()).stdout(Stdio::null()).spawn().unwrap();
    let mut err = String::new();
    for line in BufReader::new(child.stderr.take().unwrap()).lines() {
        let line = line.unwrap();
        if line.contains("sweep 2/4") && !err.contains("sweep 2/4") {
            // Fill every byte left.
            let mut f = std::fs::File::create(disk.0.join("other-job.bin")).unwrap();
            let block = vec![0u8; 64 << 10];
            while f.write_all(&block).is_ok() {}
            let _ = f.sync_all();
        }
        err.push_str(&line);
        err.push('\n');
    }
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(1), "the work folder did not fill up: {err}");
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("nst3d: error")).collect();
    assert!(lines.len() == 1 && lines[0].contains("No space left on device"), "{err}");
    std::fs::remove_file(disk.0.join("other-job.bin")).unwrap();
    let left = names(&disk.0);
    assert!(left.iter().all(|n| !n.contains(".tmp")), "temporary state left: {left:?}");
    assert!(left.iter().any(|n| n == "checkpoint"), "no checkpoint: {left:?}");
    let roomy = dir.path().join("roomy");
    std::fs::create_dir(&roomy).unwrap();
    for n in &left {
        std::fs::copy(disk.0.join(n), roomy.join(n)).unwrap();
    }
    drop(disk);
    let o = seq(&roomy).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("resuming at octave 1 sweep 2"), "{err}");
}
