//! End-to-end checks of the strand splatting renderer: against an
//! independent brute-force eq. 7, against a PyTorch autograd reference,
//! finite-difference gradients, visibility culling, determinism and input
//! validation.

#![allow(clippy::needless_range_loop)]

use nst3d_core::gradcheck::{check_gradient, dot, pseudo_random};
use nst3d_core::Image;
use nst3d_splat::{
    render, render_backward, render_backward_all, SplatCamera, SplatError, SplatOutput, StrandStyle, Strands,
};

/// `n` wavy strands of `m` points in front of a camera on +z, each tilted
/// towards the camera and at its own depth, so depth order is unambiguous and
/// stays put under small perturbations.
fn scene(n: usize, m: usize, seed: u64) -> (Vec<[f32; 3]>, Vec<usize>, Vec<[f32; 3]>) {
    let r = pseudo_random(n * 6, seed);
    let mut points = Vec::new();
    let mut offsets = vec![0];
    for i in 0..n {
        let v = &r[6 * i..6 * i + 6];
        // Strands span disjoint depth ranges (0.8 apart, 0.3 + 0.05 deep).
        let root = [v[0] * 0.8, v[1] * 0.8, -0.8 * i as f32];
        let dir = [0.6 * v[2], 0.8 + 0.3 * v[3], 0.3];
        for k in 0..m {
            let u = k as f32 / (m - 1) as f32;
            let wave = 0.15 * (4.0 * u + 3.0 * v[4]).sin();
            points.push([root[0] + dir[0] * u + wave, root[1] + dir[1] * u, root[2] + dir[2] * u + 0.05 * v[5] * u]);
        }
        offsets.push(points.len());
    }
    let colors = (0..points.len()).map(|k| {
        let c = pseudo_random(3, 100 + k as u64);
        [0.6 + 0.4 * c[0], 0.6 + 0.4 * c[1], 0.6 + 0.4 * c[2]]
    });
    (points, offsets, colors.collect())
}

fn camera(w: usize, h: usize) -> SplatCamera {
    SplatCamera::look_at([0.2, 0.3, 4.0], [0.0, 0.3, 0.0], [0.0, 1.0, 0.0], 40.0, w, h).unwrap()
}

fn strands<'a>(p: &'a [[f32; 3]], o: &'a [usize], c: Option<&'a [[f32; 3]]>) -> Strands<'a> {
    Strands { points: p, offsets: o, colors: c, root_normals: None }
}

// ---------------------------------------------------------------- brute force

type M3 = [[f64; 3]; 3];

fn matmul<const A: usize, const B: usize, const C: usize>(x: &[[f64; B]; A], y: &[[f64; C]; B]) -> [[f64; C]; A] {
    std::array::from_fn(|i| std::array::from_fn(|j| (0..B).map(|k| x[i][k] * y[k][j]).sum()))
}

