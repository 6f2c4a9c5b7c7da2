//! Closest-point and inside/outside queries against a triangle mesh (the
//! head or body), for the collision projection of Sec. 3.4.
//!
//! A binary BVH (median split of triangle centroids on the widest axis,
//! up to 4 triangles per leaf) answers closest-point queries exactly by
//! nearest-box-first traversal with pruning. Inside/outside comes from the
//! *angle-weighted pseudo-normal* at the closest feature (Bærentzen & Aanæs
//! 2005): the normal of the face, edge or vertex the closest point lies on,
//! so `(p − x) · n < 0` is exactly "inside" for a closed, consistently
//! oriented mesh — the test eq. 11–12 of the paper are written with. On an
//! open mesh (the Bangs head has a neck opening) it stays the local
//! half-space test near the surface, which is what collision handling needs.
//! A ray-parity test ([`MeshBvh::inside_by_ray_parity`]) is provided as an
//! independent check for closed meshes.
//!
//! **Meshes made of overlapping parts** (Blender's Suzanne: ears and eyes
//! pushed into the head) break the pseudo-normal test: near a seam the
//! nearest triangle may be part of an ear *inside* the head, whose outside
//! is the head's inside, so a control point under the skin reads as
//! outside and the collision push drives it deeper. So each triangle is
//! classified once by the generalized winding number just off its outer
//! side ([`Side`]): triangles buried inside another part are left out of
//! every query (nothing outside the mesh is nearest to them), and where the
//! nearest triangle straddles a seam the side is the winding number's and
//! an inside point is sent to the nearest surface it can leave by. A mesh
//! without overlapping parts has no such triangle and is queried exactly as
//! before.

use std::collections::HashMap;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::OnceLock;

use rayon::prelude::*;

use nst3d_core::mesh::TriMesh;

use crate::winding::WindingNumber;
use crate::StrandError;
use nst3d_core::math::{add, cross, dist2, dot, norm, normalize, scale, sub, V3};

const LEAF: usize = 4;

/// Which part of a triangle a closest point lies on; selects the
/// pseudo-normal used for the sign.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Feature {
    /// Strictly inside the face.
    Face,
    /// On edge `k` (corners `k`, `k+1 mod 3`).
    Edge(u8),
    /// On corner `k`.
    Vertex(u8),
}

/// Result of a closest-point query.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClosestHit {
    /// Closest surface point `x`.
    pub point: [f32; 3],
    /// Index of the triangle it lies on (into the mesh's triangles).
    pub triangle: usize,
    /// Feature of that triangle the point lies on.
    pub feature: Feature,
    /// Unit angle-weighted pseudo-normal `n` at `x`.
    pub normal: [f32; 3],
    /// `‖p − x‖`, negated when `(p − x) · n < 0` (inside).
    pub signed_distance: f32,
}

#[derive(Clone, Copy, Debug)]
struct Node {
    lo: V3,
    hi: V3,
    /// Leaf: triangle range in `order`; inner: children `start`, `end`.
    start: u32,
    end: u32,
    leaf: bool,
}

/// A bounding volume hierarchy over a triangle mesh with per-feature
/// pseudo-normals.
#[derive(Clone, Debug)]
pub struct MeshBvh {
    verts: Vec<V3>,
    tris: Vec<[u32; 3]>,
    /// Non-degenerate triangle indices, permuted so leaves own ranges.
    order: Vec<u32>,
    nodes: Vec<Node>,
    face_n: Vec<V3>,
    vert_n: Vec<V3>,
    edge_n: HashMap<(u32, u32), V3>,
    /// Per triangle: clear of other parts, straddling a seam or buried.
    side: Vec<Side>,
    /// The winding number, kept only when some triangle is buried or
    /// straddles a seam.
    winding: Option<WindingNumber>,
    /// Per triangle, with `winding`: a lower bound on its distance to the
    /// nearest triangle that is not clean. An inside point whose nearest
    /// triangle is clean and farther than the push from every seam leaves
    /// by it without a winding-number check.
    seam_dist: Vec<f32>,
    /// Built on the first [`MeshBvh::closest_point_within`].
    gate: OnceLock<DistanceGate>,
}

/// How far off a triangle, as a fraction of the mesh's bounding-box
/// diagonal, its sides are sampled for [`Side::classify`] and an exit point
/// is checked in [`MeshBvh::closest_point`].
const SAMPLE_OFFSET: f32 = 1e-4;
/// Triangles [`MeshBvh::closest_point`] tries, nearest first, for the way
/// out of a mesh of overlapping parts.
const EXIT_TRIES: usize = 16;

/// Where a triangle sits in a mesh made of parts that may overlap.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Side {
    /// Its outside is the whole mesh's outside everywhere sampled.
    Clean,
    /// Partly inside another part (a seam where two parts meet crosses it),
    /// touching a buried triangle, or on an open rim of a mesh whose parts
    /// overlap: where its pseudo-normal's sign cannot be trusted.
    Straddles,
    /// Inside another part everywhere sampled (an ear's root inside the
    /// head, the back of an eye): no point outside the mesh is nearest to
    /// it, and its own outside is the other part's inside.
    Buried,
}

