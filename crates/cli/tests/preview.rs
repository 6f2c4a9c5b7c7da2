//! `nst3d preview` end to end on the shared smoke files: every mode writes the
//! pictures it promises (upright, centred, one size per set), and every bad
//! input is one error line with nothing left on disk.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn shared(rel: &str) -> PathBuf {
    let p = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data/volumes")).join(rel);
    // A pattern is checked through its first frame.
    let probe = p.to_string_lossy().replace("####", "0001").replace('#', "1");
    assert!(Path::new(&probe).exists(), "shared test data missing: {probe} (the repo expects ../shared beside it)");
    p
}

fn plume(frame: u32) -> PathBuf {
    shared(&format!("plume48/fluid_data_{frame:04}.vdb"))
}

fn nst3d(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_nst3d")).arg("preview").args(args).output().expect("run nst3d")
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn ok(o: &Output) -> String {
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "nst3d preview failed: {err}");
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// Grey levels of a PNG, row-major, with its width and height.
fn grey(p: &Path) -> (Vec<f32>, usize, usize) {
    let img = image::open(p).unwrap_or_else(|e| panic!("{}: {e}", p.display())).to_rgb8();
    let (w, h) = (img.width() as usize, img.height() as usize);
    (img.pixels().map(|px| px.0.iter().map(|&c| c as f32).sum::<f32>() / (3.0 * 255.0)).collect(), w, h)
}

/// Brightness-weighted centre of a picture in `[0, 1]²` (x right, y down).
fn centroid(p: &Path) -> [f32; 2] {
    let (g, w, h) = grey(p);
    let (mut sx, mut sy, mut sum) = (0.0, 0.0, 0.0);
    for (i, v) in g.iter().enumerate() {
        sx += v * ((i % w) as f32 + 0.5) / w as f32;
        sy += v * ((i / w) as f32 + 0.5) / h as f32;
        sum += v;
    }
    assert!(sum > 0.0, "{} is black", p.display());
    [sx / sum, sy / sum]
}

/// Files in `dir`, sorted.
fn listing(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .map(|r| r.filter_map(|e| e.ok()).map(|e| e.file_name().to_string_lossy().into_owned()).collect())
        .unwrap_or_default();
    v.sort();
    v
}

/// A clean failure: exit 1, one line naming `needle`, no panic, nothing written in `dir`.
fn assert_fails(o: &Output, dir: &Path, needle: &str) {
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "expected exit 1, stderr: {err}");
    let lines: Vec<&str> = err.lines().collect();
    assert_eq!(lines.len(), 1, "expected one error line, got: {err}");
    assert!(lines[0].starts_with("nst3d: error: "), "not an error line: {err}");
    assert!(lines[0].contains(needle), "error should mention '{needle}': {err}");
    assert!(!err.contains("panicked") && !err.contains("internal error"), "panic: {err}");
    assert!(listing(dir).is_empty(), "a failed run left files: {:?}", listing(dir));
}

#[test]
fn front_view_is_upright_and_centred() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("preview.png");
    let msg = ok(&nst3d(&["--input", s(&plume(30)), "--out", s(&out)]));
    assert!(msg.contains("wrote 1 preview picture") && msg.contains("absorption"), "{msg}");
    let (g, w, h) = grey(&out);
    assert_eq!(h, 384);
    // plume48's box is 32 wide by 48 high at most: a portrait picture.
    assert!((150..384).contains(&w), "width {w}");
    // Smoke is there but not flat white (auto absorption: optical depth 3 at most).
    let lit = g.iter().filter(|&&v| v > 0.1).count() as f32 / g.len() as f32;
    assert!((0.15..0.9).contains(&lit), "lit fraction {lit}");
    assert!(g.iter().cloned().fold(0.0, f32::max) > 0.6);
    // Centred left-right; the z-up plume's cap rises, so its top half is the heavier one.
    let [cx, _] = centroid(&out);
    assert!((cx - 0.5).abs() < 0.08, "not centred: x {cx}");
    let rows = |r: std::ops::Range<usize>| r.map(|y| g[y * w..][..w].iter().sum::<f32>()).sum::<f32>();
    assert!(rows(0..h / 3) > rows(2 * h / 3..h), "cap should be at the top");

    // Other cameras, axes and sizes render too.
    let small = dir.path().join("small.png");
    ok(&nst3d(&["--input", s(&plume(30)), "--out", s(&small), "--camera", "orthographic", "--height", "96"]));
    assert_eq!(grey(&small).2, 96);
    let yup = dir.path().join("yup.png");
    ok(&nst3d(&["--input", s(&shared("smoke_000003.vdb")), "--out", s(&yup), "--up", "y", "--absorption", "0.05"]));
    assert_eq!(grey(&yup).2, 384);
}