fn transpose<const A: usize, const B: usize>(x: &[[f64; B]; A]) -> [[f64; A]; B] {
    std::array::from_fn(|i| std::array::from_fn(|j| x[j][i]))
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

fn unit(a: [f64; 3]) -> [f64; 3] {
    let n = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
    a.map(|v| v / n)
}

/// Eq. 6 and 7 the slow way, in f64 with full matrices and an explicit
/// rotation frame: every splat at every pixel, depth-sorted, no tiles.
/// Planar image in the layout `style.output` asks for.
fn brute_force(s: &Strands, cam: &SplatCamera, style: &StrandStyle) -> Vec<f64> {
    let w_rot: M3 = [cam.right, cam.down, cam.forward].map(|r| r.map(f64::from));
    let eye = cam.eye.map(f64::from);
    let (fx, fy, cx, cy) = (cam.fx as f64, cam.fy as f64, cam.cx as f64, cam.cy as f64);
    struct G {
        mean: [f64; 2],
        inv: [[f64; 2]; 2],
        color: [f64; 3],
        opacity: f64,
        depth: f64,
    }
    let mut gs = Vec::new();
    for i in 0..s.len() {
        let (lo, hi) = (s.offsets[i], s.offsets[i + 1]);
        for k in lo..hi - 1 {
            let (a, b) = (s.points[k].map(f64::from), s.points[k + 1].map(f64::from));
            let d: [f64; 3] = std::array::from_fn(|j| b[j] - a[j]);
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            let e = unit(d);
            let e2 = unit(cross(e, if e[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] }));
            let e3 = cross(e, e2);
            let rot: M3 = transpose(&[e, e2, e3]);
            let (sx, sw) = (style.length_sigma as f64 * len, style.width as f64);
            let scale: M3 = [[sx * sx, 0.0, 0.0], [0.0, sw * sw, 0.0], [0.0, 0.0, sw * sw]];
            let sigma3 = matmul(&matmul(&rot, &scale), &transpose(&rot));
            let m: [f64; 3] = std::array::from_fn(|j| 0.5 * (a[j] + b[j]) - eye[j]);
            let t: [f64; 3] = std::array::from_fn(|r| (0..3).map(|j| w_rot[r][j] * m[j]).sum());
            let jac = [[fx / t[2], 0.0, -fx * t[0] / (t[2] * t[2])], [0.0, fy / t[2], -fy * t[1] / (t[2] * t[2])]];
            let jw = matmul(&jac, &w_rot);
            let mut sigma2 = matmul(&matmul(&jw, &sigma3), &transpose(&jw));
            sigma2[0][0] += style.dilation as f64;
            sigma2[1][1] += style.dilation as f64;
            let det = sigma2[0][0] * sigma2[1][1] - sigma2[0][1] * sigma2[1][0];
            let inv = [[sigma2[1][1] / det, -sigma2[0][1] / det], [-sigma2[1][0] / det, sigma2[0][0] / det]];
            let u = ((k - lo) as f64 + 0.5) / (hi - lo - 1) as f64;
            let lerp = |p: f32, q: f32| p as f64 + (q as f64 - p as f64) * u;
            let base: [f64; 3] = match s.colors {
                Some(c) => std::array::from_fn(|j| 0.5 * (c[k][j] as f64 + c[k + 1][j] as f64)),
                None => [1.0; 3],
            };
            let shade = lerp(style.root_shade, style.tip_shade);
            gs.push(G {
                mean: [fx * t[0] / t[2] + cx, fy * t[1] / t[2] + cy],
                inv,
                color: base.map(|v| v * shade),
                opacity: lerp(style.root_opacity, style.tip_opacity),
                depth: t[2],
            });
        }
    }
    gs.sort_by(|a, b| a.depth.total_cmp(&b.depth));
    let (w, h) = (cam.width, cam.height);
    let mut img = vec![0.0; 3 * w * h];
    let mut alpha_img = vec![0.0; w * h];
    let e9 = (-4.5f64).exp();
    for y in 0..h {
        for x in 0..w {
            let (mut c, mut t) = ([0.0f64; 3], 1.0f64);
            for g in &gs {
                let d = [x as f64 + 0.5 - g.mean[0], y as f64 + 0.5 - g.mean[1]];
                let q =
                    d[0] * (g.inv[0][0] * d[0] + g.inv[0][1] * d[1]) + d[1] * (g.inv[1][0] * d[0] + g.inv[1][1] * d[1]);
                if q >= 9.0 {
                    continue;
                }
                let alpha = (g.opacity * ((-0.5 * q).exp() - e9) / (1.0 - e9)).min(0.99);
                for j in 0..3 {
                    c[j] += g.color[j] * alpha * t;
                }
                t *= 1.0 - alpha;
                if t < 1e-4 {
                    break;
                }
            }
            for j in 0..3 {
                img[(j * h + y) * w + x] = c[j] + t * style.background[j] as f64;
            }
            alpha_img[y * w + x] = 1.0 - t;
        }
    }
    match style.output {
        SplatOutput::Rgb => img,
        SplatOutput::GreyAlpha => {
            let lum = |p: usize| 0.2126 * img[p] + 0.7152 * img[w * h + p] + 0.0722 * img[2 * w * h + p];
            (0..w * h).map(lum).chain(alpha_img).collect()
        }
    }
}

