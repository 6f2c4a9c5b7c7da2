//! `nst3d train` and `nst3d volume --model` end to end: a tiny model trained
//! on plume frames stylizes another frame; wrong models and settings give
//! one clear line and exit 1 with no output left behind.

mod common;
use common::{nst3d, s, shared};

use std::path::Path;
use std::process::Output;

fn fails_with(o: &Output, out: &Path, needle: &str) {
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("nst3d: error")).collect();
    assert!(lines.len() == 1 && lines[0].contains(needle), "expected one error line with '{needle}': {err}");
    assert!(!out.exists(), "a failed run left {}", out.display());
}

#[test]
fn a_trained_model_stylizes_a_frame_it_never_saw() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("m.safetensors");
    let plume = shared("volumes/plume48").join("fluid_data_####.vdb");
    let o = nst3d(&[
        "--threads",
        "2",
        "train",
        "--input",
        s(&plume),
        "--frames",
        "20-22",
        "--style",
        s(&shared("styles/starry_night.jpg")),
        "--out",
        s(&model),
        "--steps",
        "3",
        "--patch",
        "16",
        "--channels",
        "2",
        "--mode",
        "density",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stdout).contains("trained 3 of 3 steps"));
    assert!(model.with_extension("csv").exists() && model.with_extension("loss.png").exists());

    let frame = shared("volumes/plume48/fluid_data_0030.vdb");
    let out = dir.path().join("styled.vdb");
    let o = nst3d(&["--threads", "2", "volume", "--model", s(&model), "--input", s(&frame), "--out", s(&out)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stdout).contains("stylized by the Density-mode model"));
    // A model of today's training gets neither note about older models.
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!err.contains("scale pin") && !err.contains("z axis only"), "{err}");
    let styled = nst3d_io::vdb::read_vdb(&out).unwrap();
    let (_, d) = styled.grid("density").unwrap().to_dense().unwrap();
    assert!(d.data.iter().all(|v| v.is_finite()) && d.max() > 0.0);
    // Tiles smaller than the frame (the equality of tiled and untiled
    // inference is network::tiled's test).
    let tiled = dir.path().join("tiled.vdb");
    let o = nst3d(&[
        "--threads",
        "2",
        "volume",
        "--model",
        s(&model),
        "--input",
        s(&frame),
        "--out",
        s(&tiled),
        "--tile",
        "8",
        "--tile-margin",
        "8",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    let bad = dir.path().join("bad.vdb");
    let run = |extra: &[&str]| {
        let mut a = vec!["volume", "--input", s(&frame), "--out", s(&bad)];
        a.extend_from_slice(extra);
        nst3d(&a)
    };
    fails_with(&run(&["--model", s(&model), "--mode", "velocity"]), &bad, "Density-mode model");
    fails_with(&run(&["--model", s(&model), "--tile", "16", "--tile-margin", "32"]), &bad, "--tile");
    let mut bytes = std::fs::read(&model).unwrap();
    let n = bytes.len();
    bytes[n - 4..].copy_from_slice(&f32::NAN.to_le_bytes());
    let nan = dir.path().join("nan.safetensors");
    std::fs::write(&nan, &bytes).unwrap();
    fails_with(&run(&["--model", s(&nan)]), &bad, "non-finite");
    std::fs::write(&nan, &bytes[..n / 2]).unwrap();
    fails_with(&run(&["--model", s(&nan)]), &bad, "nan.safetensors");
    // Metadata that promises other widths than the tensors have.
    let mut wider = std::fs::read(&model).unwrap();
    let key = b"\"channels\":\"2\"";
    let at = wider.windows(key.len()).position(|w| w == key).expect("channels in the header");
    wider[at + key.len() - 2] = b'3';
    let widths = dir.path().join("widths.safetensors");
    std::fs::write(&widths, &wider).unwrap();
    fails_with(&run(&["--model", s(&widths)]), &bad, "channels 3");
    let empty = shared("volumes/smoke_000001.vdb");
    let o = nst3d(&["volume", "--model", s(&model), "--input", s(&empty), "--out", s(&bad)]);
    fails_with(&o, &bad, "empty");
}

/// A training process killed between two checkpoints (SIGKILL: no chance
/// to write anything) resumes from the last checkpoint and ends with the
/// same model, byte for byte, as a run never interrupted.
#[test]
fn a_training_killed_between_checkpoints_resumes_to_the_same_model() {
    use std::io::{BufRead, BufReader};
    use std::process::{Command, Stdio};
    let dir = tempfile::tempdir().unwrap();
    let plume = shared("volumes/plume48").join("fluid_data_####.vdb");
    let style = shared("styles/starry_night.jpg");
    let args = |out: &Path| -> Vec<String> {
        [
            "--threads",
            "1",
            "train",
            "--input",
            s(&plume),
            "--frames",
            "20-22",
            "--style",
            s(&style),
            "--out",
            s(out),
            "--steps",
            "9",
            "--checkpoint-every",
            "3",
            "--patch",
            "16",
            "--channels",
            "2",
        ]
        .iter()
        .map(|a| a.to_string())
        .collect()
    };
    let whole = dir.path().join("whole.safetensors");
    let o = Command::new(env!("CARGO_BIN_EXE_nst3d")).args(args(&whole)).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    let killed = dir.path().join("killed.safetensors");
    let mut child = Command::new(env!("CARGO_BIN_EXE_nst3d"))
        .args(args(&killed))
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Step 4 is past the checkpoint of step 3 and before the one of step 6.
    let mut seen = false;
    for line in BufReader::new(child.stderr.take().unwrap()).lines() {
        if line.unwrap().contains("step 4/9") {
            seen = true;
            child.kill().unwrap();
            break;
        }
    }
    child.wait().unwrap();
    assert!(seen, "never saw step 4 in the progress lines");
    let ckpt = nst3d_train::job::checkpoint_path(&killed);
    assert!(ckpt.exists(), "no checkpoint left by the killed run");

    let o = Command::new(env!("CARGO_BIN_EXE_nst3d")).args(args(&killed)).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("resuming at step 4 of 9"), "did not resume from the step-3 checkpoint: {err}");
    assert!(String::from_utf8_lossy(&o.stdout).contains("(resumed at step 4)"));
    assert_eq!(std::fs::read(&whole).unwrap(), std::fs::read(&killed).unwrap(), "the resumed model differs");
}

