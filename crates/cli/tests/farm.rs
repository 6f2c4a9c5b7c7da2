//! Render-farm behaviour of `nst3d volume --frames`: chunks with warm-up
//! blend at their seams, a killed run resumes from its checkpoint and loses
//! no finished frame, finished frames are skipped, a missing frame fails the
//! job with its name; and omniview cameras stylize views they never saw.

mod common;
use common::{s, shared};

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

use nst3d_core::Grid3;

fn plume() -> PathBuf {
    shared("volumes/plume48").join("fluid_data_####.vdb")
}

/// `nst3d volume` over plume frames with fast settings (1 octave, 4 sweeps)
/// at the files' resolution: these frames' common box is small enough for
/// `--upsample auto` to refine it, which the farm behaviour does not need.
fn sequence_cmd(frames: &str, out: &Path, extra: &[&str]) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_nst3d"));
    c.args(["--threads", "2", "volume", "--input", s(&plume()), "--frames", frames])
        .args(["--style", s(&shared("styles/starry_night.jpg")), "--out", s(out)])
        .args(["--iters", "4", "--octaves", "1", "--upsample", "1"])
        .args(extra);
    c
}

fn ok(o: &Output) -> String {
    assert!(o.status.success(), "nst3d failed: {}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).to_string()
}

/// The density of `path` in a fixed index box, so files with different
/// active boxes compare voxel for voxel.
fn density(path: &Path) -> Grid3 {
    const LO: i32 = -16;
    const N: usize = 96;
    let file = nst3d_io::vdb::read_vdb(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let (bx, d) = file.grid("density").unwrap().to_dense().unwrap();
    let mut out = Grid3::zeros([N; 3]);
    for z in 0..bx.dims[2] {
        for y in 0..bx.dims[1] {
            for x in 0..bx.dims[0] {
                let p = [x, y, z].map(|v| v as i32);
                let q: [usize; 3] = std::array::from_fn(|a| (bx.origin[a] + p[a] - LO) as usize);
                assert!(q.iter().all(|&v| v < N), "grid outside the comparison box");
                let i = out.index(q[0], q[1], q[2]);
                out.data[i] = d.data[d.index(x, y, z)];
            }
        }
    }
    out
}

/// `‖a − b‖ / ‖a − input‖`: a difference between two stylizations measured
/// against how much the stylization changed the smoke at all.
fn relative(a: &Grid3, b: &Grid3, input: &Grid3) -> f64 {
    let sq = |x: &Grid3, y: &Grid3| x.data.iter().zip(&y.data).map(|(p, q)| ((p - q) as f64).powi(2)).sum::<f64>();
    (sq(a, b) / sq(a, input).max(1e-30)).sqrt()
}

fn max_abs(a: &Grid3, b: &Grid3) -> f32 {
    a.data.iter().zip(&b.data).map(|(p, q)| (p - q).abs()).fold(0.0, f32::max)
}

/// 12 frames as one run and as 3 chunks of 4, with the default settings
/// (so with `--ema-settle`, which is the default). Without warm-up the seam
/// frames are stylized differently (the EMA of a chunk starts cold); with 4
/// frames of warm-up they move towards the single run's, and the frames a
/// chunk's warm-up covers entirely are identical (docs/guide/farm.md has the
/// numbers for longer sequences).
#[test]
fn chunks_with_warmup_blend_at_the_seams() {
    let dir = tempfile::tempdir().unwrap();
    let full = dir.path().join("full/s_####.vdb");
    ok(&sequence_cmd("20-31", &full, &[]).output().unwrap());
    let seams = [23, 24, 27, 28];
    let mut worst = Vec::new();
    for k in [0, 4] {
        let out = dir.path().join(format!("k{k}/s_####.vdb"));
        for chunk in ["20-23", "24-27", "28-31"] {
            let stdout =
                ok(&sequence_cmd("20-31", &out, &["--chunk", chunk, "--warmup", &k.to_string()]).output().unwrap());
            assert!(stdout.contains("4 frames stylized"), "{stdout}");
        }
        let mut rel = Vec::new();
        for f in seams {
            let name = format!("s_{f:04}.vdb");
            let a = density(&dir.path().join("full").join(&name));
            let b = density(&dir.path().join(format!("k{k}")).join(&name));
            let input = density(&shared(&format!("volumes/plume48/fluid_data_{f:04}.vdb")));
            rel.push(relative(&a, &b, &input));
            eprintln!(
                "warm-up {k}: frame {f}: max |chunk - full| {:.4}, relative {:.3}",
                max_abs(&a, &b),
                rel.last().unwrap()
            );
        }
        worst.push(rel);
    }
    // Chunk 24-27 with 4 frames of warm-up sees all of 20-31: exact.
    assert_eq!(worst[1][1], 0.0);
    assert_eq!(worst[1][2], 0.0);
    // The seams a warm-up only partly covers are still closer than cold chunks.
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    assert!(mean(&worst[1]) < 0.3 * mean(&worst[0]), "warm-up did not bring the seams closer: {worst:?}");
    // Both the end (23) and the start (28) of a chunk: measured 0.15 and 0.07.
    // A start seam that stays near 0.5+ means the first sweep's EMA is back,
    // e.g. --ema-settle is no longer the default (docs/guide/farm.md).
    assert!(worst[1][0] < 0.25 && worst[1][3] < 0.15, "seams too far from the single run: {worst:?}");
}

/// Kill a run during sweep 2, rerun the same command: it says where it
/// resumes and ends with the same bytes as an uninterrupted run. Then the
/// finished frames are skipped, a deleted one is redone, --force redoes all.
#[test]
fn a_killed_run_resumes_and_loses_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let clean = dir.path().join("clean/s_####.vdb");
    ok(&sequence_cmd("20-23", &clean, &[]).output().unwrap());

    let out = dir.path().join("killed/s_####.vdb");
    let mut child = sequence_cmd("20-23", &out, &[]).stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap();
    let mut seen = false;
    for line in BufReader::new(child.stderr.take().unwrap()).lines() {
        if line.unwrap().contains("sweep 2/4") {
            seen = true;
            child.kill().unwrap();
            break;
        }
    }
    child.wait().unwrap();
    assert!(seen, "never saw sweep 2 in the progress lines");
    let work = dir.path().join("killed/.nst3d-work");
    assert!(work.exists(), "no work folder after the kill");

    let o = sequence_cmd("20-23", &out, &[]).output().unwrap();
    ok(&o);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("resuming at octave 1 sweep "), "{err}");
    assert!(!err.contains("sweep 1/4"), "the resumed run redid sweep 1: {err}");
    for f in 20..=23 {
        let name = format!("s_{f:04}.vdb");
        let a = std::fs::read(dir.path().join("clean").join(&name)).unwrap();
        let b = std::fs::read(dir.path().join("killed").join(&name)).unwrap();
        assert!(a == b, "frame {f} differs from the uninterrupted run");
    }
    assert!(std::fs::read_dir(&work).unwrap().next().is_none(), "work folder not cleaned up after success");

    let again = ok(&sequence_cmd("20-23", &out, &[]).output().unwrap());
    assert!(again.contains("nothing to do"), "{again}");
    let redo = dir.path().join("killed/s_0022.vdb");
    std::fs::remove_file(&redo).unwrap();
    let one = ok(&sequence_cmd("20-23", &out, &[]).output().unwrap());
    assert!(one.contains("1 frames stylized"), "{one}");
    assert!(std::fs::read(&redo).unwrap() == std::fs::read(dir.path().join("clean/s_0022.vdb")).unwrap());
    let all = ok(&sequence_cmd("20-23", &out, &["--force"]).output().unwrap());
    assert!(all.contains("4 frames stylized"), "{all}");
}

