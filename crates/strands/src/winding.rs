//! The generalized winding number of a triangle mesh (Jacobson, Kavan &
//! Sorkine-Hornung 2013): the signed solid angle the surface subtends at a
//! point, over 4π. It is 1 inside and 0 outside a closed, outward-oriented
//! shell, 2 where two such shells overlap, and varies smoothly across the
//! holes of an open one — so "inside" (`w ≥ ½`) stays meaningful for meshes
//! built from parts pushed into each other (Suzanne's ears and eyes), where
//! the nearest triangle's side does not say which side of the *whole* a
//! point is on.
//!
//! Summed exactly over every triangle it costs a mesh per query; far
//! clusters of triangles are replaced by their first-order dipole
//! (Barill et al. 2018, "Fast Winding Numbers for Soups and Clouds"): a node
//! whose triangles have area vector `N = Σ aᵢ n̂ᵢ` around the area-weighted
//! centre `c` contributes `N · (c − p) / (4π ‖c − p‖³)` once `p` is farther
//! than `β` times the node's radius. Near the surface, where the answer
//! matters, the nodes open down to exact triangles.

use nst3d_core::math::{cross, dot, norm, sub, V3};

/// Triangles per leaf.
const LEAF: usize = 8;
/// A node is approximated by its dipole when the query is farther than this
/// many of its radii from its centre (Barill et al. use 2 with second- and third-order terms; the first-order
/// dipole alone is within 0.011 of the exact sum at 4, 0.024 at 3, 0.066 at 2
/// on the meshes tested — ample for a test against ½).
const BETA: f64 = 4.0;

type D3 = [f64; 3];

fn d3(v: V3) -> D3 {
    v.map(f64::from)
}

/// The signed solid angle of triangle `abc` seen from `p`, over 4π
/// (Van Oosterom & Strackee 1983): positive when `p` is behind the face
/// whose normal is `(b − a) × (c − a)`.
pub(crate) fn triangle_winding(p: D3, a: D3, b: D3, c: D3) -> f64 {
    solid_angle_by(p, a, b, c, f64::atan2)
}

/// [`triangle_winding`] with a polynomial arctangent (within 2e-6 rad):
/// `libm`'s `atan2` was 43 % of the collision projection's time on the
/// monkey.
fn triangle_winding_fast(p: D3, a: D3, b: D3, c: D3) -> f64 {
    solid_angle_by(p, a, b, c, fast_atan2)
}

/// `atan2(y, x)` to within 2e-6 rad: an 11th-order odd polynomial for
/// `atan` on [0, 1] folded to every octant.
fn fast_atan2(y: f64, x: f64) -> f64 {
    use std::f64::consts::{FRAC_PI_2, PI};
    let (ax, ay) = (x.abs(), y.abs());
    let (lo, hi) = (ax.min(ay), ax.max(ay));
    if hi == 0.0 {
        return 0.0;
    }
    let a = lo / hi;
    let s = a * a;
    // Least-squares odd polynomial for atan on [0, 1] (max error 1.8e-6).
    let mut r = a
        * (0.999_979_831_590_576_9
            + s * (-0.332_655_419_451_317_66
                + s * (0.193_669_888_280_036_98
                    + s * (-0.116_649_978_772_942_74 + s * (0.052_822_194_889_601_13 - s * 0.011_769_974_089_825_9)))));
    if ay > ax {
        r = FRAC_PI_2 - r;
    }
    if x < 0.0 {
        r = PI - r;
    }
    if y < 0.0 {
        -r
    } else {
        r
    }
}

fn solid_angle_by(p: D3, a: D3, b: D3, c: D3, atan2: impl Fn(f64, f64) -> f64) -> f64 {
    let (a, b, c) = (sub(a, p), sub(b, p), sub(c, p));
    let (la, lb, lc) = (norm(a), norm(b), norm(c));
    let num = dot(a, cross(b, c));
    let den = la * lb * lc + dot(a, b) * lc + dot(b, c) * la + dot(c, a) * lb;
    if num == 0.0 && den <= 0.0 {
        // On the triangle's plane, inside it or on its edges: ill-posed,
        // taken as the plane's own value.
        return 0.0;
    }
    atan2(num, den) / (2.0 * std::f64::consts::PI)
}

