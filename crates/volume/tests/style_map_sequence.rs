//! A style map over a sequence: each frame reads its own map (here the
//! plume's temperature), each region of each written frame moves toward
//! the painting the map gives it, and a map that one frame lacks fails the
//! job before anything is written.

use std::path::{Path, PathBuf};

use nst3d_stylize::Mode;
use nst3d_volume::{
    judge_map, stylize_frame_file, stylize_sequence_files, JudgeSettings, SequenceReport, SequenceSettings, Silent,
    Upsample, VolumeSettings,
};

fn shared(rel: &str) -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data").join(rel);
    assert!(p.exists(), "shared test data missing: {} (the repo expects ../shared beside it)", p.display());
    p
}

fn frames() -> PathBuf {
    shared("volumes/plume48").join("fluid_data_####.vdb")
}

/// Two stripe paintings, horizontal (`h.png`) and vertical (`v.png`):
/// Gram matrices tell their strokes apart at once, where two real
/// paintings on a grid this small move any region toward both alike.
fn stripes(dir: &Path) -> [PathBuf; 2] {
    let n = 128;
    let draw = |horizontal: bool| {
        let mut img = nst3d_core::Image::zeros(3, n, n);
        for (i, v) in img.data.iter_mut().enumerate() {
            let (y, x) = ((i / n) % n, i % n);
            *v = if (if horizontal { y } else { x } / 8) % 2 == 1 { 0.9 } else { 0.1 };
        }
        img
    };
    let paths = [dir.join("h.png"), dir.join("v.png")];
    for (p, horizontal) in paths.iter().zip([true, false]) {
        nst3d_io::image::write_png(p, &draw(horizontal)).unwrap();
    }
    paths
}

/// Two paintings on frames 20 and 21 (or frame 21 alone), split by each
/// frame's temperature, small enough for a test.
fn settings(paintings: [&Path; 2], out: PathBuf, frames: Option<&str>) -> VolumeSettings {
    let input = match frames {
        Some(_) => self::frames(),
        None => shared("volumes/plume48/fluid_data_0021.vdb"),
    };
    let mut s = VolumeSettings::new(input, paintings[0], out);
    s.more_styles = vec![paintings[1].to_path_buf()];
    s.style_map = Some("temperature".into());
    s.mode = Mode::Density;
    s.iters = 6;
    s.octaves = Some(1);
    s.upsample = Upsample::Factor(1);
    s.sequence = frames.map(|f| SequenceSettings { frames: f.into(), ..SequenceSettings::default() });
    s
}

/// Judged from the optimised (front) camera: `[region][painting]`, the
/// loss ratio of `result` to the input `frame`, against `paintings`.
fn ratios(paintings: &[PathBuf; 2], frame: &Path, result: &Path) -> Vec<Vec<f32>> {
    let mut j = JudgeSettings::new(&paintings[0], frame, vec![result.to_path_buf()]);
    j.more_styles = vec![paintings[1].clone()];
    j.cameras = "front".into();
    let v = judge_map(&j, "temperature", false, &mut Silent).unwrap();
    v[0].regions
        .iter()
        .map(|r| r.iter().map(|p| p.as_ref().expect("the front view shows it").mean()).collect())
        .collect()
}

/// Each region is nearer the painting the map gave it than the result in
/// which the map gave it the other painting (`ba`, the paintings
/// swapped), and farther from the other painting.
fn follows_the_map(paintings: &[PathBuf; 2], frame: &Path, (ab, ba): (&Path, &Path), what: &str) {
    let (ab, ba) = (ratios(paintings, frame, ab), ratios(paintings, frame, ba));
    // Region 0 took painting 0 in `ab` and painting 1 in `ba`; region 1 the reverse.
    for (r, own) in [(0, 0), (1, 1)] {
        let other = 1 - own;
        assert!(ab[r][own] < ba[r][own], "{what}: region {r}, its painting: {ab:?} against swapped {ba:?}");
        assert!(ab[r][other] > ba[r][other], "{what}: region {r}, the other painting: {ab:?} against swapped {ba:?}");
    }
}

