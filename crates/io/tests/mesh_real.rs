//! Mesh reader on the shared head (binary PLY with extra double s,t vertex
//! properties) and Spot (OBJ with v/vt faces), synthetic ascii PLY and OBJ
//! corner forms, normals, and the robustness rule.

use std::path::{Path, PathBuf};

use nst3d_io::mesh::*;

fn data(rel: &str) -> PathBuf {
    let p = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data")).join(rel);
    assert!(p.exists(), "test data missing: {} (the shared/ data folder must sit beside the repo)", p.display());
    p
}

#[test]
fn bangs_head_ply() {
    let m = read_mesh(&data("grooms/Bangs_head.ply")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(m.vertices.len(), 3943);
    // All faces are triangles here, so one triangle per face.
    assert_eq!(m.triangles.len(), 7694);
    assert!(m.normals.is_none());
    assert!(m.vertices.iter().flatten().all(|c| c.is_finite()));
    // The groom grows from this head: the groom's roots lie within its bounds
    // (slightly padded), which also checks s,t were skipped at the right size.
    let (lo, hi) = m.bbox().unwrap();
    let g = nst3d_io::groom::read_groom(&data("grooms/Bangs_100.hair")).unwrap();
    for s in &g.strands {
        let r = s.points[0];
        for a in 0..3 {
            let pad = 0.05 * (hi[a] - lo[a]);
            assert!(r[a] >= lo[a] - pad && r[a] <= hi[a] + pad, "root {r:?} outside head {lo:?}..{hi:?}");
        }
    }
    let n = m.vertex_normals();
    let unit = n.iter().filter(|v| ((v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) - 1.0).abs() < 1e-4).count();
    assert!(unit > 3900, "{unit} unit normals");
}

#[test]
fn spot_obj_counts_match_its_lines() {
    let path = data("meshes/spot.obj");
    let text = std::fs::read_to_string(&path).unwrap();
    let v = text.lines().filter(|l| l.starts_with("v ")).count();
    let tris: usize =
        text.lines().filter(|l| l.starts_with("f ")).map(|l| l.split_ascii_whitespace().count() - 3).sum();
    let m = read_mesh(&path).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(m.vertices.len(), v);
    assert_eq!(m.triangles.len(), tris);
    assert_eq!((v, tris), (2930, 5856));
    // Spot is closed: every edge is shared by exactly two triangles, and the
    // area-weighted normals point outward (positive flux through the surface).
    let mut edges = std::collections::HashMap::new();
    for t in &m.triangles {
        for k in 0..3 {
            let (a, b) = (t[k].min(t[(k + 1) % 3]), t[k].max(t[(k + 1) % 3]));
            *edges.entry((a, b)).or_insert(0) += 1;
        }
    }
    assert!(edges.values().all(|&c| c == 2), "spot should be closed");
    let (lo, hi) = m.bbox().unwrap();
    let c = [0, 1, 2].map(|a| 0.5 * (lo[a] + hi[a]));
    let n = m.vertex_normals();
    let outward =
        m.vertices.iter().zip(&n).filter(|(p, n)| (0..3).map(|a| (p[a] - c[a]) * n[a]).sum::<f32>() > 0.0).count();
    assert!(outward as f32 > 0.8 * v as f32, "{outward} of {v} normals point out");
}

#[test]
fn ascii_ply_polygons_and_obj_forms() {
    let dir = tempfile::tempdir().unwrap();
    let ply = dir.path().join("quad.ply");
    std::fs::write(
        &ply,
        "ply\nformat ascii 1.0\ncomment a unit quad and a triangle\nelement vertex 5\nproperty float x\nproperty float y\n\
         property float z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty uchar red\n\
         element face 2\nproperty list uchar int vertex_indices\nproperty int flags\nend_header\n\
         0 0 0 0 0 1 9\n1 0 0 0 0 1 9\n1 1 0 0 0 1 9\n0 1 0 0 0 1 9\n2 2 0 0 0 1 9\n4 0 1 2 3 7\n3 1 4 2 7\n",
    )
    .unwrap();
    let m = read_mesh(&ply).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3], [1, 4, 2]]);
    assert_eq!(m.normals.as_ref().unwrap()[4], [0.0, 0.0, 1.0]);
    for n in m.vertex_normals() {
        assert_eq!(n, [0.0, 0.0, 1.0]);
    }

    let obj = dir.path().join("forms.obj");
    std::fs::write(
        &obj,
        "# all corner forms\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 1\nvn 0 0 1\n\
         f 1 2 3\nf 1/1 3/2 4/1\nf 1//1 2//1 3//1\nf -4/-2/-1 -2/-1/-1 -1/-2/-1\nf 1 2 3 4\n",
    )
    .unwrap();
    let m = read_mesh(&obj).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3], [0, 1, 2], [0, 2, 3], [0, 1, 2], [0, 2, 3]]);
    assert!(m.normals.is_none(), "not every corner names a normal");

    let obj2 = dir.path().join("normals.obj");
    std::fs::write(&obj2, "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 -1\nf 1//1 3//1 2//1\n").unwrap();
    let m = read_mesh(&obj2).unwrap();
    assert_eq!(m.normals, Some(vec![[0.0, 0.0, -1.0]; 3]));
    assert_eq!(m.vertex_normals(), vec![[0.0, 0.0, -1.0]; 3]);
}