#[derive(Clone, Copy, Debug)]
struct Node {
    /// Area-weighted centre of the node's triangles.
    centre: D3,
    /// `Σ aᵢ n̂ᵢ`, half the sum of the triangles' edge cross products.
    dipole: D3,
    /// Largest distance from `centre` to a corner of the node's triangles.
    radius: f64,
    /// Leaf: triangle range in `order`; inner: the two children.
    start: u32,
    end: u32,
    leaf: bool,
}

/// Fast generalized winding numbers of one triangle mesh.
#[derive(Clone, Debug)]
pub struct WindingNumber {
    tris: Vec<[D3; 3]>,
    order: Vec<u32>,
    nodes: Vec<Node>,
}

impl WindingNumber {
    /// Builds the tree over the triangles `tris` (indices into `verts`).
    pub fn new(verts: &[V3], tris: &[[u32; 3]]) -> Self {
        let tris: Vec<[D3; 3]> = tris.iter().map(|t| t.map(|i| d3(verts[i as usize]))).collect();
        let mut w = WindingNumber { order: (0..tris.len() as u32).collect(), tris, nodes: Vec::new() };
        if !w.tris.is_empty() {
            let n = w.order.len();
            w.build(0, n);
        }
        w
    }

    fn centroid(&self, f: u32) -> D3 {
        let [a, b, c] = self.tris[f as usize];
        std::array::from_fn(|k| (a[k] + b[k] + c[k]) / 3.0)
    }

