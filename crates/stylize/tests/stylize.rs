//! The stylisation chain as a whole: gradients through transport, render,
//! upsampling, VGG and the Gram loss agree with finite differences, and the
//! multi-octave loop lowers the loss while keeping the Sec. 3.3 limits.

use nst3d_core::gradcheck::{check_gradient, dot, pseudo_random};
use nst3d_core::{Grid3, Image};
use nst3d_features::{Vgg19, VggFlavor, VggLayer};
use nst3d_render::{Camera, Projection};
use nst3d_stylize::{
    bench::synthetic_smoke, stylize_color, stylize_color_map, stylize_frame, ColorStageParams, Field, FrameParams,
    JointDensity, Limits, MapLoss, Mode, StyleSpec, ViewLoss, ViewSpec,
};

fn style(n: usize) -> Image {
    // Stripes: a style with structure a smooth ball does not have.
    let mut img = Image::zeros(3, n, n);
    for c in 0..3 {
        for y in 0..n {
            for x in 0..n {
                img.data[(c * n + y) * n + x] = if (x + 2 * y) % 8 < 4 { 0.9 } else { 0.1 };
            }
        }
    }
    img
}

#[test]
fn field_transport_gradients_match_finite_differences() {
    let d = Grid3::from_vec([6, 5, 4], pseudo_random(120, 3).iter().map(|v| v.abs()).collect());
    let w = pseudo_random(120, 4);
    for mode in [Mode::Velocity, Mode::Density] {
        let mut field = Field::identity(mode, d.len());
        // Away from integer offsets, where trilinear sampling has kinks.
        for (i, p) in field.params_mut().iter_mut().enumerate() {
            *p += 0.3 + 0.1 * ((i * 7 % 5) as f32 / 5.0);
        }
        let grad = field.transport_backward(&d, &w);
        let mut probe = field.clone();
        let r = check_gradient(
            field.params(),
            &grad,
            |x| {
                probe.params_mut().copy_from_slice(x);
                dot(&w, &probe.transport(&d).data)
            },
            // The map is linear inside a cell, so a large step is exact and
            // keeps f32 rounding out of the difference.
            1e-2,
            200,
            1e-2,
        );
        assert!(r.max_rel_err < 1e-2, "{mode:?}: {r:?}");
    }
}

/// d(loss)/d(density) through the whole view chain. FP32 finite differences
/// through thousands of ReLU kinks are noisy, so most (not all) probed
/// entries (70%) must agree within 5%, and all must agree in sign where large.
#[test]
fn view_loss_gradient_matches_finite_differences() {
    nst3d_core::precision::fp32(|| {
        let vgg = Vgg19::random(VggFlavor::Torchvision, 1);
        let spec = StyleSpec { layers: vec![VggLayer::Relu1_1, VggLayer::Relu2_1], layer_weights: vec![1.0, 0.5] };
        let loss = ViewLoss::new(&vgg, &style(24), &spec).unwrap();
        let d = synthetic_smoke(12, 5);
        let persp = Camera::front(d.dims).with_projection(Projection::Perspective);
        for (name, camera, equalize) in
            [("march", None, false), ("perspective", Some(persp), false), ("equalized", None, true)]
        {
            let view = ViewSpec { camera, gamma: 0.3, exposure: 0.3, equalize };
            let (_, grad) = loss.loss_and_grad(&d, &view).unwrap();
            let mut probe = d.clone();
            let mut good = 0;
            let mut checked = 0;
            let big = grad.data.iter().fold(0f32, |m, v| m.max(v.abs()));
            for i in (0..d.len()).step_by(97) {
                if grad.data[i].abs() < 1e-3 * big {
                    continue;
                }
                let eps = 2e-3;
                probe.data[i] = d.data[i] + eps;
                let up = loss.loss(&probe, &view).unwrap() as f64;
                probe.data[i] = d.data[i] - eps;
                let down = loss.loss(&probe, &view).unwrap() as f64;
                probe.data[i] = d.data[i];
                let numeric = (up - down) / (2.0 * eps as f64);
                let a = grad.data[i] as f64;
                checked += 1;
                if (a - numeric).abs() <= 0.05 * a.abs().max(numeric.abs()) {
                    good += 1;
                }
            }
            assert!(checked >= 5, "{name}: too few entries with gradient");
            assert!(good * 10 >= checked * 7, "{name}: only {good}/{checked} entries match finite differences");
        }
    })
}

