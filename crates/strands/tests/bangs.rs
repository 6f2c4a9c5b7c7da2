//! The groom stages end to end on the real Bangs groom and head: densify,
//! deform with a field that drives strands into the head, restore lengths,
//! project collisions.

use std::path::{Path, PathBuf};

use nst3d_core::gradcheck::{check_gradient, dot, pseudo_random};
use nst3d_strands::*;

fn data(name: &str) -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/grooms").join(name);
    assert!(p.exists(), "test data missing: {}", p.display());
    p
}

fn load() -> (FlatStrands, nst3d_io::mesh::TriMesh) {
    let groom = nst3d_io::groom::read_groom(&data("Bangs_100.hair")).expect("read Bangs_100.hair");
    let head = nst3d_io::mesh::read_mesh(&data("Bangs_head.ply")).expect("read Bangs_head.ply");
    (FlatStrands::from_groom(&groom).unwrap(), head)
}

#[test]
fn bangs_densify_deform_constrain() {
    let (guides, head) = load();
    let bvh = MeshBvh::new(&head).unwrap();
    let (lo, hi) = head.bbox().unwrap();
    let diag = (0..3).map(|a| (hi[a] - lo[a]).powi(2)).sum::<f32>().sqrt();

    // Densify: deterministic, roots on the head near the guide roots.
    let params = DensifyParams { count: 400, points_per_strand: Some(16), seed: 1, ..Default::default() };
    let proxies = densify(&guides, Some(&head), &params).unwrap();
    assert_eq!(proxies, densify(&guides, Some(&head), &params).unwrap());
    assert_eq!(proxies.strand_count(), 400);
    // Every proxy root lies in the root region: within twice the guide
    // roots' mean nearest-neighbour spacing of a guide root (the default
    // radius), measured here by brute force — an eighth of the head, where
    // the old bound (half the head's diagonal) could not fail.
    let groots = guides.roots();
    let dist = |a: [f32; 3], b: [f32; 3]| (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f32>().sqrt();
    let nearest = |p: [f32; 3], skip: Option<usize>| {
        groots
            .iter()
            .enumerate()
            .filter(|(j, _)| Some(*j) != skip)
            .map(|(_, &g)| dist(p, g))
            .fold(f32::INFINITY, f32::min)
    };
    let spacing = groots.iter().enumerate().map(|(i, &g)| nearest(g, Some(i))).sum::<f32>() / groots.len() as f32;
    let radius = 2.0 * spacing;
    assert!(radius < 0.2 * diag, "guide roots {spacing} apart on a head of {diag}");
    let mut near_guide = vec![false; groots.len()];
    for r in proxies.roots() {
        assert!(bvh.signed_distance(r).abs() < 1e-3 * diag, "proxy root off the scalp");
        let d = nearest(r, None);
        assert!(d <= radius * (1.0 + 1e-5), "proxy root {d} from the nearest guide root, outside the region {radius}");
        for (j, &g) in groots.iter().enumerate() {
            near_guide[j] |= dist(r, g) <= radius;
        }
    }
    // And the proxies spread over the scalp instead of crowding one guide.
    let covered = near_guide.iter().filter(|&&c| c).count();
    assert!(covered * 10 >= groots.len() * 8, "only {covered} of {} guides have a proxy nearby", groots.len());
    let mut all = guides.clone();
    all.append(&proxies);

    // Field on the guides, acting on guides and proxies.
    let field = DeformationField::on_guides(&guides, &all, SampleDensity::Fraction(0.665), Kernel::Cubic, 8).unwrap();
    let n_guide_points = guides.points.len();
    assert_eq!(field.sample_count(), (0.665 * n_guide_points as f64).round() as usize);

    // Gradient check on the real configuration.
    let v0: Vec<f32> = pseudo_random(3 * field.sample_count(), 2).iter().map(|x| x * 5.0).collect();
    let w: Vec<f32> = pseudo_random(3 * all.points.len(), 3);
    let unflat = |x: &[f32]| x.chunks(3).map(|c| [c[0], c[1], c[2]]).collect::<Vec<_>>();
    let flat = |v: &[[f32; 3]]| v.iter().flatten().copied().collect::<Vec<f32>>();
    let analytic = flat(&field.backward(&unflat(&w)).unwrap());
    // Points sit ~200 units from the origin, so f32 rounding of p + Wv is
    // ~1e-5; T is affine in v, so a large step keeps that out of the ratio.
    let r = check_gradient(&v0, &analytic, |x| dot(&w, &flat(&field.forward(&unflat(x)).unwrap())), 20.0, 200, 1e-2);
    assert!(r.max_rel_err < 1e-3, "{r:?}");

    // Velocities pulling every sample towards the head's centre.
    let centre: [f32; 3] = std::array::from_fn(|a| 0.5 * (lo[a] + hi[a]));
    let v: Vec<[f32; 3]> = field.samples().iter().map(|o| std::array::from_fn(|a| 0.35 * (centre[a] - o[a]))).collect();
    let mut deformed = all.with_points(field.forward(&v).unwrap()).unwrap();
    let inside_before = deformed.points.iter().filter(|&&p| bvh.is_inside(p)).count();
    assert!(inside_before > 100, "the test field should cause penetrations, got {inside_before}");

    preserve_lengths(&mut deformed, &all).unwrap();
    for (a, b) in deformed.segment_lengths().iter().zip(all.segment_lengths()) {
        assert!((a - b).abs() <= 1e-5 * b, "segment {a} vs rest {b}");
    }

    let collision = CollisionParams { tau: 0.005 * diag, kappa: 0.5, skip_roots: true };
    let stats = project_collisions(&mut deformed, &bvh, collision).unwrap();
    assert!(stats.inside > 0 && stats.moved >= stats.inside);
    let is_root: std::collections::HashSet<usize> =
        deformed.offsets[..deformed.strand_count()].iter().copied().collect();
    let inside_after =
        (0..deformed.points.len()).filter(|i| !is_root.contains(i) && bvh.is_inside(deformed.points[*i])).count();
    assert_eq!(inside_after, 0, "{inside_after} control points still inside the head");
    // Repelled points end κτ outside, up to the faceting of the head (the
    // push follows the nearest feature; a neighbouring facet or a concave
    // spot can be a little closer).
    let near = (0..deformed.points.len())
        .filter(|i| !is_root.contains(i))
        .filter(|&i| bvh.signed_distance(deformed.points[i]) < 0.5 * collision.kappa * collision.tau)
        .count();
    assert!(near * 50 <= stats.moved, "{near} of {} moved points end closer than κτ/2", stats.moved);

    // The combined operator keeps the same guarantee.
    let cons = Constraints { rest: all.clone(), collider: Some(bvh.clone()), collision };
    let mut again = all.with_points(field.forward(&v).unwrap()).unwrap();
    cons.apply(&mut again).unwrap();
    assert!((0..again.points.len()).all(|i| is_root.contains(&i) || !bvh.is_inside(again.points[i])));
}