#[test]
fn turntable_writes_one_equal_sized_picture_per_camera() {
    let dir = tempfile::tempdir().unwrap();
    let pattern = dir.path().join("turn_####.png");
    let msg = ok(&nst3d(&["--input", s(&shared("smoke_000003.vdb")), "--turntable", "4", "--out", s(&pattern)]));
    assert!(msg.contains("wrote 4 preview pictures"), "{msg}");
    assert_eq!(listing(dir.path()), ["turn_0001.png", "turn_0002.png", "turn_0003.png", "turn_0004.png"]);
    let sizes: Vec<(usize, usize)> = listing(dir.path())
        .iter()
        .map(|f| {
            let (_, w, h) = grey(&dir.path().join(f));
            (w, h)
        })
        .collect();
    assert!(sizes.iter().all(|&sz| sz == sizes[0]), "flipbook sizes differ: {sizes:?}");
    assert_eq!(sizes[0].1, 384);
    // Every view sees the smoke near the middle of the canvas.
    for f in listing(dir.path()) {
        let [cx, _] = centroid(&dir.path().join(&f));
        assert!((cx - 0.5).abs() < 0.15, "{f} off centre: {cx}");
    }
    // The first turntable view is the front view.
    let front = dir.path().join("front.png");
    ok(&nst3d(&["--input", s(&shared("smoke_000003.vdb")), "--out", s(&front), "--camera", "orthographic"]));
    let first = dir.path().join("o_#.png");
    ok(&nst3d(&[
        "--input",
        s(&shared("smoke_000003.vdb")),
        "--out",
        s(&first),
        "--camera",
        "orthographic",
        "--turntable",
        "1",
        "--elevation",
        "0",
    ]));
    let (a, wa, ha) = grey(&front);
    let (b, wb, hb) = grey(&dir.path().join("o_1.png"));
    assert_eq!((wa, ha), (wb, hb));
    let diff = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).sum::<f32>() / a.len() as f32;
    assert!(diff < 0.02, "turntable view 1 differs from the front view by {diff}");
}

#[test]
fn compare_sheet_uses_one_camera_and_absorption() {
    let dir = tempfile::tempdir().unwrap();
    let single = dir.path().join("single.png");
    ok(&nst3d(&["--input", s(&plume(30)), "--out", s(&single)]));
    let (one, w1, h1) = grey(&single);

    // A file compared with itself: two identical halves around a thin bar.
    let sheet = dir.path().join("sheet.png");
    ok(&nst3d(&["--input", s(&plume(30)), "--compare", s(&plume(30)), "--out", s(&sheet)]));
    let (g, w, h) = grey(&sheet);
    assert_eq!(h, h1);
    assert!(w > 2 * w1 && w <= 2 * w1 + 8, "sheet width {w} for pictures {w1} wide");
    let right = w - w1;
    for y in 0..h {
        for x in 0..w1 {
            assert_eq!(g[y * w + x], g[y * w + right + x], "halves differ at ({x}, {y})");
            assert_eq!(g[y * w + x], one[y * w1 + x], "left half differs from the single picture");
        }
    }

    // Different boxes line up in their union, and the input alone sets γ:
    // the young puff of frame 10 stays inside the frame-30 plume's picture.
    let mixed = dir.path().join("mixed.png");
    let msg = ok(&nst3d(&["--input", s(&plume(10)), "--compare", s(&plume(30)), "--out", s(&mixed)]));
    let alone = ok(&nst3d(&["--input", s(&plume(10)), "--out", s(&dir.path().join("ten.png"))]));
    let gamma = |m: &str| m.rsplit("absorption ").next().unwrap().trim().to_string();
    let (_, wm, _) = grey(&mixed);
    assert!(wm > 2 * 100, "mixed sheet width {wm}");
    assert!(!gamma(&msg).is_empty());
    // γ is from frame 10 in both runs up to the perspective of a larger box.
    let (g1, g2): (f32, f32) = (gamma(&msg).parse().unwrap(), gamma(&alone).parse().unwrap());
    assert!((g1 / g2 - 1.0).abs() < 0.25, "compare γ {g1} vs alone {g2}");
}

