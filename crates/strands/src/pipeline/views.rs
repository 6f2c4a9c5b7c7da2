//! Where the cameras go (the view frame and best-candidate angles) and what
//! a view's render is matched against (style targets, eq. 2); see the module
//! notes of [`crate::pipeline`].

use nst3d_core::math::{add, cross, dot, norm, normalize, scale, sub, V3};
use nst3d_core::mesh::TriMesh;
use nst3d_core::Image;
use nst3d_features::Vgg19;
use nst3d_loss::cell_mask;
use nst3d_loss::nnst::{nnst_loss_matched, NnstMatch, NnstParams, NnstTarget};
use nst3d_splat::SplatCamera;

use crate::strand_rng;
use crate::strands::FlatStrands;
use crate::StrandError;

use super::{PipelineError, StrandScene, NNST_LAYERS};

/// Where the cameras live: the groom's centre, enclosing radius and the
/// front/up/side axes the angle ranges are measured from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ViewFrame {
    /// Look-at point (bounding-box centre of the rest strands).
    pub centre: [f32; 3],
    /// Radius of the sphere about `centre` enclosing every rest point.
    pub radius: f32,
    /// Unit direction the groom faces (azimuth 0, polar 0).
    pub front: [f32; 3],
    /// Unit up, orthogonal to `front` (positive polar angles tilt towards it).
    pub up: [f32; 3],
    /// Unit `front × up` (positive azimuths turn towards it).
    pub side: [f32; 3],
}

impl ViewFrame {
    /// Unit direction from the centre to the eye at polar `ψ` (elevation
    /// towards `up`) and azimuth `δ` (about `up`), degrees.
    pub fn direction(&self, polar_deg: f32, azimuth_deg: f32) -> [f32; 3] {
        let (p, a) = (polar_deg.to_radians(), azimuth_deg.to_radians());
        let h = add(scale(self.front, a.cos()), scale(self.side, a.sin()));
        add(scale(h, p.cos()), scale(self.up, p.sin()))
    }
}

impl StrandScene {
    /// The camera at polar `ψ` / azimuth `δ` (degrees) on the shell.
    pub fn camera(&self, polar_deg: f32, azimuth_deg: f32) -> Result<SplatCamera, PipelineError> {
        self.camera_at(self.frame.direction(polar_deg, azimuth_deg), self.render_size)
    }

    /// The front camera (ψ = δ = 0) at `size²` pixels, for previews.
    pub fn front_camera(&self, size: usize) -> Result<SplatCamera, PipelineError> {
        self.camera_at(self.frame.front, size)
    }

    fn camera_at(&self, dir: [f32; 3], size: usize) -> Result<SplatCamera, PipelineError> {
        let eye = add(self.frame.centre, scale(dir, self.distance));
        Ok(SplatCamera::look_at(eye, self.frame.centre, self.frame.up, self.fov_deg, size, size)?)
    }
}

