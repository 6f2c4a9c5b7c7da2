//! `nst3d strands` end to end on the shared Bangs groom and head, at a small
//! render size and few iterations (the full-size run is a report, not CI):
//! the written groom reads back with the right shape, keeps its lengths,
//! stays out of the head and lowers the NNST loss; bad grooms fail with one
//! line.

mod common;
use common::{assert_fails, s, shared, small_strands};

use std::path::Path;
use std::process::Output;

use nst3d_io::groom::{read_groom, read_usda_curves};
use nst3d_strands::pipeline::polyline_length;
use nst3d_strands::MeshBvh;

/// Runs `nst3d strands` on `groom` with fast settings.
fn strands(groom: &Path, out: &Path, extra: &[&str]) -> Output {
    let mesh = shared("grooms/Bangs_head.ply");
    small_strands(groom, Some(&mesh), out, extra)
}

/// The two numbers of "NNST loss A -> B" in the summary line.
fn losses(stdout: &str) -> (f64, f64) {
    let rest = stdout.split("NNST loss ").nth(1).unwrap_or_else(|| panic!("no loss in summary: {stdout}"));
    let mut it = rest.split_whitespace();
    let a = it.next().unwrap().parse().unwrap();
    assert_eq!(it.next(), Some("->"));
    let b = it.next().unwrap().parse().unwrap();
    (a, b)
}

