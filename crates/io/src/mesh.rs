//! Triangle meshes in: the head or body a groom grows from (roots,
//! visibility, collisions). PLY (ascii, binary either endian; faces as any
//! integer list, extra properties skipped by type size) and Wavefront OBJ
//! (`v`, `vn`, `f` with `v`, `v/vt`, `v//vn`, `v/vt/vn` corners, negative
//! relative indices). Polygons are triangulated as fans from their first
//! corner, which is exact for the convex faces DCC exports carry.

use std::path::Path;

pub use nst3d_core::mesh::TriMesh;

use crate::bytes::{corrupt, read_file};
use crate::groom::ply::parse_ply;
use crate::{Error, ErrorKind};

/// Writes `mesh` as an ASCII PLY (what `--mesh` reads), atomically: a
/// killed job never leaves half a mesh. Normals are not written; readers
/// recompute them from the triangles.
pub fn write_mesh_ply(path: &Path, mesh: &TriMesh) -> std::io::Result<()> {
    crate::atomic::write_atomic(path, |w| {
        write!(
            w,
            "ply\nformat ascii 1.0\ncomment Written by nst3d\nelement vertex {}\nproperty float x\nproperty float y\n\
             property float z\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
            mesh.vertices.len(),
            mesh.triangles.len()
        )?;
        for v in &mesh.vertices {
            writeln!(w, "{} {} {}", v[0], v[1], v[2])?;
        }
        for t in &mesh.triangles {
            writeln!(w, "3 {} {} {}", t[0], t[1], t[2])?;
        }
        Ok(())
    })
}

/// Reads a `.ply` or `.obj` mesh, chosen by magic (`ply`) then extension.
/// OBJ normals are per corner in the file; they are folded onto positions
/// (the last corner naming a vertex wins) and kept only when every corner
/// names one. Texture coordinates and materials are ignored.
pub fn read_mesh(path: &Path) -> Result<TriMesh, Error> {
    let bytes = read_file(path)?;
    read_mesh_bytes(path, &bytes)
}

/// [`read_mesh`] on bytes in memory; `path` names them in errors and its
/// extension picks the format when the content has no magic.
pub fn read_mesh_bytes(path: &Path, bytes: &[u8]) -> Result<TriMesh, Error> {
    let ext = path.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase());
    let mesh = if bytes.starts_with(b"ply") {
        parse_ply_mesh(bytes)
    } else {
        match ext.as_deref() {
            Some("ply") => parse_ply_mesh(bytes),
            Some("obj") => parse_obj(bytes),
            _ => {
                let reason = "expected .ply or .obj".into();
                return Err(Error::new(path, ErrorKind::UnknownFormat { what: "mesh", reason }));
            }
        }
    };
    mesh.and_then(checked).map_err(Error::at(path))
}

/// What every caller relies on: triangles, finite vertices and normals.
/// (Indices are checked as faces are read.)
fn checked(mesh: TriMesh) -> Result<TriMesh, ErrorKind> {
    if mesh.triangles.is_empty() {
        return Err(corrupt("the mesh has no faces"));
    }
    if let Some(i) = mesh.vertices.iter().position(|v| v.iter().any(|c| !c.is_finite())) {
        return Err(corrupt(format!("vertex {i} is not finite: {:?}", mesh.vertices[i])));
    }
    if let Some(i) = mesh.normals.iter().flatten().position(|v| v.iter().any(|c| !c.is_finite())) {
        return Err(corrupt(format!("the normal of vertex {i} is not finite")));
    }
    Ok(mesh)
}

/// Appends the fan triangulation of `poly`, checking every index.
fn push_fan(out: &mut Vec<[u32; 3]>, poly: &[u32], vertex_count: usize, face: usize) -> Result<(), ErrorKind> {
    if poly.len() < 3 {
        return Err(corrupt(format!("face {face} has {} corners, need at least 3", poly.len())));
    }
    if let Some(&i) = poly.iter().find(|&&i| i as usize >= vertex_count) {
        return Err(corrupt(format!("face {face} names vertex {i} but there are {vertex_count} vertices")));
    }
    for k in 1..poly.len() - 1 {
        out.push([poly[0], poly[k], poly[k + 1]]);
    }
    Ok(())
}

