//! Camera rendering `R_θ` (paper eq. 1, 6): resample the grid on the camera's
//! lattice, then march it; the backward runs the same two stages in reverse.

use crate::camera::{Affine, Camera, Frustum, Sampling, View};
use crate::march::{march, march_backward, march_emission, march_emission_backward};
use crate::RenderError;
use nst3d_core::{Grid3, Image};
use nst3d_transport::{sample_trilinear_rows, sample_trilinear_rows_backward};
use rayon::prelude::*;

/// What [`render_backward`] needs from the forward pass.
#[derive(Clone, Debug)]
pub struct RenderCache {
    /// The camera lattice the image was marched on.
    pub view: View,
    /// Densities resampled on the lattice (`view.dims`), the march's input.
    pub lattice: Grid3,
    /// Absorption the march used.
    pub gamma: f32,
}

/// `dst[(z·ny + y)·nx + x] = src[map(x, y, z)]`: the pure permutation an
/// axis-aligned view applies, in either direction.
fn permute(src: &[f32], dst_dims: [usize; 3], map: &Affine) -> Vec<f32> {
    let [nx, ny, _] = dst_dims;
    let mut dst = vec![0f32; dst_dims.iter().product()];
    if dst.is_empty() {
        return dst;
    }
    dst.par_chunks_mut(nx).enumerate().for_each(|(r, row)| {
        let start = map.base + (r % ny) as isize * map.strides[1] + (r / ny) as isize * map.strides[2];
        match map.strides[0] {
            // Contiguous source rows, forwards or mirrored, are the common (front/back) views.
            1 => row.copy_from_slice(&src[start as usize..][..nx]),
            -1 => {
                let s = &src[(start + 1) as usize - nx..][..nx];
                row.iter_mut().zip(s.iter().rev()).for_each(|(d, v)| *d = *v);
            }
            step => row.iter_mut().enumerate().for_each(|(x, d)| *d = src[(start + x as isize * step) as usize]),
        }
    });
    dst
}

/// Row filler for the sampling kernel: positions of lattice row `row = k·h + r`.
fn lattice_positions(f: &Frustum, h: usize) -> impl Fn(usize, &mut [[f32; 3]]) + Sync + '_ {
    move |row, pos| {
        let (start, step) = f.row(row % h, row / h);
        for (c, p) in pos.iter_mut().enumerate() {
            let c = c as f32;
            *p = [start[0] + c * step[0], start[1] + c * step[1], start[2] + c * step[2]];
        }
    }
}

/// Renders `g` through `cam` with absorption `gamma` (paper eq. 6): a
/// `1 x H x W` image, row 0 at the top, and the cache for [`render_backward`].
/// Axis-aligned orthographic cameras (e.g. [`Camera::front`]) skip
/// interpolation: their lattice is a permutation of the voxels.
pub fn render(g: &Grid3, cam: &Camera, gamma: f32) -> Result<(Image, RenderCache), RenderError> {
    render_view(g, cam.view(g.dims)?, gamma)
}

/// [`render`] for a precomputed [`View`] (of a grid with `g`'s dims).
pub fn render_view(g: &Grid3, view: View, gamma: f32) -> Result<(Image, RenderCache), RenderError> {
    check_view(g, &view, gamma)?;
    let lattice = to_lattice(g, &view);
    let img = march(&lattice, gamma);
    Ok((img, RenderCache { view, lattice, gamma }))
}

/// The view was made for `g`'s dims and the absorption is usable.
fn check_view(g: &Grid3, view: &View, gamma: f32) -> Result<(), RenderError> {
    if view.grid_dims != g.dims {
        return Err(RenderError::ViewMismatch { view: view.grid_dims, grid: g.dims });
    }
    if !gamma.is_finite() {
        return Err(RenderError::BadGamma(gamma));
    }
    Ok(())
}