impl Side {
    /// Classifies the triangles `valid` by the winding number just off
    /// their outer side at seven points (the centroid, and a half and nine
    /// tenths of the way from it to each corner — a seam often passes near
    /// a corner): below ½ there means outside the whole mesh. Returns the winding number too when some triangle is not
    /// clean; a mesh without overlapping parts needs it no further.
    fn classify(verts: &[V3], tris: &[[u32; 3]], face_n: &[V3], valid: &[u32]) -> (Vec<Side>, Option<WindingNumber>) {
        let kept: Vec<[u32; 3]> = valid.iter().map(|&f| tris[f as usize]).collect();
        let w = WindingNumber::new(verts, &kept);
        let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        for t in &kept {
            for &i in t {
                for a in 0..3 {
                    lo[a] = lo[a].min(verts[i as usize][a]);
                    hi[a] = hi[a].max(verts[i as usize][a]);
                }
            }
        }
        let eps = SAMPLE_OFFSET * norm(sub(hi, lo));
        let mut side = vec![Side::Clean; tris.len()];
        let found: Vec<(u32, Side)> = valid
            .par_iter()
            .with_min_len(64)
            .map(|&f| {
                let p = tris[f as usize].map(|i| verts[i as usize]);
                let g = scale(add(add(p[0], p[1]), p[2]), 1.0 / 3.0);
                let n = scale(face_n[f as usize], eps);
                let toward = |k: usize, t: f32| add(scale(g, 1.0 - t), scale(p[k], t));
                let samples =
                    [g, toward(0, 0.5), toward(1, 0.5), toward(2, 0.5), toward(0, 0.9), toward(1, 0.9), toward(2, 0.9)];
                let outside = samples.iter().filter(|&&x| w.at(add(x, n)) < 0.5).count();
                (
                    f,
                    match outside {
                        7 => Side::Clean,
                        0 => Side::Buried,
                        _ => Side::Straddles,
                    },
                )
            })
            .collect();
        for (f, s) in found {
            side[f as usize] = s;
        }
        // A clean triangle touching a buried one borders a hole in the
        // queried surface: its edge and corner pseudo-normals there lack the
        // buried face, so their sign cannot be trusted either.
        let mut at_seam = vec![false; verts.len()];
        for &f in valid {
            if side[f as usize] == Side::Buried {
                for i in tris[f as usize] {
                    at_seam[i as usize] = true;
                }
            }
        }
        let overlapping = side.iter().any(|&s| s != Side::Clean);
        // On a mesh of overlapping parts, an open rim (an eye that is a
        // hemisphere) is a hole of the same kind. A mesh in one part keeps
        // the pseudo-normal's local half-space at its rims (a scalp cap, a
        // neck opening), as it always had.
        let mut uses: HashMap<(u32, u32), u32> = HashMap::new();
        if overlapping {
            for &f in valid {
                let t = tris[f as usize];
                for k in 0..3 {
                    *uses.entry(edge_key(t[k], t[(k + 1) % 3])).or_insert(0) += 1;
                }
            }
        }
        for &f in valid {
            let t = tris[f as usize];
            let rim = overlapping && (0..3).any(|k| uses[&edge_key(t[k], t[(k + 1) % 3])] == 1);
            if side[f as usize] == Side::Clean && (rim || t.iter().any(|&i| at_seam[i as usize])) {
                side[f as usize] = Side::Straddles;
            }
        }
        (side, overlapping.then_some(w))
    }
}

/// Cells along the longest axis of the mesh's box grown by [`GATE_PAD`]
/// of its diagonal on every side: this sets [`DistanceGate`]'s cell size.
const GATE_CELLS: usize = 64;
/// See [`GATE_CELLS`].
const GATE_PAD: f32 = 0.25;
/// [`DistanceGate`]'s grid is the mesh's box grown by this fraction of its
/// diagonal on every side (at [`GATE_CELLS`]' cell size): a groom's hair
/// reaches far beyond the skin (monkey_curly's spikes: 440 k of its 3 M
/// control points lay outside a grid grown by [`GATE_PAD`], and on an open
/// mesh nothing bounds a point off the grid, so every one of them was
/// searched in every pass).
const GATE_REACH: f32 = 1.0;
/// Most cells of [`DistanceGate`]'s grid along an axis (memory: at most
/// 4 bytes a cell); the grid's reach shrinks where this binds.
const GATE_MAX_DIM: usize = 256;
/// A [`DistanceGate`] cell whose centre has not been measured yet (a NaN
/// no distance computation returns: they are stored as measured or as
/// `−∞`).
const GATE_UNSET: u32 = 0x7FC0_6A7E;
/// Deepest possible traversal stack: the median split halves the triangles
/// at every level, so a `u32`-indexed tree is at most 32 deep and the stack
/// (both children pushed per level) holds at most two entries a level.
const MAX_STACK: usize = 72;

/// Exact signed distances at the centres of a grid of cells over and around
/// the mesh, used as a lower bound to answer "outside and farther than τ"
/// without a closest-point search: unsigned distance is 1-Lipschitz, so a point `p`
/// whose nearest cell centre `c` is outside at distance `d(c)` is at least
/// `d(c) − ‖p − c‖` from the surface, and, when that is positive, on the
/// same side as `c` (exact for a closed mesh; on others a centre counts as
/// outside only where the pseudo-normal and the ray parity agree, see
/// [`DistanceGate::centre`]). Most control points of a groom are hair far from the scalp, so
/// the collision projection checks millions of points a pass at the cost of
/// a grid lookup and searches the BVH only near the skin. A cell is measured
/// the first time a point falls in it (the grid reaches far, and a groom
/// visits a small part of it); its value depends only on its centre, so the
/// answers do not depend on which thread measured it first.
#[derive(Clone, Debug)]
struct DistanceGate {
    /// The mesh's own bounding box.
    mesh_lo: V3,
    mesh_hi: V3,
    lo: V3,
    cell: f32,
    dims: [usize; 3],
    /// Per cell the centre's signed distance as `f32` bits, or [`GATE_UNSET`].
    signed: std::sync::Arc<[AtomicU32]>,
    /// Every edge is shared by exactly two triangles: only then is a point
    /// outside the mesh's box outside the mesh. A ground plane's box is
    /// flat, and a blade bent below the plane is outside the box but under
    /// the ground; trusting the box there let such points skip the
    /// collision projection.
    closed: bool,
}

