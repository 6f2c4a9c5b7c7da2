//! Densification (Sec. 3.1, Table 1's "densified strands"): proxy strands
//! grown between the guides so the renders are dense, moved by the same
//! deformation field as the guides (they are just more points `p`).
//!
//! Roots are sampled uniformly by area on the scalp mesh, restricted to the
//! guides' root region: the points within `root_radius` of some guide root
//! (default: twice the mean distance from a guide root to its nearest other
//! guide root, which covers the gaps between guides without spreading onto
//! bald skin). A proxy's shape is the inverse-squared-distance weighted sum
//! of its nearest guides' root-relative offsets, all guides resampled to a
//! common point count by arc length.

use nst3d_core::mesh::TriMesh;

use crate::kdtree::KdTree;
use crate::strand_rng;
use crate::strands::{resample_polyline, FlatStrands};
use crate::StrandError;
use nst3d_core::math::{add, cross, dist2, norm, normalize, scale, sub, SplitMix64, V3};

/// Densification settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DensifyParams {
    /// Number of proxy strands `M` to grow.
    pub count: usize,
    /// Points per proxy strand; `None` takes the guides' largest count.
    pub points_per_strand: Option<usize>,
    /// Guides blended per proxy (nearest by root distance).
    pub neighbors: usize,
    /// Root region radius around the guide roots; `None` picks the default
    /// described in the module notes.
    pub root_radius: Option<f32>,
    /// Seed of the root sampler; equal seeds give equal proxies.
    pub seed: u64,
}

impl Default for DensifyParams {
    fn default() -> Self {
        DensifyParams { count: 0, points_per_strand: None, neighbors: 4, root_radius: None, seed: 0 }
    }
}

/// Grows `params.count` proxy strands on `scalp` between `guides`. Without
/// a scalp (grooms exported without their mesh) a proxy's root is drawn in
/// the disc around a random guide root, perpendicular to that guide's first
/// segment (the hair leaves the skin along its normal, so the disc stands
/// in for the skin's tangent plane).
pub fn densify(
    guides: &FlatStrands,
    scalp: Option<&TriMesh>,
    params: &DensifyParams,
) -> Result<FlatStrands, StrandError> {
    Ok(densify_weighted(guides, scalp, params)?.0)
}

/// Which guides a proxy strand was blended from, and with what weights
/// (they sum to 1): its shape is its root plus this blend of the guides'
/// root-relative shapes, point by point.
pub type ProxyBlend = Vec<(u32, f32)>;

