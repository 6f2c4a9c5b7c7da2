//! Camera sets: Houdini-style camera files mapped into index space, keyed
//! paths, file errors, and the omniview / turntable distributions.

use nst3d_core::Grid3;
use nst3d_render::{
    min_angular_distance_deg, omniview, poisson_disk_sphere, render, ring, sphere_uniform, Camera, CameraFileError,
    CameraRig, Projection,
};

/// Voxel size 0.1 and a translation: `world = 0.1 · ijk + t`.
const T: [f64; 3] = [-1.2, 0.5, 2.0];
fn scale_translate(voxel: [f64; 3], t: [f64; 3]) -> [[f64; 4]; 4] {
    let mut m = [[0.0; 4]; 4];
    for a in 0..3 {
        m[a][a] = voxel[a];
        m[a][3] = t[a];
    }
    m[3][3] = 1.0;
    m
}

fn assert_vec(got: [f32; 3], want: [f64; 3], tol: f64, what: &str) {
    for a in 0..3 {
        assert!((got[a] as f64 - want[a]).abs() <= tol, "{what}: got {got:?}, want {want:?}");
    }
}

fn unit(v: [f32; 3]) -> [f64; 3] {
    let n = v.iter().map(|x| (*x as f64).powi(2)).sum::<f64>().sqrt();
    v.map(|x| x as f64 / n)
}

fn forward(c: &Camera) -> [f64; 3] {
    unit(std::array::from_fn(|a| c.target[a] - c.eye[a]))
}

fn parse(json: &str) -> CameraRig {
    CameraRig::from_json_str(json, "shot.json").unwrap_or_else(|e| panic!("{e}"))
}