impl DistanceGate {
    fn new(bvh: &MeshBvh) -> Self {
        let root = &bvh.nodes[0];
        let (mesh_lo, mesh_hi) = (root.lo, root.hi);
        let diag = norm(sub(mesh_hi, mesh_lo)).max(f32::MIN_POSITIVE);
        let longest = (0..3).map(|a| mesh_hi[a] - mesh_lo[a]).fold(0.0, f32::max) + 2.0 * GATE_PAD * diag;
        let cell = longest / GATE_CELLS as f32;
        let lo = mesh_lo.map(|c| c - GATE_REACH * diag);
        let dims: [usize; 3] = std::array::from_fn(|a| {
            (((mesh_hi[a] - mesh_lo[a] + 2.0 * GATE_REACH * diag) / cell).ceil() as usize).clamp(1, GATE_MAX_DIM)
        });
        // Centred on the mesh where the cap binds.
        let lo = std::array::from_fn(|a| {
            let span = dims[a] as f32 * cell;
            lo[a].max(0.5 * (mesh_lo[a] + mesh_hi[a]) - 0.5 * span)
        });
        let signed = (0..dims[0] * dims[1] * dims[2]).map(|_| AtomicU32::new(GATE_UNSET)).collect();
        DistanceGate { mesh_lo, mesh_hi, lo, cell, dims, signed, closed: bvh.is_closed() }
    }

    /// The signed distance at cell `i`'s centre `c`, measured on first use.
    fn at(&self, bvh: &MeshBvh, i: usize, c: V3) -> f32 {
        let slot = &self.signed[i];
        let bits = slot.load(Ordering::Relaxed);
        if bits != GATE_UNSET {
            return f32::from_bits(bits);
        }
        let s = Self::centre(bvh, c);
        slot.store(s.to_bits(), Ordering::Relaxed);
        s
    }

    /// The signed distance of a cell centre as the gate trusts it.
    fn centre(bvh: &MeshBvh, c: V3) -> f32 {
        let s = bvh.closest_point(c).signed_distance;
        // A centre is trusted as outside only when the ray's parity
        // agrees with the pseudo-normal: on a mesh with overlapping
        // parts (eyes set into a head) or holes the pseudo-normal's
        // sign can be wrong away from the surface, and a wrong
        // "outside" here would let a point under the skin skip the
        // collision projection. A disagreement costs only a search.
        let s = if s > 0.0 && bvh.inside_by_ray_parity(c) { -s } else { s };
        if s.is_nan() {
            f32::NEG_INFINITY
        } else {
            s
        }
    }

    /// A lower bound on the distance of `p` to the surface when `p` is
    /// certainly outside, else `None`.
    fn outside_by(&self, bvh: &MeshBvh, p: V3) -> Option<f32> {
        // Beyond the grid, the distance to the mesh's box bounds the
        // distance to the mesh (and a point outside the box of a closed
        // mesh is outside it).
        let box_d2: f32 = (0..3)
            .map(|a| {
                let e = (self.mesh_lo[a] - p[a]).max(0.0).max(p[a] - self.mesh_hi[a]);
                e * e
            })
            .sum();
        let outside_box = box_d2.sqrt();
        let mut idx = [0usize; 3];
        let mut centre = [0.0f32; 3];
        let mut e2 = 0.0;
        for a in 0..3 {
            let t = ((p[a] - self.lo[a]) / self.cell).floor();
            let i = if t.is_nan() { 0 } else { (t.max(0.0) as usize).min(self.dims[a] - 1) };
            idx[a] = i;
            centre[a] = self.lo[a] + (i as f32 + 0.5) * self.cell;
            let d = p[a] - centre[a];
            e2 += d * d;
        }
        let s = self.at(bvh, idx[0] + self.dims[0] * (idx[1] + self.dims[1] * idx[2]), centre);
        let near = s - e2.sqrt();
        let bound = if self.closed { near.max(outside_box) } else { near };
        (bound > 0.0).then_some(bound)
    }
}

fn edge_key(a: u32, b: u32) -> (u32, u32) {
    (a.min(b), a.max(b))
}