#[test]
fn octaves_lower_the_loss_and_keep_the_limits() {
    let vgg = Vgg19::random(VggFlavor::Torchvision, 2);
    let loss = ViewLoss::new(&vgg, &style(32), &StyleSpec::default()).unwrap();
    let d = synthetic_smoke(24, 9);
    let view = ViewSpec { camera: Some(Camera::front(d.dims)), gamma: 0.2, exposure: 0.2, equalize: false };
    for (mode, lr) in [(Mode::Velocity, 0.5), (Mode::Density, 0.1)] {
        let limits = Limits { vmax: 1.5, smin: 0.2, smax: 1.8 };
        let params = FrameParams { mode, octaves: 2, iterations: 8, learning_rate: lr, limits, view: view.clone() };
        let mut steps = 0;
        let r = stylize_frame(&d, &loss, &params, &mut |_| steps += 1).unwrap();
        assert_eq!(steps, 16);
        assert!(r.loss_after < 0.9 * r.loss_before, "{mode:?}: {} -> {}", r.loss_before, r.loss_after);
        assert!(r.density.data.iter().all(|v| v.is_finite()));
        match &r.field {
            Field::Velocity(v) => {
                let max = v.iter().map(|u| (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt()).fold(0f32, f32::max);
                assert!(max <= 1.5 + 1e-4, "vmax exceeded: {max}");
                assert!(max > 0.1, "velocity did not move");
            }
            Field::Scale(s) => assert!(s.iter().all(|x| (0.2..=1.8).contains(x))),
        }
    }
}

/// Mean L1 difference between the velocities of neighbouring voxels (all
/// three axes) over the mean L1 length, inside the smoke where it moves.
/// About 1 (or more) is noise from voxel to voxel; a smooth field is well below.
fn roughness(v: &[[f32; 3]], d: &Grid3) -> f32 {
    let [nx, ny, nz] = d.dims;
    let l1 = |u: [f32; 3]| u[0].abs() + u[1].abs() + u[2].abs();
    let (mut diff, mut len, mut n) = (0f64, 0f64, 0f64);
    for z in 0..nz - 1 {
        for y in 0..ny - 1 {
            for x in 0..nx - 1 {
                let i = (z * ny + y) * nx + x;
                if d.data[i] < 0.05 || l1(v[i]) < 0.05 {
                    continue;
                }
                for j in [i + 1, i + nx, i + nx * ny] {
                    diff += l1(std::array::from_fn(|a| v[j][a] - v[i][a])) as f64;
                    len += l1(v[i]) as f64;
                    n += 1.0;
                }
            }
        }
    }
    assert!(n > 100.0, "the velocity hardly moved anything");
    (diff / len) as f32
}

/// Velocity mode must not turn into voxel-scale noise (docs/design/volumes.md).
/// On smoke_000003 neighbouring velocities differed by about
/// their own length (roughness 1.1), which scrambles dense smoke into blocks
/// and gives edges staircases along the grid axes. The mechanism needs no
/// network: the style loss's gradient w.r.t. the density has voxel-scale
/// structure, the velocity's gradient is that times the slope of the
/// piecewise-linear density at `g + v`, and Adam moves every component by
/// about `±lr` whatever the gradient's size. Here the density gradient is a
/// fixed pseudo-random pattern on the synthetic smoke, and the optimiser
/// loop is the frame loop's (Adam, then the `vmax` limiter).
#[test]
fn velocity_mode_moves_the_smoke_by_a_smooth_field() {
    let d = synthetic_smoke(24, 9);
    let grad_dstar = pseudo_random(d.len(), 21);
    let vmax = 1.5;
    let limits = Limits { vmax, smin: 0.0, smax: 2.0 };
    let mut field = Field::identity(Mode::Velocity, d.len());
    let mut adam = nst3d_optim::Adam::new(field.len(), 0.5);
    for _ in 0..20 {
        let g = field.transport_backward(&d, &grad_dstar);
        adam.step(field.params_mut(), &g);
        field.constrain(&limits, vmax);
    }
    let v = field.velocity(d.dims).unwrap();
    let rough = roughness(&v, &d);
    assert!(rough < 0.9, "voxel-scale velocity noise: roughness {rough:.3}");
    let max = v.iter().map(|u| (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt()).fold(0f32, f32::max);
    assert!(max <= vmax + 1e-4, "vmax exceeded: {max}");
    assert!(max > 0.5, "the velocity did not move");
}

/// Density mode's counterpart: per-voxel scales stepped along the raw
/// gradient drew small grid-aligned marks in dense smoke. The same
/// optimiser loop on the same fixed voxel pattern, stepping along
/// [`Field::descent`], must leave the scale smooth (roughness 1.00 along the
/// raw gradient, 0.51 along the smoothed one; 0.54 when the field itself
/// was smoothed).
#[test]
fn density_mode_scales_the_smoke_by_a_smooth_field() {
    let d = synthetic_smoke(24, 9);
    let grad_dstar = pseudo_random(d.len(), 21);
    let limits = Limits { vmax: 1.0, smin: 0.0, smax: 2.0 };
    let mut field = Field::identity(Mode::Density, d.len());
    let mut adam = nst3d_optim::Adam::new(field.len(), 0.1);
    let mut raw = field.clone();
    let mut raw_adam = nst3d_optim::Adam::new(field.len(), 0.1);
    for _ in 0..20 {
        let g = field.descent(field.transport_backward(&d, &grad_dstar), d.dims);
        adam.step(field.params_mut(), &g);
        field.constrain(&limits, 1.0);
        let g = raw.transport_backward(&d, &grad_dstar);
        raw_adam.step(raw.params_mut(), &g);
        raw.constrain(&limits, 1.0);
    }
    // The control: along the raw gradient the scale is voxel-scale noise.
    let dev = |s: &[f32]| -> Vec<[f32; 3]> { s.iter().map(|v| [v - 1.0, 0.0, 0.0]).collect() };
    let raw_rough = roughness(&dev(raw.scale().unwrap()), &d);
    assert!(raw_rough > 0.95, "the control is not noisy: roughness {raw_rough:.3}");
    let s = field.scale().unwrap();
    let rough = roughness(&dev(s), &d);
    assert!(rough < 0.9, "voxel-scale scale noise: roughness {rough:.3}");
    assert!(s.iter().all(|v| (0.0..=2.0).contains(v)), "scale left [smin, smax]");
    assert!(s.iter().any(|v| (v - 1.0).abs() > 0.3), "the scale did not move");
}

/// A colourful painting: red and blue stripes (no grey picture has them).
fn color_style(n: usize) -> Image {
    let mut img = Image::zeros(3, n, n);
    for y in 0..n {
        for x in 0..n {
            let red = (x + 2 * y) % 8 < 4;
            let rgb = if red { [0.9, 0.15, 0.1] } else { [0.1, 0.2, 0.85] };
            for c in 0..3 {
                img.data[(c * n + y) * n + x] = rgb[c];
            }
        }
    }
    img
}

/// The colour stage colours a stylized density from several views
/// in turn: the RGB loss from every one of them falls well below the grey
/// result's (white colour), the grey loss of the colour render's luminance
/// (what the grey guard holds) stays near the grey result's, the colour
/// stays in its range and is no longer white, and both sweep sums are
/// reported.
#[test]
fn color_stage_lowers_the_rgb_loss_of_every_view() {
    let vgg = Vgg19::random(VggFlavor::Torchvision, 2);
    let grey_loss = ViewLoss::new(&vgg, &color_style(32).luminance3(), &StyleSpec::default()).unwrap();
    let loss = ViewLoss::new(&vgg, &color_style(32), &StyleSpec::default()).unwrap();
    let d = synthetic_smoke(24, 9);
    let view = ViewSpec { camera: Some(Camera::front(d.dims)), gamma: 0.2, exposure: 0.2, equalize: false };
    let limits = Limits { vmax: 1.5, smin: 0.2, smax: 1.8 };
    let grey =
        FrameParams { mode: Mode::Density, octaves: 2, iterations: 8, learning_rate: 0.1, limits, view: view.clone() };
    let g = stylize_frame(&d, &grey_loss, &grey, &mut |_| {}).unwrap();
    let views: Vec<ViewSpec> = [0.0, 120.0, 240.0]
        .iter()
        .map(|az| ViewSpec { camera: Some(Camera::orbit(d.dims, *az, 15.0)), ..view.clone() })
        .collect();
    let white = vec![Grid3::from_vec(d.dims, vec![1.0; d.len()]); 3];
    let run = |grey_guard: f32| {
        let params = ColorStageParams {
            iterations: 30,
            learning_rate: nst3d_stylize::color::LEARNING_RATE,
            grey_guard,
            smoke_term: 0.0,
            density: None,
        };
        let mut seen = 0;
        stylize_color(&g.density, &loss, &grey_loss, &views, &params, &mut |p| {
            seen += 1;
            assert_eq!((p.iteration, p.iterations), (seen, 30));
        })
        .unwrap()
    };
    let (lo, hi) = nst3d_stylize::color_stage::COLOR_RANGE;
    let grey_of =
        |c: &[Grid3]| -> f32 { views.iter().map(|v| grey_loss.loss_color_luminance(&g.density, c, v).unwrap()).sum() };
    let grey_before: f32 = views.iter().map(|v| grey_loss.loss(&g.density, v).unwrap()).sum();
    let grey_white = grey_of(&white);
    assert!(
        (grey_white - grey_before).abs() <= 1e-3 * grey_before,
        "white colour's luminance {grey_white} is not the grey render's {grey_before}"
    );
    let unguarded = grey_of(&run(0.0).color);
    let c = run(10.0);
    let color = &c.color;
    assert_eq!(color.len(), 3);
    assert!(color.iter().all(|ch| ch.dims == d.dims && ch.data.iter().all(|v| (lo..=hi).contains(v))));
    let moved = color.iter().flat_map(|ch| &ch.data).map(|v| (v - 1.0).abs()).fold(0f32, f32::max);
    assert!(moved > 0.1, "colour stayed white (max change {moved})");
    for v in &views {
        let before = loss.loss_color(&g.density, &white, v).unwrap();
        let after = loss.loss_color(&g.density, color, v).unwrap();
        assert!(after < 0.8 * before, "colour RGB loss {after} vs the grey result's {before}");
    }
    let guarded = grey_of(color);
    assert!(
        guarded < unguarded && guarded < 1.2 * grey_before,
        "grey loss: grey result {grey_before}, colour unguarded {unguarded}, guarded {guarded}"
    );
    assert!(c.loss_last_sweep < 0.8 * c.loss_first_sweep, "{} -> {}", c.loss_first_sweep, c.loss_last_sweep);
}

/// The density moving with the colour
/// ([`nst3d_stylize::JointDensity`]): the stage returns a density that is the
/// given one scaled within the limits, moved by the stage, and the stage's
/// loss falls over the run; without it the density comes back unchanged.
/// (The scale's gradient is the density gradient of
/// `color_view_gradient_matches_finite_differences` through density mode's
/// `Field::Scale` backward, both checked against finite differences.)
#[test]
fn color_stage_moves_the_density_within_its_limits() {
    let vgg = Vgg19::random(VggFlavor::Torchvision, 2);
    let grey_loss = ViewLoss::new(&vgg, &color_style(16).luminance3(), &StyleSpec::default()).unwrap();
    let loss = ViewLoss::new(&vgg, &color_style(16), &StyleSpec::default()).unwrap();
    let d = synthetic_smoke(16, 9);
    let views: Vec<ViewSpec> = [0.0, 180.0]
        .iter()
        .map(|az| ViewSpec {
            camera: Some(Camera::orbit(d.dims, *az, 15.0)),
            gamma: 0.2,
            exposure: 0.2,
            equalize: false,
        })
        .collect();
    let run = |density: Option<JointDensity>| {
        let params = ColorStageParams { iterations: 8, learning_rate: 0.05, grey_guard: 1.0, smoke_term: 0.5, density };
        stylize_color(&d, &loss, &grey_loss, &views, &params, &mut |_| {}).unwrap()
    };
    assert_eq!(run(None).density.data, d.data, "without the joint density the density is the one given");
    let (smin, smax) = (0.5, 1.5);
    let r = run(Some(JointDensity { learning_rate: 0.05, smin, smax }));
    let mut moved = 0f32;
    for (after, before) in r.density.data.iter().zip(&d.data) {
        assert!(
            *after >= smin * before - 1e-6 && *after <= smax * before + 1e-6,
            "density {after} outside [{smin}, {smax}] x {before}"
        );
        if *before > 0.05 {
            moved = moved.max((after / before - 1.0).abs());
        }
    }
    assert!(moved > 0.1, "the density did not move (largest scale change {moved})");
    assert!(r.loss_last_sweep < r.loss_first_sweep, "{} -> {}", r.loss_first_sweep, r.loss_last_sweep);
}

/// The colour stage with a style map of one painting that holds every
/// voxel is the colour stage of that painting alone, bit for bit: the same
/// colour, the same density (moved with the colour) and the same losses.
#[test]
fn color_stage_with_a_one_painting_map_is_the_color_stage() {
    let vgg = Vgg19::random(VggFlavor::Torchvision, 2);
    let spec = StyleSpec::default();
    let d = synthetic_smoke(16, 9);
    let views: Vec<ViewSpec> = [0.0, 180.0]
        .iter()
        .map(|az| ViewSpec {
            camera: Some(Camera::orbit(d.dims, *az, 15.0)),
            gamma: 0.2,
            exposure: 0.2,
            equalize: false,
        })
        .collect();
    let density = Some(JointDensity { learning_rate: 0.05, smin: 0.5, smax: 1.5 });
    let params = ColorStageParams { iterations: 4, learning_rate: 0.05, grey_guard: 1.0, smoke_term: 0.5, density };
    let loss = ViewLoss::new(&vgg, &color_style(16), &spec).unwrap();
    let grey = ViewLoss::new(&vgg, &color_style(16).luminance3(), &spec).unwrap();
    let alone = stylize_color(&d, &loss, &grey, &views, &params, &mut |_| {}).unwrap();
    let map = MapLoss::new(vec![ViewLoss::new(&vgg, &color_style(16), &spec).unwrap()]);
    let map_grey = MapLoss::new(vec![ViewLoss::new(&vgg, &color_style(16).luminance3(), &spec).unwrap()]);
    let all = [Grid3::from_vec(d.dims, vec![1.0; d.len()])];
    let mapped = stylize_color_map(&d, (&map, &map_grey, &all), &views, &params, &mut |_| {}).unwrap();
    assert_eq!(mapped.density.data, alone.density.data);
    assert!(mapped.color.iter().zip(&alone.color).all(|(a, b)| a.data == b.data));
    assert_eq!((mapped.loss_first_sweep, mapped.loss_last_sweep), (alone.loss_first_sweep, alone.loss_last_sweep));
}

/// d(RGB loss)/d(density, colour) through render, upsampling, VGG and the
/// Gram loss against finite differences, alone, with the colour stage's
/// grey guard added (the render's luminance → VGG → Gram loss to a grey
/// target), and with the smoke term too (the same Gram loss over the cells
/// that show smoke; which pixels show smoke is held fixed, so a probe that
/// moves a pixel across the threshold is one the rule below tolerates)
/// (same tolerance rule as the grey chain above: most probed entries agree
/// within 5 %).
#[test]
fn color_view_gradient_matches_finite_differences() {
    nst3d_core::precision::fp32(|| {
        let vgg = Vgg19::random(VggFlavor::Torchvision, 5);
        let loss = ViewLoss::new(&vgg, &color_style(16), &StyleSpec::default()).unwrap();
        let grey = ViewLoss::new(&vgg, &color_style(16).luminance3(), &StyleSpec::default()).unwrap();
        let dims = [8, 8, 6];
        let n = 384;
        let d = Grid3::from_vec(dims, pseudo_random(n, 51).iter().map(|v| 0.5 + 0.4 * v).collect());
        let color: Vec<Grid3> = (0..3)
            .map(|ch| Grid3::from_vec(dims, pseudo_random(n, 52 + ch).iter().map(|v| 1.0 + 0.5 * v).collect()))
            .collect();
        let view =
            ViewSpec { camera: Some(Camera::orbit(dims, 20.0, 10.0)), gamma: 0.3, exposure: 0.3, equalize: false };
        for (smoke, guard) in [(0.0, None), (0.0, Some((&grey, 2.0f32))), (0.5, Some((&grey, 2.0f32)))] {
            let (_, _, gd, gc) = loss.loss_and_grad_color_guarded(&d, &color, &view, smoke, guard).unwrap();
            let x0: Vec<f32> = [d.data.clone(), color.iter().flat_map(|c| c.data.clone()).collect()].concat();
            let analytic: Vec<f32> = [gd.data, gc.into_iter().flat_map(|c| c.data).collect()].concat();
            let f = |x: &[f32]| {
                let d = Grid3::from_vec(dims, x[..n].to_vec());
                let c: Vec<Grid3> = (0..3).map(|ch| Grid3::from_vec(dims, x[n + ch * n..][..n].to_vec())).collect();
                let g = guard.map_or(0.0, |(g, w)| w * g.loss_color_luminance(&d, &c, &view).unwrap());
                let on_smoke = smoke * loss.loss_color_on_smoke(&d, &c, &view).unwrap().unwrap_or(0.0);
                (loss.loss_color(&d, &c, &view).unwrap() + on_smoke + g) as f64
            };
            let big = analytic.iter().fold(0f32, |m, v| m.max(v.abs()));
            let (mut agree, mut probed) = (0, 0);
            for i in (0..x0.len()).step_by(7) {
                if analytic[i].abs() < 0.05 * big {
                    continue;
                }
                let h = 1e-2f32;
                let mut xp = x0.clone();
                xp[i] += h;
                let mut xm = x0.clone();
                xm[i] -= h;
                let fd = (f(&xp) - f(&xm)) / (2.0 * h as f64);
                probed += 1;
                assert!(fd.signum() == (analytic[i] as f64).signum(), "sign at {i}: fd {fd} vs {}", analytic[i]);
                if ((fd - analytic[i] as f64) / fd).abs() < 0.05 {
                    agree += 1;
                }
            }
            let with = match (smoke > 0.0, guard.is_some()) {
                (true, _) => "with the smoke term and the guard",
                (false, true) => "with the guard",
                (false, false) => "alone",
            };
            assert!(probed >= 20, "{with}: only {probed} large entries probed");
            assert!(agree as f64 >= 0.7 * probed as f64, "{with}: {agree} of {probed} agree within 5%");
        }
    })
}

/// A frame too small for VGG-19 to reach its style layers is refused with
/// an error naming the size, not a crash deep in a convolution.
#[test]
fn a_picture_too_small_for_the_style_layers_is_an_error() {
    let vgg = Vgg19::random(VggFlavor::Gatys, 4);
    let loss = ViewLoss::new(&vgg, &style(24), &StyleSpec::default()).unwrap();
    let view = ViewSpec { camera: None, gamma: 0.3, exposure: 0.3, equalize: false };
    let tiny = synthetic_smoke(4, 1);
    let err = loss.loss_and_grad(&tiny, &view).unwrap_err().to_string();
    assert!(err.contains("4x4 pixels") && err.contains("--octaves"), "{err}");
    assert!(loss.loss(&tiny, &view).is_err());
    assert!(loss.loss_and_grad(&synthetic_smoke(5, 1), &view).is_ok());
}
