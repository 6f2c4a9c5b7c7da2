//! Procedural test grooms of Table 1 — the fur ball (Fig. 8) and the grass
//! patch (Fig. 12) — with their collider meshes, and a deterministic
//! time-varying wind to animate them (Fig. 8's fur ball is "subjected to
//! wind with varying direction"). Y is up, like the Bangs groom.

use nst3d_core::mesh::TriMesh;

use crate::constraints::preserve_lengths;
use crate::strand_rng;
use crate::strands::FlatStrands;
use crate::StrandError;
use nst3d_core::math::{add, cross, dot, normalize, scale, V3};

/// A closed UV sphere of `radius` centred at the origin, `rings ≥ 2`
/// latitude bands and `segments ≥ 3` longitude slices, counter-clockwise
/// seen from outside (outward normals).
pub fn uv_sphere(radius: f32, rings: usize, segments: usize) -> TriMesh {
    let (rings, segments) = (rings.max(2), segments.max(3));
    let mut vertices = vec![[0.0, radius, 0.0]];
    for i in 1..rings {
        let th = std::f32::consts::PI * i as f32 / rings as f32;
        for j in 0..segments {
            let ph = std::f32::consts::TAU * j as f32 / segments as f32;
            vertices.push([radius * th.sin() * ph.cos(), radius * th.cos(), radius * th.sin() * ph.sin()]);
        }
    }
    vertices.push([0.0, -radius, 0.0]);
    let south = (vertices.len() - 1) as u32;
    let ring = |i: usize, j: usize| (1 + (i - 1) * segments + j % segments) as u32;
    let mut triangles = Vec::new();
    for j in 0..segments {
        triangles.push([0, ring(1, j + 1), ring(1, j)]);
        triangles.push([south, ring(rings - 1, j), ring(rings - 1, j + 1)]);
    }
    for i in 1..rings - 1 {
        for j in 0..segments {
            let (a, b, c, d) = (ring(i, j), ring(i, j + 1), ring(i + 1, j), ring(i + 1, j + 1));
            triangles.push([a, b, d]);
            triangles.push([a, d, c]);
        }
    }
    TriMesh { vertices, triangles, normals: None }
}

fn straight_strand(root: V3, dir: V3, length: f32, points: usize) -> Vec<V3> {
    (0..points).map(|k| add(root, scale(dir, length * k as f32 / (points - 1) as f32))).collect()
}

fn check_counts(strands: usize, points: usize, length: f32) -> Result<(), StrandError> {
    if strands == 0 || points < 2 {
        return Err(StrandError::Parameter(format!(
            "{strands} strands × {points} points: need ≥ 1 strand of ≥ 2 points"
        )));
    }
    if !(length > 0.0 && length.is_finite()) {
        return Err(StrandError::Parameter(format!("strand length {length} must be > 0")));
    }
    Ok(())
}

/// Fur ball settings (Fig. 8; Table 1: 8 K guides of 9 points).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FurBallParams {
    /// Sphere radius.
    pub radius: f32,
    /// Number of strands `N`.
    pub strands: usize,
    /// Control points per strand `P`.
    pub points: usize,
    /// Strand length `L`.
    pub length: f32,
    /// Seed of the root sampler.
    pub seed: u64,
}

impl Default for FurBallParams {
    /// Table 1's counts; radius 1 and length 0.25 are our choice (the
    /// paper gives neither).
    fn default() -> Self {
        FurBallParams { radius: 1.0, strands: 8000, points: 9, length: 0.25, seed: 0 }
    }
}

/// Straight strands along the normal of a sphere, roots uniform on it, and
/// the sphere as a 32 × 64 UV mesh (its facets lie up to `0.0012 r` inside
/// the true sphere, so roots sit just outside the collider).
pub fn fur_ball(p: &FurBallParams) -> Result<(FlatStrands, TriMesh), StrandError> {
    check_counts(p.strands, p.points, p.length)?;
    if !(p.radius > 0.0 && p.radius.is_finite()) {
        return Err(StrandError::Parameter(format!("fur ball radius {} must be > 0", p.radius)));
    }
    let mut rng = strand_rng(p.seed);
    let strands = (0..p.strands).map(|_| {
        let n = rng.unit_vector();
        straight_strand(scale(n, p.radius), n, p.length, p.points)
    });
    Ok((FlatStrands::from_strands(strands)?, uv_sphere(p.radius, 32, 64)))
}

/// Grass patch settings (Fig. 12; Table 1: 3 K guides of 9 points).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GrassParams {
    /// Patch extent along X.
    pub width: f32,
    /// Patch extent along Z.
    pub depth: f32,
    /// Number of blades `N`.
    pub strands: usize,
    /// Control points per blade `P`.
    pub points: usize,
    /// Blade length `L`.
    pub length: f32,
    /// Largest tilt from vertical, degrees.
    pub max_tilt_deg: f32,
    /// Seed of the root and tilt sampler.
    pub seed: u64,
}