#[test]
fn a_sequence_with_a_map_puts_each_painting_in_its_region() {
    let dir = tempfile::tempdir().unwrap();
    let [h, v] = stripes(dir.path());
    let out = |name: &str| dir.path().join(name);
    for (paintings, name) in [([h.as_path(), &v], "ab_####.vdb"), ([v.as_path(), &h], "ba_####.vdb")] {
        let report = stylize_sequence_files(&settings(paintings, out(name), Some("20-21")), &mut Silent).unwrap();
        assert!(matches!(report, SequenceReport::Done(ref d) if d.stylized == 2 && d.flicker > 0.0), "{report:?}");
    }
    let paintings = [h.clone(), v.clone()];
    for f in [20, 21] {
        let frame = shared(&format!("volumes/plume48/fluid_data_{f:04}.vdb"));
        let (ab, ba) = (out(&format!("ab_{f:04}.vdb")), out(&format!("ba_{f:04}.vdb")));
        follows_the_map(&paintings, &frame, (&ab, &ba), &format!("sequence frame {f}"));
    }
    // The same check on frame 21 stylized alone.
    for (p, name) in [([h.as_path(), &v], "ab.vdb"), ([v.as_path(), &h], "ba.vdb")] {
        stylize_frame_file(&settings(p, out(name), None), &mut Silent).unwrap();
    }
    let frame = shared("volumes/plume48/fluid_data_0021.vdb");
    follows_the_map(&paintings, &frame, (&out("ab.vdb"), &out("ba.vdb")), "single frame 21");
}

/// A map grid one frame lacks (a per-frame map file that is another
/// simulation's) or a missing map file: one error naming the frame, before
/// any frame is written or the work folder made.
#[test]
fn a_map_missing_in_one_frame_fails_before_writing() {
    let dir = tempfile::tempdir().unwrap();
    let maps = dir.path().join("maps");
    std::fs::create_dir(&maps).unwrap();
    std::fs::copy(shared("volumes/plume48/fluid_data_0020.vdb"), maps.join("m_0020.vdb")).unwrap();
    std::fs::copy(shared("volumes/smoke_000003.vdb"), maps.join("m_0021.vdb")).unwrap();
    let pattern = maps.join("m_####.vdb");
    let (a, b) = (shared("styles/starry_night.jpg"), shared("styles/shipwreck.jpg"));
    for (frames, needle) in [("20-21", "frame 21: --style-map"), ("20-22", "frame 21: --style-map")] {
        let out = dir.path().join("out");
        let mut s = settings([a.as_path(), &b], out.join("o_####.vdb"), Some(frames));
        s.style_map = Some(format!("{}:temperature", pattern.display()));
        let e = stylize_sequence_files(&s, &mut Silent).unwrap_err();
        let line = nst3d_core::report::one_line(e.as_ref());
        assert!(line.contains(needle) && line.contains("no grid named 'temperature'"), "{line}");
        assert!(!line.contains('\n'));
        assert!(!out.exists(), "nothing is written, not even the work folder");
    }
    // A farm chunk reads its warm-up frames' maps too, each its own frame's.
    let out = dir.path().join("out");
    let mut s = settings([a.as_path(), &b], out.join("o_####.vdb"), Some("20-22"));
    s.style_map = Some(format!("{}:temperature", pattern.display()));
    let seq = s.sequence.as_mut().unwrap();
    (seq.chunk, seq.warmup) = (Some("22-22".into()), 1);
    let line = nst3d_core::report::one_line(stylize_sequence_files(&s, &mut Silent).unwrap_err().as_ref());
    assert!(line.contains("frame 21: --style-map") && line.contains("m_0021.vdb"), "{line}");
    assert!(!out.exists());
    // Frame 22's map file does not exist at all.
    std::fs::copy(shared("volumes/plume48/fluid_data_0021.vdb"), maps.join("m_0021.vdb")).unwrap();
    let out = dir.path().join("out");
    let mut s = settings([a.as_path(), &b], out.join("o_####.vdb"), Some("20-22"));
    s.style_map = Some(format!("{}:temperature", pattern.display()));
    let line = nst3d_core::report::one_line(stylize_sequence_files(&s, &mut Silent).unwrap_err().as_ref());
    assert!(line.contains("frame 22") && line.contains("m_0022.vdb"), "{line}");
    assert!(!out.exists());
}