#[test]
fn matches_brute_force_eq7() {
    let (p, o, c) = scene(5, 9, 11);
    let cam = camera(70, 50);
    for output in [SplatOutput::Rgb, SplatOutput::GreyAlpha] {
        // Opaque roots exercise the 0.99 clamp and several overlapping layers.
        let style = StrandStyle {
            width: 0.06,
            root_opacity: 1.0,
            tip_opacity: 0.5,
            background: [0.2, 0.3, 0.1],
            output,
            ..Default::default()
        };
        let s = strands(&p, &o, Some(&c));
        let (img, cache) = render(&s, &cam, &style).unwrap();
        assert_eq!(cache.splat_count(), 5 * 8);
        let reference = brute_force(&s, &cam, &style);
        let err = img.data.iter().zip(&reference).map(|(a, b)| (*a as f64 - b).abs()).fold(0.0, f64::max);
        assert!(err < 1e-5, "{output:?}: max |tiled - brute force| = {err}");
        let plane = 70 * 50;
        let bg = reference[0];
        let covered = (0..plane).filter(|&i| (reference[i] - bg).abs() > 0.05).count();
        assert!(covered > 100, "scene should cover a fair number of pixels, covers {covered}");
    }
}

// ------------------------------------------------------------ PyTorch fixture

fn read_fixture() -> Vec<f32> {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/splat_reference.bin");
    let bytes = std::fs::read(path)
        .unwrap_or_else(|e| panic!("missing fixture {path} ({e}); regenerate with tools/fixtures/splat_reference.py"));
    bytes.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect()
}

#[test]
fn matches_pytorch_reference() {
    let blob = read_fixture();
    let mut at = 0;
    let mut take = |n: usize| {
        let s = blob[at..at + n].to_vec();
        at += n;
        s
    };
    let head = take(5);
    let (np, ns, w, h, fov) = (head[0] as usize, head[1] as usize, head[2] as usize, head[3] as usize, head[4]);
    let v3 = |v: Vec<f32>| [v[0], v[1], v[2]];
    let (eye, target, up) = (v3(take(3)), v3(take(3)), v3(take(3)));
    let st = take(11);
    let style = StrandStyle {
        width: st[0],
        length_sigma: st[1],
        root_shade: st[2],
        tip_shade: st[3],
        root_opacity: st[4],
        tip_opacity: st[5],
        background: [st[6], st[7], st[8]],
        visibility_threshold: st[9],
        dilation: st[10],
        output: SplatOutput::Rgb,
    };
    let offsets: Vec<usize> = take(ns + 1).iter().map(|&v| v as usize).collect();
    let triples = |v: Vec<f32>| v.chunks(3).map(|c| [c[0], c[1], c[2]]).collect::<Vec<_>>();
    let points = triples(take(3 * np));
    let colors = triples(take(3 * np));
    let normals = triples(take(3 * ns));
    let probe = take(3 * w * h);
    let want_img = take(3 * w * h);
    let want_grad = take(3 * np);
    assert_eq!(at, blob.len(), "fixture layout");

    let cam = SplatCamera::look_at(eye, target, up, fov, w, h).unwrap();
    let s = Strands { points: &points, offsets: &offsets, colors: Some(&colors), root_normals: Some(&normals) };
    let (img, cache) = render(&s, &cam, &style).unwrap();
    assert_eq!(cache.visible_strands(), ns - 1, "the fixture culls one strand");
    let err = img.data.iter().zip(&want_img).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
    assert!(err < 2e-5, "image vs PyTorch: max error {err}");
    let g = render_backward(&s, &cam, &style, &cache, &Image::from_vec(3, h, w, probe)).unwrap();
    let scale = want_grad.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    let gerr = g.iter().flatten().zip(&want_grad).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
    assert!(gerr < 1e-4 * scale, "gradient vs PyTorch: max error {gerr} (scale {scale})");
}

// ------------------------------------------------------ finite differences

/// Small depth-separated scene and a random probe `w` for gradient checks.
struct Probe {
    points: Vec<[f32; 3]>,
    offsets: Vec<usize>,
    colors: Vec<[f32; 3]>,
    cam: SplatCamera,
    style: StrandStyle,
    w: Vec<f32>,
}

