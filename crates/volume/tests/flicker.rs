//! `flicker_of_outputs` scores written frames exactly as an optimised
//! sequence scores itself, so feed-forward and optimised sequences can be
//! compared with one metric (docs/design/feedforward.md).

use std::path::{Path, PathBuf};

use nst3d_stylize::Mode;
use nst3d_volume::{
    flicker_of_outputs, stylize_sequence_files, SequenceReport, SequenceSettings, Silent, Upsample, VolumeSettings,
};

fn shared(rel: &str) -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data").join(rel);
    assert!(p.exists(), "shared test data missing: {} (the repo expects ../shared beside it)", p.display());
    p
}

#[test]
fn written_frames_score_the_flicker_the_run_reported() {
    let dir = tempfile::tempdir().unwrap();
    let mut s = VolumeSettings::new(
        shared("volumes/plume48").join("fluid_data_####.vdb"),
        shared("styles/starry_night.jpg"),
        dir.path().join("styled_####.vdb"),
    );
    s.mode = Mode::Density;
    s.iters = 2;
    s.octaves = Some(1);
    s.upsample = Upsample::Factor(1);
    s.sequence = Some(SequenceSettings { frames: "20-23".into(), ema: 0.0, ..SequenceSettings::default() });
    let reported = match stylize_sequence_files(&s, &mut Silent).unwrap() {
        SequenceReport::Done(d) => d.flicker,
        SequenceReport::NothingToDo { .. } => panic!("nothing was stylized"),
    };
    let scored = flicker_of_outputs(&s, &mut Silent).unwrap().expect("three pairs of frames");
    assert!(reported > 0.0);
    assert!((scored - reported).abs() <= 1e-6 * reported.max(1.0), "scored {scored} vs reported {reported}");
}