/// [`densify`] with each proxy's [`ProxyBlend`], so attributes other than
/// the shape (a stylized colour) can be blended the same way.
pub fn densify_weighted(
    guides: &FlatStrands,
    scalp: Option<&TriMesh>,
    params: &DensifyParams,
) -> Result<(FlatStrands, Vec<ProxyBlend>), StrandError> {
    if params.neighbors == 0 {
        return Err(StrandError::Parameter("densification needs at least 1 guide per proxy".into()));
    }
    let roots = guides.roots();
    let root_tree = KdTree::new(&roots);
    let radius = match params.root_radius {
        Some(r) if r > 0.0 && r.is_finite() => r,
        Some(r) => return Err(StrandError::Parameter(format!("root radius {r} must be finite and > 0"))),
        None => {
            if roots.len() < 2 {
                return Err(StrandError::Parameter("one guide: give the root radius explicitly".into()));
            }
            let mean: f64 =
                roots.iter().map(|&r| root_tree.knn(r, 2)[1].0.sqrt() as f64).sum::<f64>() / roots.len() as f64;
            (2.0 * mean).max(1e-12) as f32
        }
    };
    let p = params
        .points_per_strand
        .unwrap_or_else(|| (0..guides.strand_count()).map(|s| guides.strand(s).len()).max().unwrap_or(2));
    if p < 2 {
        return Err(StrandError::Parameter(format!("{p} points per proxy strand, need at least 2")));
    }
    let sampler = match scalp {
        Some(scalp) => RootSampler::on_scalp(scalp, &root_tree, radius, params.count)?,
        None => RootSampler::AroundGuides(
            (0..guides.strand_count())
                .map(|s| {
                    let g = guides.strand(s);
                    let d = g.get(1).and_then(|&q| normalize(sub(q, g[0]))).unwrap_or([0.0, 0.0, 1.0]);
                    (g[0], d)
                })
                .collect(),
        ),
    };
    // Guide shapes as root-relative offsets at the common point count.
    let offsets: Vec<Vec<V3>> = (0..guides.strand_count())
        .map(|s| {
            let g = guides.strand(s);
            let g = if g.len() == p { g.to_vec() } else { resample_polyline(g, p) };
            g.iter().map(|&q| sub(q, g[0])).collect()
        })
        .collect();
    let mut rng = strand_rng(params.seed);
    let max_attempts = 1000 * params.count.max(1);
    let mut attempts = 0;
    let mut strands = Vec::with_capacity(params.count);
    let mut blends = Vec::with_capacity(params.count);
    while strands.len() < params.count {
        attempts += 1;
        if attempts > max_attempts {
            return Err(StrandError::Invalid(format!(
                "densification accepted only {} of {} roots in {max_attempts} tries: the root region barely touches the scalp",
                strands.len(),
                params.count
            )));
        }
        let root = sampler.sample(&mut rng, radius);
        let nn = root_tree.knn(root, params.neighbors);
        if nn[0].0.sqrt() > radius {
            continue;
        }
        let weights: Vec<(usize, f64)> = if nn[0].0 <= 1e-12 * radius * radius {
            vec![(nn[0].1 as usize, 1.0)]
        } else {
            let w: Vec<f64> = nn.iter().map(|&(d2, _)| 1.0 / d2 as f64).collect();
            let sum: f64 = w.iter().sum();
            nn.iter().zip(w).map(|(&(_, g), w)| (g as usize, w / sum)).collect()
        };
        let pts = (0..p)
            .map(|k| {
                let mut q = root.map(f64::from);
                for &(g, w) in &weights {
                    for ax in 0..3 {
                        q[ax] += w * offsets[g][k][ax] as f64;
                    }
                }
                q.map(|c| c as f32)
            })
            .collect();
        strands.push(pts);
        blends.push(weights.iter().map(|&(g, w)| (g as u32, w as f32)).collect());
    }
    if strands.is_empty() {
        return Ok((FlatStrands { points: Vec::new(), offsets: vec![0] }, blends));
    }
    Ok((FlatStrands::from_strands(strands)?, blends))
}

/// Where proxy roots are drawn.
enum RootSampler {
    /// Area-uniform on the scalp triangles near a guide root: the triangle
    /// corners and the running sum of areas.
    OnScalp { triangles: Vec<[V3; 3]>, cdf: Vec<f64> },
    /// In the disc of the root radius around a uniformly chosen guide root,
    /// perpendicular to its growth direction: `(root, direction)` per guide.
    AroundGuides(Vec<(V3, V3)>),
}

impl RootSampler {
    fn on_scalp(scalp: &TriMesh, root_tree: &KdTree, radius: f32, count: usize) -> Result<Self, StrandError> {
        // Candidate triangles: those whose bounding sphere reaches the region.
        let nv = scalp.vertices.len();
        let (mut triangles, mut cdf) = (Vec::new(), Vec::new());
        let mut acc = 0.0;
        for t in &scalp.triangles {
            if t.iter().any(|&i| i as usize >= nv) {
                return Err(StrandError::Invalid(format!("scalp triangle names a vertex beyond the {nv} vertices")));
            }
            let v = t.map(|i| scalp.vertices[i as usize]);
            let c = scale(add(add(v[0], v[1]), v[2]), 1.0 / 3.0);
            let rad = v.iter().map(|&q| dist2(q, c)).fold(0.0, f32::max).sqrt();
            let area = 0.5 * norm(cross(sub(v[1], v[0]), sub(v[2], v[0]))) as f64;
            let near = root_tree.nearest(c).map(|(d2, _)| d2.sqrt()).unwrap_or(f32::INFINITY);
            if area > 0.0 && near <= radius + rad {
                acc += area;
                triangles.push(v);
                cdf.push(acc);
            }
        }
        if triangles.is_empty() && count > 0 {
            return Err(StrandError::Invalid(format!("no scalp triangle within {radius} of a guide root")));
        }
        Ok(RootSampler::OnScalp { triangles, cdf })
    }