/// SIGTERM (a farm cancelling the task) during sweep 2: the job stops
/// after the sweep in progress, within seconds, exits 143, leaves no
/// temporary file, and the rerun resumes after the last committed sweep and
/// ends with the bytes of an uninterrupted run. SIGINT exits 130.
#[test]
fn sigterm_stops_cleanly_and_the_rerun_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let clean = dir.path().join("clean/s_####.vdb");
    ok(&sequence_cmd("20-23", &clean, &[]).output().unwrap());

    for (signal, code) in [("-TERM", 143), ("-INT", 130)] {
        let out = dir.path().join(format!("stopped{code}/s_####.vdb"));
        let mut child = sequence_cmd("20-23", &out, &[]).stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap();
        let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
        let mut sent = None;
        let mut said = String::new();
        for line in lines.by_ref() {
            let line = line.unwrap();
            said.push_str(&line);
            said.push('\n');
            if sent.is_none() && line.contains("sweep 2/4") {
                let k = Command::new("kill").args([signal, &child.id().to_string()]).status().unwrap();
                assert!(k.success());
                sent = Some(std::time::Instant::now());
            }
        }
        let status = child.wait().unwrap();
        let took = sent.expect("never saw sweep 2 in the progress lines").elapsed();
        assert_eq!(status.code(), Some(code), "{signal}: {said}");
        assert!(took.as_secs_f64() < 5.0, "{signal}: took {took:?} to stop");
        assert!(said.contains("rerun to resume"), "{said}");
        assert!(!said.contains("sweep 4/4"), "{signal}: the job did not stop: {said}");
        let folder = out.parent().unwrap();
        // nst3d's atomic writes go through `.nst3d-*.tmp` beside the target.
        let leftovers: Vec<_> = walk(folder)
            .into_iter()
            .filter(|p| p.file_name().is_some_and(|n| n.to_string_lossy().ends_with(".tmp")))
            .collect();
        assert!(leftovers.is_empty(), "temporary files left: {leftovers:?}");

        let o = sequence_cmd("20-23", &out, &[]).output().unwrap();
        ok(&o);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains("resuming at octave 1 sweep "), "{err}");
        for f in 20..=23 {
            let name = format!("s_{f:04}.vdb");
            let a = std::fs::read(dir.path().join("clean").join(&name)).unwrap();
            let b = std::fs::read(folder.join(&name)).unwrap();
            assert!(a == b, "frame {f} differs from the uninterrupted run");
        }
    }
}

