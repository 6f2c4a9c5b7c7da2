//! `nst3d strands generate` and `nst3d strands --frames` on a tiny wind-blown
//! fur ball: frame patterns expand, every frame is written and reads back
//! with the input's topology, the sequence reports its flicker; a frame with
//! other strands, or a pattern without a placeholder, fails with one line
//! before any stylization; a killed sequence resumes after its last
//! finished frame and ends with the bytes of an uninterrupted run.

mod common;
use common::shared;

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Output, Stdio};

use nst3d_io::groom::read_groom;

fn nst3d(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_nst3d")).current_dir(dir).args(args).output().expect("run nst3d")
}

fn ok(o: &Output) -> String {
    let (out, err) = (String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert!(o.status.success(), "nst3d failed:\n{out}\n{err}");
    out.into_owned()
}

/// The one error line of a failed run.
fn fails(o: &Output) -> String {
    assert!(!o.status.success(), "expected failure: {}", String::from_utf8_lossy(&o.stdout));
    let err = String::from_utf8_lossy(&o.stderr).trim().to_string();
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(!err.contains("panicked"), "{err}");
    err
}

/// Frames 1-3 of a 30-strand fur ball in wind, and its sphere.
fn generate(dir: &Path, strands: &str, frames: &str) -> Output {
    nst3d(
        dir,
        &[
            "strands",
            "generate",
            "fur-ball",
            "--frames",
            frames,
            "--strands",
            strands,
            "--points",
            "5",
            "--out",
            "anim/fur_####.ply",
            "--mesh-out",
            "sphere.ply",
        ],
    )
}

fn stylize_args<'a>(style: &'a str, extra: &[&'a str]) -> Vec<&'a str> {
    let mut a = vec![
        "strands",
        "--groom",
        "anim/fur_####.ply",
        "--mesh",
        "sphere.ply",
        "--style",
        style,
        "--preset",
        "fur-ball",
        "--out",
        "out/fur_%04d.ply",
        "--render-size",
        "48",
        "--iters",
        "3",
        "--proxies",
        "20",
        "--views-per-scale",
        "1",
        "--lr-scale",
        "1",
    ];
    a.extend_from_slice(extra);
    a
}

#[test]
fn generates_and_stylizes_a_frame_pattern() {
    let dir = tempfile::tempdir().unwrap();
    let style = shared("styles/starry_night.jpg");
    let style = style.to_str().unwrap();
    let said = ok(&generate(dir.path(), "30", "1-3"));
    assert!(said.contains("3 frames"), "{said}");
    let (f1, f2) = (
        read_groom(&dir.path().join("anim/fur_0001.ply")).unwrap(),
        read_groom(&dir.path().join("anim/fur_0002.ply")).unwrap(),
    );
    assert_eq!((f1.strand_count(), f1.strands[0].points.len()), (30, 5));
    // The wind moves the strands between frames, roots stay.
    assert_ne!(f1.strands[0].points[4], f2.strands[0].points[4]);
    assert_eq!(f1.strands[0].points[0], f2.strands[0].points[0]);

    let out = ok(&nst3d(dir.path(), &stylize_args(style, &["--frames", "1-3", "--preview", "prev/p_####.png"])));
    for f in 1..=3 {
        let g = read_groom(&dir.path().join(format!("out/fur_{f:04}.ply"))).unwrap();
        // The input's topology (5 points per strand), not the preset's 9.
        assert_eq!((g.strand_count(), g.strands[0].points.len()), (30, 5), "frame {f}");
        assert!(dir.path().join(format!("prev/p_{f:04}.png")).exists());
        assert!(out.contains(&format!("frame {f}: NNST loss")), "{out}");
    }
    assert!(!dir.path().join("out/fur_0004.ply").exists());
    // The fur ball's preset combs along the strokes, so its EMA holds on
    // to the previous frame's field longer than Table 1's 0.6.
    let head = format!("sequence: 3 frames (EMA sigma 1 nu {} + 1-euro", nst3d_strands::ORIENTATION_EMA_NU);
    let summary = out.lines().find(|l| l.starts_with(&head)).expect(&out);
    let flicker: f64 = summary.split("flicker ").nth(1).unwrap().split_whitespace().next().unwrap().parse().unwrap();
    assert!(flicker.is_finite() && flicker >= 0.0, "{summary}");
    assert!(summary.contains("0 control points inside the mesh"), "{summary}");
}

#[test]
fn bad_sequences_fail_before_stylizing() {
    let dir = tempfile::tempdir().unwrap();
    let style = shared("styles/starry_night.jpg");
    let style = style.to_str().unwrap();
    ok(&generate(dir.path(), "30", "1-2"));
    // Frame 3 from another groom: 29 strands.
    ok(&generate(dir.path(), "29", "3"));
    let err = fails(&nst3d(dir.path(), &stylize_args(style, &["--frames", "1-3"])));
    assert!(err.contains("frame 3") && err.contains("29 strands, the first frame has 30"), "{err}");
    assert!(!dir.path().join("out").exists(), "nothing is written");

    let err = fails(&nst3d(dir.path(), &stylize_args(style, &["--frames", "1-2,4"])));
    assert!(err.contains("fur_0004.ply"), "{err}");
    let mut args = stylize_args(style, &["--frames", "1-2"]);
    let out = args.iter().position(|&a| a == "out/fur_%04d.ply").unwrap();
    args[out] = "out/fur.ply";
    let err = fails(&nst3d(dir.path(), &args));
    assert!(err.contains("--out") && err.contains("placeholder"), "{err}");
    let err = fails(&nst3d(dir.path(), &stylize_args(style, &["--frames", "3-1"])));
    assert!(err.contains("bad frame spec"), "{err}");
    let err = fails(&nst3d(dir.path(), &stylize_args(style, &["--frames", "1-2", "--style-flow", "1,2"])));
    assert!(err.contains("--style-flow"), "{err}");
    let err = fails(&nst3d(dir.path(), &["strands", "generate", "fur-ball", "--out", "x.ply", "--fps", "0"]));
    assert!(err.contains("--fps"), "{err}");
}

/// Kill a run once frame 3's iterations start (frames 1-2 written, their
/// state saved), rerun the same command: it resumes after frame 2 and every
/// frame has the bytes of an uninterrupted run (the EMA and 1€ history came
/// back exactly). A finished job is not redone; a state an older nst3d
/// wrote is refused; --force redoes it.
#[test]
fn a_killed_sequence_resumes_after_its_last_finished_frame() {
    let dir = tempfile::tempdir().unwrap();
    let style = shared("styles/starry_night.jpg");
    let style = style.to_str().unwrap();
    ok(&generate(dir.path(), "30", "1-4"));
    let run = |out: &str, extra: &[&str]| {
        let mut a = stylize_args(style, &["--frames", "1-4", "--threads", "1"]);
        let o = a.iter().position(|&x| x == "out/fur_%04d.ply").unwrap();
        a[o] = out;
        a.extend_from_slice(extra);
        let mut c = Command::new(env!("CARGO_BIN_EXE_nst3d"));
        c.current_dir(dir.path()).args(a);
        c
    };
    ok(&run("clean/fur_%04d.ply", &[]).output().unwrap());

    let mut child = run("killed/fur_%04d.ply", &[]).stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap();
    let mut seen = false;
    for line in BufReader::new(child.stderr.take().unwrap()).lines() {
        if line.unwrap().contains("frame 3 scale 1/3") {
            seen = true;
            child.kill().unwrap();
            break;
        }
    }
    child.wait().unwrap();
    assert!(seen, "never saw frame 3 start in the progress lines");
    assert!(!dir.path().join("killed/fur_0003.ply").exists(), "killed too late");

    let o = run("killed/fur_%04d.ply", &[]).output().unwrap();
    let out = ok(&o);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("resuming after frame 2 (2 of 4 done)"), "{err}");
    assert!(!out.contains("frame 1:") && out.contains("frame 3:"), "{out}");
    assert!(out.contains("sequence: 4 frames"), "the report counts the resumed frames: {out}");
    for f in 1..=4 {
        let name = format!("fur_{f:04}.ply");
        let a = std::fs::read(dir.path().join("clean").join(&name)).unwrap();
        let b = std::fs::read(dir.path().join("killed").join(&name)).unwrap();
        assert!(a == b, "frame {f} differs from the uninterrupted run");
    }

    let again = run("killed/fur_%04d.ply", &[]).output().unwrap();
    ok(&again);
    assert!(String::from_utf8_lossy(&again.stderr).contains("all 4 frames already done"));
    // A state an older nst3d left in the work folder is refused in one
    // line that says how to start over, and --force starts over.
    let work = std::fs::read_dir(dir.path().join("killed/.nst3d-work"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.is_dir())
        .expect("the work folder");
    std::fs::write(work.join("strands.state"), b"NST3DSQ1\x01\x00\x00").unwrap();
    let old = run("killed/fur_%04d.ply", &[]).output().unwrap();
    let err = String::from_utf8_lossy(&old.stderr);
    assert_eq!(old.status.code(), Some(1), "{err}");
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("nst3d: error")).collect();
    assert!(lines.len() == 1 && lines[0].contains("older nst3d") && lines[0].contains("--force starts over"), "{err}");
    let forced = ok(&run("killed/fur_%04d.ply", &["--force"]).output().unwrap());
    assert!(forced.contains("frame 1:"), "{forced}");
    let redone = std::fs::read(dir.path().join("killed/fur_0004.ply")).unwrap();
    assert!(redone == std::fs::read(dir.path().join("clean/fur_0004.ply")).unwrap());
}

/// A generated grass patch stylized on its own ground moves: every blade's
/// root normal is the ground's, perpendicular to the preset's front views,
/// and Table 1's visibility threshold culled them all (loss unchanged,
/// held-out loss NaN).
#[test]
fn grass_stylized_on_its_ground_moves() {
    let dir = tempfile::tempdir().unwrap();
    let style = shared("styles/starry_night.jpg");
    ok(&nst3d(
        dir.path(),
        &["strands", "generate", "grass", "--strands", "200", "--out", "g.ply", "--mesh-out", "ground.ply"],
    ));
    let out = ok(&nst3d(
        dir.path(),
        &[
            "strands",
            "--groom",
            "g.ply",
            "--mesh",
            "ground.ply",
            "--preset",
            "grass",
            "--render-size",
            "64",
            "--iters",
            "3",
            "--style",
            style.to_str().unwrap(),
            "--out",
            "o.ply",
        ],
    ));
    assert!(!out.contains("NaN"), "{out}");
    let (a, b) = (read_groom(&dir.path().join("g.ply")).unwrap(), read_groom(&dir.path().join("o.ply")).unwrap());
    let moved = a.strands.iter().zip(&b.strands).any(|(s, t)| s.points.last() != t.points.last());
    assert!(moved, "no blade moved: {out}");
}

/// A style map over an animation: the values of the first frame (each
/// root's height) share two paintings in every frame; a map of one
/// painting everywhere is that painting's sequence, byte for byte.
#[test]
fn a_style_map_carries_through_a_sequence() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (shared("styles/starry_night.jpg"), shared("styles/shipwreck.jpg"));
    let (a, b) = (a.to_str().unwrap(), b.to_str().unwrap());
    ok(&generate(dir.path(), "30", "1-2"));
    let out = ok(&nst3d(dir.path(), &stylize_args(a, &["--frames", "1-2", "--style", b, "--style-map", "@height"])));
    assert!(out.contains("sequence: 2 frames"), "{out}");
    let split: Vec<_> =
        (1..=2).map(|f| std::fs::read(dir.path().join(format!("out/fur_{f:04}.ply"))).unwrap()).collect();

    std::fs::write(dir.path().join("zero.txt"), "0\n".repeat(30)).unwrap();
    let zero = ["--frames", "1-2", "--style", b, "--style-map", "zero.txt", "--style-map-labels", "--force"];
    ok(&nst3d(dir.path(), &stylize_args(a, &zero)));
    let first: Vec<_> =
        (1..=2).map(|f| std::fs::read(dir.path().join(format!("out/fur_{f:04}.ply"))).unwrap()).collect();
    ok(&nst3d(dir.path(), &stylize_args(a, &["--frames", "1-2", "--force"])));
    for f in 1..=2 {
        let single = std::fs::read(dir.path().join(format!("out/fur_{f:04}.ply"))).unwrap();
        assert_eq!(first[f - 1], single, "frame {f}: a map of the first painting everywhere");
        assert_ne!(split[f - 1], single, "frame {f}: a height map gave the first painting's groom");
    }
}