#[test]
fn stylizes_bangs_and_keeps_constraints() {
    let dir = tempfile::tempdir().unwrap();
    let (groom_path, out, preview) =
        (shared("grooms/Bangs_100.hair"), dir.path().join("out.usda"), dir.path().join("p.png"));
    let o = strands(&groom_path, &out, &["--preview", s(&preview)]);
    let (stdout, stderr) = (String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert!(o.status.success(), "nst3d strands failed: {stderr}");

    let input = read_groom(&groom_path).unwrap();
    let result = read_usda_curves(&out).unwrap_or_else(|e| panic!("{e}"));
    // Same topology as the input: strand count and points per strand (the
    // optimization's re-sampled splines are carried back to the input's
    // control points), so the output can replace the input in a scene.
    assert_eq!(result.strand_count(), input.strand_count());
    for (i, (a, b)) in input.strands.iter().zip(&result.strands).enumerate() {
        assert_eq!(a.points.len(), b.points.len(), "strand {i}: point count");
    }
    let moved = input.strands.iter().zip(&result.strands).flat_map(|(a, b)| a.points.iter().zip(&b.points));
    let max_move = moved.map(|(p, q)| (0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f32>().sqrt()).fold(0.0, f32::max);
    assert!(max_move > 0.1, "the written groom is the input (max move {max_move})");
    for (i, (a, b)) in input.strands.iter().zip(&result.strands).enumerate() {
        let (la, lb) = (polyline_length(&a.points), polyline_length(&b.points));
        assert!((lb / la - 1.0).abs() < 0.01, "strand {i}: length {lb} vs input {la}");
    }
    let head = nst3d_io::mesh::read_mesh(&shared("grooms/Bangs_head.ply")).unwrap();
    let bvh = MeshBvh::new(&head).unwrap();
    let inside = result.strands.iter().flat_map(|st| &st.points).filter(|&&p| bvh.is_inside(p)).count();
    assert_eq!(inside, 0, "{inside} control points inside the head");

    let (before, after) = losses(&stdout);
    assert!(after < before, "NNST loss did not drop: {before} -> {after}\n{stdout}");
    let png = image::open(&preview).unwrap();
    assert_eq!(png.height(), 384, "preview height");
    assert!(png.width() > 3 * 384 - 10, "preview holds before | after | painting");
}

#[test]
fn bad_grooms_give_one_line_errors() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.usda");
    let hair = std::fs::read(shared("grooms/Bangs_100.hair")).unwrap();

    assert_fails(&strands(&dir.path().join("missing.hair"), &out, &[]), &out, "missing.hair");

    let truncated = dir.path().join("truncated.hair");
    std::fs::write(&truncated, &hair[..hair.len() / 2]).unwrap();
    assert_fails(&strands(&truncated, &out, &[]), &out, "truncated");

    // cyHair header announcing zero strands and zero points.
    let mut empty = hair[..128].to_vec();
    empty[4..12].fill(0);
    let empty_path = dir.path().join("empty.hair");
    std::fs::write(&empty_path, &empty).unwrap();
    assert_fails(&strands(&empty_path, &out, &[]), &out, "no strands");

    // A NaN coordinate in the first point (after the header and the
    // per-strand segment counts).
    let mut nan = hair.clone();
    let at = 128 + 2 * 100;
    nan[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    let nan_path = dir.path().join("nan.hair");
    std::fs::write(&nan_path, &nan).unwrap();
    assert_fails(&strands(&nan_path, &out, &[]), &out, "not finite");

    // A strand of a single point is not a curve.
    let one_path = dir.path().join("one.usda");
    std::fs::write(
        &one_path,
        "#usda 1.0\n\ndef BasisCurves \"Groom\"\n{\n    uniform token type = \"linear\"\n    \
         int[] curveVertexCounts = [3, 1]\n    \
         point3f[] points = [(0, 0, 0), (0, 1, 0), (0, 2, 0), (1, 1, 1)]\n}\n",
    )
    .unwrap();
    assert_fails(&strands(&one_path, &out, &[]), &out, "strand 1 has 1 point(s)");

    let bad_out = dir.path().join("out.abc");
    assert_fails(
        &strands(&shared("grooms/Bangs_100.hair"), &bad_out, &[]),
        &bad_out,
        ".usda, .usdc, .usd, .usdz or .ply",
    );
}

#[test]
fn a_groom_without_its_mesh_is_stylized_without_collisions_and_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let (groom_path, out) = (shared("grooms/Bangs_100.hair"), dir.path().join("out.ply"));
    let o = small_strands(&groom_path, None, &out, &[]);
    let (stdout, stderr) = (String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert!(o.status.success(), "nst3d strands without --mesh failed: {stderr}");
    assert_eq!(stderr.matches("no --mesh").count(), 1, "the missing mesh is said once: {stderr}");
    assert!(stdout.contains("no mesh, no collision check"), "{stdout}");
    let (input, result) = (read_groom(&groom_path).unwrap(), read_groom(&out).unwrap());
    assert_eq!(input.strand_count(), result.strand_count());
    for (a, b) in input.strands.iter().zip(&result.strands) {
        assert_eq!(a.points.len(), b.points.len());
        let (la, lb) = (polyline_length(&a.points), polyline_length(&b.points));
        assert!(((lb - la) / la).abs() < 1e-3, "length {la} -> {lb}");
    }
    assert_ne!(input.strands, result.strands, "the groom did not change");
}

/// A stylization that cannot fit in this machine's memory is refused before
/// any work, naming the estimate and what is available; an absurd render
/// size is refused outright.
#[test]
fn a_job_too_big_for_memory_is_refused_up_front() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o.usda");
    let (groom, head, style) =
        (shared("grooms/Bangs_100.hair"), shared("grooms/Bangs_head.ply"), shared("styles/starry_night.jpg"));
    let run = |size: &str| {
        let t = std::time::Instant::now();
        let o = common::nst3d(&[
            "strands",
            "--groom",
            s(&groom),
            "--mesh",
            s(&head),
            "--style",
            s(&style),
            "--out",
            s(&out),
            "--render-size",
            size,
        ]);
        (o, t.elapsed())
    };
    let (o, took) = run("16000");
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("needs about") && err.contains("GB is available") && err.contains("--render-size"), "{err}");
    assert!(took.as_secs_f64() < 10.0, "refused only after {took:?}");
    assert!(!out.exists());
    let (o, _) = run("100000");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.code() == Some(1) && err.contains("--render-size must be 16 to 16384"), "{err}");
}