    fn build(&mut self, start: usize, end: usize) -> u32 {
        let (mut area, mut centre, mut dipole) = (0.0, [0.0; 3], [0.0; 3]);
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for &f in &self.order[start..end] {
            let [a, b, c] = self.tris[f as usize];
            let n = cross(sub(b, a), sub(c, a));
            let ar = 0.5 * norm(n);
            let g = self.centroid(f);
            for k in 0..3 {
                dipole[k] += 0.5 * n[k];
                centre[k] += ar * g[k];
                lo[k] = lo[k].min(g[k]);
                hi[k] = hi[k].max(g[k]);
            }
            area += ar;
        }
        if area > 0.0 {
            centre = centre.map(|c| c / area);
        } else {
            centre = std::array::from_fn(|k| 0.5 * (lo[k] + hi[k]));
        }
        let radius = self.order[start..end]
            .iter()
            .flat_map(|&f| self.tris[f as usize])
            .map(|v| norm(sub(v, centre)))
            .fold(0.0, f64::max);
        let id = self.nodes.len() as u32;
        self.nodes.push(Node { centre, dipole, radius, start: start as u32, end: end as u32, leaf: true });
        let axis = (0..3).max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b]))).unwrap_or(0);
        if end - start <= LEAF || hi[axis] <= lo[axis] {
            return id;
        }
        let mid = (start + end) / 2;
        let mut order = std::mem::take(&mut self.order);
        order[start..end]
            .select_nth_unstable_by(mid - start, |&a, &b| self.centroid(a)[axis].total_cmp(&self.centroid(b)[axis]));
        self.order = order;
        let l = self.build(start, mid);
        let r = self.build(mid, end);
        let node = &mut self.nodes[id as usize];
        node.leaf = false;
        node.start = l;
        node.end = r;
        id
    }

    /// The winding number at `p`, fast (see the module's notes): within
    /// about 0.01 of [`WindingNumber::exact`] on the meshes tested.
    pub fn at(&self, p: V3) -> f64 {
        if self.nodes.is_empty() {
            return 0.0;
        }
        let p = d3(p);
        let mut w = 0.0;
        let mut stack = vec![0u32];
        while let Some(id) = stack.pop() {
            let n = self.nodes[id as usize];
            let r = sub(n.centre, p);
            let d = norm(r);
            if d > BETA * n.radius {
                w += dot(n.dipole, r) / (4.0 * std::f64::consts::PI * d * d * d);
            } else if n.leaf {
                for &f in &self.order[n.start as usize..n.end as usize] {
                    let [a, b, c] = self.tris[f as usize];
                    w += triangle_winding_fast(p, a, b, c);
                }
            } else {
                stack.push(n.start);
                stack.push(n.end);
            }
        }
        w
    }

    /// The winding number at `p` summed exactly over every triangle (the
    /// reference for [`WindingNumber::at`]).
    pub fn exact(&self, p: V3) -> f64 {
        let p = d3(p);
        self.tris.iter().map(|&[a, b, c]| triangle_winding(p, a, b, c)).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::tests::data;
    use nst3d_core::gradcheck::pseudo_random;
    use nst3d_core::mesh::TriMesh;

    fn box_points(mesh: &TriMesh, n: usize, seed: u64) -> Vec<V3> {
        let (lo, hi) = mesh.bbox().unwrap();
        pseudo_random(3 * n, seed)
            .chunks(3)
            .map(|c| std::array::from_fn(|a| lo[a] + (0.5 + 0.6 * c[a]) * (hi[a] - lo[a])))
            .collect()
    }

    #[test]
    fn fast_arctangent_is_within_2e_6() {
        let r = pseudo_random(2 * 20_000, 4);
        for c in r.chunks(2) {
            let (y, x) = (c[0] as f64 * 3.0, c[1] as f64 * 2.0);
            assert!((fast_atan2(y, x) - y.atan2(x)).abs() < 2e-6, "{y} {x}");
        }
        for (y, x) in [(0.0, 1.0), (1.0, 0.0), (0.0, -1.0), (-1.0, 0.0), (1.0, 1.0), (-1.0, -1.0)] {
            assert!((fast_atan2(y, x) - f64::atan2(y, x)).abs() < 2e-6, "{y} {x}");
        }
    }

    /// One triangle's solid angle: a quarter of the sphere seen from the
    /// corner of an octant's face triangle far away is tiny, and from just
    /// behind the middle of a huge triangle it is half the sphere.
    #[test]
    fn triangle_solid_angle() {
        let (a, b, c) = ([-1e4, -1e4, 0.0], [1e4, -1e4, 0.0], [0.0, 1e4, 0.0]);
        assert!((triangle_winding([0.0, 0.0, -1.0], a, b, c) - 0.5).abs() < 1e-3);
        assert!((triangle_winding([0.0, 0.0, 1.0], a, b, c) + 0.5).abs() < 1e-3);
        // The octant triangle (1,0,0),(0,1,0),(0,0,1) from the origin: 1/8 of
        // the sphere, and the origin is behind it.
        let w = triangle_winding([0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]);
        assert!((w - 0.125).abs() < 1e-12, "{w}");
    }

    /// A closed mesh (spot, the cow): 1 inside, 0 outside, exactly as the
    /// parity of ray crossings says, and the fast sum within 0.02 of the
    /// exact one.
    #[test]
    fn closed_mesh_is_zero_or_one_and_fast_matches_exact() {
        let mesh = data("meshes/spot.obj");
        let wn = WindingNumber::new(&mesh.vertices, &mesh.triangles);
        let bvh = crate::MeshBvh::new(&mesh).unwrap();
        let (mut inside, mut worst) = (0, 0.0f64);
        for p in box_points(&mesh, 400, 3) {
            let (fast, exact) = (wn.at(p), wn.exact(p));
            worst = worst.max((fast - exact).abs());
            if bvh.closest_point(p).signed_distance.abs() < 1e-3 {
                continue;
            }
            let parity = bvh.inside_by_ray_parity(p);
            assert!((exact - parity as u8 as f64).abs() < 1e-6, "w = {exact} at {p:?}, parity inside {parity}");
            inside += parity as usize;
        }
        assert!(worst < 0.02, "fast vs exact {worst}");
        assert!(inside > 20, "only {inside} points inside");
    }

    /// Suzanne (the monkey's mesh): its ears and eyes are pushed into the
    /// head, so the winding number goes above 1 where they overlap (not to
    /// 2: the parts are open, up to 1.66 at the points sampled); the fast
    /// sum stays within 0.02 of the exact one there too.
    #[test]
    fn overlapping_shells_count_twice() {
        let mesh = data("grooms/monkey_curly_mesh.obj");
        let wn = WindingNumber::new(&mesh.vertices, &mesh.triangles);
        let (mut twice, mut worst) = (0, 0.0f64);
        for p in box_points(&mesh, 3000, 7) {
            let (fast, exact) = (wn.at(p), wn.exact(p));
            worst = worst.max((fast - exact).abs());
            twice += (exact > 1.2) as usize;
        }
        assert!(worst < 0.02, "fast vs exact {worst}");
        assert!(twice > 0, "no point found where two parts overlap");
    }
}