#[test]
fn sequence_writes_one_picture_per_frame_with_a_fixed_camera_and_gamma() {
    let dir = tempfile::tempdir().unwrap();
    let input = shared("plume48/fluid_data_####.vdb");
    let out = dir.path().join("prev/p_####.png");
    let msg = ok(&nst3d(&["--input", s(&input), "--frames", "1-40:13", "--out", s(&out)]));
    assert!(msg.contains("wrote 4 preview pictures"), "{msg}");
    let prev = dir.path().join("prev");
    assert_eq!(listing(&prev), ["p_0001.png", "p_0014.png", "p_0027.png", "p_0040.png"]);
    let pics: Vec<_> = listing(&prev).iter().map(|f| grey(&prev.join(f))).collect();
    assert!(pics.iter().all(|p| (p.1, p.2) == (pics[0].1, pics[0].2)), "frame sizes differ");
    // Fixed camera: the plume grows upwards from the same inflow, so the lit
    // area grows and the brightness centre rises frame by frame.
    let lit: Vec<usize> = pics.iter().map(|p| p.0.iter().filter(|&&v| v > 0.1).count()).collect();
    assert!(lit.windows(2).all(|w| w[0] < w[1]), "lit areas {lit:?}");
    let ys: Vec<f32> = listing(&prev).iter().map(|f| centroid(&prev.join(f))[1]).collect();
    assert!(ys.windows(2).all(|w| w[0] > w[1]), "centroid heights {ys:?}");
    // γ from the densest frame: no frame turns flat white.
    for (f, p) in listing(&prev).iter().zip(&pics) {
        let white = p.0.iter().filter(|&&v| v > 0.98).count() as f32 / p.0.len() as f32;
        assert!(white < 0.05, "{f} is {white:.2} white");
    }

    // Side by side per frame, and empty frames render black instead of failing.
    let cmp = dir.path().join("cmp/c_%04d.png");
    ok(&nst3d(&["--input", s(&input), "--frames", "5,6", "--compare", s(&input), "--out", s(&cmp)]));
    assert_eq!(listing(&dir.path().join("cmp")), ["c_0005.png", "c_0006.png"]);
    assert!(grey(&dir.path().join("cmp/c_0005.png")).1 > 2 * pics[0].1);
    let smoke = shared("smoke_00000#.vdb");
    let msg = ok(&nst3d(&["--input", s(&smoke), "--frames", "1-3", "--out", s(&dir.path().join("sm/s_#.png"))]));
    assert!(msg.contains("wrote 3"), "{msg}");
    let (first, ..) = grey(&dir.path().join("sm/s_1.png"));
    assert!(first.iter().all(|&v| v == 0.0), "the empty frame should be black");
}