impl Default for GrassParams {
    /// Table 1's counts; the 1 × 1 patch, 0.3 blades and 10° tilt are our
    /// choice.
    fn default() -> Self {
        GrassParams { width: 1.0, depth: 1.0, strands: 3000, points: 9, length: 0.3, max_tilt_deg: 10.0, seed: 0 }
    }
}

/// Near-vertical straight blades rooted uniformly on the `y = 0` plane
/// patch centred at the origin, each tilted by a uniform angle in
/// `[0, max_tilt]` towards a uniform azimuth; the patch as a two-triangle
/// mesh facing +Y.
pub fn grass_patch(p: &GrassParams) -> Result<(FlatStrands, TriMesh), StrandError> {
    check_counts(p.strands, p.points, p.length)?;
    if !(p.width > 0.0 && p.depth > 0.0 && (0.0..90.0).contains(&p.max_tilt_deg)) {
        return Err(StrandError::Parameter(format!(
            "grass patch {} × {} with tilt {}°: need positive extents and tilt in [0, 90)",
            p.width, p.depth, p.max_tilt_deg
        )));
    }
    let mut rng = strand_rng(p.seed);
    let strands = (0..p.strands).map(|_| {
        let root = [(rng.uniform_f32() - 0.5) * p.width, 0.0, (rng.uniform_f32() - 0.5) * p.depth];
        let tilt = p.max_tilt_deg.to_radians() * rng.uniform_f32();
        let az = std::f32::consts::TAU * rng.uniform_f32();
        let dir = [tilt.sin() * az.cos(), tilt.cos(), tilt.sin() * az.sin()];
        straight_strand(root, dir, p.length, p.points)
    });
    let (w, d) = (0.5 * p.width, 0.5 * p.depth);
    let mesh = TriMesh {
        vertices: vec![[-w, 0.0, -d], [w, 0.0, -d], [w, 0.0, d], [-w, 0.0, d]],
        triangles: vec![[0, 2, 1], [0, 3, 2]],
        normals: None,
    };
    Ok((FlatStrands::from_strands(strands)?, mesh))
}

/// A smooth, deterministic wind: a horizontal push whose direction turns
/// slowly and whose strength is a mean plus two travelling sine gusts,
/// bending each strand more towards the tip. Segment lengths are kept.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Wind {
    /// Wind azimuth at `t = 0` in the XZ plane, degrees (0 = +X).
    pub direction_deg: f32,
    /// How fast the azimuth turns, degrees per second.
    pub turn_deg_per_s: f32,
    /// Tip displacement before length restoration, in strand lengths.
    pub strength: f32,
    /// Gust wavelength along the wind, scene units.
    pub wavelength: f32,
    /// Gust frequency, Hz.
    pub frequency_hz: f32,
}

impl Default for Wind {
    /// A moderate breeze for unit-sized scenes (our choice).
    fn default() -> Self {
        Wind { direction_deg: 0.0, turn_deg_per_s: 30.0, strength: 0.6, wavelength: 1.5, frequency_hz: 0.7 }
    }
}

impl Wind {
    /// The strands of `rest` at time `time_s` (seconds): each point moves by
    /// `strength · L · s² · g(root, t) · w(t)` with `s` its rest arc-length
    /// fraction (0 at the root), `w(t)` the horizontal wind direction and
    /// `g` the gust profile (mean 0.5, always ≥ 0.1); then
    /// [`preserve_lengths`] restores every rest segment length, so the
    /// push turns into a bend. Roots stay fixed.
    pub fn at_time(&self, rest: &FlatStrands, time_s: f32) -> Result<FlatStrands, StrandError> {
        let az = (self.direction_deg + self.turn_deg_per_s * time_s).to_radians();
        let w = [az.cos(), 0.0, az.sin()];
        // A second gust direction, across the wind, decorrelates neighbours.
        let across = normalize(cross([0.0, 1.0, 0.0], w)).unwrap_or([0.0, 0.0, 1.0]);
        let k = std::f32::consts::TAU / self.wavelength.max(1e-6);
        let om = std::f32::consts::TAU * self.frequency_hz;
        let mut out = rest.clone();
        for s in 0..rest.strand_count() {
            let pts = rest.strand(s);
            let root = pts[0];
            let along = dot(root, w);
            let g = 0.5
                + 0.25 * (k * along - om * time_s).sin()
                + 0.15 * (1.7 * k * dot(root, across) + 0.6 * k * along - 1.9 * om * time_s + 1.3).sin();
            let mut acc = vec![0.0f32; pts.len()];
            for i in 1..pts.len() {
                acc[i] = acc[i - 1] + nst3d_core::math::norm(nst3d_core::math::sub(pts[i], pts[i - 1]));
            }
            let len = acc[pts.len() - 1].max(1e-20);
            let range = rest.range(s);
            for (i, q) in out.points[range].iter_mut().enumerate() {
                let f = acc[i] / len;
                *q = add(*q, scale(w, self.strength * len * f * f * g));
            }
        }
        preserve_lengths(&mut out, rest)?;
        Ok(out)
    }

