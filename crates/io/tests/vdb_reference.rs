//! Our OpenVDB reader and writer against the real library (Debian's
//! python3-openvdb, OpenVDB 10) through tools/fixtures/io_vdb_reference.py:
//! files OpenVDB writes must read back exactly, files we write must read
//! in OpenVDB with the same names, transforms, active voxels and values.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Once;

use nst3d_core::Grid3;
use nst3d_io::vdb::*;
use serde_json::{json, Value};

const PYTHON: &str = "/usr/bin/python3";
const SCRIPT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../tools/fixtures/io_vdb_reference.py");

fn volumes() -> PathBuf {
    let dir = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data/volumes"));
    assert!(dir.is_dir(), "test data missing: {} (the shared/ data folder must sit beside the repo)", dir.display());
    dir
}

fn require_openvdb() {
    static CHECK: Once = Once::new();
    CHECK.call_once(|| {
        let ok = Command::new(PYTHON)
            .args(["-c", "import pyopenvdb, numpy"])
            .output()
            .map(|o| o.status.success())
            .unwrap_or(false);
        assert!(
            ok,
            "{PYTHON} cannot import pyopenvdb (the OpenVDB reference library): run `apt-get install python3-openvdb python3-numpy`"
        );
    });
}

/// Runs the reference script; panics with its stderr on failure.
fn reference(args: &[&str]) -> String {
    require_openvdb();
    let out = Command::new(PYTHON).arg(SCRIPT).args(args).output().expect("run python3");
    assert!(
        out.status.success(),
        "io_vdb_reference.py {} failed:\n{}{}",
        args.join(" "),
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn json_file(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn ijk(v: &Value) -> [i32; 3] {
    [0, 1, 2].map(|a| v[a].as_i64().unwrap() as i32)
}

/// Same formula as `known_value` in the script (Python's `%` is Euclidean).
fn known_value(i: i32, j: i32, k: i32) -> f32 {
    ((i * 7 + j * 3 - k * 5).rem_euclid(97)) as f32 / 8.0 - 4.0
}

fn float_grid(g: &VdbGrid) -> &SparseGrid<f32> {
    match &g.values {
        GridValues::Float(s) => s,
        other => panic!("grid {} is {}", g.name, other.type_name()),
    }
}

/// Compares our grid's summary with the reference's `grid_info`.
fn assert_info(g: &VdbGrid, info: &Value) {
    let name = info["name"].as_str().unwrap();
    assert_eq!(g.name, name);
    assert_eq!(g.class, info["class"].as_str().unwrap(), "{name} class");
    assert_eq!(g.values.type_name(), info["value_type"].as_str().unwrap(), "{name} type");
    assert_eq!(g.active_voxel_count(), info["active_count"].as_u64().unwrap(), "{name} active count");
    if g.active_voxel_count() > 0 {
        assert_eq!(g.active_bbox(), Some((ijk(&info["bbox_min"]), ijk(&info["bbox_max"]))), "{name} bbox");
    }
    let vs: Vec<f64> = info["voxel_size"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    for a in 0..3 {
        assert!(
            (g.transform.voxel_size[a] - vs[a]).abs() < 1e-12,
            "{name} voxel size {:?} vs {vs:?}",
            g.transform.voxel_size
        );
    }
    assert_eq!(g.saved_as_half, info["half"].as_bool().unwrap(), "{name} half flag");
}

/// (a) A file OpenVDB writes with known values (sparse voxels over many
/// leaves with negative coordinates, tiles at both internal levels, half
/// floats, a staggered vec3s grid) reads back exactly.
#[test]
fn openvdb_written_file_reads_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let vdb = dir.path().join("known.vdb");
    let meta = dir.path().join("known.json");
    reference(&["make", vdb.to_str().unwrap(), meta.to_str().unwrap()]);
    let expect = json_file(&meta);
    let file = read_vdb(&vdb).unwrap();
    assert_eq!(file.library_version.0, 10);
    for info in expect["grids"].as_array().unwrap() {
        let g = file.grid(info["name"].as_str().unwrap()).expect("grid present");
        assert_info(g, info);
    }
    let voxels: Vec<([i32; 3], f32)> = expect["voxels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| ([0, 1, 2].map(|a| v[a].as_i64().unwrap() as i32), v[3].as_f64().unwrap() as f32))
        .collect();
    for name in ["sparse", "sparse_half"] {
        let s = float_grid(file.grid(name).unwrap());
        // The fill below came after the sparse voxels and overwrote those in its box.
        let in_fill = |c: [i32; 3]| (-16..=-9).contains(&c[0]) && (8..=15).contains(&c[1]) && (16..=23).contains(&c[2]);
        for &(c, v) in voxels.iter().filter(|(c, _)| !in_fill(*c)) {
            assert!(s.is_active(c), "{name} {c:?} inactive");
            assert_eq!(s.get(c), v, "{name} {c:?}");
            assert_eq!(v, known_value(c[0], c[1], c[2]));
        }
        // The 8^3 fill (an active tile of a 16^3 node).
        for c in [[-16, 8, 16], [-9, 15, 23], [-12, 11, 20]] {
            assert!(s.is_active(c) && s.get(c) == 2.5, "{name} tile voxel {c:?}");
        }
        assert!(!s.is_active([-17, 8, 16]) && s.get([-17, 8, 16]) == 0.0);
    }
    let sparse = file.grid("sparse").unwrap();
    let w = sparse.transform.index_to_world([1.0, 2.0, 3.0]);
    assert_eq!(w, [1.75, -1.0, 5.0], "index (1,2,3) of 'sparse' in world space");
    // A 128^3 active tile of a 32^3 node expands to 2M voxels.
    let tiles = float_grid(file.grid("tiles").unwrap());
    for c in [[128, -128, 0], [255, -1, 127], [200, -50, 64]] {
        assert!(tiles.is_active(c) && tiles.get(c) == 0.75, "tiles {c:?}");
    }
    assert_eq!(tiles.get([300, 2, 3]), -1.5);
    assert!(!tiles.is_active([127, -128, 0]));
    let vel = file.grid("velocity").unwrap();
    let GridValues::Vec3(vel) = &vel.values else { panic!("velocity not vec3") };
    for &(c, _) in voxels.iter().step_by(3) {
        let [i, j, k] = c;
        assert_eq!(vel.get(c), [known_value(i, j, k), -known_value(j, k, i), i as f32 * 0.5], "velocity {c:?}");
    }
}

/// (b) What our writer produces reads in OpenVDB: names, classes, voxel
/// sizes, transforms, active counts, bboxes and values (also half floats,
/// vec3s and a real smoke frame rewritten), and round-trips through our
/// reader unchanged.
#[test]
fn our_files_read_in_openvdb() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("ours.vdb");

    // Sparse-ish blob spanning several leaves and negative coordinates.
    let dims = [21, 13, 17];
    let mut dense = Grid3::zeros(dims);
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let (fx, fy, fz) = (x as f32 - 10.0, y as f32 - 6.0, z as f32 - 8.0);
                let v = 1.0 - (fx * fx + fy * fy + fz * fz) / 80.0;
                let i = dense.index(x, y, z);
                dense.data[i] = if v > 0.0 { v * 3.0 } else { 0.0 };
            }
        }
    }
    let origin = [-13, -4, 7];
    let density = VdbGrid::from_dense(
        "density",
        Transform::scale_translate([0.25, 0.5, 0.125], [1.0, -2.0, 0.5]),
        origin,
        &dense,
        0.0,
    );
    let mut half = VdbGrid::from_dense("density_half", Transform::uniform(0.1), origin, &dense, 0.5);
    half.saved_as_half = true;
    let comps = [0.0f32, 1.0, 2.0].map(|c| {
        let mut g = dense.clone();
        g.data.iter_mut().for_each(|v| *v = if *v > 0.0 { *v + c } else { 0.0 });
        g
    });
    let vel = VdbGrid::from_dense_vec3(
        "velocity",
        "staggered",
        Transform::uniform(0.0625),
        [3, -9, 0],
        [&comps[0], &comps[1], &comps[2]],
        0.0,
    );
    // A rotated frame exercises the AffineMap path.
    let (c, s) = (0.6, 0.8);
    let rot = Transform::from_matrix(
        "AffineMap",
        [[c * 2.0, -s * 2.0, 0.0, 4.0], [s * 2.0, c * 2.0, 0.0, 5.0], [0.0, 0.0, 2.0, 6.0], [0.0, 0.0, 0.0, 1.0]],
    );
    let rotated = VdbGrid::from_dense("rotated", rot, [0, 0, 0], &dense, 0.0);
    let mut smoke = read_vdb(&volumes().join("smoke_000003.vdb")).unwrap().grids.remove(0);
    smoke.name = "smoke".into();
    let grids = vec![density, half, vel, rotated, smoke];
    write_vdb(&out, &grids).unwrap();

    // Our reader: identical values (half grids: the half-rounded values).
    let back = read_vdb(&out).unwrap();
    assert_eq!(back.grids.len(), grids.len());
    for (a, b) in grids.iter().zip(&back.grids) {
        assert_eq!(a.name, b.name);
        assert_eq!(a.class, b.class);
        assert_eq!(a.transform.index_to_world, b.transform.index_to_world, "{}", a.name);
        assert_eq!(a.active_voxel_count(), b.active_voxel_count(), "{}", a.name);
        if a.saved_as_half {
            let (sa, sb) = (float_grid(a), float_grid(b));
            for (c, v) in sa.iter_active() {
                assert_eq!(sb.get(c), half::f16::from_f32(v).to_f32(), "{} {c:?}", a.name);
            }
        } else {
            assert!(a.values == b.values, "{} values differ after round trip", a.name);
        }
    }

    // OpenVDB: the script checks every listed property and probe voxel.
    let mut expect = Vec::new();
    for g in &grids {
        let (lo, hi) = g.active_bbox().unwrap();
        let mut probes = Vec::new();
        let w = g.transform.index_to_world([1.0, 2.0, 3.0]);
        match &g.values {
            GridValues::Float(s) => {
                for (c, v) in s.iter_active().step_by(37) {
                    let v = if g.saved_as_half { half::f16::from_f32(v).to_f32() } else { v };
                    probes.push(json!([c, v, true]));
                }
                probes.push(json!([[lo[0] - 1, lo[1], lo[2]], 0.0, false]));
            }
            GridValues::Vec3(s) => {
                for (c, v) in s.iter_active().step_by(37) {
                    probes.push(json!([c, v, true]));
                }
                probes.push(json!([[hi[0] + 1, hi[1], hi[2]], [0.0, 0.0, 0.0], false]));
            }
            GridValues::Unsupported { .. } => unreachable!(),
        }
        expect.push(json!({
            "name": g.name,
            "class": g.class,
            "value_type": g.values.type_name(),
            "active_count": g.active_voxel_count(),
            "bbox_min": lo,
            "bbox_max": hi,
            "voxel_size": g.transform.voxel_size,
            "half": g.saved_as_half,
            "world_of_123": w,
            "probes": probes,
        }));
    }
    let expect_path = dir.path().join("expect.json");
    std::fs::write(&expect_path, json!({ "grids": expect }).to_string()).unwrap();
    let said = reference(&["check", out.to_str().unwrap(), expect_path.to_str().unwrap()]);
    assert_eq!(said.trim(), "OK");
}