#[test]
fn binary_big_endian_ply_matches_little_endian() {
    let verts = [[0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let faces: [[i32; 3]; 2] = [[0, 1, 2], [0, 2, 3]];
    let dir = tempfile::tempdir().unwrap();
    let mut results = Vec::new();
    for (fmt, be) in [("binary_little_endian", false), ("binary_big_endian", true)] {
        let mut b = format!(
            "ply\nformat {fmt} 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n\
             property double s\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n"
        )
        .into_bytes();
        for v in verts {
            for c in v {
                b.extend(if be { c.to_be_bytes() } else { c.to_le_bytes() });
            }
            b.extend(if be { 7.5f64.to_be_bytes() } else { 7.5f64.to_le_bytes() });
        }
        for f in faces {
            b.push(3);
            for i in f {
                b.extend(if be { i.to_be_bytes() } else { i.to_le_bytes() });
            }
        }
        let p = dir.path().join(format!("{fmt}.ply"));
        std::fs::write(&p, &b).unwrap();
        results.push(read_mesh(&p).unwrap_or_else(|e| panic!("{fmt}: {e}")));
    }
    assert_eq!(results[0], results[1]);
    assert_eq!(results[0].vertices, verts.to_vec());
    assert_eq!(results[0].triangles, vec![[0, 1, 2], [0, 2, 3]]);
}

#[test]
fn bad_indices_and_missing_files_are_named_errors() {
    let e = read_mesh_bytes(Path::new("bad.obj"), b"v 0 0 0\nv 1 0 0\nf 1 2 3\n").unwrap_err().to_string();
    assert!(e.contains("bad.obj") && e.contains("line 3"), "{e}");
    let e = read_mesh_bytes(Path::new("zero.obj"), b"v 0 0 0\nf 0 1 1\n").unwrap_err().to_string();
    assert!(e.contains("zero.obj"), "{e}");
    let e = read_mesh(Path::new("/nonexistent/head.ply")).unwrap_err().to_string();
    assert!(e.contains("/nonexistent/head.ply") && e.contains("cannot read"), "{e}");
    let e = read_mesh_bytes(Path::new("x.stl"), b"solid").unwrap_err().to_string();
    assert!(e.contains("x.stl"), "{e}");
}

#[test]
fn truncated_files_fail_cleanly() {
    for rel in ["grooms/Bangs_head.ply", "meshes/spot.obj"] {
        let path = data(rel);
        let name = path.file_name().unwrap().to_str().unwrap().to_string();
        let bytes = std::fs::read(&path).unwrap();
        let step = (bytes.len() / 300).max(1);
        let mut cuts: Vec<usize> = (0..bytes.len()).step_by(step).collect();
        cuts.extend(0..400.min(bytes.len()));
        for cut in cuts {
            match read_mesh_bytes(&path, &bytes[..cut]) {
                Err(e) => {
                    let msg = e.to_string();
                    assert!(msg.contains(&name) && !msg.contains('\n'), "cut {cut}: {msg}");
                }
                // OBJ has no counts: a prefix cut at a line end is a smaller
                // valid mesh. A binary PLY prefix never is.
                Ok(m) => assert!(rel.ends_with(".obj") && m.vertices.len() <= 2930, "{rel}: cut {cut} parsed"),
            }
        }
    }
}

#[test]
fn random_and_corrupted_bytes_never_panic() {
    let mut x = 0x2545_f491_4f6c_dd1du64;
    let mut rnd = move || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    };
    let files: Vec<(PathBuf, Vec<u8>)> = ["grooms/Bangs_head.ply", "meshes/spot.obj"]
        .iter()
        .map(|r| (data(r), std::fs::read(data(r)).unwrap()))
        .collect();
    for trial in 0..600 {
        let (path, real) = &files[trial % 2];
        let len = (rnd() % 4096) as usize;
        let mut b: Vec<u8> = (0..len).map(|_| rnd() as u8).collect();
        let keep = (rnd() % 400) as usize;
        if trial % 2 == 0 && b.len() > keep {
            b[..keep].copy_from_slice(&real[..keep]);
        }
        let _ = read_mesh_bytes(path, &b);
        let mut c = real.clone();
        for _ in 0..1 + trial % 5 {
            let i = (rnd() as usize) % c.len();
            c[i] = rnd() as u8;
        }
        if let Ok(m) = read_mesh_bytes(path, &c) {
            let _ = m.vertex_normals();
        }
    }
}
