//! The whole strands chain of Alg. 1 — velocities → RBF transport (eq. 5) →
//! length and collision projections → Gaussian-splat render → VGG-19 →
//! NNST loss against matched targets — differentiated by
//! [`loss_and_gradient`] and checked against central finite differences,
//! on the real Bangs groom and its head (as the volume chain's
//! `view_loss_gradient_matches_finite_differences` is on smoke).

use std::path::{Path, PathBuf};

use nst3d_core::gradcheck::pseudo_random;
use nst3d_core::Image;
use nst3d_features::{Vgg19, VggFlavor, VggLayer};
use nst3d_strands::pipeline::*;
use nst3d_strands::Preset;

fn data(name: &str) -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/grooms").join(name);
    assert!(p.exists(), "test data missing: {}", p.display());
    p
}

/// A painting-like test pattern: diagonal stripes under a soft blob.
fn painting(n: usize) -> Image {
    let mut data = vec![0.0; 3 * n * n];
    for c in 0..3 {
        for y in 0..n {
            for x in 0..n {
                let (u, v) = (x as f32 / n as f32, y as f32 / n as f32);
                let stripes = 0.5 + 0.5 * (18.0 * (u + 0.6 * v) + c as f32).sin();
                let blob = (-((u - 0.4).powi(2) + (v - 0.6).powi(2)) * 6.0).exp();
                data[(c * n + y) * n + x] = 0.7 * stripes * (0.3 + 0.7 * blob);
            }
        }
    }
    Image::from_vec(3, n, n, data)
}

/// Checks [`loss_and_gradient`] at a small random velocity field on Bangs
/// (with or without its head) against central differences: along the
/// gradient itself, which is what the optimizer follows (a wrong component
/// anywhere lowers the numeric slope below `|g|`), and entry by entry on
/// the largest entries. Along random directions the slope is `|g|/√n`,
/// below f32's resolution of the loss, so those are not probed.
fn check_chain(with_head: bool) {
    let groom = nst3d_io::groom::read_groom(&data("Bangs_100.hair")).expect("read Bangs_100.hair");
    let head = nst3d_io::mesh::read_mesh(&data("Bangs_head.ply")).expect("read Bangs_head.ply");
    let mut params = StylizeParams::from_preset(Preset::ShortHair.params(), groom.strand_count());
    params.proxies = 150;
    params.render_size = 64;
    let scene = StrandScene::new(&groom, with_head.then_some(&head), &params).unwrap();
    let vgg = Vgg19::random(VggFlavor::Torchvision, 7);
    vgg.prepare(VggLayer::Relu4_1);
    let target = style_target(&vgg, &painting(64), 48).unwrap();
    // Looking down on the bangs from 40° above the horizon, about where the
    // roots' mean normal pointed (the cameras' front before they circled
    // the up axis). From near the horizon the bangs' strands overlap in
    // depth and, with the head, every large entry sits on a depth-order
    // switch (10°: 0 of 16 entries smooth; 25°: 3 of 5 agree).
    let cam = scene.camera(40.0, 5.0).unwrap();
    let (matched, _) = match_view(&scene, &vgg, &target, &cam).unwrap();

    // Velocities of about 0.2% of the groom's radius: lengths are being
    // restored and, with the head, strands lying on the skin are being
    // pushed out.
    let n = 3 * scene.field.sample_count();
    let radius = scene.frame.radius;
    let v: Vec<f32> = pseudo_random(n, 11).iter().map(|x| x * 0.002 * radius).collect();
    let loss = |x: &[f32]| loss_and_gradient(&scene, &vgg, &cam, &matched, x).unwrap().0.loss as f64;
    let (report, grad) = loss_and_gradient(&scene, &vgg, &cam, &matched, &v).unwrap();
    assert!(report.loss > 0.0 && grad.iter().all(|g| g.is_finite()));
    assert_eq!(
        report.stats.moved > 0,
        with_head,
        "collision projection active iff there is a head: {:?}",
        report.stats
    );

    // The collision projection is piecewise smooth (a point enters or
    // leaves the skin's band), so the step stays small.
    let eps = 2e-4 * radius;
    let norm = grad.iter().map(|g| (*g as f64).powi(2)).sum::<f64>().sqrt();
    let along = |s: f64| v.iter().zip(&grad).map(|(a, g)| a + (s * *g as f64 / norm) as f32).collect::<Vec<f32>>();
    let h = 2.5 * eps as f64;
    let slope = (loss(&along(h)) - loss(&along(-h))) / (2.0 * h);
    let rel = (slope - norm).abs() / norm;
    println!("head {with_head}: |g| {norm:.5e}, slope along g {slope:.5e}, rel {rel:.2e}");
    // With the head, strands lying on the skin (Bangs lies on the
    // forehead) change which points the projections move within any step
    // (the projection is piecewise linear), which bends the slope a little.
    let tolerance = if with_head { 0.05 } else { 0.01 };
    assert!(rel < tolerance, "head {with_head}: slope along the gradient {slope:e} vs |g| {norm:e}");

    // The largest single entries. Depth order of the splats and the
    // skin's nearest feature switch at isolated points, where the loss has
    // a kink or a small jump; an entry whose one-sided slopes disagree
    // straddles one and says nothing about the derivative, so it is
    // skipped. Of the rest, 90% must agree within 5% (f32 through VGG).
    // (Without the head all 16 are smooth and agree.)
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| grad[b].abs().total_cmp(&grad[a].abs()));
    let l0 = loss(&v);
    let (mut smooth, mut good) = (0, 0);
    for &i in &order[..16] {
        let mut probe = v.clone();
        probe[i] = v[i] + eps;
        let forward = (loss(&probe) - l0) / eps as f64;
        probe[i] = v[i] - eps;
        let backward = (l0 - loss(&probe)) / eps as f64;
        let a = grad[i] as f64;
        let kinked = (forward - backward).abs() > 0.1 * forward.abs().max(backward.abs());
        let numeric = 0.5 * (forward + backward);
        println!("head {with_head}: entry {i}: analytic {a:.5e} numeric {numeric:.5e} (one-sided {forward:.4e}, {backward:.4e})");
        if !kinked {
            smooth += 1;
            good += ((a - numeric).abs() <= 0.05 * a.abs().max(numeric.abs())) as usize;
        }
    }
    // On the head about a third of the largest entries sit on such a kink
    // (their velocity moves strands lying on the skin).
    assert!(smooth >= 4, "head {with_head}: only {smooth} of 16 entries are away from a kink");
    assert!(good * 10 >= smooth * 9, "head {with_head}: only {good}/{smooth} entries match finite differences");
}