/// A model trained with a solid texture (`--texture`) writes it into the
/// model file, and its result does not depend on the tiles: the texture is
/// fixed in the frame's index space, as the network's stride lattice is.
#[test]
fn a_textured_model_is_seamless_across_tiles() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("t.safetensors");
    let plume = shared("volumes/plume48").join("fluid_data_####.vdb");
    let (style, frames) = (shared("styles/starry_night.jpg"), "20-22");
    let train = ["train", "--input", s(&plume), "--frames", frames, "--style", s(&style), "--out", s(&model)];
    let small = ["--steps", "3", "--patch", "16", "--channels", "2", "--texture", "12"];
    let o = nst3d(&[&["--threads", "2"][..], &train, &small].concat());
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let m = nst3d_network::Model::from_bytes(&std::fs::read(&model).unwrap(), &model).unwrap();
    assert_eq!(m.texture.as_ref().map(|t| t.period), Some(12));

    let frame = shared("volumes/plume48/fluid_data_0030.vdb");
    let dense = |extra: &[&str], name: &str| {
        let out = dir.path().join(name);
        let mut a = vec!["--threads", "2", "volume", "--model", s(&model), "--input", s(&frame), "--out", s(&out)];
        a.extend_from_slice(extra);
        let o = nst3d(&a);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        nst3d_io::vdb::read_vdb(&out).unwrap().grid("density").unwrap().to_dense().unwrap()
    };
    let whole = dense(&[], "whole.vdb");
    let tiled = dense(&["--tile", "32", "--tile-margin", "32"], "tiled.vdb");
    assert_eq!(whole.0, tiled.0);
    let worst = whole.1.data.iter().zip(&tiled.1.data).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    assert!(worst <= 1e-6 * whole.1.max(), "tiles change the result by {worst}");
    // Refused: a period the texture cannot have.
    let bad = dir.path().join("bad.safetensors");
    let o = nst3d(&[
        "train",
        "--input",
        s(&plume),
        "--frames",
        frames,
        "--style",
        s(&style),
        "--out",
        s(&bad),
        "--texture",
        "1",
    ]);
    fails_with(&o, &bad, "--texture");
}
