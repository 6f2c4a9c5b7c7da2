//! The rest groom fitted outside the head mesh before a stylization starts:
//! roots lifted out, strands threading through the mesh turned out, then
//! lengths and collisions enforced to convergence.

use nst3d_core::math::{add, cross, dot, normalize, scale, sub, V3};

use rayon::prelude::*;

use super::enforce;
use crate::bvh::MeshBvh;
use crate::constraints::{strand_length_error, strands_mut, CollisionParams, ConstraintTape, Constraints};
use crate::pipeline::PipelineError;
use crate::strands::FlatStrands;

/// The undeformed groom `x₀` the stylization starts from: real grooms do not
/// fit their heads exactly (a tenth of the Bangs groom's control points lie
/// up to 15 units inside its head, some roots 1.7 units under the scalp), so
/// strands whose root is inside are first moved out along the root's normal,
/// rigidly, and then lengths and collisions are enforced in turn until the
/// groom is outside the mesh with its segment lengths kept to 0.1 %. Without
/// this the first iteration's collision pass would move the groom away from
/// the render the targets were matched on.
pub(super) fn resolve_rest(
    raw: &FlatStrands,
    bvh: &MeshBvh,
    collision: CollisionParams,
    diag: f32,
) -> Result<FlatStrands, PipelineError> {
    let mut s = raw.clone();
    lift_roots(&mut s, bvh, lift_margin(diag));
    let c = Constraints { rest: raw.clone(), collider: Some(bvh.clone()), collision };
    fit_outside(&mut s, &c, bvh)?;
    Ok(s)
}

/// The constraints enforced to convergence on `s` (lengths of `c.rest`,
/// outside `bvh`). A strand the projections could not fit threads through
/// the mesh (in one side of an ear and out of the other, or pushed through
/// a thin part by the stylization): pushing each point to its nearest side
/// stretches it across. Such a strand is first turned rigidly about its
/// root to the nearest pose with the least penetration, then fitted like
/// the others.
pub(super) fn fit_outside(s: &mut FlatStrands, c: &Constraints, bvh: &MeshBvh) -> Result<(), PipelineError> {
    let mut fitted = s.clone();
    enforce(&mut fitted, c, 200, &mut ConstraintTape::off())?;
    let stuck: Vec<usize> = (0..s.strand_count())
        .filter(|&k| strand_length_error(fitted.strand(k), c.rest.strand(k)) > STUCK_LENGTH_ERROR)
        .collect();
    if stuck.is_empty() {
        *s = fitted;
        return Ok(());
    }
    // The projections act on each strand alone, so only the turned strands
    // are fitted again; the others keep the first fit (the same points a
    // second fit of the whole groom gave, at a fraction of its time).
    let subset = |from: &FlatStrands| FlatStrands::from_strands(stuck.iter().map(|&k| from.strand(k).to_vec()));
    let mut turned = subset(s)?;
    let offsets = turned.offsets.clone();
    strands_mut(&mut turned.points, &offsets).into_par_iter().for_each(|pts| turn_out_of_mesh(pts, bvh));
    let sub = Constraints { rest: subset(&c.rest)?, collider: c.collider.clone(), collision: c.collision };
    enforce(&mut turned, &sub, 200, &mut ConstraintTape::off())?;
    for (i, &k) in stuck.iter().enumerate() {
        let r = fitted.range(k);
        fitted.points[r].copy_from_slice(turned.strand(i));
    }
    *s = fitted;
    Ok(())
}

/// Relative segment-length error above which [`resolve_rest`] turns a
/// strand out of the mesh.
pub(super) const STUCK_LENGTH_ERROR: f32 = 0.01;