#[test]
fn loss_and_gradient_matches_finite_differences_without_a_head() {
    nst3d_core::precision::fp32(|| {
        check_chain(false);
    })
}

#[test]
fn loss_and_gradient_matches_finite_differences_through_the_collision_projection() {
    nst3d_core::precision::fp32(|| {
        check_chain(true);
    })
}

/// The colour half of the chain (issue 29): raw guide colours → smoothing
/// along the guides and blending onto the proxies → splat render → VGG-19 →
/// NNST loss against targets matched in colour, differentiated by
/// [`loss_and_gradient_colored`] (targets matched in grey, taken in colour)
/// and checked against central differences
/// along the gradient and on its largest entries. Colours never move a
/// splat, so the loss is smooth in them (no depth-order kinks).
#[test]
fn colour_gradient_matches_finite_differences() {
    nst3d_core::precision::fp32(|| {
        let groom = nst3d_io::groom::read_groom(&data("Bangs_100.hair")).expect("read Bangs_100.hair");
        let mut params = StylizeParams::from_preset(Preset::ShortHair.params(), groom.strand_count());
        params.proxies = 150;
        params.render_size = 64;
        let scene = StrandScene::new(&groom, None, &params).unwrap();
        let vgg = Vgg19::random(VggFlavor::Torchvision, 7);
        vgg.prepare(VggLayer::Relu4_1);
        let target = ScaleStyle::new(&vgg, &painting(64), 48, true).unwrap();
        let cam = scene.camera(40.0, 5.0).unwrap();
        let start = scene.color_layer.forward(&scene.color_layer.start());
        let (matched, _) = match_view_colored(&scene, &scene.undeformed, Some(&start), &vgg, &target, &cam).unwrap();
        let v = vec![0.0f32; 3 * scene.field.sample_count()];
        // Bangs has no colours (white): offsets of -0.5 ± 0.3 keep every colour inside [0, 1].
        let raw: Vec<f32> = pseudo_random(3 * scene.color_layer.sites(), 5).iter().map(|x| -0.5 + 0.3 * x).collect();
        let unflat = |x: &[f32]| x.chunks(3).map(|c| [c[0], c[1], c[2]]).collect::<Vec<_>>();
        let color = matched.color.as_ref().expect("colour targets");
        let loss = |x: &[f32]| {
            let r = unflat(x);
            let step = loss_and_gradient_colored(&scene, &vgg, &cam, &matched.grey, &v, Some((&r, color))).unwrap();
            step.0.color_loss.expect("a colour loss") as f64
        };
        let r = unflat(&raw);
        let (_, grad_v, grad) =
            loss_and_gradient_colored(&scene, &vgg, &cam, &matched.grey, &v, Some((&r, color))).unwrap();
        let grad = grad.expect("a colour gradient");
        assert!(grad_v.iter().any(|g| *g != 0.0) && grad.iter().all(|g| g.is_finite()));
        let norm = grad.iter().map(|g| (*g as f64).powi(2)).sum::<f64>().sqrt();
        assert!(norm > 0.0);
        let h = 0.02;
        let along =
            |s: f64| raw.iter().zip(&grad).map(|(a, g)| a + (s * *g as f64 / norm) as f32).collect::<Vec<f32>>();
        let slope = (loss(&along(h)) - loss(&along(-h))) / (2.0 * h);
        let rel = (slope - norm).abs() / norm;
        println!("colour: |g| {norm:.5e}, slope along g {slope:.5e}, rel {rel:.2e}");
        assert!(rel < 0.01, "slope along the colour gradient {slope:e} vs |g| {norm:e}");
        let mut order: Vec<usize> = (0..grad.len()).collect();
        order.sort_by(|&a, &b| grad[b].abs().total_cmp(&grad[a].abs()));
        let eps = 0.01f32;
        for &i in &order[..8] {
            let mut probe = raw.clone();
            probe[i] = raw[i] + eps;
            let up = loss(&probe);
            probe[i] = raw[i] - eps;
            let numeric = (up - loss(&probe)) / (2.0 * eps as f64);
            let a = grad[i] as f64;
            println!("colour entry {i}: analytic {a:.5e} numeric {numeric:.5e}");
            assert!((a - numeric).abs() <= 0.05 * a.abs().max(numeric.abs()), "entry {i}: {a:e} vs {numeric:e}");
        }
    })
}