/// `g` resampled on the view's lattice (or permuted, for axis-aligned views).
fn to_lattice(g: &Grid3, view: &View) -> Grid3 {
    let [w, h, _] = view.dims;
    let data = match &view.sampling {
        Sampling::Axis { lattice_to_grid, .. } => permute(&g.data, view.dims, lattice_to_grid),
        Sampling::Resample(f) => sample_trilinear_rows(g, view.dims.iter().product(), w, lattice_positions(f, h)),
    };
    Grid3::from_vec(view.dims, data)
}

/// Adjoint of [`to_lattice`]: a lattice gradient scattered back onto the grid.
fn from_lattice(g: &Grid3, view: &View, grad_lattice: &Grid3) -> Grid3 {
    match &view.sampling {
        Sampling::Axis { grid_to_lattice, .. } => {
            Grid3::from_vec(view.grid_dims, permute(&grad_lattice.data, view.grid_dims, grid_to_lattice))
        }
        Sampling::Resample(f) => {
            let [w, h, _] = view.dims;
            let mut grad = Grid3::zeros(view.grid_dims);
            sample_trilinear_rows_backward(
                g,
                grad_lattice.len(),
                w,
                lattice_positions(f, h),
                &grad_lattice.data,
                Some(&mut grad.data),
                None,
            );
            grad
        }
    }
}

/// Backward of [`render`]: `∂L/∂g` for `grad_img = ∂L/∂I`, march backward on
/// the lattice, then the resampling's adjoint (a scatter into the grid, or
/// the inverse permutation for axis-aligned views).
///
/// # Panics
/// If `grad_img` does not have the rendered image's shape.
pub fn render_backward(g: &Grid3, cache: &RenderCache, grad_img: &Image) -> Grid3 {
    let view = &cache.view;
    assert_eq!(g.dims, view.grid_dims, "render_backward: grid differs from the rendered one");
    let grad_lattice = march_backward(&cache.lattice, cache.gamma, grad_img);
    from_lattice(g, view, &grad_lattice)
}

/// What [`render_color_backward`] needs from the forward pass.
#[derive(Clone, Debug)]
pub struct ColorRenderCache {
    /// The camera lattice the image was marched on.
    pub view: View,
    /// Densities resampled on the lattice.
    pub lattice: Grid3,
    /// Each channel's emission `c · d` resampled on the lattice.
    pub emission: Vec<Grid3>,
    /// Absorption the march used.
    pub gamma: f32,
}

/// [`render_view`] with a colour per voxel: the emission
/// `c · d` of each channel is formed on the grid, resampled on the camera
/// lattice like the density, and marched by [`march_emission`] into a
/// `channels x H x W` image; colour 1 everywhere renders the grey image.
pub fn render_color_view(
    g: &Grid3,
    color: &[Grid3],
    view: View,
    gamma: f32,
) -> Result<(Image, ColorRenderCache), RenderError> {
    if let Some(c) = color.iter().find(|c| c.dims != g.dims) {
        return Err(RenderError::ViewMismatch { view: g.dims, grid: c.dims });
    }
    // The density's lattice only: its grey march would be thrown away.
    check_view(g, &view, gamma)?;
    let lattice = to_lattice(g, &view);
    let emission: Vec<Grid3> = color.iter().map(|c| to_lattice(&premultiply(g, c), &view)).collect();
    let img = march_emission(&lattice, &emission, gamma);
    Ok((img, ColorRenderCache { view, lattice, emission, gamma }))
}

/// [`render_color_view`]'s picture on the lattice a grey render of the same
/// grid and view already made (`cache`): only the emissions are resampled.
pub fn march_color_on(cache: &RenderCache, g: &Grid3, color: &[Grid3]) -> Image {
    let emission: Vec<Grid3> = color.iter().map(|c| to_lattice(&premultiply(g, c), &cache.view)).collect();
    march_emission(&cache.lattice, &emission, cache.gamma)
}