/// Every plume48 density frame (half floats, Blosc), a vec3s velocity frame,
/// and smoke_000003 equal what OpenVDB's `copyToArray` gives, voxel for voxel.
#[test]
fn real_frames_match_openvdb_voxel_for_voxel() {
    let dir = tempfile::tempdir().unwrap();
    let mut pairs: Vec<(PathBuf, &str)> =
        (1..=40).map(|f| (volumes().join(format!("plume48/fluid_data_{f:04}.vdb")), "density")).collect();
    pairs.push((volumes().join("plume48/fluid_data_0020.vdb"), "velocity"));
    pairs.push((volumes().join("plume48/fluid_data_0040.vdb"), "temperature"));
    pairs.push((volumes().join("smoke_000003.vdb"), "density"));
    let mut args = vec!["dump".to_string(), dir.path().to_str().unwrap().to_string()];
    for (p, g) in &pairs {
        args.push(p.to_str().unwrap().to_string());
        args.push(g.to_string());
    }
    reference(&args.iter().map(String::as_str).collect::<Vec<_>>());
    for (n, (path, name)) in pairs.iter().enumerate() {
        let info = json_file(&dir.path().join(format!("{n}.json")));
        let file = read_vdb(path).unwrap();
        let g = file.grid(name).unwrap();
        assert_info(g, &info);
        let raw = std::fs::read(dir.path().join(format!("{n}.bin"))).unwrap();
        let theirs: Vec<f32> = raw.chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect();
        // Reference order is C order over (i, j, k) (x slowest), vec3 interleaved.
        let (bx, comps): (DenseBox, Vec<Grid3>) = match &g.values {
            GridValues::Float(_) => {
                let (b, d) = g.to_dense().unwrap();
                (b, vec![d])
            }
            _ => {
                let (b, d) = g.to_dense_vec3().unwrap();
                (b, d.to_vec())
            }
        };
        let [nx, ny, nz] = bx.dims;
        let nc = comps.len();
        assert_eq!(theirs.len(), nx * ny * nz * nc, "{} {name}", path.display());
        let mut mismatches = 0;
        for i in 0..nx {
            for j in 0..ny {
                for k in 0..nz {
                    for (c, comp) in comps.iter().enumerate() {
                        let t = theirs[((i * ny + j) * nz + k) * nc + c];
                        let o = comp.at(i, j, k);
                        if t.to_bits() != o.to_bits() {
                            mismatches += 1;
                        }
                    }
                }
            }
        }
        assert_eq!(mismatches, 0, "{} grid {name}: {mismatches} voxels differ from OpenVDB", path.display());
    }
}