impl MeshBvh {
    /// Builds the BVH and pseudo-normals. Zero-area triangles are left out
    /// (they have no normal; their points lie on neighbouring faces in any
    /// valid surface). Fails on an out-of-range index or a mesh with no
    /// usable triangle.
    pub fn new(mesh: &TriMesh) -> Result<Self, StrandError> {
        let nv = mesh.vertices.len();
        if let Some((t, _)) = mesh.triangles.iter().enumerate().find(|(_, t)| t.iter().any(|&i| i as usize >= nv)) {
            return Err(StrandError::Invalid(format!("mesh triangle {t} names a vertex beyond the {nv} vertices")));
        }
        let verts = mesh.vertices.clone();
        let tris = mesh.triangles.clone();
        let mut face_n = vec![[0.0; 3]; tris.len()];
        let mut valid = Vec::with_capacity(tris.len());
        for (f, t) in tris.iter().enumerate() {
            let p = t.map(|i| verts[i as usize]);
            if let Some(n) = normalize(cross(sub(p[1], p[0]), sub(p[2], p[0]))) {
                face_n[f] = n;
                valid.push(f as u32);
            }
        }
        if valid.is_empty() {
            return Err(StrandError::Invalid("mesh has no triangle with non-zero area".into()));
        }
        let (side, winding) = Side::classify(&verts, &tris, &face_n, &valid);
        let order: Vec<u32> = valid.into_iter().filter(|&f| side[f as usize] != Side::Buried).collect();
        let mut vert_acc = vec![[0f64; 3]; nv];
        let mut edge_acc: HashMap<(u32, u32), [f64; 3]> = HashMap::new();
        for &f in &order {
            let t = tris[f as usize];
            let p = t.map(|i| verts[i as usize]);
            let n = face_n[f as usize];
            for k in 0..3 {
                // Angle-weighted vertex normals make the pseudo-normal sign
                // test exact at vertices (Bærentzen & Aanæs 2005).
                let e1 = normalize(sub(p[(k + 1) % 3], p[k]));
                let e2 = normalize(sub(p[(k + 2) % 3], p[k]));
                if let (Some(e1), Some(e2)) = (e1, e2) {
                    let ang = dot(e1, e2).clamp(-1.0, 1.0).acos() as f64;
                    for a in 0..3 {
                        vert_acc[t[k] as usize][a] += ang * n[a] as f64;
                    }
                }
                let e = edge_acc.entry(edge_key(t[k], t[(k + 1) % 3])).or_insert([0.0; 3]);
                for a in 0..3 {
                    e[a] += n[a] as f64;
                }
            }
        }
        let unit = |v: [f64; 3]| normalize(v.map(|c| c as f32)).unwrap_or([0.0; 3]);
        let vert_n = vert_acc.into_iter().map(unit).collect();
        let edge_n = edge_acc.into_iter().map(|(k, v)| (k, unit(v))).collect();
        let mut bvh = MeshBvh {
            verts,
            tris,
            order,
            nodes: Vec::new(),
            face_n,
            vert_n,
            edge_n,
            side,
            winding,
            seam_dist: Vec::new(),
            gate: OnceLock::new(),
        };
        let centroids: Vec<V3> = bvh
            .tris
            .iter()
            .map(|t| {
                scale(add(add(bvh.verts[t[0] as usize], bvh.verts[t[1] as usize]), bvh.verts[t[2] as usize]), 1.0 / 3.0)
            })
            .collect();
        let n = bvh.order.len();
        bvh.build(&centroids, 0, n);
        if bvh.winding.is_some() {
            bvh.seam_dist = bvh.distances_to_seams();
        }
        Ok(bvh)
    }

    /// [`MeshBvh::seam_dist`]: for each clean triangle the least distance
    /// from its corners and centroid to a straddling triangle, less half its
    /// longest edge (every point of the triangle is that close to one of
    /// them). Buried triangles are walled in by straddling ones, which
    /// touch them.
    fn distances_to_seams(&self) -> Vec<f32> {
        let seam = |f: u32| self.side[f as usize] == Side::Straddles;
        (0..self.tris.len())
            .into_par_iter()
            .with_min_len(64)
            .map(|f| {
                if self.side[f] != Side::Clean {
                    return 0.0;
                }
                let p = self.tri(f as u32);
                let g = scale(add(add(p[0], p[1]), p[2]), 1.0 / 3.0);
                let edge = (0..3).map(|k| norm(sub(p[(k + 1) % 3], p[k]))).fold(0.0, f32::max);
                let near = [p[0], p[1], p[2], g]
                    .iter()
                    .map(|&x| self.nearest(x, seam).map_or(f32::INFINITY, |h| norm(sub(x, h.point))))
                    .fold(f32::INFINITY, f32::min);
                (near - 0.5 * edge).max(0.0)
            })
            .collect()
    }

    /// How many triangles are buried inside another part of the mesh (left
    /// out of every query) and how many straddle a seam where two parts
    /// meet (see [`MeshBvh`]'s notes on overlapping parts).
    pub fn buried_and_straddling(&self) -> (usize, usize) {
        let count = |s: Side| self.side.iter().filter(|&&x| x == s).count();
        (count(Side::Buried), count(Side::Straddles))
    }

    fn tri(&self, f: u32) -> [V3; 3] {
        self.tris[f as usize].map(|i| self.verts[i as usize])
    }

    fn build(&mut self, centroids: &[V3], start: usize, end: usize) -> u32 {
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        let mut clo = lo;
        let mut chi = hi;
        for &f in &self.order[start..end] {
            for p in self.tri(f) {
                for a in 0..3 {
                    lo[a] = lo[a].min(p[a]);
                    hi[a] = hi[a].max(p[a]);
                }
            }
            let c = centroids[f as usize];
            for a in 0..3 {
                clo[a] = clo[a].min(c[a]);
                chi[a] = chi[a].max(c[a]);
            }
        }
        let id = self.nodes.len() as u32;
        self.nodes.push(Node { lo, hi, start: start as u32, end: end as u32, leaf: true });
        let axis = (0..3).max_by(|&a, &b| (chi[a] - clo[a]).total_cmp(&(chi[b] - clo[b]))).unwrap_or(0);
        if end - start <= LEAF || chi[axis] <= clo[axis] {
            return id;
        }
        let mid = (start + end) / 2;
        self.order[start..end].select_nth_unstable_by(mid - start, |&a, &b| {
            centroids[a as usize][axis].total_cmp(&centroids[b as usize][axis])
        });
        let l = self.build(centroids, start, mid);
        let r = self.build(centroids, mid, end);
        let node = &mut self.nodes[id as usize];
        node.leaf = false;
        node.start = l;
        node.end = r;
        id
    }

    /// Closest point on the mesh to `p`, with its pseudo-normal and signed
    /// distance (negative inside). On a mesh whose parts overlap, the
    /// closest point of the union's surface, signed by the winding number
    /// where the nearest triangle straddles a seam; and a point inside gets
    /// the nearest point it can leave the whole mesh by.
    pub fn closest_point(&self, p: [f32; 3]) -> ClosestHit {
        self.closest_point_reaching(p, 0.0)
    }

