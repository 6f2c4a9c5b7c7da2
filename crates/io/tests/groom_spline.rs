//! Natural cubic strand splines: interpolation, natural end conditions,
//! straight lines, arc-length resampling, and the control-point gradient
//! (`basis_weights`) against finite differences.

use nst3d_core::gradcheck::{check_gradient, dot, pseudo_random};
use nst3d_io::groom::*;

fn wavy(n: usize) -> Vec<[f32; 3]> {
    (0..n)
        .map(|i| {
            let t = i as f32 * 0.7;
            [t.cos() * 2.0, t * 1.3 + 0.2 * (i % 3) as f32, t.sin() * 1.5]
        })
        .collect()
}

#[test]
fn passes_through_control_points_with_chord_length_knots() {
    let p = wavy(9);
    let s = StrandSpline::new(&p).unwrap();
    let mut chord = 0.0f64;
    for (i, q) in p.iter().enumerate() {
        if i > 0 {
            chord += (0..3).map(|a| (q[a] as f64 - p[i - 1][a] as f64).powi(2)).sum::<f64>().sqrt();
        }
        assert!((s.knots()[i] - chord).abs() < 1e-9);
        let e = s.eval(s.knots()[i]);
        for a in 0..3 {
            assert!((e[a] - q[a]).abs() < 1e-5, "point {i}: {e:?} vs {q:?}");
        }
    }
    assert_eq!(s.length_param(), chord);
    // Outside the strand the parameter is clamped to root and tip.
    assert_eq!(s.eval(-5.0), s.eval(0.0));
    assert_eq!(s.eval(chord + 5.0), s.eval(chord));
}

#[test]
fn natural_end_conditions_and_c2_continuity() {
    let s = StrandSpline::new(&wavy(7)).unwrap();
    let m = s.second_derivatives();
    assert_eq!(m[0], [0.0; 3]);
    assert_eq!(m[6], [0.0; 3]);
    assert!(m[3].iter().any(|c| c.abs() > 1e-2), "interior curvature expected");
    // Numerically: the change of the tangent right at each end is ~0,
    // while inside the strand it is not.
    let h = 1e-3 * s.length_param();
    let curvature = |t: f64| {
        let (a, b) = (s.tangent(t), s.tangent(t + h));
        (0..3).map(|k| ((b[k] - a[k]) as f64 / h).abs()).fold(0.0, f64::max)
    };
    let inner = curvature(s.knots()[3]);
    assert!(curvature(0.0) < 0.02 * inner, "{} vs {inner}", curvature(0.0));
    assert!(curvature(s.length_param() - h) < 0.02 * inner);
    // Tangent is continuous across knots and matches finite differences.
    for k in 1..6 {
        let t = s.knots()[k];
        let (l, r) = (s.tangent(t - 1e-7), s.tangent(t + 1e-7));
        for a in 0..3 {
            assert!((l[a] - r[a]).abs() < 1e-4, "tangent jump at knot {k}");
        }
        let (ahead, behind, tan) = (s.eval(t + 1e-3), s.eval(t - 1e-3), s.tangent(t));
        for a in 0..3 {
            let fd = (ahead[a] - behind[a]) as f64 / 2e-3;
            assert!((fd - tan[a] as f64).abs() < 1e-2, "tangent vs FD at knot {k}");
        }
    }
}

#[test]
fn straight_line_stays_straight_and_resamples_evenly() {
    let dir = [0.3f32, -0.5, 0.8];
    let ts = [0.0f32, 0.1, 0.15, 0.9, 2.0, 2.05, 3.7];
    let p: Vec<[f32; 3]> = ts.iter().map(|&t| dir.map(|d| 1.0 + d * t)).collect();
    let s = StrandSpline::new(&p).unwrap();
    for m in s.second_derivatives() {
        assert!(m.iter().all(|c| c.abs() < 1e-4), "{m:?}");
    }
    let len = (dir.iter().map(|d| d * d).sum::<f32>()).sqrt() * 3.7;
    let r = s.resample(12);
    assert_eq!(r.len(), 12);
    for (k, q) in r.iter().enumerate() {
        let t = 3.7 * k as f32 / 11.0;
        for a in 0..3 {
            assert!((q[a] - (1.0 + dir[a] * t)).abs() < 1e-4, "sample {k}: {q:?}");
        }
    }
    assert!((s.arc_length() as f32 - len).abs() < 1e-4);
}

