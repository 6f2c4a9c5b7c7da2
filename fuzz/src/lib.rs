//! What each fuzz target does with its input: the reader of one format, then
//! the checks a caller relies on when the reader says yes (a groom passes
//! `Groom::validate`, a mesh's triangles index its vertices, a grid converts
//! to dense or refuses). A panic anywhere, an overflow (the release profile
//! keeps overflow checks), an input slower than the time-out or an allocation
//! over the memory limit is a finding. The targets in `fuzz_targets/` are one
//! line each; the seeds are made by `tools/fuzz.sh` from `../shared/data` and
//! the test fixtures.

use std::path::Path;

use nst3d_io::groom::{
    read_alembic_curves_bytes, read_cyhair_bytes, read_groom_file_bytes, read_hairsalon_bytes,
    read_usd_curves_file_bytes, Groom, UsdAssets,
};
use nst3d_io::mesh::read_mesh_bytes;
use nst3d_io::vdb::{read_vdb_bytes, write_vdb_bytes, GridValues};
use nst3d_weights::{parse_as, parse_safetensors, WeightsFormat};

/// Dense boxes up to this many voxels are materialised: larger ones are
/// allocations the caller asks for on purpose, after its memory check.
const DENSE_PROBE_VOXELS: u64 = 1 << 20;

fn valid(groom: &Groom) {
    groom.validate().expect("a reader returned a groom that fails validation");
}

/// OpenVDB: header, metadata, transforms, trees, Blosc/zlib/half buffers;
/// then each grid's active box, and when small a dense copy and the file
/// written back.
pub fn vdb(data: &[u8]) {
    let Ok(file) = read_vdb_bytes(Path::new("fuzz.vdb"), data) else { return };
    for g in &file.grids {
        // No box: nothing active, nothing to densify.
        let small = g.active_bbox().is_some_and(|(lo, hi)| {
            (0..3).map(|a| (i64::from(hi[a]) - i64::from(lo[a]) + 1) as u64).product::<u64>() <= DENSE_PROBE_VOXELS
        });
        if small {
            match &g.values {
                GridValues::Float(_) => drop(g.to_dense()),
                GridValues::Vec3(_) => drop(g.to_dense_vec3()),
                GridValues::Unsupported { .. } => {}
            }
        }
    }
    if file.grids.iter().map(|g| g.active_voxel_count()).sum::<u64>() <= DENSE_PROBE_VOXELS {
        let _ = write_vdb_bytes(Path::new("fuzz.vdb"), &file.grids);
    }
}

/// cyHair `.hair`.
pub fn cyhair(data: &[u8]) {
    if let Ok(g) = read_cyhair_bytes(Path::new("fuzz.hair"), data) {
        valid(&g);
    }
}

/// USC-HairSalon `.data`.
pub fn hairsalon(data: &[u8]) {
    if let Ok(g) = read_hairsalon_bytes(Path::new("fuzz.data"), data) {
        valid(&g);
    }
}

/// Strand PLY (ASCII and binary, with colours and widths).
pub fn strand_ply(data: &[u8]) {
    if let Ok(f) = read_groom_file_bytes(Path::new("fuzz.ply"), data) {
        valid(&f.groom);
    }
}

/// USD `BasisCurves` with primvars, the stage composed from what the
/// input holds (a package's own files; nothing is read from disk).
fn usd(data: &[u8], name: &str) {
    if let Ok(f) = read_usd_curves_file_bytes(Path::new(name), data, UsdAssets::PackageOnly) {
        valid(&f.groom);
        assert_eq!(f.usd_primvars.curve_points.len(), f.groom.strands.len(), "primvars for other curves");
    }
}

/// Text USD layers.
pub fn usda(data: &[u8]) {
    usd(data, "fuzz.usda");
}

/// Binary USD crate files: sections, compression, value representations.
pub fn usdc(data: &[u8]) {
    usd(data, "fuzz.usdc");
}

/// `.usdz` packages and the layers in them: the input as it is, then with
/// every entry's checksum made right, so that mutations inside a packaged
/// layer reach its reader instead of stopping at the checksum.
pub fn usdz(data: &[u8]) {
    usd(data, "fuzz.usdz");
    let mut fixed = data.to_vec();
    let mut at = 0;
    let half = |b: &[u8], i: usize| u16::from_le_bytes([b[i], b[i + 1]]) as usize;
    while fixed.len() >= at + 30 && fixed[at..at + 4] == [0x50, 0x4b, 3, 4] {
        let size = u32::from_le_bytes(fixed[at + 18..at + 22].try_into().expect("4 bytes")) as usize;
        let start = at + 30 + half(&fixed, at + 26) + half(&fixed, at + 28);
        let Some(entry) = fixed.get(start..start.saturating_add(size)) else { break };
        let crc = crc32fast::hash(entry);
        fixed[at + 14..at + 18].copy_from_slice(&crc.to_le_bytes());
        at = start + size;
    }
    if fixed != data {
        usd(&fixed, "fuzz.usdz");
    }
}

