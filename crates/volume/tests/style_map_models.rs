//! A style map over trained models: every model stylizes the frame and the
//! results are blended voxel by voxel by the map's weights, so a label map
//! gives each region exactly its own model's result and a height ramp
//! their mix.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use nst3d_io::vdb::{read_vdb, GridValues};
use nst3d_volume::{stylize_with_model, ModelSettings, Silent, VolumeSettings};

fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..").join(rel)
}

fn frame() -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/volumes/plume48/fluid_data_0030.vdb");
    assert!(p.exists(), "shared test data missing: {} (the repo expects ../shared beside it)", p.display());
    p
}

/// `models` on plume frame 30 into `out`, split by `map` if any.
fn run(models: &[&str], map: Option<&str>, out: &Path) -> anyhow::Result<()> {
    let mut s = VolumeSettings::new(frame(), "", out);
    let mut m = ModelSettings::new(repo(models[0]));
    m.more = models[1..].iter().map(|p| repo(p)).collect();
    s.model = Some(m.clone());
    s.style_map = map.map(String::from);
    stylize_with_model(&s, &m, &mut Silent).map(|_| ())
}

/// The density grid's active voxels.
fn voxels(path: &Path) -> HashMap<[i32; 3], f32> {
    let file = read_vdb(path).unwrap();
    let GridValues::Float(g) = &file.grid("density").unwrap().values else { panic!("a float grid") };
    g.iter_active().collect()
}

const A: &str = "models/starry_density.safetensors";
const B: &str = "models/shipwreck_density.safetensors";

#[test]
fn each_region_gets_its_models_result() {
    let dir = tempfile::tempdir().unwrap();
    let path = |n: &str| dir.path().join(n);
    run(&[A], None, &path("a.vdb")).unwrap();
    run(&[B], None, &path("b.vdb")).unwrap();
    run(&[A, B], Some("@height-split"), &path("split.vdb")).unwrap();
    run(&[A, B], Some("@height"), &path("ramp.vdb")).unwrap();
    let (a, b) = (voxels(&path("a.vdb")), voxels(&path("b.vdb")));
    // The ramp spans the input's smoke along z (up).
    let input = read_vdb(&frame()).unwrap();
    let (lo, hi) = input.grid("density").unwrap().active_bbox().unwrap();
    let h = |ijk: [i32; 3]| ((ijk[2] - lo[2]) as f32 / (hi[2] - lo[2]) as f32).clamp(0.0, 1.0);
    let at = |g: &HashMap<[i32; 3], f32>, ijk: &[i32; 3]| g.get(ijk).copied().unwrap_or(0.0);
    let (split, ramp) = (voxels(&path("split.vdb")), voxels(&path("ramp.vdb")));
    let mut seen = [0, 0];
    for ijk in a.keys().chain(b.keys()) {
        let upper = h(*ijk) >= 0.5;
        seen[upper as usize] += 1;
        let want = if upper { at(&b, ijk) } else { at(&a, ijk) };
        assert_eq!(at(&split, ijk), want, "{ijk:?}");
        let mix = (1.0 - h(*ijk)) * at(&a, ijk) + h(*ijk) * at(&b, ijk);
        assert!((at(&ramp, ijk) - mix).abs() <= 1e-5 * mix.max(1.0), "{ijk:?}: {} vs {mix}", at(&ramp, ijk));
    }
    assert!(seen[0] > 100 && seen[1] > 100, "both regions hold smoke: {seen:?}");
    assert!(a.iter().any(|(k, v)| (v - at(&b, k)).abs() > 1e-3), "the two models differ");
}

/// One model with a map, two without, or models of two modes: one error
/// line each, before anything is written.
#[test]
fn models_and_maps_that_do_not_fit_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o.vdb");
    for (models, map, needle) in [
        (&[A][..], Some("@height"), "at least two --model files"),
        (&[A, B][..], None, "2 --model files need a --style-map"),
        (&[A, "models/starry_velocity.safetensors"][..], Some("@height"), "blends models of one mode"),
        (&[A, B][..], Some("nope"), "no grid named 'nope'"),
    ] {
        let e = run(models, map, &out).unwrap_err();
        let line = nst3d_core::report::one_line(e.as_ref());
        assert!(line.contains(needle), "{line}");
        assert!(!out.exists());
    }
}