/// Backward of [`render_color_view`]: `(∂L/∂g, ∂L/∂color)`, through the
/// march, the resampling's adjoint and the product `e = c · d`.
///
/// # Panics
/// If `grad_img` or `color` do not match the render.
pub fn render_color_backward(
    g: &Grid3,
    color: &[Grid3],
    cache: &ColorRenderCache,
    grad_img: &Image,
) -> (Grid3, Vec<Grid3>) {
    assert_eq!(g.dims, cache.view.grid_dims, "render_color_backward: grid differs from the rendered one");
    assert_eq!(color.len(), cache.emission.len(), "render_color_backward: channel count differs from the render's");
    let (gd_lat, ge_lat) = march_emission_backward(&cache.lattice, &cache.emission, cache.gamma, grad_img);
    let mut grad_d = from_lattice(g, &cache.view, &gd_lat);
    let ge: Vec<Grid3> = ge_lat.iter().map(|ge| from_lattice(g, &cache.view, ge)).collect();
    let grad_c = emission_backward(g, color, &ge, &mut grad_d);
    (grad_d, grad_c)
}

/// Backward of the premultiplied emission `e = c · d`: adds `Σ_ch ∂L/∂e_ch ·
/// c_ch` to `grad_d` and returns `∂L/∂c_ch = ∂L/∂e_ch · d`.
fn emission_backward(g: &Grid3, color: &[Grid3], grad_e: &[Grid3], grad_d: &mut Grid3) -> Vec<Grid3> {
    grad_d.data.par_chunks_mut(CHUNK).enumerate().for_each(|(k, gd)| {
        let at = k * CHUNK;
        for (c, ge) in color.iter().zip(grad_e) {
            for (i, v) in gd.iter_mut().enumerate() {
                *v += ge.data[at + i] * c.data[at + i];
            }
        }
    });
    grad_e.iter().map(|ge| product(g, ge)).collect()
}

/// Voxels per unit of parallel work in the per-voxel products.
const CHUNK: usize = 1 << 14;

/// `a ⊙ b` voxel by voxel (the emission `c · d`, or `∂L/∂e · d`).
fn product(a: &Grid3, b: &Grid3) -> Grid3 {
    let mut out = vec![0.0; a.data.len()];
    out.par_chunks_mut(CHUNK)
        .zip(a.data.par_chunks(CHUNK).zip(b.data.par_chunks(CHUNK)))
        .for_each(|(o, (x, y))| o.iter_mut().zip(x.iter().zip(y)).for_each(|(o, (x, y))| *o = x * y));
    Grid3::from_vec(a.dims, out)
}

fn premultiply(g: &Grid3, c: &Grid3) -> Grid3 {
    product(g, c)
}

/// The colour render without a camera: [`march_emission`] of `e = c · d`
/// straight along the grid's z (slice 0 nearest), as [`march`] is for grey
/// — the `volume-iter --color` benchmark's view. Returns the emission for
/// [`march_color_backward`].
///
/// # Panics
/// If a colour grid's dims differ from `g`'s.
pub fn march_color(g: &Grid3, color: &[Grid3], gamma: f32) -> (Image, Vec<Grid3>) {
    let emission: Vec<Grid3> = color.iter().map(|c| premultiply(g, c)).collect();
    (march_emission(g, &emission, gamma), emission)
}