#[test]
fn resample_is_even_in_arc_length_on_a_curved_strand() {
    let s = StrandSpline::new(&wavy(8)).unwrap();
    let r = s.resample(40);
    assert_eq!(r[0], s.eval(0.0));
    assert_eq!(r[39], s.eval(s.length_param()));
    let seg: Vec<f32> = r.windows(2).map(|w| (0..3).map(|a| (w[1][a] - w[0][a]).powi(2)).sum::<f32>().sqrt()).collect();
    let mean = seg.iter().sum::<f32>() / seg.len() as f32;
    for (k, l) in seg.iter().enumerate() {
        assert!((l - mean).abs() < 0.01 * mean, "segment {k}: {l} vs {mean}");
    }
    assert!(s.arc_length() >= s.length_param(), "arc length is at least chord length");
    assert!(s.resample(0).is_empty());
    assert_eq!(s.resample(1), vec![s.eval(0.0)]);
}

#[test]
fn basis_weights_reproduce_eval_and_sum_to_one() {
    let p = wavy(10);
    let s = StrandSpline::new(&p).unwrap();
    for k in 0..=50 {
        let t = s.length_param() * k as f64 / 50.0;
        let w = s.basis_weights(t);
        assert_eq!(w.len(), p.len());
        let sum: f32 = w.iter().map(|x| x.1).sum();
        assert!((sum - 1.0).abs() < 1e-5, "weights sum {sum} at t={t}");
        let e = s.eval(t);
        for a in 0..3 {
            let v: f32 = w.iter().map(|&(j, x)| x * p[j][a]).sum();
            assert!((v - e[a]).abs() < 1e-4, "t={t}: {v} vs {}", e[a]);
        }
    }
}

/// Gradient of `L = Σ_k g_k · S(t_k)` with respect to the control points,
/// mapped through `basis_weights`, against finite differences with the
/// knots held fixed (the documented semantics of the backward).
#[test]
fn basis_weights_gradient_matches_finite_differences() {
    for (n, seed) in [(2usize, 1u64), (3, 2), (6, 3), (13, 4)] {
        let p = wavy(n);
        let s = StrandSpline::new(&p).unwrap();
        let knots = s.knots().to_vec();
        let params: Vec<f64> = (0..17).map(|k| s.length_param() * (k as f64 + 0.3) / 17.0).collect();
        let upstream = pseudo_random(params.len() * 3, seed);
        let mut analytic = vec![0f32; n * 3];
        for (k, &t) in params.iter().enumerate() {
            for (j, w) in s.basis_weights(t) {
                for a in 0..3 {
                    analytic[j * 3 + a] += w * upstream[k * 3 + a];
                }
            }
        }
        let x: Vec<f32> = p.iter().flatten().copied().collect();
        let loss = |x: &[f32]| {
            let pts: Vec<[f32; 3]> = x.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
            let sp = StrandSpline::with_knots(&pts, &knots).unwrap();
            let samples: Vec<f32> = params.iter().flat_map(|&t| sp.eval(t)).collect();
            dot(&upstream, &samples)
        };
        // The samples are exactly linear in the points, so a large step
        // costs no truncation error and keeps f32 rounding small.
        let r = check_gradient(&x, &analytic, loss, 0.25, 1000, 1e-2);
        assert!(r.max_rel_err < 1e-3, "n={n}: {r:?}");
    }
}

#[test]
fn bad_control_points_are_errors() {
    assert!(StrandSpline::new(&[[0.0; 3]]).is_err());
    let e = StrandSpline::new(&[[0.0; 3], [0.0; 3], [1.0; 3]]).unwrap_err().to_string();
    assert!(e.contains("coincide"), "{e}");
    assert!(StrandSpline::new(&[[0.0; 3], [f32::NAN, 0.0, 0.0]]).is_err());
    assert!(StrandSpline::with_knots(&[[0.0; 3], [1.0; 3]], &[0.0]).is_err());
}

#[test]
fn splines_fit_every_bangs_strand() {
    let dir = std::path::PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data/grooms"));
    assert!(dir.is_dir(), "test data missing: {}", dir.display());
    let g = read_groom(&dir.join("Bangs_100.hair")).unwrap();
    for (i, st) in g.strands.iter().enumerate() {
        let s = StrandSpline::new(&st.points).unwrap_or_else(|e| panic!("strand {i}: {e}"));
        let r = s.resample(32);
        assert!(r.iter().flatten().all(|c| c.is_finite()));
        assert!(s.arc_length() >= s.length_param() * (1.0 - 1e-9));
    }
}