#[test]
fn bad_inputs_give_one_line_errors_and_no_files() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("out");
    std::fs::create_dir(&dir).unwrap();
    let out = dir.join("p.png");
    let pat = dir.join("p_####.png");
    let frames = shared("plume48/fluid_data_####.vdb");
    let f1 = plume(1);
    let (jpg, empty, empty_frames) =
        (shared("../styles/shipwreck.jpg"), shared("smoke_000001.vdb"), shared("smoke_00000#.vdb"));
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (vec!["--input", "/nonexistent/missing.vdb", "--out", s(&out)], "missing.vdb"),
        (vec!["--input", s(&jpg), "--out", s(&out)], "not an OpenVDB file"),
        (vec!["--input", s(&f1), "--grid", "smoke", "--out", s(&out)], "no grid named 'smoke'"),
        (vec!["--input", s(&f1), "--grid", "velocity", "--out", s(&out)], "vec3s"),
        (vec!["--input", s(&empty), "--out", s(&out)], "empty"),
        (vec!["--input", s(&f1), "--compare", "/nonexistent/styled.vdb", "--out", s(&out)], "styled.vdb"),
        (vec!["--input", s(&frames), "--out", s(&out)], "give --frames"),
        (vec!["--input", s(&f1), "--frames", "1-3", "--out", s(&pat)], "placeholder"),
        (vec!["--input", s(&frames), "--frames", "1-3", "--out", s(&out)], "placeholder"),
        (vec!["--input", s(&frames), "--frames", "1-3", "--compare", s(&f1), "--out", s(&pat)], "placeholder"),
        (vec!["--input", s(&f1), "--turntable", "3", "--out", s(&out)], "placeholder"),
        (vec!["--input", s(&frames), "--frames", "3-1", "--out", s(&pat)], "bad frame spec"),
        // Frame 41 does not exist: frames 38-40 must not be written either.
        (vec!["--input", s(&frames), "--frames", "38-41", "--out", s(&pat)], "fluid_data_0041.vdb"),
        (vec!["--input", s(&empty_frames), "--frames", "1", "--out", s(&pat)], "empty in every frame"),
        (vec!["--input", s(&f1), "--turntable", "0", "--out", s(&pat)], "--turntable"),
        (vec!["--input", s(&frames), "--frames", "1-2", "--turntable", "2", "--out", s(&pat)], "cannot be combined"),
        (vec!["--input", s(&f1), "--absorption", "-1", "--out", s(&out)], "--absorption"),
        (vec!["--input", s(&f1), "--height", "0", "--out", s(&out)], "--height"),
        (vec!["--input", s(&f1), "--turntable", "2", "--elevation", "95", "--out", s(&pat)], "--elevation"),
    ];
    for (args, needle) in cases {
        assert_fails(&nst3d(&args), &dir, needle);
    }
}

/// A shared groom file.
fn groom(rel: &str) -> PathBuf {
    let p = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data/grooms")).join(rel);
    assert!(p.exists(), "shared test data missing: {} (the repo expects ../shared beside it)", p.display());
    p
}

#[test]
fn a_groom_is_drawn_alone_beside_another_and_around() {
    let dir = tempfile::tempdir().unwrap();
    let (hair, head) = (groom("Bangs_100.hair"), groom("Bangs_head.ply"));
    let one = dir.path().join("bangs.png");
    ok(&nst3d(&["--input", s(&hair), "--mesh", s(&head), "--out", s(&one), "--height", "128"]));
    let (g, w, h) = grey(&one);
    assert_eq!((w, h), (128, 128));
    assert!(g.iter().filter(|&&v| v > 0.05).count() > 200, "the groom is barely drawn");
    let c = centroid(&one);
    assert!((c[0] - 0.5).abs() < 0.2 && (c[1] - 0.5).abs() < 0.2, "groom off centre: {c:?}");

    // Before | after of two formats of the same groom: the halves agree.
    let pair = dir.path().join("pair.png");
    let ply = groom("Bangs_100_binary.ply");
    ok(&nst3d(&["--input", s(&hair), "--compare", s(&ply), "--out", s(&pair), "--height", "96"]));
    let (g, w, h) = grey(&pair);
    assert!(w >= 192 && h == 96, "two pictures side by side: {w}x{h}");
    let half =
        |x0: usize| (0..h).flat_map(|y| (0..96).map(move |x| (y, x0 + x))).map(|(y, x)| g[y * w + x]).sum::<f32>();
    let (l, r) = (half(0), half(w - 96));
    assert!((l - r).abs() < 0.02 * l, "same groom, different pictures: {l} vs {r}");

    let turn = dir.path().join("turn_####.png");
    let out = ok(&nst3d(&["--input", s(&hair), "--out", s(&turn), "--turntable", "3", "--height", "64"]));
    assert!(out.contains("wrote 3 preview pictures"), "{out}");
    assert_eq!(listing(dir.path()).iter().filter(|f| f.starts_with("turn_")).count(), 3);

    // Volume-only settings on a groom are one clear line.
    let o = nst3d(&["--input", s(&hair), "--out", s(&one), "--absorption", "1"]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("apply to volumes"));
}