impl Probe {
    fn new(output: SplatOutput, width: f32, seed: u64) -> Self {
        let (points, offsets, colors) = scene(4, 7, seed);
        let cam = camera(48, 40);
        // Opacities below the 0.99 clamp and few layers: no early termination.
        let style = StrandStyle {
            width,
            root_opacity: 0.8,
            tip_opacity: 0.3,
            background: [0.3, 0.1, 0.2],
            output,
            ..Default::default()
        };
        let w = pseudo_random(output.channels() * 40 * 48, seed + 1);
        Self { points, offsets, colors, cam, style, w }
    }

    fn strands<'a>(&'a self, points: &'a [[f32; 3]]) -> Strands<'a> {
        strands(points, &self.offsets, Some(&self.colors))
    }

    fn analytic(&self) -> Vec<f32> {
        let s = self.strands(&self.points);
        let (img, cache) = render(&s, &self.cam, &self.style).unwrap();
        let grad = Image::from_vec(img.channels, img.height, img.width, self.w.clone());
        render_backward(&s, &self.cam, &self.style, &cache, &grad).unwrap().into_iter().flatten().collect()
    }

    fn flat(&self) -> Vec<f32> {
        self.points.iter().flatten().copied().collect()
    }

    fn unflat(x: &[f32]) -> Vec<[f32; 3]> {
        x.chunks(3).map(|v| [v[0], v[1], v[2]]).collect()
    }
}

/// The analytic gradient against central differences of the f64 brute-force
/// eq. 7. The 3σ truncation leaves a kink in every footprint (its slope drops
/// by about 5 % to zero there), and thin strands move their ellipse boundary
/// across pixel centres fast, so the step is tiny (2⁻¹⁶, exact in f32 for
/// these coordinates) and the reference is f64; that the renderer equals the
/// brute force is checked separately.
/// Measured worst relative error: 3e-5.
fn gradcheck_f64(output: SplatOutput, seed: u64) {
    let probe = Probe::new(output, 0.03, seed);
    let analytic = probe.analytic();
    let loss = |x: &[f32]| {
        let img = brute_force(&probe.strands(&Probe::unflat(x)), &probe.cam, &probe.style);
        img.iter().zip(&probe.w).map(|(a, b)| a * *b as f64).sum::<f64>()
    };
    let scale = analytic.iter().fold(0.0f32, |m, v| m.max(v.abs())) as f64;
    assert!(scale > 1.0, "probe should have a sizeable gradient");
    let flat = probe.flat();
    let res = check_gradient(&flat, &analytic, loss, 1.0 / 65536.0, flat.len(), 1e-2 * scale);
    assert!(res.max_rel_err < 1e-3, "{output:?}: {res:?}, gradient scale {scale}");
}

/// The analytic gradient against central differences of the renderer itself
/// (f32 image, f64 probe). Larger steps cross footprint kinks and smaller
/// ones drown in f32 rounding, so this check is looser than the f64 one
/// (measured worst: 1.5 % RGB, 1.9 % grey + alpha).
fn gradcheck_f32(output: SplatOutput, seed: u64) {
    let probe = Probe::new(output, 0.06, seed);
    let analytic = probe.analytic();
    let loss = |x: &[f32]| {
        let pts = Probe::unflat(x);
        dot(&probe.w, &render(&probe.strands(&pts), &probe.cam, &probe.style).unwrap().0.data)
    };
    let scale = analytic.iter().fold(0.0f32, |m, v| m.max(v.abs())) as f64;
    let flat = probe.flat();
    let res = check_gradient(&flat, &analytic, loss, 1.0 / 4096.0, flat.len(), 5e-2 * scale);
    assert!(res.max_rel_err < 4e-2, "{output:?}: {res:?}, gradient scale {scale}");
}

#[test]
fn gradient_rgb_matches_f64_finite_differences() {
    gradcheck_f64(SplatOutput::Rgb, 21);
}

#[test]
fn gradient_grey_alpha_matches_f64_finite_differences() {
    gradcheck_f64(SplatOutput::GreyAlpha, 33);
}