    fn sample(&self, rng: &mut SplitMix64, radius: f32) -> V3 {
        match self {
            RootSampler::OnScalp { triangles, cdf } => {
                let u = rng.uniform_f64() * cdf.last().copied().unwrap_or(0.0);
                let ti = cdf.partition_point(|&c| c <= u).min(triangles.len() - 1);
                let [a, b, c] = triangles[ti];
                // Uniform point in a triangle (square-root warp).
                let (r1, r2) = (rng.uniform_f32().sqrt(), rng.uniform_f32());
                add(add(scale(a, 1.0 - r1), scale(b, r1 * (1.0 - r2))), scale(c, r1 * r2))
            }
            RootSampler::AroundGuides(guides) => {
                let g = ((rng.uniform_f64() * guides.len() as f64) as usize).min(guides.len() - 1);
                let (root, d) = guides[g];
                let helper = if d[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
                let e1 = normalize(cross(d, helper)).unwrap_or([0.0, 1.0, 0.0]);
                let e2 = cross(d, e1);
                // Uniform in the disc (square-root warp of the radius).
                let (r, phi) = (radius * rng.uniform_f32().sqrt(), std::f32::consts::TAU * rng.uniform_f32());
                add(root, add(scale(e1, r * phi.cos()), scale(e2, r * phi.sin())))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::generators::{fur_ball, FurBallParams};

    #[test]
    fn proxies_are_deterministic_on_the_scalp_and_between_guides() {
        let (guides, mesh) = fur_ball(&FurBallParams { strands: 200, points: 6, ..Default::default() }).unwrap();
        let params = DensifyParams { count: 300, seed: 7, ..Default::default() };
        let a = densify(&guides, Some(&mesh), &params).unwrap();
        let b = densify(&guides, Some(&mesh), &params).unwrap();
        assert_eq!(a, b);
        let c = densify(&guides, Some(&mesh), &DensifyParams { seed: 8, ..params }).unwrap();
        assert_ne!(a, c);
        assert_eq!(a.strand_count(), 300);
        let bvh = crate::bvh::MeshBvh::new(&mesh).unwrap();
        for s in 0..a.strand_count() {
            let st = a.strand(s);
            assert_eq!(st.len(), 6);
            assert!(bvh.signed_distance(st[0]).abs() < 1e-5);
            // Fur points along the normal: a blend of nearby normals still
            // points outwards.
            assert!(bvh.signed_distance(st[5]) > 0.5 * 0.2);
        }
    }

    #[test]
    fn without_a_scalp_proxies_root_in_the_guides_tangent_discs() {
        let (guides, _) = fur_ball(&FurBallParams { strands: 200, points: 6, ..Default::default() }).unwrap();
        let params = DensifyParams { count: 300, seed: 7, root_radius: Some(0.1), ..Default::default() };
        let a = densify(&guides, None, &params).unwrap();
        assert_eq!(a, densify(&guides, None, &params).unwrap());
        assert_eq!(a.strand_count(), 300);
        let roots = guides.roots();
        for s in 0..a.strand_count() {
            let r = a.strand(s)[0];
            let near = roots.iter().map(|&g| dist2(g, r)).fold(f32::INFINITY, f32::min).sqrt();
            assert!(near <= 0.1 * 1.0001, "root {r:?} is {near} from the nearest guide root");
            // The fur ball is the unit sphere: a root in a tangent disc of
            // radius 0.1 is within 0.005 of it.
            assert!((norm(r) - 1.0).abs() < 0.006, "root {r:?} off the sphere's tangent planes");
        }
    }
}