/// Grass on its ground seen from the side: a head's culling threshold
/// hides every blade (their root normals face up, away from the camera),
/// the grass preset's draws them, as the stylization does.
#[test]
fn a_groom_is_drawn_with_its_preset_s_culling() {
    let dir = tempfile::tempdir().unwrap();
    let (grass, ground) = (dir.path().join("grass.ply"), dir.path().join("ground.ply"));
    let gen = Command::new(env!("CARGO_BIN_EXE_nst3d"))
        .args(["strands", "generate", "grass", "--out", s(&grass), "--mesh-out", s(&ground)])
        .output()
        .unwrap();
    ok(&gen);
    let drawn = |preset: &[&str]| {
        let out = dir.path().join("grass.png");
        let mut args = vec!["--input", s(&grass), "--mesh", s(&ground), "--out", s(&out), "--height", "96"];
        args.extend_from_slice(preset);
        ok(&nst3d(&args));
        grey(&out).0.iter().filter(|&&v| v > 0.05).count()
    };
    assert_eq!(drawn(&[]), 0, "a head's culling is expected to hide grass seen from the side");
    assert!(drawn(&["--preset", "grass"]) > 500, "the grass preset draws the blades");

    let o = nst3d(&["--input", s(&plume(1)), "--preset", "grass", "--out", s(&dir.path().join("v.png"))]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("apply to grooms"));
}

/// The preview's judge: with `--style`, every picture's Gram loss to the
/// painting, and with `--compare` the ratio per picture. The same groom
/// scores 1 everywhere; a z-up copy drawn with `--up z` is the same
/// pictures (the turntable circles the up axis), so the same losses.
#[test]
fn a_groom_is_judged_against_a_painting_from_every_picture() {
    let dir = tempfile::tempdir().unwrap();
    let (hair, head) = (groom("Bangs_100.hair"), groom("Bangs_head.ply"));
    let style = shared("../styles/starry_night.jpg");
    let turn = dir.path().join("j_####.png");
    let args = |input: &Path, mesh: &Path, extra: &[&str]| -> String {
        let mut a = vec!["--input", s(input), "--mesh", s(mesh), "--compare", s(input), "--style", s(&style)];
        a.extend_from_slice(&["--out", s(&turn), "--turntable", "4", "--elevation", "15", "--height", "96"]);
        a.extend_from_slice(extra);
        ok(&nst3d(&a))
    };
    // Both heads through the same writer (no normals: the reader derives them).
    let hy = dir.path().join("head_y.ply");
    nst3d_io::mesh::write_mesh_ply(&hy, &nst3d_io::mesh::read_mesh(&head).unwrap()).unwrap();
    let y = args(&hair, &hy, &[]);
    assert!(y.contains("compare/input per picture 1.000 1.000 1.000 1.000; median 1.000, worst 1.000"), "{y}");
    assert!(y.contains("hair only: compare/input per picture 1.000 1.000 1.000 1.000; median 1.000"), "{y}");
    assert!(
        y.contains("hair only, tone matched: compare/input per picture 1.000 1.000 1.000 1.000; median 1.000"),
        "{y}"
    );

    let to_z = |p: [f32; 3]| nst3d_core::UpAxis::Z.from_y_up(p);
    let mut g = nst3d_io::groom::read_groom(&hair).unwrap();
    g.strands.iter_mut().for_each(|st| st.points.iter_mut().for_each(|p| *p = to_z(*p)));
    let zg = dir.path().join("bangs_z.ply");
    nst3d_io::groom::write_ply_strands(&zg, &g).unwrap();
    let mut m = nst3d_io::mesh::read_mesh(&head).unwrap();
    m.vertices.iter_mut().for_each(|p| *p = to_z(*p));
    let zm = dir.path().join("head_z.ply");
    nst3d_io::mesh::write_mesh_ply(&zm, &m).unwrap();
    let z = args(&zg, &zm, &["--up", "z"]);
    let losses = |out: &str| out.lines().find(|l| l.contains("input ")).unwrap().to_string();
    assert_eq!(losses(&y), losses(&z), "a z-up copy drawn with --up z: the same pictures");

    // A turntable needs a numbered --out, and says so in its own words.
    let o = nst3d(&["--input", s(&hair), "--out", s(&dir.path().join("t.png")), "--turntable", "2"]);
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("with --turntable needs"));

    // Only grooms are judged.
    let o = nst3d(&["--input", s(&plume(40)), "--out", s(&dir.path().join("v.png")), "--style", s(&style)]);
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("apply to grooms"));
}