/// Two blades, one job: while a sequence runs, the same command started
/// again exits at once naming the first process; the first goes on, and
/// once it ends (here by SIGTERM) no lock file is left.
#[test]
fn a_second_blade_on_the_same_job_exits_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("shared/s_####.vdb");
    let slow = ["--strength", "10"]; // 40 sweeps: still running when the second starts
    let mut first = sequence_cmd("20-23", &out, &slow).stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap();
    let mut lines = BufReader::new(first.stderr.take().unwrap()).lines();
    for line in lines.by_ref() {
        if line.unwrap().contains("sweep 1/40") {
            break;
        }
    }
    let t = std::time::Instant::now();
    let second = sequence_cmd("20-23", &out, &slow).output().unwrap();
    let err = String::from_utf8_lossy(&second.stderr);
    assert_eq!(second.status.code(), Some(1), "{err}");
    assert!(err.contains("another nst3d is running this job") && err.contains(&first.id().to_string()), "{err}");
    assert!(t.elapsed().as_secs_f64() < 5.0, "the second blade took {:?}", t.elapsed());
    assert!(first.try_wait().unwrap().is_none(), "the first blade stopped");
    Command::new("kill").args(["-TERM", &first.id().to_string()]).status().unwrap();
    for _ in lines {}
    assert_eq!(first.wait().unwrap().code(), Some(143));
    let locks: Vec<_> =
        walk(&dir.path().join("shared")).into_iter().filter(|p| p.to_string_lossy().ends_with(".lock")).collect();
    assert!(locks.is_empty(), "lock files left: {locks:?}");
}

/// Every file under `dir`.
fn walk(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).into_iter().flatten().flatten() {
        let p = e.path();
        if p.is_dir() {
            out.extend(walk(&p));
        } else {
            out.push(p);
        }
    }
    out
}

/// A frame missing in the middle of the range fails the job (exit 1) with
/// an error naming the file, before any slow work.
#[test]
fn a_missing_frame_fails_the_job_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    for f in [20, 21, 23] {
        let name = format!("fluid_data_{f:04}.vdb");
        std::fs::copy(shared("volumes/plume48").join(&name), dir.path().join(&name)).unwrap();
    }
    let o = Command::new(env!("CARGO_BIN_EXE_nst3d"))
        .args(["volume", "--input", s(&dir.path().join("fluid_data_####.vdb")), "--frames", "20-23"])
        .args(["--style", s(&shared("styles/starry_night.jpg")), "--out", s(&dir.path().join("o_####.vdb"))])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("fluid_data_0022.vdb"), "{err}");
    assert!(!dir.path().join("o_0020.vdb").exists(), "wrote frames of a job that cannot complete");
}

/// Parses "held-out cameras ...: mean style loss A -> B" into B.
fn held_out(stdout: &str) -> f32 {
    let line = stdout.lines().find(|l| l.starts_with("held-out cameras")).unwrap_or_else(|| panic!("{stdout}"));
    line.rsplit("-> ").next().unwrap().trim().parse().unwrap()
}

