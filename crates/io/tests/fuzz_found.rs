//! Inputs the fuzzer found (`tools/fuzz.sh`, docs/design/performance.md), kept as
//! regression tests: each was a panic, a hang or a reader saying yes to
//! something its callers cannot use. Each must now be a one-line error.

use std::path::{Path, PathBuf};

use nst3d_io::mesh::read_mesh;
use nst3d_io::vdb::read_vdb;
use nst3d_io::ErrorKind;

fn fixture(name: &str) -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/fuzz").join(name);
    assert!(p.is_file(), "fuzz regression input missing: {}", p.display());
    p
}

#[test]
fn a_vertex_that_overflows_f32_is_refused() {
    // `v 0777…7 0 1` parses to +inf; the mesh used to be returned with it.
    let e = read_mesh(&fixture("mesh_overflowing_vertex.obj")).unwrap_err().to_string();
    assert!(e.contains("mesh_overflowing_vertex.obj") && e.contains("not finite"), "{e}");
}

#[test]
fn a_nan_vertex_in_a_binary_ply_is_refused() {
    // The fuzzer's NaN (bytes 00 9e ff ff) in an otherwise well-formed mesh.
    let e = read_mesh(&fixture("mesh_nan_vertex.ply")).unwrap_err().to_string();
    assert!(e.contains("vertex 0 is not finite"), "{e}");
}

#[test]
fn a_mesh_without_faces_is_refused() {
    // The fuzzer's original input: the face element renamed away, so the
    // mesh had vertices (one NaN) and no triangles at all.
    let e = read_mesh(&fixture("mesh_nan_vertex_no_faces.ply")).unwrap_err().to_string();
    assert!(e.contains("no faces"), "{e}");
}

#[test]
fn tiles_claiming_more_than_the_file_budget_are_refused_before_filling() {
    // 8.9 KB written by OpenVDB itself (pyopenvdb `fill` + `prune`): active
    // tiles covering 1024 x 1024 x 512 voxels, 2 GiB once expanded.
    let e = read_vdb(&fixture("vdb_tiles_claim_2e29_voxels.vdb")).unwrap_err();
    assert!(matches!(e.kind(), ErrorKind::TileExpansion { values: 536_870_912, .. }), "{e}");
    assert!(e.to_string().contains("'density'") && e.to_string().contains("536870912"), "{e}");
}

#[test]
fn a_cyhair_header_claiming_a_billion_strands_is_refused_at_once() {
    // 370 bytes: 0x42424242 strands of the default segment count and as many
    // points, no segment array. Refused from the point array's size, before
    // the per-strand list is built (it used to take 10 s).
    let e = nst3d_io::groom::read_cyhair(&fixture("cyhair_billion_default_strands.hair")).unwrap_err().to_string();
    assert!(e.contains("cyHair point array"), "{e}");
}

#[test]
fn a_53_kb_mutant_claiming_226_million_tile_voxels_is_refused() {
    // A plume48 frame with a few mask bytes changed, found as a time-out
    // (0.65 s to fill, 1 s under instrumentation): its density grid's tiles
    // cover 226 million voxels, 4,250 per byte of the file.
    let e = read_vdb(&fixture("vdb_plume_mutant_tiles_226m_voxels.vdb")).unwrap_err();
    assert!(matches!(e.kind(), ErrorKind::TileExpansion { limit: 54_519_808, .. }), "{e}");
    assert!(e.to_string().contains("'density'"), "{e}");
}

#[test]
fn real_caches_stay_well_inside_the_tile_budget() {
    // Every real file reads (vdb_real.rs checks their voxels); the budget
    // only counts tiles, and these have none or few.
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/volumes");
    for f in ["smoke_000003.vdb", "plume48/fluid_data_0040.vdb"] {
        let p = data.join(f);
        assert!(p.is_file(), "real data missing: {}", p.display());
        read_vdb(&p).unwrap_or_else(|e| panic!("{e}"));
    }
}
