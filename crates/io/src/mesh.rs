//! Triangle meshes in: the head or body a groom grows from (roots,
//! visibility, collisions). PLY (ascii, binary either endian; faces as any
//! integer list, extra properties skipped by type size) and Wavefront OBJ
//! (`v`, `vn`, `f` with `v`, `v/vt`, `v//vn`, `v/vt/vn` corners, negative
//! relative indices). Polygons are triangulated as fans from their first
//! corner, which is exact for the convex faces DCC exports carry.

use std::path::{Path, PathBuf};

use crate::groom::bytes::{corrupt, FormatError};
use crate::groom::ply::parse_ply;

/// An indexed triangle mesh.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriMesh {
    /// Vertex positions.
    pub vertices: Vec<[f32; 3]>,
    /// Counter-clockwise vertex index triples.
    pub triangles: Vec<[u32; 3]>,
    /// Per-vertex normals when the file stores them (PLY `nx, ny, nz`; OBJ
    /// `vn` folded onto positions, see [`read_mesh`]).
    pub normals: Option<Vec<[f32; 3]>>,
}

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

/// Everything that can go wrong reading a mesh; one line naming the file.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    /// The file could not be opened or read.
    #[error("{path}: cannot read: {source}")]
    Open {
        /// File concerned.
        path: PathBuf,
        /// Underlying error.
        source: std::io::Error,
    },
    /// Neither the content nor the extension is PLY or OBJ.
    #[error("{path}: not a mesh file nst3d reads (expected .ply or .obj)")]
    UnknownFormat {
        /// File concerned.
        path: PathBuf,
    },
    /// The file ends before the structure it announces.
    #[error("{path}: truncated: needed {needed} more bytes at offset {offset} while reading {what}")]
    Truncated {
        /// File concerned.
        path: PathBuf,
        /// What was being decoded.
        what: &'static str,
        /// Byte offset where the read started.
        offset: usize,
        /// Bytes requested.
        needed: usize,
    },
    /// A value in the file is inconsistent (bad index, bad number, ...).
    #[error("{path}: corrupt: {reason}")]
    Corrupt {
        /// File concerned.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// Valid file using a feature this reader does not implement.
    #[error("{path}: unsupported: {reason}")]
    Unsupported {
        /// File concerned.
        path: PathBuf,
        /// The feature.
        reason: String,
    },
}

impl MeshError {
    fn from_format(path: &Path, e: FormatError) -> Self {
        match e {
            FormatError::Truncated { what, offset, needed } => {
                MeshError::Truncated { path: path.into(), what, offset, needed }
            }
            FormatError::Corrupt(reason) => MeshError::Corrupt { path: path.into(), reason },
            FormatError::Unsupported(reason) => MeshError::Unsupported { path: path.into(), reason },
        }
    }
}

impl TriMesh {
    /// Area-weighted vertex normals: each triangle adds its unnormalized
    /// cross product (twice its area times its normal) to its corners, so
    /// large faces dominate slivers. A vertex touching no non-degenerate
    /// triangle gets `[0, 0, 0]`.
    pub fn vertex_normals(&self) -> Vec<[f32; 3]> {
        let mut acc = vec![[0f64; 3]; self.vertices.len()];
        let p = |i: u32| self.vertices[i as usize].map(f64::from);
        for t in &self.triangles {
            if t.iter().any(|&i| i as usize >= self.vertices.len()) {
                continue;
            }
            let (a, b, c) = (p(t[0]), p(t[1]), p(t[2]));
            let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
            let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
            let n = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
            for &i in t {
                for a in 0..3 {
                    acc[i as usize][a] += n[a];
                }
            }
        }
        acc.into_iter()
            .map(|n| {
                let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                if len > 0.0 {
                    n.map(|c| (c / len) as f32)
                } else {
                    [0.0; 3]
                }
            })
            .collect()
    }

    /// Axis-aligned bounds `(min, max)`; `None` without vertices.
    pub fn bbox(&self) -> Option<([f32; 3], [f32; 3])> {
        let first = *self.vertices.first()?;
        Some(self.vertices.iter().fold((first, first), |(mut lo, mut hi), p| {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
            (lo, hi)
        }))
    }
}

/// Reads a `.ply` or `.obj` mesh, chosen by magic (`ply`) then extension.
/// OBJ normals are per corner in the file; they are folded onto positions
/// (the last corner naming a vertex wins) and kept only when every corner
/// names one. Texture coordinates and materials are ignored.
pub fn read_mesh(path: &Path) -> Result<TriMesh, MeshError> {
    let bytes = std::fs::read(path).map_err(|source| MeshError::Open { path: path.into(), source })?;
    read_mesh_bytes(path, &bytes)
}

/// [`read_mesh`] on bytes in memory; `path` names them in errors and its
/// extension picks the format when the content has no magic.
pub fn read_mesh_bytes(path: &Path, bytes: &[u8]) -> Result<TriMesh, MeshError> {
    let ext = path.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase());
    let mesh = if bytes.starts_with(b"ply") {
        parse_ply_mesh(bytes)
    } else {
        match ext.as_deref() {
            Some("ply") => parse_ply_mesh(bytes),
            Some("obj") => parse_obj(bytes),
            _ => return Err(MeshError::UnknownFormat { path: path.into() }),
        }
    };
    mesh.map_err(|e| MeshError::from_format(path, e))
}

/// Appends the fan triangulation of `poly`, checking every index.
fn push_fan(out: &mut Vec<[u32; 3]>, poly: &[u32], vertex_count: usize, face: usize) -> Result<(), FormatError> {
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

fn parse_ply_mesh(bytes: &[u8]) -> Result<TriMesh, FormatError> {
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
fn obj_index(tok: &str, len: usize, line: usize, what: &str) -> Result<u32, FormatError> {
    let i: i64 = tok.parse().map_err(|_| corrupt(format!("line {line}: bad {what} index '{tok}'")))?;
    let resolved = if i > 0 { i - 1 } else { len as i64 + i };
    if i == 0 || resolved < 0 || resolved >= len as i64 {
        return Err(corrupt(format!("line {line}: {what} index {i} out of range (have {len})")));
    }
    Ok(resolved as u32)
}

fn parse_obj(bytes: &[u8]) -> Result<TriMesh, FormatError> {
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
    let vec3 = |w: &mut std::str::SplitAsciiWhitespace, line: usize, what: &str| -> Result<[f32; 3], FormatError> {
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
                    FormatError::Corrupt(r) => corrupt(format!("line {line}: {r}")),
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
