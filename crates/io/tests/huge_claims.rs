//! Small files that claim huge sizes (bounded allocation): every
//! reader checks a claimed count against the bytes that are really there
//! before it allocates, so a 14 KB file claiming billions of strands is a
//! clear error in milliseconds, not an out-of-memory kill.

use std::path::{Path, PathBuf};
use std::time::Instant;

use nst3d_io::groom::read_groom_bytes;
use nst3d_io::mesh::read_mesh_bytes;

fn shared(rel: &str) -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data").join(rel);
    assert!(p.exists(), "shared test data missing: {}", p.display());
    p
}

/// `read` refuses `bytes` quickly with an error mentioning `needle`.
fn refused<E: std::fmt::Display, T>(what: &str, needle: &str, read: impl FnOnce() -> Result<T, E>) {
    let t = Instant::now();
    let e = match read() {
        Ok(_) => panic!("{what}: a file claiming a huge size was accepted"),
        Err(e) => e.to_string(),
    };
    assert!(t.elapsed().as_millis() < 500, "{what}: took {:?}", t.elapsed());
    assert!(e.contains(needle), "{what}: {e}");
    eprintln!("{what}: {e}");
}

#[test]
fn huge_claimed_counts_are_refused_before_allocating() {
    // Strand PLY: 3 billion vertices, then 1 billion strands.
    let ply = std::fs::read(shared("grooms/Bangs_100_binary.ply")).unwrap();
    let path = Path::new("huge.ply");
    let text = |from: &str, to: &str| -> Vec<u8> {
        let at = ply.windows(from.len()).position(|w| w == from.as_bytes()).unwrap();
        [&ply[..at], to.as_bytes(), &ply[at + from.len()..]].concat()
    };
    let b = text("element vertex 1165", "element vertex 3000000000");
    refused("ply vertices", "truncated", || read_groom_bytes(path, &b));
    let b = text("element strand 100", "element strand 1000000000");
    refused("ply strands", "truncated", || read_groom_bytes(path, &b));

    // cyHair: 4 billion strands and points in the header.
    let mut hair = std::fs::read(shared("grooms/Bangs_100.hair")).unwrap();
    hair[4..8].copy_from_slice(&4_000_000_000u32.to_le_bytes());
    hair[8..12].copy_from_slice(&4_000_000_000u32.to_le_bytes());
    refused("cyhair", "truncated", || read_groom_bytes(Path::new("huge.hair"), &hair));

    // HairSalon .data: 2 billion strands; then one strand of 2 billion points.
    let data = std::fs::read(shared("grooms/Bangs_100.data")).unwrap();
    let mut b = data.clone();
    b[0..4].copy_from_slice(&2_000_000_000i32.to_le_bytes());
    refused("hairsalon strands", "truncated", || read_groom_bytes(Path::new("huge.data"), &b));
    let mut b = data.clone();
    b[4..8].copy_from_slice(&2_000_000_000i32.to_le_bytes());
    refused("hairsalon points", "truncated", || read_groom_bytes(Path::new("huge.data"), &b));

    // Mesh PLY: 2 billion faces.
    let mesh = std::fs::read(shared("grooms/Bangs_head.ply")).unwrap();
    let head = String::from_utf8_lossy(&mesh[..mesh.len().min(2000)]).to_string();
    let line = head.lines().find(|l| l.starts_with("element face")).expect("a face element").to_string();
    let at = mesh.windows(line.len()).position(|w| w == line.as_bytes()).unwrap();
    let b = [&mesh[..at], b"element face 2000000000", &mesh[at + line.len()..]].concat();
    refused("mesh faces", "truncated", || read_mesh_bytes(Path::new("huge_head.ply"), &b));

    // safetensors: a header length of 2^60 bytes.
    let st = nst3d_weights::safetensors_bytes(&[("w", &[2, 2], &[1.0, 2.0, 3.0, 4.0])], &Default::default());
    let mut b = st.clone();
    b[0..8].copy_from_slice(&(1u64 << 60).to_le_bytes());
    refused("safetensors header", "not a .safetensors file", || {
        nst3d_weights::parse_safetensors(&b, Path::new("huge.safetensors"))
    });
    // ... and a tensor whose shape claims 2^40 values.
    let json_len = u64::from_le_bytes(st[0..8].try_into().unwrap()) as usize;
    let json = String::from_utf8(st[8..8 + json_len].to_vec()).unwrap();
    let big = json.replacen("[2,2]", "[1048576,1048576]", 1);
    assert_ne!(big, json, "the shape was not found in {json}");
    let mut b = (big.len() as u64).to_le_bytes().to_vec();
    b.extend_from_slice(big.as_bytes());
    b.extend_from_slice(&st[8 + json_len..]);
    refused("safetensors shape", "invalid shape, data type, or offset", || {
        nst3d_weights::parse_safetensors(&b, Path::new("huge.safetensors"))
    });
}
