//! `nst3d bench strands-iter` runs end to end at a tiny size, prints its
//! per-stage breakdown with the median last, and writes the PyTorch peer's
//! inputs with `--dump`.

mod common;
use common::shared;

use std::process::Command;

#[test]
fn strands_iter_runs_and_dumps_the_peer_inputs() {
    let dir = tempfile::tempdir().unwrap();
    let (groom, mesh, style) =
        (shared("grooms/Bangs_100.hair"), shared("grooms/Bangs_head.ply"), shared("styles/starry_night.jpg"));
    let o = Command::new(env!("CARGO_BIN_EXE_nst3d"))
        .args(["--threads", "2", "bench", "strands-iter", "--iters", "1", "--size", "64"])
        .arg("--groom")
        .arg(&groom)
        .arg("--mesh")
        .arg(&mesh)
        .arg("--style")
        .arg(&style)
        .arg("--dump")
        .arg(dir.path())
        .output()
        .expect("run nst3d");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8(o.stdout).unwrap();
    for stage in ["transport", "constraints", "render", "vgg_forward", "nnst_loss", "vgg_backward", "adamw"] {
        assert!(stdout.lines().any(|l| l.starts_with("stage_ms") && l.contains(stage)), "no {stage}: {stdout}");
    }
    assert!(stdout.contains("match_ms "), "{stdout}");
    let last = stdout.lines().last().unwrap();
    assert!(last.starts_with("ms_per_iter "), "{stdout}");
    assert!(last[12..].trim().parse::<f64>().unwrap() > 0.0);
    for f in ["meta.json", "rest.npy", "rbf_vals.npy", "targets.npy", "style_columns.npy", "render0.npy"] {
        let p = dir.path().join(f);
        assert!(p.metadata().map(|m| m.len() > 0).unwrap_or(false), "missing {}", p.display());
    }
    let npy = std::fs::read(dir.path().join("render0.npy")).unwrap();
    assert!(npy.starts_with(b"\x93NUMPY\x01\x00"));
    let header = String::from_utf8_lossy(&npy[10..10 + u16::from_le_bytes([npy[8], npy[9]]) as usize]).to_string();
    assert!(header.contains("'shape': (3, 64, 64)"), "{header}");
    assert_eq!(npy.len(), 10 + header.len() + 3 * 64 * 64 * 4);
}

#[test]
fn strands_iter_refuses_a_bad_size() {
    let o = Command::new(env!("CARGO_BIN_EXE_nst3d"))
        .args(["bench", "strands-iter", "--size", "8"])
        .output()
        .expect("run nst3d");
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("--size must be between 32 and 4096") && err.lines().count() == 1, "{err}");
}