    /// [`MeshBvh::closest_point`], where an inside point's way out must
    /// also be outside the whole mesh `reach` beyond the surface along the
    /// way (the collision push's `κτ`).
    fn closest_point_reaching(&self, p: V3, reach: f32) -> ClosestHit {
        let Some(hit) = self.nearest(p, |_| true) else { unreachable!("MeshBvh::new keeps at least one triangle") };
        let Some(w) = &self.winding else { return hit };
        let inside =
            if self.side[hit.triangle] == Side::Straddles { w.at(p) >= 0.5 } else { hit.signed_distance < 0.0 };
        if !inside {
            return ClosestHit { signed_distance: hit.signed_distance.abs(), ..hit };
        }
        let eps = SAMPLE_OFFSET * norm(sub(self.nodes[0].hi, self.nodes[0].lo));
        if self.side[hit.triangle] == Side::Clean && self.seam_dist[hit.triangle] > reach.max(eps) {
            return hit;
        }
        self.exit(p, hit, w, reach)
    }

    /// For a point `p` inside a mesh of overlapping parts, the nearest
    /// surface point `x` it can leave the whole mesh by: the collision push
    /// continues along `p → x` past `x`, so the winding number just beyond
    /// `x` on that line, and `reach` beyond it, must be below ½. Near a seam the nearest triangle
    /// may fail that (an eye's rim inside its socket, where the push would
    /// run into the head), and the next nearest triangle is tried, up to
    /// [`EXIT_TRIES`]; if none passes, the nearest hit stands and the next
    /// pass continues from where this one left the point.
    fn exit(&self, p: V3, hit: ClosestHit, w: &WindingNumber, reach: f32) -> ClosestHit {
        let eps = SAMPLE_OFFSET * norm(sub(self.nodes[0].hi, self.nodes[0].lo));
        let outside = |x: V3, way: V3| [eps, reach.max(eps)].iter().all(|&r| w.at(add(x, scale(way, r))) < 0.5);
        let mut tried = Vec::new();
        let mut cand = hit;
        for _ in 0..EXIT_TRIES {
            let way = normalize(sub(cand.point, p)).unwrap_or(self.face_n[cand.triangle]);
            if outside(cand.point, way) {
                return ClosestHit { signed_distance: -norm(sub(p, cand.point)), ..cand };
            }
            tried.push(cand.triangle as u32);
            match self.nearest(p, |f| !tried.contains(&f)) {
                Some(next) => cand = next,
                None => break,
            }
        }
        ClosestHit { signed_distance: -norm(sub(p, hit.point)), ..hit }
    }

    /// The nearest point on the indexed triangles that `keep` accepts,
    /// signed by its pseudo-normal; `None` when no triangle qualifies.
    fn nearest(&self, p: V3, keep: impl Fn(u32) -> bool) -> Option<ClosestHit> {
        let mut best = (f32::INFINITY, u32::MAX, [0.0; 3], Feature::Face);
        // A fixed stack: this runs for millions of points per constraint
        // pass, and a heap allocation per query was a tenth of its time.
        let mut stack = [(0u32, 0f32); MAX_STACK];
        stack[0] = (0, box_dist2(p, &self.nodes[0]));
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let (id, bd) = stack[top];
            if bd > best.0 {
                continue;
            }
            let n = self.nodes[id as usize];
            if n.leaf {
                for &f in &self.order[n.start as usize..n.end as usize] {
                    if !keep(f) {
                        continue;
                    }
                    let [a, b, c] = self.tri(f);
                    let (x, feat) = closest_point_on_triangle(p, a, b, c);
                    let d = dist2(p, x);
                    if d < best.0 || (d == best.0 && f < best.1) {
                        best = (d, f, x, feat);
                    }
                }
                continue;
            }
            let (l, r) = (n.start, n.end);
            let (dl, dr) = (box_dist2(p, &self.nodes[l as usize]), box_dist2(p, &self.nodes[r as usize]));
            // Push the farther child first so the nearer one is searched
            // first and tightens the bound.
            let (near, far) = if dl <= dr { ((l, dl), (r, dr)) } else { ((r, dr), (l, dl)) };
            if far.1 <= best.0 {
                stack[top] = far;
                top += 1;
            }
            if near.1 <= best.0 {
                stack[top] = near;
                top += 1;
            }
        }
        let (d2, f, x, feature) = best;
        if f == u32::MAX {
            return None;
        }
        let normal = self.pseudo_normal(f, feature);
        let d = d2.sqrt();
        let signed_distance = if dot(sub(p, x), normal) < 0.0 { -d } else { d };
        Some(ClosestHit { point: x, triangle: f as usize, feature, normal, signed_distance })
    }

    /// [`MeshBvh::closest_point`] for a point that only matters when it is
    /// inside or closer than `tau` (the collision projection): `None` when a
    /// coarse grid of distances ([`DistanceGate`], built on the first call)
    /// shows `p` outside and at least `tau` away, without searching. On a
    /// mesh of overlapping parts an inside point's way out must also be
    /// outside `tau` beyond the surface, where the push takes it.
    pub fn closest_point_within(&self, p: [f32; 3], tau: f32) -> Option<ClosestHit> {
        let gate = self.gate.get_or_init(|| DistanceGate::new(self));
        match gate.outside_by(self, p) {
            Some(d) if d >= tau => None,
            _ => Some(self.closest_point_reaching(p, tau)),
        }
    }

    fn pseudo_normal(&self, f: u32, feature: Feature) -> V3 {
        let t = self.tris[f as usize];
        match feature {
            Feature::Face => self.face_n[f as usize],
            Feature::Edge(k) => self.edge_n[&edge_key(t[k as usize], t[(k as usize + 1) % 3])],
            Feature::Vertex(k) => self.vert_n[t[k as usize] as usize],
        }
    }

    /// Signed distance to the surface (negative inside, by pseudo-normal).
    pub fn signed_distance(&self, p: [f32; 3]) -> f32 {
        self.closest_point(p).signed_distance
    }

    /// Every edge borders exactly two of the triangles (a closed surface).
    fn is_closed(&self) -> bool {
        let mut count: HashMap<(u32, u32), u32> = HashMap::new();
        for t in &self.tris {
            for k in 0..3 {
                *count.entry(edge_key(t[k], t[(k + 1) % 3])).or_default() += 1;
            }
        }
        count.values().all(|&n| n == 2)
    }

    /// Inside test by the pseudo-normal sign of the closest point.
    pub fn is_inside(&self, p: [f32; 3]) -> bool {
        self.signed_distance(p) < 0.0
    }

    /// Inside test by the parity of ray crossings (closed meshes only): the
    /// ray leaves along a fixed direction with no simple rational slope, so
    /// it almost never grazes an edge or vertex exactly.
    pub fn inside_by_ray_parity(&self, p: [f32; 3]) -> bool {
        let dir = RAY_DIR;
        let inv = dir.map(|c| 1.0 / c);
        let mut hits = 0usize;
        let mut stack = vec![0u32];
        while let Some(id) = stack.pop() {
            let n = self.nodes[id as usize];
            if !ray_hits_box(p, inv, &n) {
                continue;
            }
            if n.leaf {
                for &f in &self.order[n.start as usize..n.end as usize] {
                    let [a, b, c] = self.tri(f);
                    if ray_triangle(p, dir, a, b, c).is_some() {
                        hits += 1;
                    }
                }
            } else {
                stack.push(n.start);
                stack.push(n.end);
            }
        }
        hits % 2 == 1
    }

    /// Number of triangles indexed (zero-area ones excluded).
    pub fn triangle_count(&self) -> usize {
        self.order.len()
    }
}

