//! Camera sets Θ for eq. 1 sampled on a sphere around the volume: the
//! *omniview* distribution (Sec. 4), relaxed towards a Poisson-disk set so
//! no side of the smoke is left unseen, and turntable rings for previews and
//! held-out views. Directions come from a seeded SplitMix64, so a seed fixes
//! the cameras.

use crate::camera::{Camera, Projection};
use nst3d_core::math::{add, dot, norm, sub, unit, SplitMix64};

/// `count` independent uniform directions on the unit sphere (Archimedes:
/// uniform height and azimuth give uniform area), deterministic for a seed.
pub fn sphere_uniform(count: usize, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = SplitMix64::new(seed);
    (0..count)
        .map(|_| {
            let u = rng.uniform_f64();
            sphere_point(u, rng.uniform_f64())
        })
        .collect()
}

/// The unit direction at height `1 − 2u` and azimuth `2πv`: uniform on the
/// sphere for `u`, `v` uniform in `[0, 1)` (Archimedes).
pub fn sphere_point(u: f64, v: f64) -> [f64; 3] {
    let z = 1.0 - 2.0 * u;
    let phi = std::f64::consts::TAU * v;
    let s = (1.0 - z * z).max(0.0).sqrt();
    [s * phi.cos(), s * phi.sin(), z]
}

/// Relaxation iterations; enough for a few hundred cameras to settle.
const RELAX_ITERS: usize = 400;

/// The omniview directions of Sec. 4: [`sphere_uniform`] samples relaxed
/// towards a Poisson-disk distribution by iterative repulsion. Each step
/// moves every point along the tangent of its Riesz-energy force
/// `Σ (p_i − p_j) / |p_i − p_j|^(s+2)` and projects it back onto the sphere.
/// The exponent `s` is annealed from 2 (Coulomb-like, spreads points
/// globally) to 24 (only nearest neighbours matter), so the end state
/// approximately maximises the minimum separation: a Poisson-disk set with the
/// largest disk radius, close to the best (Tammes) packing. The step length
/// shrinks from a tenth to a thousandth of the mean spacing. O(count²) per
/// iteration, fine for the tens to hundreds of cameras used per frame.
pub fn poisson_disk_sphere(count: usize, seed: u64) -> Vec<[f64; 3]> {
    let mut pts = sphere_uniform(count, seed);
    if count < 2 {
        return pts;
    }
    let spacing = (4.0 * std::f64::consts::PI / count as f64).sqrt();
    let mut force = vec![[0.0f64; 3]; count];
    for it in 0..RELAX_ITERS {
        let a = it as f64 / (RELAX_ITERS - 1) as f64;
        let s = 2.0 + 22.0 * a;
        let step = spacing * 0.1 * (0.01f64).powf(a);
        // Distances relative to the current minimum keep (d_min/d)^(s+2) in range.
        let mut d_min = f64::INFINITY;
        for i in 0..count {
            for j in i + 1..count {
                d_min = d_min.min(norm(sub(pts[i], pts[j])));
            }
        }
        let d_min = d_min.max(1e-9);
        force.iter_mut().for_each(|f| *f = [0.0; 3]);
        for i in 0..count {
            for j in i + 1..count {
                let d = sub(pts[i], pts[j]);
                let len = norm(d).max(1e-9);
                let w = (d_min / len).powf(s + 2.0);
                for a in 0..3 {
                    force[i][a] += w * d[a];
                    force[j][a] -= w * d[a];
                }
            }
        }
        // Tangential part only; normalised by the largest so the step length is controlled.
        let tangents: Vec<[f64; 3]> =
            pts.iter().zip(&force).map(|(p, f)| sub(*f, p.map(|x| x * dot(*f, *p)))).collect();
        let t_max = tangents.iter().map(|t| norm(*t)).fold(0.0, f64::max);
        if t_max <= 0.0 {
            break;
        }
        for (p, t) in pts.iter_mut().zip(&tangents) {
            *p = unit(add(*p, t.map(|x| x * step / t_max)));
        }
    }
    pts
}

/// Smallest angle in degrees between any two of the unit directions
/// (`180` for fewer than two): the Poisson-disk radius a set achieves.
pub fn min_angular_distance_deg(dirs: &[[f64; 3]]) -> f64 {
    let mut best = 180f64;
    for i in 0..dirs.len() {
        for j in i + 1..dirs.len() {
            best = best.min(dot(dirs[i], dirs[j]).clamp(-1.0, 1.0).acos().to_degrees());
        }
    }
    best
}

/// A camera on [`Camera::orbit`]'s sphere around the grid centre in direction
/// `dir` (unit, index space), looking at the centre with the given up.
fn sphere_camera(grid_dims: [usize; 3], projection: Projection, dir: [f64; 3], up: [f64; 3]) -> Camera {
    let base = Camera::orbit(grid_dims, 0.0, 0.0);
    let dist = norm(std::array::from_fn(|a| (base.eye[a] - base.target[a]) as f64));
    Camera {
        projection,
        eye: std::array::from_fn(|a| base.target[a] + (dist * dir[a]) as f32),
        up: up.map(|x| x as f32),
        ..base
    }
}

/// `count` omniview cameras (Sec. 4) for a grid of `grid_dims`: directions
/// from [`poisson_disk_sphere`], each eye on [`Camera::orbit`]'s sphere
/// (outside the grid's bounding sphere, which fits its field of view) looking
/// at the grid centre. Up is +y, as for the orbit cameras, unless the view is
/// within ~25° of vertical; then it is the world axis least aligned with the
/// view, so it is never parallel to it. Deterministic for a seed.
pub fn omniview(count: usize, seed: u64, grid_dims: [usize; 3], projection: Projection) -> Vec<Camera> {
    poisson_disk_sphere(count, seed).into_iter().map(|dir| camera_towards(dir, grid_dims, projection)).collect()
}

/// The camera of an omniview set in direction `dir` (unit, index space):
/// on [`Camera::orbit`]'s sphere, looking at the grid centre, up +y unless
/// the view is within ~25° of vertical (then the world axis least aligned
/// with it).
pub fn camera_towards(dir: [f64; 3], grid_dims: [usize; 3], projection: Projection) -> Camera {
    let up = if dir[1].abs() < 0.9 {
        [0.0, 1.0, 0.0]
    } else if dir[0].abs() <= dir[2].abs() {
        [1.0, 0.0, 0.0]
    } else {
        [0.0, 0.0, 1.0]
    };
    sphere_camera(grid_dims, projection, dir, up)
}

/// A turntable: `count` cameras at evenly spaced azimuths (starting at the
/// [`Camera::front`] view, turning towards +x) and a common elevation, for
/// previews and held-out test views. Up is the elevation tangent, which is
/// +y re-orthogonalised (as [`Camera::orbit`]) and stays valid at ±90°.
pub fn ring(count: usize, elevation_deg: f32, grid_dims: [usize; 3], projection: Projection) -> Vec<Camera> {
    let el = (elevation_deg as f64).to_radians();
    (0..count)
        .map(|i| {
            let az = std::f64::consts::TAU * i as f64 / count as f64;
            let dir = [az.sin() * el.cos(), el.sin(), az.cos() * el.cos()];
            let up = [-az.sin() * el.sin(), el.cos(), -az.cos() * el.sin()];
            sphere_camera(grid_dims, projection, dir, up)
        })
        .collect()
}