/// Backward of [`march_color`]: `(∂L/∂g, ∂L/∂color)`.
pub fn march_color_backward(
    g: &Grid3,
    color: &[Grid3],
    emission: &[Grid3],
    gamma: f32,
    grad_img: &Image,
) -> (Grid3, Vec<Grid3>) {
    let (mut grad_d, ge) = march_emission_backward(g, emission, gamma, grad_img);
    let grad_c = emission_backward(g, color, &ge, &mut grad_d);
    (grad_d, grad_c)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Projection;
    use nst3d_core::gradcheck::{check_gradient, dot, pseudo_random};

    fn random_density(dims: [usize; 3], seed: u64) -> Grid3 {
        let n = dims.iter().product();
        Grid3::from_vec(dims, pseudo_random(n, seed).iter().map(|v| 0.5 * (v + 1.0)).collect())
    }

    fn sphere(dims: [usize; 3], radius: f32) -> Grid3 {
        let c = dims.map(|n| (n as f32 - 1.0) * 0.5);
        let mut g = Grid3::zeros(dims);
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    let r2 = (x as f32 - c[0]).powi(2) + (y as f32 - c[1]).powi(2) + (z as f32 - c[2]).powi(2);
                    let i = g.index(x, y, z);
                    g.data[i] = if r2.sqrt() <= radius { 0.5 } else { 0.0 };
                }
            }
        }
        g
    }

    fn assert_close(a: &[f32], b: &[f32], tol: f32, what: &str) {
        assert_eq!(a.len(), b.len(), "{what} length");
        for (i, (x, y)) in a.iter().zip(b).enumerate() {
            assert!((x - y).abs() <= tol * (1.0 + y.abs()), "{what}[{i}]: {x} vs {y}");
        }
    }

    /// Weighted centroid (column, row) and the number of lit columns/rows.
    fn footprint(img: &Image) -> ([f32; 2], [usize; 2]) {
        let (mut s, mut cx, mut cy) = (0f64, 0f64, 0f64);
        let mut cols = vec![false; img.width];
        let mut rows = vec![false; img.height];
        for (y, row) in img.data.chunks(img.width).enumerate() {
            for (x, &v) in row.iter().enumerate() {
                let v = v as f64;
                s += v;
                cx += v * x as f64;
                cy += v * y as f64;
                if v > 1e-3 {
                    cols[x] = true;
                    rows[y] = true;
                }
            }
        }
        let count = |b: &[bool]| b.iter().filter(|&&v| v).count();
        ([(cx / s) as f32, (cy / s) as f32], [count(&cols), count(&rows)])
    }

    #[test]
    fn front_camera_is_march_of_flipped_grid() {
        let dims = [5, 4, 3];
        let g = random_density(dims, 1);
        let cam = Camera::front(dims);
        assert!(cam.view(dims).unwrap().is_axis_aligned());
        // Looking along -z with +y up: slice z = nz-1 is nearest, row 0 is the highest y.
        let mut flipped = Grid3::zeros(dims);
        for z in 0..3 {
            for y in 0..4 {
                for x in 0..5 {
                    let i = flipped.index(x, y, z);
                    flipped.data[i] = g.at(x, 3 - y, 2 - z);
                }
            }
        }
        let (img, _) = render(&g, &cam, 0.7).unwrap();
        assert_eq!((img.height, img.width), (4, 5));
        assert_close(&img.data, &march(&flipped, 0.7).data, 1e-6, "front render");
    }

    #[test]
    fn axis_shortcut_matches_resampling() {
        let dims = [6, 5, 4];
        let g = random_density(dims, 2);
        let w = pseudo_random(64, 3);
        let cams = [
            Camera::front(dims),
            Camera::orbit(dims, 90.0, 0.0),
            Camera::orbit(dims, 180.0, 0.0),
            Camera::orbit(dims, -90.0, 0.0),
            Camera { up: [1.0, 0.0, 0.0], ..Camera::orbit(dims, 0.0, 90.0) },
            Camera { up: [0.0, 0.0, -1.0], ..Camera::orbit(dims, 0.0, -90.0) },
        ];
        for cam in cams {
            let fast = View::build(&cam, dims, true).unwrap();
            let slow = View::build(&cam, dims, false).unwrap();
            assert!(fast.is_axis_aligned() && !slow.is_axis_aligned());
            assert_eq!(fast.dims, slow.dims, "{cam:?}");
            let (a, ca) = render_view(&g, fast, 0.5).unwrap();
            let (b, cb) = render_view(&g, slow, 0.5).unwrap();
            assert_close(&a.data, &b.data, 1e-4, "image");
            let gi = Image::from_vec(1, a.height, a.width, w[..a.data.len()].to_vec());
            let ga = render_backward(&g, &ca, &gi);
            let gb = render_backward(&g, &cb, &gi);
            assert_close(&ga.data, &gb.data, 1e-4, "gradient");
        }
    }

    fn render_gradient_check(cam: Camera) {
        let dims = [6, 5, 7];
        let g = random_density(dims, 4);
        let gamma = 0.4;
        let (img, cache) = render(&g, &cam, gamma).unwrap();
        let w = Image::from_vec(1, img.height, img.width, pseudo_random(img.data.len(), 5));
        let grad = render_backward(&g, &cache, &w);
        let r = check_gradient(
            &g.data,
            &grad.data,
            |x| dot(&w.data, &render(&Grid3::from_vec(dims, x.to_vec()), &cam, gamma).unwrap().0.data),
            // The render is smooth in the density; a large step keeps f32 rounding out of the check.
            3e-2,
            210,
            1e-2,
        );
        assert!(r.max_rel_err < 5e-3, "{cam:?}: {r:?}");
    }

    #[test]
    fn render_gradient_ortho_axis() {
        render_gradient_check(Camera::front([6, 5, 7]));
    }

    #[test]
    fn render_gradient_ortho_rotated() {
        render_gradient_check(Camera::orbit([6, 5, 7], 30.0, 20.0));
    }

    #[test]
    fn render_gradient_perspective() {
        render_gradient_check(Camera::front([6, 5, 7]).with_projection(Projection::Perspective));
        render_gradient_check(Camera::orbit([6, 5, 7], -50.0, 35.0).with_projection(Projection::Perspective));
    }

    #[test]
    fn sphere_is_centred_and_sized() {
        let dims = [40, 32, 24];
        let g = sphere(dims, 10.0);
        let ortho = Camera::front(dims);
        let (img, _) = render(&g, &ortho, 0.1).unwrap();
        assert_eq!((img.height, img.width), (32, 40));
        let ([cx, cy], [w, h]) = footprint(&img);
        assert!((cx - 19.5).abs() < 0.05 && (cy - 15.5).abs() < 0.05, "ortho centroid {cx} {cy}");
        assert!((19..=21).contains(&w) && (19..=21).contains(&h), "ortho footprint {w} x {h}");

        let persp = ortho.with_projection(Projection::Perspective);
        let (img, _) = render(&g, &persp, 0.1).unwrap();
        // One pixel per voxel at the bounding plane nearest the camera: the front face.
        assert_eq!((img.height, img.width), (32, 40));
        let ([cx, cy], [pw, ph]) = footprint(&img);
        assert!((cx - 19.5).abs() < 0.05 && (cy - 15.5).abs() < 0.05, "perspective centroid {cx} {cy}");
        // Farther than the near plane, so a little smaller than orthographic.
        assert!(pw <= w && pw >= w - 4 && ph <= h && ph >= h - 4, "perspective footprint {pw} x {ph}");
    }

    #[test]
    fn image_row_zero_is_top() {
        let dims = [4, 6, 3];
        let mut g = Grid3::zeros(dims);
        let i = g.index(1, 5, 1);
        g.data[i] = 1.0;
        for cam in [Camera::front(dims), Camera::front(dims).with_projection(Projection::Perspective)] {
            let (img, _) = render(&g, &cam, 0.5).unwrap();
            let first_lit = img.data.iter().position(|v| *v > 0.0).unwrap();
            assert_eq!(first_lit / img.width, 0, "{cam:?}");
        }
    }

    #[test]
    fn bad_cameras_are_errors() {
        let dims = [8, 8, 8];
        let inside = Camera { eye: [4.0, 4.0, 4.0], ..Camera::front(dims).with_projection(Projection::Perspective) };
        assert_eq!(inside.view(dims), Err(RenderError::EyeInsideBounds));
        let up = Camera { up: [0.0, 0.0, 1.0], ..Camera::front(dims) };
        assert_eq!(up.view(dims), Err(RenderError::DegenerateUp));
        let away = Camera { target: [3.5, 3.5, 100.0], ..Camera::front(dims).with_projection(Projection::Perspective) };
        assert!(away.view(dims).is_err());
        assert_eq!(Camera::front([0, 3, 3]).view([0, 3, 3]), Err(RenderError::EmptyGrid));
    }

    fn render_color_gradient_check(cam: Camera) {
        let dims = [5, 4, 6];
        let n = 120;
        let g = random_density(dims, 41);
        let color: Vec<Grid3> = (0..3)
            .map(|ch| Grid3::from_vec(dims, pseudo_random(n, 42 + ch).iter().map(|v| 0.5 + 0.4 * v).collect()))
            .collect();
        let gamma = 0.4;
        let view = cam.view(dims).unwrap();
        let (img, cache) = render_color_view(&g, &color, view, gamma).unwrap();
        assert_eq!(img.channels, 3);
        let w = Image::from_vec(3, img.height, img.width, pseudo_random(img.data.len(), 45));
        let (gd, gc) = render_color_backward(&g, &color, &cache, &w);
        let x0 = [g.data.clone(), color.iter().flat_map(|c| c.data.clone()).collect()].concat();
        let analytic = [gd.data, gc.into_iter().flat_map(|c| c.data).collect()].concat();
        let r = check_gradient(
            &x0,
            &analytic,
            |x| {
                let g = Grid3::from_vec(dims, x[..n].to_vec());
                let col: Vec<Grid3> = (0..3).map(|ch| Grid3::from_vec(dims, x[n + ch * n..][..n].to_vec())).collect();
                dot(&w.data, &render_color_view(&g, &col, view, gamma).unwrap().0.data)
            },
            3e-2,
            4 * n,
            1e-2,
        );
        assert!(r.max_rel_err < 5e-3, "{cam:?}: {r:?}");
    }

    #[test]
    fn render_color_gradient_axis_and_rotated() {
        render_color_gradient_check(Camera::front([5, 4, 6]));
        render_color_gradient_check(Camera::orbit([5, 4, 6], 30.0, 20.0));
        render_color_gradient_check(Camera::orbit([5, 4, 6], -50.0, 35.0).with_projection(Projection::Perspective));
    }

    /// The camera-less colour march (the benchmark's view): its backward
    /// against finite differences, and white is the grey march.
    #[test]
    fn march_color_gradient_and_white_is_grey() {
        let dims = [5, 4, 6];
        let n = 120;
        let g = random_density(dims, 61);
        let color: Vec<Grid3> = (0..3)
            .map(|ch| Grid3::from_vec(dims, pseudo_random(n, 62 + ch).iter().map(|v| 0.5 + 0.4 * v).collect()))
            .collect();
        let (img, emission) = march_color(&g, &color, 0.4);
        let w = Image::from_vec(3, img.height, img.width, pseudo_random(img.data.len(), 65));
        let (gd, gc) = march_color_backward(&g, &color, &emission, 0.4, &w);
        let x0 = [g.data.clone(), color.iter().flat_map(|c| c.data.clone()).collect()].concat();
        let analytic = [gd.data, gc.into_iter().flat_map(|c| c.data).collect()].concat();
        let r = check_gradient(
            &x0,
            &analytic,
            |x| {
                let g = Grid3::from_vec(dims, x[..n].to_vec());
                let col: Vec<Grid3> = (0..3).map(|ch| Grid3::from_vec(dims, x[n + ch * n..][..n].to_vec())).collect();
                dot(&w.data, &march_color(&g, &col, 0.4).0.data)
            },
            3e-2,
            4 * n,
            1e-2,
        );
        assert!(r.max_rel_err < 5e-3, "{r:?}");
        let white = vec![Grid3::from_vec(dims, vec![1.0; n]); 3];
        let (rgb, _) = march_color(&g, &white, 0.4);
        let grey = march(&g, 0.4);
        for ch in 0..3 {
            assert_close(&rgb.data[ch * grey.data.len()..][..grey.data.len()], &grey.data, 1e-5, "channel");
        }
    }

    /// Colour 1 everywhere renders the grey image in every channel.
    #[test]
    fn white_render_is_grey_render() {
        let dims = [6, 5, 7];
        let g = random_density(dims, 46);
        let white = vec![Grid3::from_vec(dims, vec![1.0; 210]); 3];
        let cam = Camera::orbit(dims, 25.0, 10.0);
        let (grey, _) = render(&g, &cam, 0.5).unwrap();
        let (rgb, _) = render_color_view(&g, &white, cam.view(dims).unwrap(), 0.5).unwrap();
        let plane = grey.data.len();
        for ch in 0..3 {
            assert_close(&rgb.data[ch * plane..][..plane], &grey.data, 1e-5, "channel");
        }
    }
}