fn parse_ply_mesh(bytes: &[u8]) -> Result<TriMesh, ErrorKind> {
    let ply = parse_ply(bytes, &|el, prop| match el {
        "vertex" => matches!(prop, "x" | "y" | "z" | "nx" | "ny" | "nz"),
        "face" => matches!(prop, "vertex_indices" | "vertex_index"),
        _ => false,
    })?;
    let vertex = ply.element("vertex").ok_or_else(|| corrupt("PLY has no 'vertex' element"))?;
    let (Some(x), Some(y), Some(z)) = (vertex.scalar("x"), vertex.scalar("y"), vertex.scalar("z")) else {
        return Err(corrupt("PLY vertex element lacks scalar x, y, z"));
    };
    let vertices: Vec<[f32; 3]> = (0..x.len()).map(|i| [x[i] as f32, y[i] as f32, z[i] as f32]).collect();
    let normals = match (vertex.scalar("nx"), vertex.scalar("ny"), vertex.scalar("nz")) {
        (Some(a), Some(b), Some(c)) => Some((0..a.len()).map(|i| [a[i] as f32, b[i] as f32, c[i] as f32]).collect()),
        _ => None,
    };
    let mut triangles = Vec::new();
    if let Some(face) = ply.element("face") {
        let (offsets, values) = face
            .list("vertex_indices")
            .or_else(|| face.list("vertex_index"))
            .ok_or_else(|| corrupt("PLY face element has no vertex_indices list"))?;
        triangles.reserve(values.len().saturating_sub(2 * face.def.count));
        let mut poly = Vec::new();
        for (f, w) in offsets.windows(2).enumerate() {
            poly.clear();
            for &v in &values[w[0]..w[1]] {
                if !(0.0..=u32::MAX as f64).contains(&v) || v.fract() != 0.0 {
                    return Err(corrupt(format!("face {f} has bad vertex index {v}")));
                }
                poly.push(v as u32);
            }
            push_fan(&mut triangles, &poly, vertices.len(), f)?;
        }
    }
    Ok(TriMesh { vertices, triangles, normals })
}

/// Resolves an OBJ index (1-based, or negative = relative to the end).
fn obj_index(tok: &str, len: usize, line: usize, what: &str) -> Result<u32, ErrorKind> {
    let i: i64 = tok.parse().map_err(|_| corrupt(format!("line {line}: bad {what} index '{tok}'")))?;
    let resolved = if i > 0 { i - 1 } else { len as i64 + i };
    if i == 0 || resolved < 0 || resolved >= len as i64 {
        return Err(corrupt(format!("line {line}: {what} index {i} out of range (have {len})")));
    }
    Ok(resolved as u32)
}

fn parse_obj(bytes: &[u8]) -> Result<TriMesh, ErrorKind> {
    let text = std::str::from_utf8(bytes).map_err(|e| corrupt(format!("OBJ is not UTF-8 text ({e})")))?;
    let mut vertices: Vec<[f32; 3]> = Vec::new();
    let mut vn: Vec<[f32; 3]> = Vec::new();
    let mut vt_count = 0usize;
    let mut triangles = Vec::new();
    // Normal index per vertex, from the face corners that name one.
    let mut corner_normal: Vec<Option<u32>> = Vec::new();
    let mut all_corners_have_normals = true;
    let mut poly: Vec<u32> = Vec::new();
    let mut faces = 0usize;
    let vec3 = |w: &mut std::str::SplitAsciiWhitespace, line: usize, what: &str| -> Result<[f32; 3], ErrorKind> {
        let mut v = [0f32; 3];
        for c in v.iter_mut() {
            let tok = w.next().ok_or_else(|| corrupt(format!("line {line}: {what} needs 3 numbers")))?;
            *c = tok.parse().map_err(|_| corrupt(format!("line {line}: bad number '{tok}' in {what}")))?;
        }
        Ok(v)
    };
    for (ln, raw) in text.lines().enumerate() {
        let line = ln + 1;
        let mut w = raw.split_ascii_whitespace();
        match w.next() {
            Some("v") => {
                vertices.push(vec3(&mut w, line, "vertex")?);
                corner_normal.push(None);
            }
            Some("vn") => vn.push(vec3(&mut w, line, "normal")?),
            Some("vt") => vt_count += 1,
            Some("f") => {
                poly.clear();
                for corner in w {
                    let mut parts = corner.split('/');
                    let v = obj_index(parts.next().unwrap_or(""), vertices.len(), line, "vertex")?;
                    if let Some(t) = parts.next().filter(|t| !t.is_empty()) {
                        obj_index(t, vt_count, line, "texture")?;
                    }
                    match parts.next().filter(|n| !n.is_empty()) {
                        Some(n) => corner_normal[v as usize] = Some(obj_index(n, vn.len(), line, "normal")?),
                        None => all_corners_have_normals = false,
                    }
                    poly.push(v);
                }
                push_fan(&mut triangles, &poly, vertices.len(), faces).map_err(|e| match e {
                    ErrorKind::Corrupt { offset: None, reason } => corrupt(format!("line {line}: {reason}")),
                    other => other,
                })?;
                faces += 1;
            }
            _ => {}
        }
    }
    let normals = if faces > 0 && all_corners_have_normals && !vn.is_empty() {
        Some(corner_normal.iter().map(|n| n.map_or([0.0; 3], |i| vn[i as usize])).collect())
    } else {
        None
    };
    Ok(TriMesh { vertices, triangles, normals })
}
