//! `nst3d strands --style-map` end to end on the shared Bangs groom: a map
//! that gives every strand one painting is that painting's run byte for
//! byte, a split map is neither painting's run, and every bad map is one
//! line.

mod common;
use common::{assert_fails, s, shared, small_strands};

use std::path::Path;
use std::process::Output;

use nst3d_io::groom::read_groom;

/// The Bangs groom with Starry Night and The Shipwreck shared by `map`
/// (a `.txt` of one value per strand) and `extra`.
fn mapped(dir: &Path, map: &str, out: &Path, extra: &[&str]) -> Output {
    let path = dir.join("map.txt");
    std::fs::write(&path, map).unwrap();
    let ship = shared("styles/shipwreck.jpg");
    let mut args = vec!["--style", s(&ship), "--style-map", s(&path)];
    args.extend_from_slice(extra);
    small_strands(&shared("grooms/Bangs_100.hair"), Some(&shared("grooms/Bangs_head.ply")), out, &args)
}

/// One value per Bangs strand: `f(i)` for strand `i` of 100.
fn values(f: impl Fn(usize) -> f32) -> String {
    (0..100).map(|i| format!("{}\n", f(i))).collect()
}

#[test]
fn a_map_of_one_painting_is_that_paintings_run_and_a_split_is_neither() {
    let dir = tempfile::tempdir().unwrap();
    let (single, all_first, split) =
        (dir.path().join("single.ply"), dir.path().join("all_first.ply"), dir.path().join("split.ply"));
    let o = small_strands(&shared("grooms/Bangs_100.hair"), Some(&shared("grooms/Bangs_head.ply")), &single, &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = mapped(dir.path(), &values(|_| 0.0), &all_first, &["--style-map-labels"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(std::fs::read(&single).unwrap(), std::fs::read(&all_first).unwrap());

    let preview = dir.path().join("split.png");
    let o = mapped(dir.path(), &values(|i| (i >= 50) as u8 as f32), &split, &["--preview", s(&preview)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (a, b) = (read_groom(&single).unwrap(), read_groom(&split).unwrap());
    assert_eq!(a.strand_count(), b.strand_count());
    assert_ne!(a.strands, b.strands, "a split map gave the first painting's groom");
    // The preview: map | result | two paintings, side by side.
    let png = image::open(&preview).unwrap();
    assert!(png.width() >= 4 * png.height() - 8, "{}x{}", png.width(), png.height());
}

#[test]
fn bad_style_maps_give_one_line_errors() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.ply");
    let bangs = (shared("grooms/Bangs_100.hair"), shared("grooms/Bangs_head.ply"));
    let one = small_strands(&bangs.0, Some(&bangs.1), &out, &["--style-map", "@height"]);
    assert_fails(&one, &out, "needs two or more paintings");
    let ship = shared("styles/shipwreck.jpg");
    let two = small_strands(&bangs.0, Some(&bangs.1), &out, &["--style", s(&ship)]);
    assert_fails(&two, &out, "need a --style-map");
    assert_fails(&mapped(dir.path(), &values(|_| 0.5), &out, &["--style-map-labels"]), &out, "names no painting");
    assert_fails(&mapped(dir.path(), &values(|i| i as f32), &out, &[]), &out, "outside [0, 1]");
    assert_fails(&mapped(dir.path(), "0 1 0", &out, &[]), &out, "3 values for 100 strands");
    assert_fails(&mapped(dir.path(), "0 x", &out, &[]), &out, "is not a number: x");
    let prop = small_strands(&bangs.0, Some(&bangs.1), &out, &["--style", s(&ship), "--style-map", "side"]);
    assert_fails(&prop, &out, "is read from a .ply or USD groom");
    let ply = small_strands(
        &shared("grooms/Bangs_100_binary.ply"),
        Some(&bangs.1),
        &out,
        &["--style", s(&ship), "--style-map", "side"],
    );
    assert_fails(&ply, &out, "no scalar strand or vertex property 'side'");
}