/// Direction of the parity ray (irrational-looking components, so it is
/// not aligned with the axis-aligned or symmetric features meshes have).
pub(crate) const RAY_DIR: V3 = [0.536_398_3, 0.627_271_6, 0.564_697_2];

fn box_dist2(p: V3, n: &Node) -> f32 {
    (0..3)
        .map(|a| {
            let e = (n.lo[a] - p[a]).max(0.0).max(p[a] - n.hi[a]);
            e * e
        })
        .sum()
}

fn ray_hits_box(o: V3, inv: V3, n: &Node) -> bool {
    let (mut t0, mut t1) = (0.0f32, f32::INFINITY);
    for a in 0..3 {
        let (ta, tb) = ((n.lo[a] - o[a]) * inv[a], (n.hi[a] - o[a]) * inv[a]);
        t0 = t0.max(ta.min(tb));
        t1 = t1.min(ta.max(tb));
    }
    t0 <= t1
}

/// Möller–Trumbore ray/triangle intersection: the ray parameter `t > 0` of
/// the hit, if any (computed in `f64` so near-edge rays are decided
/// consistently between the BVH and a brute-force loop).
pub(crate) fn ray_triangle(o: V3, d: V3, a: V3, b: V3, c: V3) -> Option<f64> {
    let f = |v: V3| v.map(f64::from);
    let (o, d, a, b, c) = (f(o), f(d), f(a), f(b), f(c));
    let s3 = |x: [f64; 3], y: [f64; 3]| [x[0] - y[0], x[1] - y[1], x[2] - y[2]];
    let cr =
        |x: [f64; 3], y: [f64; 3]| [x[1] * y[2] - x[2] * y[1], x[2] * y[0] - x[0] * y[2], x[0] * y[1] - x[1] * y[0]];
    let dt = |x: [f64; 3], y: [f64; 3]| x[0] * y[0] + x[1] * y[1] + x[2] * y[2];
    let (e1, e2) = (s3(b, a), s3(c, a));
    let pv = cr(d, e2);
    let det = dt(e1, pv);
    if det.abs() < 1e-300 {
        return None;
    }
    let tv = s3(o, a);
    let u = dt(tv, pv) / det;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let qv = cr(tv, e1);
    let v = dt(d, qv) / det;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let t = dt(e2, qv) / det;
    (t > 0.0).then_some(t)
}