/// Turns the strand `pts` rigidly about its root, by the smallest of a
/// fan of angles (7.5° steps up to 180°, 8 axes perpendicular to the root's
/// normal) that minimises the summed depth of its points inside the mesh.
/// The fan reaches past 90° for a strand grown from a face buried in
/// another part (monkey_straight's strand 4140, rooted on the ear where it
/// sinks into the head): its root is lifted out of the head's side, the
/// strand points back into the head, and only turning it round frees it;
/// up to 90° the best pose was still 0.02 deep and the fit stretched it
/// 8.6 %.
fn turn_out_of_mesh(pts: &mut [V3], bvh: &MeshBvh) {
    let root = pts[0];
    // The summed depth of `q`'s points inside, or `None` once it reaches
    // `bound` (a pose no better than the best so far). A point the collision
    // gate shows outside adds nothing without a search.
    let depth = |q: &[V3], bound: f32| -> Option<f32> {
        let mut sum = 0.0f32;
        for &p in &q[1..] {
            sum += bvh.closest_point_within(p, 0.0).map_or(0.0, |h| (-h.signed_distance).max(0.0));
            // A NaN depth counts as no better.
            if !(sum < bound) {
                return None;
            }
        }
        Some(sum)
    };
    let n = bvh.closest_point(root).normal;
    let helper = if n[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
    let Some(e1) = normalize(cross(n, helper)) else { return };
    let e2 = cross(n, e1);
    let mut best = (depth(pts, f32::INFINITY).unwrap_or(f32::INFINITY), pts.to_vec());
    'search: for step in 1..=24 {
        let theta = (7.5 * step as f32).to_radians();
        for a in 0..8 {
            let phi = a as f32 * std::f32::consts::TAU / 8.0;
            let axis = add(scale(e1, phi.cos()), scale(e2, phi.sin()));
            let turned: Vec<V3> = pts.iter().map(|&p| add(root, rotate(sub(p, root), axis, theta))).collect();
            if let Some(d) = depth(&turned, best.0) {
                best = (d, turned);
            }
        }
        if best.0 == 0.0 {
            break 'search;
        }
    }
    pts.copy_from_slice(&best.1);
}

/// `v` rotated by `theta` about the unit `axis` (Rodrigues).
fn rotate(v: V3, axis: V3, theta: f32) -> V3 {
    let (c, s) = (theta.cos(), theta.sin());
    add(add(scale(v, c), scale(cross(axis, v), s)), scale(axis, dot(axis, v) * (1.0 - c)))
}

