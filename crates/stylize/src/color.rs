//! The smoke's colour (issue 29) as a chroma layer over the density.
//!
//! Each voxel's colour `c` multiplies its grey emission (the renderer's
//! premultiplied `e = c·d`, [`nst3d_render::render_color_view`]). The
//! optimiser does not hold `c`; it holds three raw channels `r` per voxel
//! and the colour is
//!
//! ```text
//!     s = S^k r        (k passes of the tent [1, 2, 1] / 4 along every axis)
//!     c = s / (w · s)  (w: the Rec. 601 luma weights, nst3d_core::image::LUMA)
//! ```
//!
//! Why this form, each measured on smoke_000003 with Woman with a Hat
//! (docs/VOLUME_LOOK.md, "Colour"):
//! - **Luminance 1.** `w · c = 1` in every voxel, so the luminance of the
//!   colour render *is* the grey render (emission is linear in `c`): colour
//!   tints and never darkens or brightens. Brightness stays with the
//!   density. The first version, `c` free in `[0, 2]`, darkened the smoke as
//!   much as it tinted it.
//! - **Smooth by construction.** Adam normalises each voxel's step, which
//!   undid a smoothed gradient and left colour speckled at voxel scale.
//!   Smoothing the parameter itself bounds how fine the colour can vary;
//!   a painting's colour lies in brush strokes, not in single voxels.
//!
//! `c` is scale-free in `r`, so `r` starts at 1 (white) and lives in
//! [`RAW_RANGE`]; its floor keeps `w · s` away from 0.

use nst3d_core::image::LUMA;
use nst3d_core::Grid3;
use nst3d_transport as transport;

/// Range of a raw channel. Its ratio bounds the saturation: a pure
/// primary of luminance 1 is out of reach, which suits paintings (their
/// colours are mixed) and keeps any channel's emission finite.
pub const RAW_RANGE: (f32, f32) = (0.02, 2.0);

/// Tent passes `k` applied to the raw channels: two passes spread a
/// voxel's colour over a 5-voxel support (at each octave's resolution, so
/// coarse octaves place broad patches).
pub const SMOOTH_PASSES: usize = 2;

/// Adam's step on the raw channels, whatever the density's mode and rate
/// (velocity mode steps voxels at 0.5, a rate that would saturate colour in
/// two steps). 0.2 is the density mode's rate, measured against 0.5: the
/// held-out colour loss was the same (0.779 vs 0.776 of the grey result's
/// on smoke_000003 with Woman with a Hat) and the picture calmer.
pub const LEARNING_RATE: f32 = 0.2;

/// What [`chroma`] keeps for [`chroma_backward`].
pub struct ChromaTape {
    /// The smoothed channels `s`.
    smoothed: Vec<Vec<f32>>,
    dims: [usize; 3],
}

fn smooth(v: &[f32], dims: [usize; 3]) -> Vec<f32> {
    let mut out = v.to_vec();
    for _ in 0..SMOOTH_PASSES {
        out = transport::tent_smooth_flat(&out, 1, dims);
    }
    out
}

/// The colour `c` (three grids of `dims`) of the raw channels `raw`.
///
/// # Panics
/// If there are not three channels of the voxel count of `dims`.
pub fn chroma(raw: &[&[f32]], dims: [usize; 3]) -> (Vec<Grid3>, ChromaTape) {
    assert_eq!(raw.len(), 3, "three colour channels");
    let smoothed: Vec<Vec<f32>> = raw.iter().map(|r| smooth(r, dims)).collect();
    let n = smoothed[0].len();
    let mut color: Vec<Vec<f32>> = vec![vec![0.0; n]; 3];
    for i in 0..n {
        let lum: f32 = (0..3).map(|ch| LUMA[ch] * smoothed[ch][i]).sum();
        for ch in 0..3 {
            color[ch][i] = smoothed[ch][i] / lum;
        }
    }
    let color = color.into_iter().map(|c| Grid3::from_vec(dims, c)).collect();
    (color, ChromaTape { smoothed, dims })
}

/// The raw channels held as scale fields (how the optimiser keeps them),
/// borrowed for [`chroma`].
pub fn raw_of(fields: &[crate::Field]) -> Vec<&[f32]> {
    fields.iter().map(|f| f.params()).collect()
}

/// Backward of [`chroma`]: with `L = w · s` and `c = s / L`,
/// `∂/∂s_j = (g_j − w_j (g · c)) / L`, then through `S^k` (self-adjoint).
pub fn chroma_backward(tape: &ChromaTape, grad_color: &[Grid3]) -> Vec<Vec<f32>> {
    let s = &tape.smoothed;
    let n = s[0].len();
    let mut grad_s: Vec<Vec<f32>> = vec![vec![0.0; n]; 3];
    for i in 0..n {
        let lum: f32 = (0..3).map(|ch| LUMA[ch] * s[ch][i]).sum();
        let g_dot_c: f32 = (0..3).map(|ch| grad_color[ch].data[i] * s[ch][i] / lum).sum();
        for ch in 0..3 {
            grad_s[ch][i] = (grad_color[ch].data[i] - LUMA[ch] * g_dot_c) / lum;
        }
    }
    grad_s.iter().map(|g| smooth(g, tape.dims)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::{check_gradient, dot, pseudo_random};

    const DIMS: [usize; 3] = [5, 4, 3];

    fn raw() -> Vec<Vec<f32>> {
        (0..3).map(|ch| pseudo_random(60, 70 + ch as u64).iter().map(|v| 1.0 + 0.8 * v).collect()).collect()
    }

    #[test]
    fn colour_has_luminance_one_and_white_stays_white() {
        let r = raw();
        let (c, _) = chroma(&[&r[0], &r[1], &r[2]], DIMS);
        for i in 0..60 {
            let lum: f32 = (0..3).map(|ch| LUMA[ch] * c[ch].data[i]).sum();
            assert!((lum - 1.0).abs() < 1e-5, "voxel {i}: luminance {lum}");
        }
        let one = vec![0.7f32; 60];
        let (w, _) = chroma(&[&one, &one, &one], DIMS);
        // The tent is zero outside the grid, so borders smooth towards 0 in
        // every channel alike: still grey, still white after the division.
        assert!(w.iter().all(|g| g.data.iter().all(|v| (v - 1.0).abs() < 1e-5)));
    }

    #[test]
    fn chroma_gradient_matches_finite_differences() {
        let r = raw();
        let y: Vec<f32> = pseudo_random(180, 80);
        let tape_of = |x: &[f32]| chroma(&[&x[..60], &x[60..120], &x[120..]], DIMS);
        let x0: Vec<f32> = r.concat();
        let (_, tape) = tape_of(&x0);
        let gc: Vec<Grid3> = (0..3).map(|ch| Grid3::from_vec(DIMS, y[ch * 60..][..60].to_vec())).collect();
        let analytic = chroma_backward(&tape, &gc).concat();
        let f = |x: &[f32]| {
            let (c, _) = tape_of(x);
            dot(&y, &c.iter().flat_map(|g| g.data.clone()).collect::<Vec<f32>>())
        };
        // f32 forward: a step of 1e-2 keeps round-off below the
        // rational function's curvature; gradients are O(1), floor 1e-2.
        let check = check_gradient(&x0, &analytic, f, 1e-2, 180, 1e-2);
        assert!(check.max_rel_err < 1e-2, "{check:?}");
    }
}