    /// [`Wind::at_time`] for frame `frame` at `fps` frames per second.
    pub fn frame(&self, rest: &FlatStrands, frame: usize, fps: f32) -> Result<FlatStrands, StrandError> {
        if !(fps > 0.0 && fps.is_finite()) {
            return Err(StrandError::Parameter(format!("frame rate {fps} must be > 0")));
        }
        self.at_time(rest, frame as f32 / fps)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::MeshBvh;
    use nst3d_core::math::{dist2, norm, sub};

    #[test]
    fn sphere_is_closed_and_outward() {
        let m = uv_sphere(2.0, 12, 24);
        let bvh = MeshBvh::new(&m).unwrap();
        assert!(bvh.is_inside([0.1, 0.2, -0.3]));
        assert!(!bvh.is_inside([0.0, 2.5, 0.0]));
        assert!(bvh.inside_by_ray_parity([0.1, 0.2, -0.3]));
        // Signed volume (divergence theorem) is positive for outward faces.
        let vol: f32 = m
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| m.vertices[i as usize]);
                dot(a, cross(b, c)) / 6.0
            })
            .sum();
        let exact = 4.0 / 3.0 * std::f32::consts::PI * 8.0;
        assert!(vol > 0.9 * exact && vol < exact);
    }

    #[test]
    fn fur_ball_and_grass_shapes() {
        let (fur, mesh) =
            fur_ball(&FurBallParams { strands: 500, points: 5, length: 0.3, radius: 1.5, seed: 3 }).unwrap();
        assert_eq!((fur.strand_count(), fur.points.len()), (500, 2500));
        assert_eq!(
            fur,
            fur_ball(&FurBallParams { strands: 500, points: 5, length: 0.3, radius: 1.5, seed: 3 }).unwrap().0
        );
        let bvh = MeshBvh::new(&mesh).unwrap();
        for s in 0..fur.strand_count() {
            let st = fur.strand(s);
            assert!((norm(st[0]) - 1.5).abs() < 1e-5 && (norm(st[4]) - 1.8).abs() < 1e-5);
            assert!(bvh.signed_distance(st[0]) >= 0.0);
        }
        let (grass, plane) = grass_patch(&GrassParams { strands: 300, ..Default::default() }).unwrap();
        assert_eq!(plane.triangles.len(), 2);
        for s in 0..grass.strand_count() {
            let st = grass.strand(s);
            assert_eq!(st[0][1], 0.0);
            let tilt = (st[8][1] / 0.3).clamp(-1.0, 1.0).acos().to_degrees();
            assert!(tilt <= 10.0 + 1e-3);
        }
        assert!(MeshBvh::new(&plane).unwrap().signed_distance([0.1, 0.2, 0.1]) > 0.0);
        assert!(fur_ball(&FurBallParams { points: 1, ..Default::default() }).is_err());
        assert!(grass_patch(&GrassParams { max_tilt_deg: 95.0, ..Default::default() }).is_err());
    }

    #[test]
    fn wind_is_smooth_deterministic_and_length_preserving() {
        let (rest, _) = grass_patch(&GrassParams { strands: 200, ..Default::default() }).unwrap();
        let wind = Wind::default();
        let f10 = wind.frame(&rest, 10, 24.0).unwrap();
        assert_eq!(f10, wind.frame(&rest, 10, 24.0).unwrap());
        let f11 = wind.frame(&rest, 11, 24.0).unwrap();
        assert_eq!(f10.roots(), rest.roots());
        for (a, b) in f10.segment_lengths().iter().zip(rest.segment_lengths()) {
            assert!((a - b).abs() <= 1e-5 * b);
        }
        let (mut mid, mut tip, mut step) = (0.0, 0.0, 0.0f32);
        for s in 0..rest.strand_count() {
            let r = rest.range(s);
            mid += dist2(f10.points[r.start + 4], rest.points[r.start + 4]).sqrt();
            tip += dist2(f10.points[r.end - 1], rest.points[r.end - 1]).sqrt();
            step = step.max(norm(sub(f11.points[r.end - 1], f10.points[r.end - 1])));
        }
        assert!(tip > 2.0 * mid && mid > 0.0, "tip {tip} mid {mid}");
        // Frame to frame the tips move a small fraction of the blade length.
        assert!(step < 0.1 * 0.3, "step {step}");
    }
}
