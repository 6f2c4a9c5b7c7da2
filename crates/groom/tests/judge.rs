//! The groom judge's sanity, with the real VGG-19 and a shared painting: the tone-matched
//! hair-only score does not call a darker or brighter copy of a picture
//! nearer the painting, where the plain hair-only score does.

use std::path::{Path, PathBuf};

use nst3d_core::Image;
use nst3d_groom::judge::GramJudge;

fn shared(rel: &str) -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data").join(rel);
    assert!(p.exists(), "shared test data missing: {} (the repo expects ../shared beside it)", p.display());
    p
}

/// A grey picture of bright diagonal "strands" (0.3–0.9) in a disc on
/// black: every hair pixel far above the hair threshold, so darkening by
/// half keeps the same hair pixels.
fn strands(h: usize, w: usize) -> Image {
    let mut img = Image::zeros(1, h, w);
    for y in 0..h {
        for x in 0..w {
            let (dy, dx) = (y as f32 - h as f32 / 2.0, x as f32 - w as f32 / 2.0);
            if dx * dx + dy * dy < (0.35 * h as f32).powi(2) {
                let t = ((x + 2 * y) as f32 * 0.7).sin() * 0.5 + 0.5;
                img.data[y * w + x] = 0.3 + 0.6 * t;
            }
        }
    }
    img
}

#[test]
fn tone_matched_hair_score_ignores_exposure() {
    let (h, w) = (96, 128);
    let judge = GramJudge::new(&shared("styles/starry_night.jpg"), h, None).unwrap();
    let pic = strands(h, w);
    let mut dark = pic.clone();
    dark.data.iter_mut().for_each(|v| *v *= 0.5);

    let toned = judge.toned_hair_loss(&pic).unwrap().unwrap();
    let toned_dark = judge.toned_hair_loss(&dark).unwrap().unwrap();
    assert!((toned_dark / toned - 1.0).abs() < 1e-3, "tone-matched: {toned} vs darkened {toned_dark}");

    // The plain hair-only score moves with exposure (why the tone-matched one exists).
    let plain = judge.hair_loss(&pic).unwrap().unwrap();
    let plain_dark = judge.hair_loss(&dark).unwrap().unwrap();
    assert!((plain_dark / plain - 1.0).abs() > 0.05, "plain hair-only: {plain} vs darkened {plain_dark}");
}