#[test]
fn gradient_rgb_matches_renderer_finite_differences() {
    gradcheck_f32(SplatOutput::Rgb, 21);
}

#[test]
fn gradient_grey_alpha_matches_renderer_finite_differences() {
    gradcheck_f32(SplatOutput::GreyAlpha, 33);
}

/// The colour gradient against central differences of the f64
/// brute-force eq. 7 in every point's colour. The render is linear in the
/// colours (they scale each splat's feature, never its alpha), so the check
/// is tight; both channel layouts, since grey + alpha sees colour through
/// the luminance only.
fn colour_gradcheck(output: SplatOutput, seed: u64) {
    let probe = Probe::new(output, 0.03, seed);
    let s = probe.strands(&probe.points);
    let (img, cache) = render(&s, &probe.cam, &probe.style).unwrap();
    let grad = Image::from_vec(img.channels, img.height, img.width, probe.w.clone());
    let all = render_backward_all(&s, &probe.cam, &probe.style, &cache, &grad).unwrap();
    assert_eq!(all.points, render_backward(&s, &probe.cam, &probe.style, &cache, &grad).unwrap());
    let analytic: Vec<f32> = all.colors.iter().flatten().copied().collect();
    let loss = |x: &[f32]| {
        let colors = Probe::unflat(x);
        let st = strands(&probe.points, &probe.offsets, Some(&colors));
        let img = brute_force(&st, &probe.cam, &probe.style);
        img.iter().zip(&probe.w).map(|(a, b)| a * *b as f64).sum::<f64>()
    };
    let scale = analytic.iter().fold(0.0f32, |m, v| m.max(v.abs())) as f64;
    assert!(scale > 0.1, "probe should have a sizeable colour gradient, got {scale}");
    let flat: Vec<f32> = probe.colors.iter().flatten().copied().collect();
    let res = check_gradient(&flat, &analytic, loss, 1.0 / 1024.0, flat.len(), 1e-3 * scale);
    assert!(res.max_rel_err < 1e-4, "{output:?}: {res:?}, gradient scale {scale}");
}

#[test]
fn colour_gradient_rgb_matches_f64_finite_differences() {
    colour_gradcheck(SplatOutput::Rgb, 21);
}

#[test]
fn colour_gradient_grey_alpha_matches_f64_finite_differences() {
    colour_gradcheck(SplatOutput::GreyAlpha, 33);
}

// ---------------------------------------------------------------- culling

#[test]
fn culls_strands_facing_away() {
    let (p, o, c) = scene(3, 6, 5);
    let cam = camera(48, 40);
    let style = StrandStyle { width: 0.03, visibility_threshold: 0.1, ..Default::default() };
    // Strand 1's root normal faces away from the camera (on +z).
    let normals = [[0.0, 0.0, 1.0], [0.0, 0.3, -1.0], [0.2, 0.0, 1.0]];
    let s = Strands { points: &p, offsets: &o, colors: Some(&c), root_normals: Some(&normals) };
    let (img, cache) = render(&s, &cam, &style).unwrap();
    assert_eq!(cache.visible_strands(), 2);

    // Same as rendering only strands 0 and 2.
    let kept: Vec<[f32; 3]> = p[o[0]..o[1]].iter().chain(&p[o[2]..o[3]]).copied().collect();
    let kept_c: Vec<[f32; 3]> = c[o[0]..o[1]].iter().chain(&c[o[2]..o[3]]).copied().collect();
    let kept_o = [0, o[1], o[1] + o[3] - o[2]];
    let (want, _) = render(&strands(&kept, &kept_o, Some(&kept_c)), &cam, &style).unwrap();
    assert_eq!(img.data, want.data);

    // Culled points get no gradient; visible ones do.
    let grad = Image::from_vec(3, 40, 48, pseudo_random(3 * 40 * 48, 4));
    let g = render_backward(&s, &cam, &style, &cache, &grad).unwrap();
    assert!(g[o[1]..o[2]].iter().flatten().all(|&v| v == 0.0));
    assert!(g[o[0]..o[1]].iter().flatten().any(|&v| v != 0.0));

    // A threshold below the dot product keeps it; no normals disables culling.
    let lenient = StrandStyle { visibility_threshold: -1.0, ..style };
    assert_eq!(render(&s, &cam, &lenient).unwrap().1.visible_strands(), 3);
    let unculled = Strands { root_normals: None, ..s };
    assert_eq!(render(&unculled, &cam, &style).unwrap().1.visible_strands(), 3);
}