/// Bounding box of a point set.
pub(super) fn points_bbox(points: &[V3]) -> (V3, V3) {
    let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for p in points {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    (lo, hi)
}

/// Margin of [`lift_roots`] for a mesh of bounding-box diagonal `diag`.
pub(super) fn lift_margin(diag: f32) -> f32 {
    1e-4 * diag
}

/// Pushes [`lift_roots`] makes at most per strand.
const LIFT_PASSES: usize = 8;

/// Moves every strand whose root is inside the mesh rigidly out along the
/// root's normal, to `margin` outside (see [`resolve_rest`]), pushing again
/// while the root is still inside: on a mesh of overlapping parts the way
/// out is the nearest surface the root can leave the whole mesh by, and one
/// push along its pseudo-normal can stop short of it near a seam
/// (monkey_curly's strand 16, rooted 0.1 inside where an eye meets the
/// head, was left 0.0013 inside after one push and written so; two push it
/// out). On a single closed surface one push always suffices.
pub(super) fn lift_roots(s: &mut FlatStrands, bvh: &MeshBvh, margin: f32) {
    for k in 0..s.strand_count() {
        let r = s.range(k);
        for _ in 0..LIFT_PASSES {
            let hit = bvh.closest_point(s.points[r.start]);
            if hit.signed_distance >= 0.0 {
                break;
            }
            let push = scale(hit.normal, -hit.signed_distance + margin);
            for p in &mut s.points[r.clone()] {
                *p = add(*p, push);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::max_length_change;
    use super::*;
    use nst3d_core::math::norm;

    /// A root deep in the seam where Suzanne's eye meets the head (the input
    /// root of monkey_curly's strand 16, 0.1 inside) is lifted outside the
    /// whole mesh, by the collider's test and by ray parity; one push along
    /// the pseudo-normal left it 0.0013 inside and the written groom had
    /// it so.
    #[test]
    fn a_root_in_a_seam_of_overlapping_parts_is_lifted_out() {
        let mesh = crate::bvh::tests::data("grooms/monkey_curly_mesh.obj");
        let bvh = MeshBvh::new(&mesh).unwrap();
        let root = [-0.18110968, -0.65078723, 0.4164371];
        assert!(bvh.closest_point(root).signed_distance < -0.05 && bvh.inside_by_ray_parity(root));
        let mut s =
            FlatStrands::from_strands([vec![root, add(root, [0.0, -0.1, 0.1]), add(root, [0.0, -0.2, 0.2])]]).unwrap();
        let before = s.clone();
        let (lo, hi) = mesh.bbox().unwrap();
        let diag = norm(sub(hi, lo));
        lift_roots(&mut s, &bvh, lift_margin(diag));
        let lifted = s.points[0];
        assert!(bvh.closest_point(lifted).signed_distance >= 0.0, "root still inside: {lifted:?}");
        assert!(!bvh.inside_by_ray_parity(lifted), "root inside by ray parity: {lifted:?}");
        // Rigidly: every point moved by the root's displacement.
        let d = sub(lifted, root);
        for (a, b) in s.points.iter().zip(&before.points) {
            assert!(norm(sub(sub(*a, *b), d)) < 1e-6);
        }
    }

    #[test]
    fn a_strand_threading_through_the_mesh_is_turned_out_with_its_length() {
        let sphere = crate::generators::uv_sphere(1.0, 32, 64);
        let bvh = MeshBvh::new(&sphere).unwrap();
        // Rooted on the sphere, entering it at 45° and leaving through the
        // far side of the cap: each point's nearest way out differs.
        let (root, dir) =
            ([1.0f32, 0.0, 0.0], [-std::f32::consts::FRAC_1_SQRT_2, 0.0, std::f32::consts::FRAC_1_SQRT_2]);
        let raw =
            FlatStrands::from_strands([(0..12).map(|k| add(root, scale(dir, 0.15 * k as f32))).collect()]).unwrap();
        assert!(raw.points[1..].iter().any(|&p| bvh.is_inside(p)));
        let collision = CollisionParams { tau: 0.01, kappa: 0.5, skip_roots: true };
        let fitted = resolve_rest(&raw, &bvh, collision, 2.0 * 3f32.sqrt()).unwrap();
        let inside = fitted.points[1..].iter().filter(|&&p| bvh.is_inside(p)).count();
        assert_eq!(inside, 0, "points left inside");
        let change = max_length_change(&raw, &fitted);
        assert!(change < 0.01, "length changed by {change}");
    }

    /// monkey_straight's strand 4140 grows from Suzanne's ear where it
    /// sinks into the head: its root and first point are inside the whole
    /// mesh. Lifted out of the head's side, it points back in; turning it
    /// up to 90° left it 0.02 deep and the fit stretched it 8.6 %, and the
    /// written groom, lifted again after its fit, had 8 points inside. The
    /// rest fit keeps its length with no point inside.
    #[test]
    fn a_strand_grown_from_a_buried_face_is_turned_round() {
        let mesh = crate::bvh::tests::data("grooms/monkey_curly_mesh.obj");
        let bvh = MeshBvh::new(&mesh).unwrap();
        let wn = crate::winding::WindingNumber::new(&mesh.vertices, &mesh.triangles);
        let (lo, hi) = mesh.bbox().unwrap();
        let diag = norm(sub(hi, lo));
        let raw = FlatStrands::from_strands([vec![
            [0.871285439, 0.326230258, 0.127717257],
            [0.853215098, 0.350033998, 0.14729321],
            [0.829127431, 0.38727501, 0.167325288],
            [0.803541183, 0.43222484, 0.182709873],
            [0.77819562, 0.481632352, 0.193571836],
            [0.751199365, 0.538507342, 0.202306166],
            [0.71989578, 0.607746363, 0.210016042],
            [0.686623514, 0.684837282, 0.214677855],
            [0.653997719, 0.764476836, 0.215443537],
            [0.61955595, 0.852038682, 0.214635789],
            [0.580241024, 0.953878641, 0.212977946],
            [0.538416922, 1.06406701, 0.208613724],
            [0.497795135, 1.17432666, 0.200648367],
            [0.455831826, 1.2909025, 0.190322086],
            [0.408953458, 1.4225421, 0.178297073],
            [0.358742565, 1.56580722, 0.163922623],
            [0.313386321, 1.70175886, 0.147172511],
        ]])
        .unwrap();
        assert!(wn.exact(raw.points[0]) > 0.5 && wn.exact(raw.points[1]) > 0.5);
        let collision = CollisionParams { tau: 0.005 * diag, kappa: 0.5, skip_roots: true };
        let fitted = resolve_rest(&raw, &bvh, collision, diag).unwrap();
        let inside = fitted.points.iter().filter(|&&q| wn.exact(q) >= 0.5).count();
        assert_eq!(inside, 0, "points left inside");
        let change = max_length_change(&raw, &fitted);
        assert!(change < 0.01, "length changed by {change}");
    }
}