/// Omniview (8 Poisson-disk cameras) against the single front camera on one
/// plume frame, both scored from a 4-camera ring at 30° elevation that
/// neither optimised: omniview's held-out style loss is lower.
#[test]
fn omniview_lowers_the_held_out_style_loss() {
    let dir = tempfile::tempdir().unwrap();
    let mut losses = Vec::new();
    for cams in ["front", "omniview:8"] {
        let o = Command::new(env!("CARGO_BIN_EXE_nst3d"))
            .args(["--threads", "2", "volume", "--input", s(&shared("volumes/plume48/fluid_data_0030.vdb"))])
            .args(["--style", s(&shared("styles/starry_night.jpg")), "--out", s(&dir.path().join("o.vdb"))])
            .args(["--iters", "8", "--octaves", "1", "--cameras", cams, "--eval-cameras", "ring:4:30"])
            .output()
            .unwrap();
        let stdout = ok(&o);
        eprintln!("{cams}: {stdout}");
        losses.push(held_out(&stdout));
    }
    assert!(losses[1] < 0.9 * losses[0], "omniview {} vs front {}", losses[1], losses[0]);
}

/// Camera options: a bad set is one clean error; a camera file drives a
/// sequence (the camera follows its path) and a single frame.
#[test]
fn camera_sets_and_files() {
    let dir = tempfile::tempdir().unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_nst3d"))
        .args(["volume", "--input", s(&shared("volumes/plume48/fluid_data_0030.vdb"))])
        .args(["--style", s(&shared("styles/starry_night.jpg")), "--out", s(&dir.path().join("o.vdb"))])
        .args(["--cameras", "omniview:x"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("omniview:x"));

    // A path around the plume (Blender world space: the plume fills about [0.3, 1.6]² x [0.1, 1.75], z up).
    let cam = dir.path().join("shot.json");
    std::fs::write(
        &cam,
        r#"{"up": [0, 0, 1], "frames": {"20": {"position": [1, -5, 1], "look_at": [1, 1, 1]},
                                        "22": {"position": [7, 1, 1], "look_at": [1, 1, 1]}}}"#,
    )
    .unwrap();
    let out = dir.path().join("c_####.vdb");
    let stdout = ok(&sequence_cmd("20-22", &out, &["--camera-file", s(&cam)]).output().unwrap());
    assert!(stdout.contains("3 frames stylized"), "{stdout}");
}

/// The three OpenUSD smoke frames as a sequence: frame 1's grid is empty
/// and no frame has a velocity grid. The empty frame is copied unchanged
/// (byte for byte) with a note, the other two are stylized with the EMA
/// carrying fields unmoved (no advection), which still couples them: they
/// end differently than with `--ema 0`.
#[test]
fn openusd_frames_with_an_empty_frame_and_no_velocity_run_as_a_sequence() {
    let dir = tempfile::tempdir().unwrap();
    let input = shared("volumes/smoke_000003.vdb").with_file_name("smoke_######.vdb");
    let run = |ema: &str, out: &Path| {
        let o = Command::new(env!("CARGO_BIN_EXE_nst3d"))
            .args(["--threads", "2", "volume", "--input", s(&input), "--frames", "1-3"])
            .args(["--style", s(&shared("styles/starry_night.jpg")), "--out", s(out)])
            .args(["--iters", "2", "--octaves", "1", "--ema", ema])
            .output()
            .unwrap();
        (ok(&o), String::from_utf8_lossy(&o.stderr).to_string())
    };
    let out = dir.path().join("ema/s_######.vdb");
    let (stdout, stderr) = run("0.7", &out);
    assert!(stdout.contains("2 frames stylized") && stdout.contains("1 empty frames copied unchanged"), "{stdout}");
    assert!(stderr.contains("frames [1] have an empty grid 'density'"), "{stderr}");
    assert!(stderr.contains("no velocity grid"), "{stderr}");
    let frame = |d: &str, f: u32| dir.path().join(d).join(format!("s_{f:06}.vdb"));
    assert!(
        std::fs::read(frame("ema", 1)).unwrap() == std::fs::read(shared("volumes/smoke_000001.vdb")).unwrap(),
        "the empty frame was not copied unchanged"
    );
    let styled = |d: &str, f: u32| {
        let file = nst3d_io::vdb::read_vdb(&frame(d, f)).unwrap();
        file.grid("density").unwrap().to_dense().unwrap().1
    };
    let input = nst3d_io::vdb::read_vdb(&shared("volumes/smoke_000003.vdb")).unwrap();
    let (_, d3) = input.grid("density").unwrap().to_dense().unwrap();
    assert!(styled("ema", 3).data != d3.data, "frame 3 was not stylized");

    let (stdout, _) = run("0", &dir.path().join("plain/s_######.vdb"));
    assert!(stdout.contains("2 frames stylized"), "{stdout}");
    assert!(styled("ema", 2).data != styled("plain", 2).data, "the EMA did nothing without a velocity grid");
}