/// Closest point to `p` on triangle `abc` and the feature it lies on
/// (Ericson, Real-Time Collision Detection, 5.1.5).
pub fn closest_point_on_triangle(p: [f32; 3], a: [f32; 3], b: [f32; 3], c: [f32; 3]) -> ([f32; 3], Feature) {
    let ab = sub(b, a);
    let ac = sub(c, a);
    let ap = sub(p, a);
    let d1 = dot(ab, ap);
    let d2 = dot(ac, ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return (a, Feature::Vertex(0));
    }
    let bp = sub(p, b);
    let d3 = dot(ab, bp);
    let d4 = dot(ac, bp);
    if d3 >= 0.0 && d4 <= d3 {
        return (b, Feature::Vertex(1));
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return (add(a, scale(ab, v)), Feature::Edge(0));
    }
    let cp = sub(p, c);
    let d5 = dot(ab, cp);
    let d6 = dot(ac, cp);
    if d6 >= 0.0 && d5 <= d6 {
        return (c, Feature::Vertex(2));
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return (add(a, scale(ac, w)), Feature::Edge(2));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (add(b, scale(sub(c, b), w)), Feature::Edge(1));
    }
    let denom = 1.0 / (va + vb + vc);
    let v = vb * denom;
    let w = vc * denom;
    (add(a, add(scale(ab, v), scale(ac, w))), Feature::Face)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use nst3d_core::gradcheck::pseudo_random;
    use std::path::Path;

    /// A mesh of the shared data, failing loudly when it is missing.
    pub(crate) fn data(rel: &str) -> TriMesh {
        let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data").join(rel);
        nst3d_io::mesh::read_mesh(&p)
            .unwrap_or_else(|e| panic!("test data missing or unreadable: {}: {e}", p.display()))
    }

    fn brute_closest(mesh: &TriMesh, p: V3) -> f32 {
        mesh.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| mesh.vertices[i as usize]);
                dist2(p, closest_point_on_triangle(p, a, b, c).0)
            })
            .fold(f32::INFINITY, f32::min)
    }

    /// A point under an open ground plane, deeper than τ, is found: the
    /// plane's box is flat, so the point is outside the box, which says
    /// nothing about an open mesh.
    #[test]
    fn the_gate_finds_a_point_under_an_open_ground() {
        let ground = TriMesh {
            vertices: vec![[-0.5, 0.0, -0.5], [0.5, 0.0, -0.5], [0.5, 0.0, 0.5], [-0.5, 0.0, 0.5]],
            triangles: vec![[0, 2, 1], [0, 3, 2]],
            ..TriMesh::default()
        };
        let bvh = MeshBvh::new(&ground).unwrap();
        assert!(!bvh.is_closed());
        let under = [0.1, -0.03, 0.2];
        let hit = bvh.closest_point_within(under, 0.005).expect("a point under the ground skips the search");
        assert!((hit.signed_distance + 0.03).abs() < 1e-6, "{}", hit.signed_distance);
        assert!(bvh.closest_point_within([0.1, 0.03, 0.2], 0.005).is_none());
    }

    /// The distance gate never lets a point that is inside skip the
    /// search. The monkey's mesh (Suzanne with eyes set into the head) has
    /// regions where the pseudo-normal's sign at a grid centre says outside
    /// while the points around it are inside by both tests; before the gate
    /// checked ray parity, a control point 0.06 under the skin there was
    /// never pushed out.
    #[test]
    fn the_gate_never_skips_a_point_inside() {
        let bvh = MeshBvh::new(&data("grooms/monkey_curly_mesh.obj")).unwrap();
        let tau = 0.02;
        let known = [0.08534093, -0.73407567, 0.3623508];
        assert!(bvh.closest_point(known).signed_distance < 0.0 && bvh.inside_by_ray_parity(known));
        assert!(bvh.closest_point_within(known, 0.0).is_some(), "the gate skips a point under the skin");
        let (lo, hi) = (bvh.nodes[0].lo, bvh.nodes[0].hi);
        let r = pseudo_random(3 * 40_000, 5);
        let mut skipped = 0;
        for c in r.chunks(3) {
            let p: V3 = std::array::from_fn(|a| lo[a] + (0.5 + 0.55 * c[a]) * (hi[a] - lo[a]));
            let exact = bvh.closest_point(p);
            match bvh.closest_point_within(p, tau) {
                None => {
                    skipped += 1;
                    assert!(exact.signed_distance.abs() >= tau, "skipped {p:?} at distance {}", exact.signed_distance);
                    assert!(
                        !(exact.signed_distance < 0.0 && bvh.inside_by_ray_parity(p)),
                        "skipped {p:?}, inside by both tests"
                    );
                }
                // An inside point's way out may be a farther one (it must
                // stay outside `tau` beyond the surface).
                Some(h) if exact.signed_distance < 0.0 => {
                    assert!(h.signed_distance <= exact.signed_distance)
                }
                Some(h) => assert_eq!(h.signed_distance, exact.signed_distance),
            }
        }
        assert!(skipped > 10_000, "the gate should still skip most far points ({skipped} of 40000)");
    }

    /// Hair reaches far beyond the skin: points up to 0.8 of the mesh's
    /// diagonal off its box (on the monkey's open mesh, where the box says
    /// nothing) are skipped when far from it, and only correctly. The grid
    /// used to stop 0.25 diagonals off the box, and monkey_curly's spikes
    /// beyond it were searched in every pass.
    #[test]
    fn the_gate_skips_far_hair_beyond_the_mesh_box() {
        let bvh = MeshBvh::new(&data("grooms/monkey_curly_mesh.obj")).unwrap();
        assert!(!bvh.is_closed());
        let tau = 0.02;
        let (lo, hi) = (bvh.nodes[0].lo, bvh.nodes[0].hi);
        let diag = norm(sub(hi, lo));
        let r = pseudo_random(3 * 20_000, 11);
        let (mut far, mut far_skipped) = (0, 0);
        for c in r.chunks(3) {
            let p: V3 = std::array::from_fn(|a| {
                let (l, h) = (lo[a] - 0.8 * diag, hi[a] + 0.8 * diag);
                l + (0.5 + 0.5 * c[a]) * (h - l)
            });
            let exact = bvh.closest_point(p);
            let skipped = bvh.closest_point_within(p, tau).is_none();
            if skipped {
                assert!(exact.signed_distance >= tau, "skipped {p:?} at {}", exact.signed_distance);
            }
            if exact.signed_distance > 0.1 * diag {
                far += 1;
                far_skipped += skipped as usize;
            }
        }
        assert!(far > 10_000 && far_skipped * 100 >= 99 * far, "{far_skipped} of {far} far points skipped");
    }

    #[test]
    fn closest_point_matches_brute_force_on_head() {
        let mesh = data("grooms/Bangs_head.ply");
        let bvh = MeshBvh::new(&mesh).unwrap();
        let (lo, hi) = mesh.bbox().unwrap();
        let r = pseudo_random(3 * 300, 11);
        for q in r.chunks(3) {
            // Queries over the box grown by 20% each side.
            let p: V3 = std::array::from_fn(|a| {
                let ext = hi[a] - lo[a];
                lo[a] - 0.2 * ext + (q[a] * 0.5 + 0.5) * 1.4 * ext
            });
            let hit = bvh.closest_point(p);
            let want = brute_closest(&mesh, p);
            let got = dist2(p, hit.point);
            assert!((got - want).abs() <= 1e-5 * want.max(1.0), "{p:?}: bvh {got} brute {want}");
            assert!((hit.signed_distance.abs() - got.sqrt()).abs() < 1e-3);
        }
    }

    #[test]
    fn spot_inside_outside_matches_ray_parity_on_grid() {
        let mesh = data("meshes/spot.obj");
        let bvh = MeshBvh::new(&mesh).unwrap();
        let (lo, hi) = mesh.bbox().unwrap();
        let n = 14;
        let (mut inside, mut checked) = (0, 0);
        for k in 0..n {
            for j in 0..n {
                for i in 0..n {
                    let p: V3 = std::array::from_fn(|a| {
                        let t = [i, j, k][a] as f32 / (n - 1) as f32;
                        lo[a] - 0.05 + t * (hi[a] - lo[a] + 0.1)
                    });
                    let hit = bvh.closest_point(p);
                    if hit.signed_distance.abs() < 1e-4 {
                        continue; // sign is ill-posed on the surface itself
                    }
                    let brute = mesh
                        .triangles
                        .iter()
                        .filter(|t| {
                            let [a, b, c] = t.map(|i| mesh.vertices[i as usize]);
                            ray_triangle(p, RAY_DIR, a, b, c).is_some()
                        })
                        .count()
                        % 2
                        == 1;
                    assert_eq!(hit.signed_distance < 0.0, brute, "pseudo-normal vs brute parity at {p:?}");
                    assert_eq!(bvh.inside_by_ray_parity(p), brute, "bvh vs brute parity at {p:?}");
                    inside += brute as usize;
                    checked += 1;
                }
            }
        }
        assert!(inside > 100 && checked - inside > 100, "inside {inside} of {checked}");
    }

    #[test]
    fn triangle_features() {
        let (a, b, c) = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
        let (x, f) = closest_point_on_triangle([0.2, 0.2, 1.0], a, b, c);
        assert!(f == Feature::Face && dist2(x, [0.2, 0.2, 0.0]) < 1e-12);
        assert_eq!(closest_point_on_triangle([-1.0, -1.0, 0.0], a, b, c).1, Feature::Vertex(0));
        assert_eq!(closest_point_on_triangle([0.5, -1.0, 0.0], a, b, c), ([0.5, 0.0, 0.0], Feature::Edge(0)));
        assert_eq!(closest_point_on_triangle([1.0, 1.0, 0.0], a, b, c).1, Feature::Edge(1));
        assert_eq!(closest_point_on_triangle([-1.0, 0.5, 0.0], a, b, c).1, Feature::Edge(2));
        assert!(MeshBvh::new(&TriMesh { vertices: vec![a, b], triangles: vec![[0, 1, 2]], normals: None }).is_err());
    }
}