// ------------------------------------------------------------ determinism

#[test]
fn bitwise_identical_across_thread_counts() {
    let (p, o, c) = scene(60, 17, 8);
    let cam = camera(160, 120);
    let style = StrandStyle { width: 0.02, ..Default::default() };
    let s = strands(&p, &o, Some(&c));
    let grad = Image::from_vec(3, 120, 160, pseudo_random(3 * 120 * 160, 2));
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            let (img, cache) = render(&s, &cam, &style).unwrap();
            let g = render_backward(&s, &cam, &style, &cache, &grad).unwrap();
            (img.data, g)
        })
    };
    let (img1, g1) = run(1);
    for threads in [2, 3, 5] {
        let (img, g) = run(threads);
        assert!(img.iter().zip(&img1).all(|(a, b)| a.to_bits() == b.to_bits()), "image differs with {threads} threads");
        assert!(
            g.iter().flatten().zip(g1.iter().flatten()).all(|(a, b)| a.to_bits() == b.to_bits()),
            "gradient differs with {threads} threads"
        );
    }
}

// ------------------------------------------------------------- validation

#[test]
fn rejects_bad_input() {
    let (p, o, _) = scene(2, 4, 1);
    let cam = camera(32, 32);
    let style = StrandStyle::default();
    let bad_offsets = [0, 3, 7];
    assert_eq!(
        render(&strands(&p, &bad_offsets, None), &cam, &style).unwrap_err(),
        SplatError::BadOffsets { points: 8 }
    );
    let mut nan = p.clone();
    nan[5][1] = f32::NAN;
    assert_eq!(render(&strands(&nan, &o, None), &cam, &style).unwrap_err(), SplatError::NonFinitePoint(5));
    let short = [[1.0f32; 3]; 3];
    assert!(matches!(
        render(&strands(&p, &o, Some(&short)), &cam, &style),
        Err(SplatError::LengthMismatch { what: "colors", .. })
    ));
    let zero_normals = [[0.0f32; 3]; 2];
    let s = Strands { root_normals: Some(&zero_normals), ..strands(&p, &o, None) };
    assert_eq!(render(&s, &cam, &style).unwrap_err(), SplatError::BadRootNormal(0));
    let bad_style = StrandStyle { width: 0.0, ..style };
    assert!(matches!(render(&strands(&p, &o, None), &cam, &bad_style), Err(SplatError::BadStyle(_))));

    assert_eq!(
        SplatCamera::look_at([0.0; 3], [0.0; 3], [0.0, 1.0, 0.0], 40.0, 8, 8).unwrap_err(),
        SplatError::EyeAtTarget
    );
    assert_eq!(
        SplatCamera::look_at([0.0, 0.0, 1.0], [0.0; 3], [0.0, 0.0, 1.0], 40.0, 8, 8).unwrap_err(),
        SplatError::DegenerateUp
    );
    assert_eq!(
        SplatCamera::look_at([0.0, 0.0, 1.0], [0.0; 3], [0.0, 1.0, 0.0], 180.0, 8, 8).unwrap_err(),
        SplatError::BadFov(180.0)
    );

    let s = strands(&p, &o, None);
    let (_, cache) = render(&s, &cam, &style).unwrap();
    let wrong = Image::zeros(2, 32, 32);
    assert!(matches!(render_backward(&s, &cam, &style, &cache, &wrong), Err(SplatError::GradShape { .. })));
    let other_cam = camera(32, 31);
    let grad = Image::zeros(3, 31, 32);
    assert_eq!(render_backward(&s, &other_cam, &style, &cache, &grad).unwrap_err(), SplatError::CacheMismatch);
}