fn parse_err(json: &str) -> String {
    match CameraRig::from_json_str(json, "shot.json") {
        Ok(r) => panic!("expected an error for {json}, got {r:?}"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn houdini_camera_maps_to_index_space() {
    let rig = parse(
        r#"{"position": [0.3, 1.5, 12.0], "look_at": [0.3, 1.5, 2.0], "up": [0, 1, 0],
            "projection": "perspective", "focal": 50, "aperture": 41.4214, "resx": 1920, "resy": 1080}"#,
    );
    assert_eq!(rig.frame_range(), None);
    let m = scale_translate([0.1; 3], T);
    let cam = rig.at_frame(7.0, &m);
    assert_eq!(cam.projection, Projection::Perspective);
    assert_vec(cam.eye, [15.0, 10.0, 100.0], 1e-4, "eye");
    assert_vec(cam.target, [15.0, 10.0, 0.0], 1e-4, "target");
    assert_vec(cam.up, [0.0, 1.0, 0.0], 1e-6, "up");
    // Houdini: fov_x = 2 atan(41.4214 / 100) = 45°, vertical aperture = aperture · 1080 / 1920.
    let want_fov_y = 2.0 * (0.414214f64 * 1080.0 / 1920.0).atan().to_degrees();
    assert!((cam.fov_y_deg as f64 - want_fov_y).abs() < 1e-4, "fov_y {}", cam.fov_y_deg);
    assert!((want_fov_y - 26.2313).abs() < 1e-3);
    assert!((cam.aspect - 16.0 / 9.0).abs() < 1e-6);
    // The horizontal field of view is the lens's 45°.
    let fov_x = 2.0 * ((cam.fov_y_deg.to_radians() * 0.5).tan() * cam.aspect).atan().to_degrees();
    assert!((fov_x - 45.0).abs() < 1e-3, "fov_x {fov_x}");

    // An explicit vertical fov and the defaults (perspective, 1920x1080, +y up).
    let cam = parse(r#"{"position": [0, 0, 5], "look_at": [0, 0, 0], "fov": 30}"#).at_frame(1.0, &m);
    assert!((cam.fov_y_deg - 30.0).abs() < 1e-5);
    assert!((cam.aspect - 16.0 / 9.0).abs() < 1e-6);
    assert_vec(cam.eye, [12.0, -5.0, 30.0], 1e-4, "eye");
}

#[test]
fn rotation_follows_houdini_xyz_order() {
    let m = scale_translate([1.0; 3], [0.0; 3]);
    // ry = +90 turns the camera's −z view towards −x.
    let cam = parse(r#"{"position": [10, 0, 0], "rotation": [0, 90, 0]}"#).at_frame(0.0, &m);
    assert_vec(forward(&cam).map(|x| x as f32), [-1.0, 0.0, 0.0], 1e-6, "forward ry=90");
    assert_vec(cam.up, [0.0, 1.0, 0.0], 1e-6, "up ry=90");
    // rx = −30 tilts the view down.
    let cam = parse(r#"{"position": [0, 0, 0], "rotation": [-30, 0, 0]}"#).at_frame(0.0, &m);
    let s = 30f64.to_radians();
    assert_vec(forward(&cam).map(|x| x as f32), [0.0, -s.sin(), -s.cos()], 1e-6, "forward rx=-30");
    // X then Y: tilt down 30° and then turn left 90°: looking along −x and down.
    let cam = parse(r#"{"position": [0, 0, 0], "rotation": [-30, 90, 0]}"#).at_frame(0.0, &m);
    assert_vec(forward(&cam).map(|x| x as f32), [-s.cos(), -s.sin(), 0.0], 1e-6, "forward xyz");
    // rz rolls the picture: up turns towards −x for a positive roll.
    let cam = parse(r#"{"position": [0, 0, 0], "rotation": [0, 0, 90]}"#).at_frame(0.0, &m);
    assert_vec(cam.up, [-1.0, 0.0, 0.0], 1e-6, "up rz=90");
}

#[test]
fn non_uniform_voxels_remeasure_the_field_of_view() {
    // y voxels twice as tall: the same world frustum spans half as many index rows.
    let m = scale_translate([0.1, 0.2, 0.1], T);
    let cam = parse(r#"{"position": [0, 0, 20], "look_at": [0, 0, 0], "fov": 40, "resx": 100, "resy": 100}"#)
        .at_frame(0.0, &m);
    let tan = 20f64.to_radians().tan();
    let want = 2.0 * (0.5 * tan).atan().to_degrees();
    assert!((cam.fov_y_deg as f64 - want).abs() < 1e-4, "fov_y {} want {want}", cam.fov_y_deg);
    assert!((cam.aspect - 2.0).abs() < 1e-5, "aspect {}", cam.aspect);
    assert_vec(cam.eye, [12.0, -2.5, 180.0], 1e-3, "eye");
}

#[test]
fn keyed_path_interpolates_and_holds() {
    let rig = parse(
        r#"{"resx": 100, "resy": 50,
            "frames": {"25": {"position": [10, 0, 0], "look_at": [0, 0, 0], "fov": 40},
                       "1":  {"position": [0, 0, 10], "look_at": [0, 2, 0], "fov": 20}}}"#,
    );
    assert_eq!(rig.frame_range(), Some((1.0, 25.0)));
    let m = scale_translate([1.0; 3], [0.0; 3]);
    let mid = rig.at_frame(13.0, &m);
    assert_vec(mid.eye, [5.0, 0.0, 5.0], 1e-5, "mid eye");
    assert_vec(mid.target, [0.0, 1.0, 0.0], 1e-5, "mid target");
    assert!((mid.fov_y_deg - 30.0).abs() < 1e-4);
    assert!((mid.aspect - 2.0).abs() < 1e-6, "path-wide resx/resy");
    let q = rig.at_frame(7.0, &m);
    assert_vec(q.eye, [2.5, 0.0, 7.5], 1e-5, "quarter eye");
    assert!((q.fov_y_deg - 25.0).abs() < 1e-4);
    // Held outside the keys.
    assert_eq!(rig.at_frame(-5.0, &m), rig.at_frame(1.0, &m));
    assert_eq!(rig.at_frame(100.0, &m), rig.at_frame(25.0, &m));
    assert_vec(rig.at_frame(100.0, &m).eye, [10.0, 0.0, 0.0], 1e-6, "held eye");

    // Rotation keys interpolate channel-wise, as Houdini's linear keys.
    let rig = parse(
        r#"{"frames": {"0": {"position": [0, 0, 0], "rotation": [0, 0, 0]},
                       "10": {"position": [0, 0, 0], "rotation": [0, 90, 0]}}}"#,
    );
    let s = 45f64.to_radians();
    assert_vec(forward(&rig.at_frame(5.0, &m)).map(|x| x as f32), [-s.sin(), 0.0, -s.cos()], 1e-6, "rot mid");
}

#[test]
fn camera_file_round_trips_through_disk() {
    let dir = std::env::temp_dir().join(format!("nst3d_cameras_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("cam.json");
    std::fs::write(&path, r#"{"position": [0, 0, 5], "look_at": [0, 0, 0], "projection": "orthographic"}"#).unwrap();
    let cam = CameraRig::from_json_file(&path).unwrap().at_frame(0.0, &scale_translate([1.0; 3], [0.0; 3]));
    assert_eq!(cam.projection, Projection::Orthographic);
    let missing = dir.join("nope.json");
    let e = CameraRig::from_json_file(&missing).unwrap_err();
    assert!(matches!(e, CameraFileError::Read { .. }));
    assert!(e.to_string().contains("nope.json"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn bad_files_name_the_key() {
    let cases: &[(&str, &str)] = &[
        (r#"{"look_at": [0, 0, 0]}"#, "\"position\": missing"),
        (r#"{"position": [0, 0, 5]}"#, "\"look_at\": missing"),
        (r#"{"position": [0, 0, 5], "look_at": [0, 0]}"#, "\"look_at\": expected [x, y, z]"),
        (r#"{"position": [0, 0, 5], "look_at": [0, 0, 5]}"#, "\"look_at\": coincides"),
        (r#"{"position": [0, 0, 5], "look_at": [0, 0, 0], "up": [0, 0, 1]}"#, "\"up\": is zero or parallel"),
        (r#"{"position": [0, 0, 5], "look_at": [0, 0, 0], "rotation": [0, 0, 0]}"#, "\"rotation\": give either"),
        (r#"{"position": [0, 0, 5], "look_at": [0, 0, 0], "fov": 200}"#, "\"fov\": must be in (0, 180)"),
        (r#"{"position": [0, 0, 5], "look_at": [0, 0, 0], "fov": 30, "focal": 35}"#, "\"focal\": give either"),
        (r#"{"position": [0, 0, 5], "look_at": [0, 0, 0], "focal": -1}"#, "\"focal\": must be positive"),
        (r#"{"position": [0, 0, 5], "look_at": [0, 0, 0], "resy": "hd"}"#, "\"resy\": expected a finite number"),
        (r#"{"position": [0, 0, 5], "look_at": [0, 0, 0], "projection": "fisheye"}"#, "\"projection\": expected"),
        (r#"{"position": [0, 0, 5], "look_at": [0, 0, 0], "fov_y": 30}"#, "\"fov_y\": unknown key"),
        (r#"{"frames": {}}"#, "\"frames\": has no keys"),
        (r#"{"frames": {"abc": {"position": [0, 0, 5], "look_at": [0, 0, 0]}}}"#, "\"frames.abc\": is not a frame"),
        (r#"{"frames": {"1": {"position": [0, 0, 5]}}}"#, "\"frames.1.look_at\": missing"),
        (
            r#"{"frames": {"1": {"position": [0, 0, 5], "look_at": [0, 0, 0]}, "1.0": {"position": [0, 0, 6], "look_at": [0, 0, 0]}}}"#,
            "same frame as key",
        ),
        (
            r#"{"frames": {"1": {"position": [0, 0, 5], "look_at": [0, 0, 0]}, "9": {"position": [0, 0, 6], "rotation": [0, 0, 0]}}}"#,
            "\"frames.9\": mixes look_at and rotation",
        ),
        (
            r#"{"frames": {"1": {"position": [0, 0, 5], "look_at": [0, 0, 0]}, "9": {"position": [0, 0, 6], "look_at": [0, 0, 0], "projection": "orthographic"}}}"#,
            "\"frames.9.projection\": differs",
        ),
        ("[1, 2]", "\"(root)\": expected a JSON object"),
    ];
    for (json, want) in cases {
        let msg = parse_err(json);
        assert!(msg.starts_with("camera file shot.json: key "), "{msg}");
        assert!(msg.contains(want), "for {json}: {msg} lacks {want}");
        assert!(!msg.contains('\n'), "{msg}");
    }
    let msg = parse_err("{\"position\": [0, 0,\n 5");
    assert!(msg.starts_with("camera file shot.json is not valid JSON"), "{msg}");
    assert!(!msg.contains('\n'), "{msg}");
}

#[test]
fn singular_transform_gives_a_camera_the_renderer_rejects() {
    let m = scale_translate([0.1, 0.0, 0.1], T);
    let cam = parse(r#"{"position": [0, 0, 5], "look_at": [0, 0, 0]}"#).at_frame(0.0, &m);
    assert!(cam.view([8, 8, 8]).is_err());
}

/// A ball of density in a non-cubic grid, centred.
fn sphere_grid(dims: [usize; 3], radius: f32) -> Grid3 {
    let c = dims.map(|n| (n as f32 - 1.0) * 0.5);
    let mut g = Grid3::zeros(dims);
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let d2 = (x as f32 - c[0]).powi(2) + (y as f32 - c[1]).powi(2) + (z as f32 - c[2]).powi(2);
                let i = g.index(x, y, z);
                g.data[i] = if d2 <= radius * radius { 1.0 } else { 0.0 };
            }
        }
    }
    g
}

/// Renders `cam` and checks the ball's image is non-empty and centred.
fn assert_centred_render(g: &Grid3, cam: &Camera, what: &str) {
    let (img, _) = render(g, cam, 1.0).unwrap_or_else(|e| panic!("{what}: {e}"));
    let total: f64 = img.data.iter().map(|&v| v as f64).sum();
    assert!(total > 1.0, "{what}: empty image");
    let (mut cx, mut cy) = (0.0, 0.0);
    for r in 0..img.height {
        for c in 0..img.width {
            let v = img.data[r * img.width + c] as f64;
            cx += v * c as f64;
            cy += v * r as f64;
        }
    }
    let (cx, cy) = (cx / total, cy / total);
    let (mx, my) = ((img.width as f64 - 1.0) * 0.5, (img.height as f64 - 1.0) * 0.5);
    assert!(
        (cx - mx).abs() < 0.08 * img.width as f64 && (cy - my).abs() < 0.08 * img.height as f64,
        "{what}: centroid ({cx:.2}, {cy:.2}) off the centre ({mx}, {my}) of {}x{}",
        img.width,
        img.height
    );
}

/// Best packing (Tammes problem) of 16 points: 52.2444°.
const TAMMES_16_DEG: f64 = 52.2444;

#[test]
fn omniview_is_poisson_disk_and_near_best_packing() {
    let mut raw_sum = 0.0;
    for seed in 0..4u64 {
        let raw = min_angular_distance_deg(&sphere_uniform(16, seed));
        let relaxed = min_angular_distance_deg(&poisson_disk_sphere(16, seed));
        raw_sum += raw;
        assert!(relaxed > 2.0 * raw, "seed {seed}: relaxed {relaxed:.2}° vs raw {raw:.2}°");
        assert!(relaxed > 0.95 * TAMMES_16_DEG, "seed {seed}: relaxed {relaxed:.2}°, best packing {TAMMES_16_DEG}°");
        assert!(relaxed <= TAMMES_16_DEG + 1e-3, "seed {seed}: {relaxed}° beats the proven optimum?");
    }
    assert!(raw_sum / 4.0 < 0.5 * TAMMES_16_DEG, "uniform samples unexpectedly well spread");
    // Other counts settle too (distinct seeds, not degenerate).
    for (n, best) in [(6usize, 90.0f64), (12, 63.4349)] {
        let got = min_angular_distance_deg(&poisson_disk_sphere(n, 7));
        assert!(got > 0.95 * best, "{n} points: {got:.2}°, best {best}°");
    }
    assert!(poisson_disk_sphere(0, 1).is_empty());
    assert_eq!(poisson_disk_sphere(1, 1).len(), 1);
}

#[test]
fn omniview_is_deterministic_for_a_seed() {
    let dims = [24, 20, 16];
    let a = omniview(16, 42, dims, Projection::Perspective);
    assert_eq!(a, omniview(16, 42, dims, Projection::Perspective));
    assert_ne!(a, omniview(16, 43, dims, Projection::Perspective));
    assert_eq!(a.len(), 16);
}

#[test]
fn omniview_cameras_render_the_ball_centred() {
    let dims = [24, 20, 16];
    let g = sphere_grid(dims, 6.0);
    let centre = dims.map(|n| (n as f32 - 1.0) * 0.5);
    let r_bound = 0.5 * dims.iter().map(|&n| (n * n) as f32).sum::<f32>().sqrt();
    for projection in [Projection::Perspective, Projection::Orthographic] {
        for (i, cam) in omniview(16, 3, dims, projection).iter().enumerate() {
            assert_eq!(cam.target, centre);
            let dist = (0..3).map(|a| (cam.eye[a] - centre[a]).powi(2)).sum::<f32>().sqrt();
            assert!(dist > r_bound, "camera {i} inside the bounding sphere");
            let f = forward(cam);
            let up = unit(cam.up);
            let cos = (f[0] * up[0] + f[1] * up[1] + f[2] * up[2]).abs();
            assert!(cos < 0.95, "camera {i}: up nearly parallel to the view ({cos})");
            assert_centred_render(&g, cam, &format!("{projection:?} omniview camera {i}"));
        }
    }
}

#[test]
fn ring_is_an_even_turntable() {
    let dims = [24, 20, 16];
    let g = sphere_grid(dims, 6.0);
    let cams = ring(8, 20.0, dims, Projection::Perspective);
    assert_eq!(cams.len(), 8);
    // Camera 0 is the orbit camera at azimuth 0 (the front view raised by 20°).
    let orbit = Camera::orbit(dims, 0.0, 20.0).with_projection(Projection::Perspective);
    assert_vec(cams[0].eye, orbit.eye.map(|x| x as f64), 1e-3, "ring[0] eye");
    assert_vec(cams[2].eye, Camera::orbit(dims, 90.0, 20.0).eye.map(|x| x as f64), 1e-3, "ring[2] eye");
    for (i, cam) in cams.iter().enumerate() {
        let f = forward(cam);
        let az = (-f[0]).atan2(-f[2]).to_degrees().rem_euclid(360.0);
        assert!((az - 45.0 * i as f64).abs() < 1e-3, "camera {i} azimuth {az}");
        assert!((f[1] + 20f64.to_radians().sin()).abs() < 1e-5, "camera {i} elevation");
        assert_centred_render(&g, cam, &format!("ring camera {i}"));
    }
    // Straight down stays well defined (no +y up to collide with).
    for cam in ring(4, 90.0, dims, Projection::Orthographic) {
        assert_centred_render(&g, &cam, "top view");
    }
}