/// Tests of the collider on meshes of overlapping parts.
#[cfg(test)]
mod overlap_tests {
    use super::tests::data;
    use super::*;
    use nst3d_core::gradcheck::pseudo_random;

    /// Inside or outside as the exact winding number says (`w ≥ ½`), at
    /// 20,000 points over the mesh's box, leaving out the few within 10⁻⁴
    /// of the surface or where `w` is within 0.3 of ½ (an open part's
    /// hole, where inside is a matter of definition). Returns how many were
    /// checked.
    fn sides_agree_with_winding_number(mesh: &TriMesh) -> usize {
        let bvh = MeshBvh::new(mesh).unwrap();
        let wn = WindingNumber::new(&mesh.vertices, &mesh.triangles);
        let (lo, hi) = mesh.bbox().unwrap();
        let mut checked = 0;
        for c in pseudo_random(3 * 20_000, 5).chunks(3) {
            let p: V3 = std::array::from_fn(|a| lo[a] + (0.5 + 0.55 * c[a]) * (hi[a] - lo[a]));
            let w = wn.exact(p);
            let hit = bvh.closest_point(p);
            if (w - 0.5).abs() < 0.3 || hit.signed_distance.abs() < 1e-4 {
                continue;
            }
            assert_eq!(
                hit.signed_distance < 0.0,
                w > 0.5,
                "at {p:?}: w = {w}, signed distance {}",
                hit.signed_distance
            );
            checked += 1;
        }
        checked
    }

    /// Suzanne's ears and eyes are pushed into the head: some triangles
    /// are buried, some straddle a seam, and inside/outside still follows
    /// the winding number everywhere (before the classification, the
    /// nearest triangle's pseudo-normal got 47 of these points wrong).
    #[test]
    fn overlapping_parts_follow_the_winding_number() {
        let mesh = data("grooms/monkey_curly_mesh.obj");
        let (buried, straddling) = MeshBvh::new(&mesh).unwrap().buried_and_straddling();
        assert!(buried > 100 && straddling > 100, "buried {buried}, straddling {straddling}");
        assert!(sides_agree_with_winding_number(&mesh) > 19_000);
    }

    /// A mesh in one part has nothing buried or straddling, so it is
    /// queried exactly as before (the Bangs head is open at the neck, the
    /// cow is closed).
    #[test]
    fn single_part_meshes_are_unchanged() {
        for m in ["grooms/Bangs_head.ply", "meshes/spot.obj"] {
            let mesh = data(m);
            let bvh = MeshBvh::new(&mesh).unwrap();
            assert_eq!(bvh.buried_and_straddling(), (0, 0), "{m}");
            assert!(bvh.winding.is_none(), "{m}");
            assert!(sides_agree_with_winding_number(&mesh) > 19_000, "{m}");
        }
    }
}
