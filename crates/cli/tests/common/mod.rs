//! Helpers every end-to-end test of the binary uses (each test file is its
//! own crate, so each compiles what it needs of this module).
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A file under `../shared/data`; fails loudly when the shared data is missing.
pub fn shared(rel: &str) -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data").join(rel);
    assert!(p.exists(), "shared test data missing: {} (the repo expects ../shared beside it)", p.display());
    p
}

/// Runs the `nst3d` binary built for these tests.
pub fn nst3d(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_nst3d")).args(args).output().expect("run nst3d")
}

/// A path as the `&str` an argument list wants.
pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// `nst3d strands` on `groom` (with `mesh`, or without one) at the small,
/// fast settings the end-to-end groom tests share (96² render, 9
/// iterations, 40 proxies, one view per scale), plus `extra`.
pub fn small_strands(groom: &Path, mesh: Option<&Path>, out: &Path, extra: &[&str]) -> Output {
    let style = shared("styles/starry_night.jpg");
    let mut args = vec!["strands", "--groom", s(groom), "--style", s(&style), "--out", s(out)];
    if let Some(m) = mesh {
        args.extend_from_slice(&["--mesh", s(m)]);
    }
    args.extend_from_slice(&[
        "--preset",
        "short-hair",
        "--iters",
        "9",
        "--render-size",
        "96",
        "--proxies",
        "40",
        "--views-per-scale",
        "1",
        "--lr-scale",
        "0.1",
    ]);
    args.extend_from_slice(extra);
    nst3d(&args)
}

/// A strands job that failed cleanly: exit 1, stderr one `nst3d: error`
/// line naming `needle`, and no `out` written.
pub fn assert_fails(o: &Output, out: &Path, needle: &str) {
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "expected exit 1, stderr: {err}");
    let lines: Vec<&str> = err.lines().collect();
    assert_eq!(lines.len(), 1, "expected one line, got: {err}");
    assert!(lines[0].starts_with("nst3d: error") && lines[0].contains(needle), "want '{needle}': {err}");
    assert!(!out.exists(), "a failed run left {}", out.display());
}