/// Alembic (Ogawa) curves.
pub fn alembic(data: &[u8]) {
    if let Ok(g) = read_alembic_curves_bytes(Path::new("fuzz.abc"), data) {
        valid(&g);
    }
}

fn mesh(data: &[u8], name: &str) {
    let Ok(m) = read_mesh_bytes(Path::new(name), data) else { return };
    let n = m.vertices.len();
    assert!(m.triangles.iter().flatten().all(|&i| (i as usize) < n), "a triangle indexes past the vertices");
    assert!(m.vertices.iter().flatten().all(|x| x.is_finite()), "a non-finite vertex was returned");
    if let Some(normals) = &m.normals {
        assert_eq!(normals.len(), n, "normals do not match the vertices");
    }
}

/// Wavefront OBJ meshes.
pub fn mesh_obj(data: &[u8]) {
    mesh(data, "fuzz.obj");
}

/// PLY meshes.
pub fn mesh_ply(data: &[u8]) {
    mesh(data, "fuzz.ply");
}

fn tensors_fill_shapes(t: &nst3d_weights::TensorMap) {
    for (name, tensor) in t {
        assert_eq!(tensor.shape.iter().product::<usize>(), tensor.data.len(), "tensor {name}: shape vs values");
    }
}

/// Legacy (pre-1.6) `torch.save` pickles.
pub fn pth_legacy(data: &[u8]) {
    if let Ok(t) = parse_as(WeightsFormat::LegacyPth, data, Path::new("fuzz.pth")) {
        tensors_fill_shapes(&t);
    }
}

/// Zip `torch.save` archives (pickle + storages).
pub fn pth_zip(data: &[u8]) {
    if let Ok(t) = parse_as(WeightsFormat::ZipPth, data, Path::new("fuzz.pth")) {
        tensors_fill_shapes(&t);
    }
}

/// `.safetensors` with metadata.
pub fn safetensors(data: &[u8]) {
    if let Ok((t, _)) = parse_safetensors(data, Path::new("fuzz.safetensors")) {
        tensors_fill_shapes(&t);
    }
}

/// nst3d feed-forward model files (safetensors + network shapes).
pub fn model(data: &[u8]) {
    let _ = nst3d_network::Model::from_bytes(data, Path::new("fuzz.nst3d"));
}

/// Houdini-style camera JSON (static or keyed); then the camera at a few
/// frames, in and out of the keyed range, as the renderer asks for it.
pub fn camera_json(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let Ok(rig) = nst3d_render::CameraRig::from_json_str(text, "fuzz.json") else { return };
    let identity = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]];
    for frame in [f64::NEG_INFINITY, -1.0, 0.0, 1.5, 24.0, 1e9, f64::NAN] {
        let _ = rig.key_at(frame);
        let _ = rig.at_frame(frame, &identity);
    }
}

/// A volume sequence's work folder: a state file read as a frame state,
/// and as the `checkpoint`.
pub fn volume_state(data: &[u8]) {
    let Ok(state) = nst3d_job::State::from_bytes(data) else { return };
    let _ = nst3d_sequence::store::checkpoint_mark(&state);
    if let Ok(st) = nst3d_sequence::store::decode(state) {
        assert!(st.m.len() == st.field.len() && st.v.len() == st.field.len(), "moments vs field");
    }
}

/// An animated groom's saved state between frames.
pub fn strand_state(data: &[u8]) {
    if let Ok(state) = nst3d_job::State::from_bytes(data) {
        let _ = nst3d_strands::sequence::SavedState::parse(&state);
    }
}

/// Every target: its name (the corpus folder and `NST3D_FUZZ_TARGET`) and
/// what it runs on an input.
pub const TARGETS: &[(&str, fn(&[u8]))] = &[
    ("vdb", vdb),
    ("cyhair", cyhair),
    ("hairsalon", hairsalon),
    ("strand_ply", strand_ply),
    ("usda", usda),
    ("usdc", usdc),
    ("usdz", usdz),
    ("alembic", alembic),
    ("mesh_obj", mesh_obj),
    ("mesh_ply", mesh_ply),
    ("pth_legacy", pth_legacy),
    ("pth_zip", pth_zip),
    ("safetensors", safetensors),
    ("model", model),
    ("camera_json", camera_json),
    ("volume_state", volume_state),
    ("strand_state", strand_state),
];

/// The target called `name`.
pub fn target(name: &str) -> Option<fn(&[u8])> {
    TARGETS.iter().find(|t| t.0 == name).map(|t| t.1)
}
