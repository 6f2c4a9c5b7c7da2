//! The up axis of a groom: the strand pipeline works
//! y-up, turns a z-up groom and mesh into that frame and the result back.
//! Bangs (a y-up groom) turned z-up and written as `.ply` (`--up z`) and as
//! a `.usda` that declares `upAxis = "Z"` stylize to the same points, and
//! those are the y-up original's result turned z-up — to the bit, since the
//! turn only swaps and negates coordinates. Small, fast settings of
//! `strands.rs`, one thread so the runs are comparable bit for bit.

mod common;
use common::{nst3d, s, shared};

use std::path::Path;

use nst3d_core::UpAxis;
use nst3d_io::groom::{read_groom, read_groom_file, write_ply_strands, write_usda_curves, Groom};
use nst3d_io::mesh::{read_mesh, write_mesh_ply};

fn turned(g: &Groom, f: impl Fn([f32; 3]) -> [f32; 3]) -> Groom {
    let mut g = g.clone();
    for st in &mut g.strands {
        st.points.iter_mut().for_each(|p| *p = f(*p));
    }
    g
}

/// `nst3d --threads 1 strands` at the small settings; must succeed.
fn run(groom: &Path, mesh: &Path, out: &Path, extra: &[&str]) -> String {
    let style = shared("styles/starry_night.jpg");
    let mut args = vec!["--threads", "1", "strands", "--groom", s(groom), "--mesh", s(mesh)];
    args.extend_from_slice(&["--style", s(&style), "--out", s(out), "--preset", "short-hair", "--iters", "6"]);
    args.extend_from_slice(&["--render-size", "64", "--proxies", "20", "--views-per-scale", "1"]);
    args.extend_from_slice(extra);
    let o = nst3d(&args);
    let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "nst3d strands failed: {stderr}");
    stderr
}

fn points(g: &Groom) -> Vec<[f32; 3]> {
    g.strands.iter().flat_map(|st| st.points.iter().copied()).collect()
}

#[test]
fn a_z_up_groom_stylizes_as_its_y_up_copy_turned() {
    let dir = tempfile::tempdir().unwrap();
    let p = |name: &str| dir.path().join(name);
    let y_groom = read_groom(&shared("grooms/Bangs_100.hair")).unwrap();
    let z_groom = turned(&y_groom, |q| UpAxis::Z.from_y_up(q));
    // Both meshes without normals (the reader recomputes them), so the two
    // frames see the same head.
    let mut head = read_mesh(&shared("grooms/Bangs_head.ply")).unwrap();
    head.normals = None;
    let mut z_head = head.clone();
    z_head.vertices.iter_mut().for_each(|q| *q = UpAxis::Z.from_y_up(*q));
    write_mesh_ply(&p("head_y.ply"), &head).unwrap();
    write_mesh_ply(&p("head_z.ply"), &z_head).unwrap();
    write_ply_strands(&p("bangs_y.ply"), &y_groom).unwrap();
    write_ply_strands(&p("bangs_z.ply"), &z_groom).unwrap();
    write_usda_curves(&p("bangs_z.usda"), &z_groom).unwrap();
    let layer = std::fs::read_to_string(p("bangs_z.usda")).unwrap();
    assert!(layer.contains("upAxis = \"Y\""));
    std::fs::write(p("bangs_z.usda"), layer.replace("upAxis = \"Y\"", "upAxis = \"Z\"")).unwrap();
    assert_eq!(read_groom(&p("bangs_z.usda")).unwrap(), z_groom, "the z-up layer holds the same points");

    run(&p("bangs_y.ply"), &p("head_y.ply"), &p("out_y.ply"), &[]);
    run(&p("bangs_z.ply"), &p("head_z.ply"), &p("out_z.ply"), &["--up", "z"]);
    run(&p("bangs_z.usda"), &p("head_z.ply"), &p("out_z.usda"), &[]);
    // The flag overrides a layer's axis, and says so.
    let stderr = run(&p("bangs_z.usda"), &p("head_z.ply"), &p("out_zy.usda"), &["--up", "y"]);
    assert!(stderr.contains("overrides"), "{stderr}");

    let out_y = read_groom(&p("out_y.ply")).unwrap();
    let out_z = read_groom(&p("out_z.ply")).unwrap();
    let out_usda = read_groom_file(&p("out_z.usda")).unwrap();
    assert_eq!(out_usda.usd_primvars.up_axis.as_deref(), Some("Z"), "the output keeps the layer's axis");
    let moved =
        points(&out_y).into_iter().zip(points(&y_groom)).map(|(a, b)| (0..3).map(|k| (a[k] - b[k]).abs()).sum::<f32>());
    assert!(moved.fold(0f32, f32::max) > 0.1, "the y-up groom did not change");
    assert_eq!(points(&out_z), points(&out_usda.groom), "z-up .ply with --up z and z-up .usda: the same result");
    let y_turned: Vec<[f32; 3]> = points(&out_y).into_iter().map(|q| UpAxis::Z.from_y_up(q)).collect();
    assert_eq!(points(&out_z), y_turned, "the z-up result is the y-up result turned");
    // Without --up the z-up .ply is read as y-up: its cameras sit
    // elsewhere, and the result differs.
    run(&p("bangs_z.ply"), &p("head_z.ply"), &p("out_z_as_y.ply"), &[]);
    assert_ne!(points(&read_groom(&p("out_z_as_y.ply")).unwrap()), points(&out_z));
}
