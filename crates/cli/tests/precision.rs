//! `--precision` from the command line: the run's header names the path,
//! both precisions run the same job to nearly the same loss, and a bad value
//! in the flag or in `NST3D_PRECISION` is one line and a non-zero exit.

mod common;
use common::{nst3d, s, shared};

use std::process::Command;

/// The "style loss A -> B" figures of a volume run's report.
fn losses(stdout: &str) -> (f64, f64) {
    let at = stdout.find("style loss ").expect("a style loss in the report") + "style loss ".len();
    let mut it = stdout[at..].split_whitespace();
    let before = it.next().unwrap().parse().unwrap();
    assert_eq!(it.next(), Some("->"));
    let after = it.next().unwrap().trim_end_matches(|c: char| !c.is_ascii_digit()).parse().unwrap();
    (before, after)
}

#[test]
fn both_precisions_run_and_the_header_says_which() {
    let dir = tempfile::tempdir().unwrap();
    let input = shared("volumes/smoke_000002.vdb");
    let style = shared("styles/starry_night.jpg");
    let mut drops = Vec::new();
    for p in ["fp32", "bf16"] {
        let out = dir.path().join(format!("{p}.vdb"));
        let o = nst3d(&[
            "--precision",
            p,
            "volume",
            "--input",
            s(&input),
            "--style",
            s(&style),
            "--out",
            s(&out),
            "--iters",
            "3",
            "--octaves",
            "1",
        ]);
        let (stdout, stderr) = (String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
        assert!(o.status.success(), "{stderr}");
        let header = stderr.lines().find(|l| l.starts_with("nst3d: precision")).expect("a precision header");
        assert!(header.starts_with(&format!("nst3d: precision {p} → {p}")), "{header}");
        let (before, after) = losses(&stdout);
        drops.push(1.0 - after / before);
    }
    // Three iterations of the same job: the drops agree to well under 2 points.
    assert!((drops[0] - drops[1]).abs() < 0.02, "fp32 drop {} vs bf16 drop {}", drops[0], drops[1]);
}

#[test]
fn bad_precisions_are_one_line_errors() {
    let o = nst3d(&["--precision", "half", "bench", "volume-iter", "--n", "16"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("auto, bf16, fp32"));
    let o = Command::new(env!("CARGO_BIN_EXE_nst3d"))
        .args(["bench", "volume-iter", "--n", "16"])
        .env("NST3D_PRECISION", "half")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains("NST3D_PRECISION: unknown precision 'half'"), "{err}");
}
