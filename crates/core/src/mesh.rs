//! Triangle meshes as values: the head or body a groom grows from (roots,
//! visibility, collisions). Reading and writing them is `nst3d-io`'s job.

/// An indexed triangle mesh.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriMesh {
    /// Vertex positions.
    pub vertices: Vec<[f32; 3]>,
    /// Counter-clockwise vertex index triples.
    pub triangles: Vec<[u32; 3]>,
    /// Per-vertex normals when the file stores them (PLY `nx, ny, nz`; OBJ
    /// `vn` folded onto positions, see `nst3d_io::mesh::read_mesh`).
    pub normals: Option<Vec<[f32; 3]>>,
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