/// Centre, radius and front/up axes (see the module notes).
pub(super) fn view_frame(
    rest: &FlatStrands,
    guide_normals: &[V3],
    head: Option<&TriMesh>,
) -> Result<ViewFrame, PipelineError> {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in &rest.points {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    let centre: V3 = std::array::from_fn(|a| 0.5 * (lo[a] + hi[a]));
    let radius = rest.points.iter().map(|&p| norm(sub(p, centre))).fold(0.0f32, f32::max);
    if !(radius > 0.0 && radius.is_finite()) {
        return Err(StrandError::Invalid("the groom has no extent (all points coincide)".into()).into());
    }
    let mut mean = [0.0f64; 3];
    for n in guide_normals {
        for a in 0..3 {
            mean[a] += n[a] as f64;
        }
    }
    let mean: V3 = mean.map(|c| (c / guide_normals.len().max(1) as f64) as f32);
    // Where the roots sit on the head: the roots never move, so a groom
    // and its stylization get the same front (the strands' box moves with
    // the stylization, and on a fur ball it once turned the preview of a
    // result half-way round from the views it was optimised from).
    let roots = rest.offsets[..rest.offsets.len().saturating_sub(1)].iter().map(|&o| rest.points[o]);
    let mut root_sum = [0.0f64; 3];
    let mut root_count = 0usize;
    for r in roots {
        (0..3).for_each(|a| root_sum[a] += r[a] as f64);
        root_count += 1;
    }
    let root_centre: V3 = root_sum.map(|c| (c / root_count.max(1) as f64) as f32);
    let head_centre =
        head.and_then(|h| h.bbox()).map(|(l, h)| std::array::from_fn(|a| 0.5 * (l[a] + h[a]))).unwrap_or(root_centre);
    // The scene is y-up (the groom crate turns a z-up file into this frame),
    // and the cameras go around that axis: the front is the horizontal part
    // of the direction the groom faces, so polar 0 is the horizon and the
    // preview stands upright whatever way the roots point on average.
    let up: V3 = [0.0, 1.0, 0.0];
    let horizontal = |v: V3, min: f32| {
        let h = sub(v, scale(up, dot(v, up)));
        if norm(h) > min {
            normalize(h)
        } else {
            None
        }
    };
    let front = horizontal(mean, 0.2)
        .or_else(|| horizontal(sub(root_centre, head_centre), 0.05 * radius))
        .unwrap_or([0.0, 0.0, 1.0]);
    let side = cross(front, up);
    Ok(ViewFrame { centre, radius, front, up, side })
}

/// `n` view angles `(ψ, δ)` in degrees within the ranges, by best-candidate
/// sampling on the sphere (see the module notes); deterministic in `seed`.
pub fn poisson_view_angles(
    frame: &ViewFrame,
    polar_deg: (f32, f32),
    azimuth_deg: (f32, f32),
    n: usize,
    seed: u64,
) -> Vec<(f32, f32)> {
    const CANDIDATES: usize = 16;
    let mut rng = strand_rng(seed ^ 0x5EED_CA3E_0000_0001);
    let mut out: Vec<(f32, f32)> = Vec::with_capacity(n);
    let mut dirs: Vec<V3> = Vec::with_capacity(n);
    let lerp = |r: (f32, f32), u: f32| r.0 + (r.1 - r.0) * u;
    for _ in 0..n {
        let mut best = (f32::NEG_INFINITY, (0.0, 0.0), [0.0; 3]);
        for _ in 0..if out.is_empty() { 1 } else { CANDIDATES } {
            // Uniform in solid angle over the polar band: sin ψ uniform.
            let (s0, s1) = (polar_deg.0.to_radians().sin(), polar_deg.1.to_radians().sin());
            let psi = (s0 + (s1 - s0) * rng.uniform_f32()).clamp(-1.0, 1.0).asin().to_degrees();
            let delta = lerp(azimuth_deg, rng.uniform_f32());
            let d = frame.direction(psi, delta);
            let gap = dirs.iter().map(|&e| dot(d, e).clamp(-1.0, 1.0).acos()).fold(f32::INFINITY, f32::min);
            if gap > best.0 {
                best = (gap, (psi, delta), d);
            }
        }
        out.push(best.1);
        dirs.push(best.2);
    }
    out
}

/// Style targets of one scale: `style` (RGB in `[0, 1]`) as grey, resized
/// to `height` rows, as NNST hyper-columns of its VGG taps. The shape
/// follows the painting's luminance, with or without `--color` (the colour
/// has a stage of its own, [`stylize_color`](super::stylize_color)).
pub fn style_target(vgg: &Vgg19, style: &Image, height: usize) -> Result<NnstTarget, PipelineError> {
    let img = nst3d_io::image::resize_to_height(&style.luminance3(), height);
    let feats = vgg.forward(&img, &NNST_LAYERS, false);
    Ok(NnstTarget::from_style_features(feats.taps(), &NnstParams::default())?)
}

/// Targets of one view (eq. 2): VGG taps of the undeformed render matched
/// to the style; also returns the undeformed groom's loss against them.
pub fn match_view(
    scene: &StrandScene,
    vgg: &Vgg19,
    style: &NnstTarget,
    cam: &SplatCamera,
) -> Result<(NnstMatch, f32), PipelineError> {
    match_view_on(scene, &scene.undeformed, vgg, style, cam)
}

/// [`match_view`] on the render of `strands` (layout of
/// [`StrandScene::rest`]) instead of the undeformed groom: the targets of a
/// scale re-matched on what the previous scales made.
pub fn match_view_on(
    scene: &StrandScene,
    strands: &FlatStrands,
    vgg: &Vgg19,
    style: &NnstTarget,
    cam: &SplatCamera,
) -> Result<(NnstMatch, f32), PipelineError> {
    let img = scene.render(strands, cam)?;
    let feats = vgg.forward(&img, &NNST_LAYERS, false);
    let m = style.match_content(feats.taps())?;
    let (loss, _) = nnst_loss_matched(feats.taps(), &m)?;
    Ok((m, loss))
}

/// Hyper-columns (row-major on `grid`) whose cell of the image holds a
/// pixel that differs from the background in any of `renders`.
pub fn hair_columns(renders: &[&Image], background: [f32; 3], grid: (usize, usize)) -> Vec<bool> {
    let mut mask = vec![false; grid.0 * grid.1];
    for img in renders {
        let cells = cell_mask(&hair_pixels(img, background), img.height, img.width, grid.0, grid.1);
        mask.iter_mut().zip(cells).for_each(|(m, c)| *m |= c);
    }
    mask
}

/// Pixels of `img` (row-major) that hold hair: a channel off `background`
/// by more than 0.02 (the held-out loss, the colour stage and the judge
/// all count hair so).
pub fn hair_pixels(img: &Image, background: [f32; 3]) -> Vec<bool> {
    let plane = img.plane();
    (0..plane)
        .map(|i| (0..img.channels.min(3)).any(|c| (img.data[c * plane + i] - background[c]).abs() > 0.02))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame() -> ViewFrame {
        ViewFrame { centre: [0.0; 3], radius: 1.0, front: [0.0, 0.0, 1.0], up: [0.0, 1.0, 0.0], side: [-1.0, 0.0, 0.0] }
    }

    /// A fur ball on a sphere has no facing of its own (its root normals
    /// cancel), so its front falls back to where the roots sit on the head;
    /// a stylization that combs one side flat moves the strands' box but
    /// not the roots, and must keep the same front.
    #[test]
    fn a_stylized_fur_ball_keeps_the_front_of_its_rest_groom() {
        let n = 400;
        let dirs: Vec<V3> = (0..n)
            .map(|i| {
                let phi = (1.0 - 2.0 * (i as f32 + 0.5) / n as f32).acos();
                let th = std::f32::consts::PI * (1.0 + 5f32.sqrt()) * (i as f32 + 0.5);
                [th.cos() * phi.sin(), phi.cos(), th.sin() * phi.sin()]
            })
            .collect();
        let groom = |tip: &dyn Fn(V3) -> V3| {
            let mut points = Vec::new();
            let mut offsets = vec![0];
            for &d in &dirs {
                points.extend([d, tip(d)]);
                offsets.push(points.len());
            }
            FlatStrands { points, offsets }
        };
        let rest = groom(&|d| scale(d, 1.4));
        // The +z side combed flat: its tips pulled back onto the sphere.
        let combed = groom(&|d| if d[2] > 0.5 { add(d, [0.3, 0.0, 0.0]) } else { scale(d, 1.4) });
        let head = TriMesh {
            vertices: vec![[-1.0, -1.0, -1.0], [1.0, -1.0, -1.0], [0.0, 1.0, -1.0], [0.0, 0.0, 1.0]],
            triangles: vec![[0, 1, 2], [0, 1, 3], [1, 2, 3], [2, 0, 3]],
            normals: None,
        };
        let a = view_frame(&rest, &dirs, Some(&head)).unwrap();
        let b = view_frame(&combed, &dirs, Some(&head)).unwrap();
        assert_eq!(a.front, b.front);
    }

    #[test]
    fn view_angles_are_deterministic_in_range_and_spread() {
        let f = frame();
        let a = poisson_view_angles(&f, (-10.0, 10.0), (-20.0, 20.0), 16, 3);
        assert_eq!(a, poisson_view_angles(&f, (-10.0, 10.0), (-20.0, 20.0), 16, 3));
        assert_ne!(a, poisson_view_angles(&f, (-10.0, 10.0), (-20.0, 20.0), 16, 4));
        assert!(a.iter().all(|&(p, d)| (-10.0..=10.0).contains(&p) && (-20.0..=20.0).contains(&d)));
        // Best-candidate spreading: no two of the first 8 views closer than
        // a quarter of the spacing a regular 8-point grid would have.
        let dirs: Vec<V3> = a[..8].iter().map(|&(p, d)| f.direction(p, d)).collect();
        let min_gap = (0..8)
            .flat_map(|i| (0..i).map(move |j| (i, j)))
            .map(|(i, j)| dot(dirs[i], dirs[j]).clamp(-1.0, 1.0).acos().to_degrees())
            .fold(f32::INFINITY, f32::min);
        let grid_gap = (20.0f32 * 40.0 / 8.0).sqrt();
        assert!(min_gap > 0.25 * grid_gap, "min gap {min_gap} deg");
    }

    #[test]
    fn direction_axes() {
        let f = frame();
        let close = |a: V3, b: V3| (0..3).all(|k| (a[k] - b[k]).abs() < 1e-6);
        assert!(close(f.direction(0.0, 0.0), f.front));
        assert!(close(f.direction(90.0, 0.0), f.up));
        assert!(close(f.direction(0.0, 90.0), f.side));
    }
}
