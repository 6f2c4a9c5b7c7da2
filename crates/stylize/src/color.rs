//! The smoke's colour as a chroma layer over the density, as a
//! sequence steps it in its sweeps. (A single frame's colour stage,
//! [`crate::color_stage`], holds the colour itself, free in brightness
//! under a grey guard: measured better there, not yet in sequences.)
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
//! (docs/design/color.md):
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
use rayon::prelude::*;

/// Range of a raw channel. Its ratio bounds the saturation: a pure
/// primary of luminance 1 is out of reach, which suits paintings (their
/// colours are mixed) and keeps any channel's emission finite.
pub const RAW_RANGE: (f32, f32) = (0.02, 2.0);

/// Tent passes `k` applied to the raw channels in a sequence's sweeps: two
/// passes spread a voxel's colour over a 5-voxel support (at each octave's
/// resolution, so coarse octaves place broad patches). A single frame's
/// colour stage does not use this layer ([`crate::color_stage`]).
pub const SMOOTH_PASSES: usize = 2;

/// Adam's step on the raw channels, whatever the density's mode and rate
/// (velocity mode steps voxels at 0.5, a rate that would saturate colour in
/// a few steps). Measured on smoke_000003 and plume48 with Woman with a Hat
/// (docs/design/color.md): from 0.2 to 0.05 the held-out colour
/// loss of a single frame stays the same (0.779 → 0.783 of the grey
/// result's) and the picture calms, while a sequence's colour flicker falls
/// from 0.66× to 0.39× of per-frame optimisation's — Adam's first steps are
/// about `rate` per voxel whatever the gradient, and the EMA only averages
/// what those steps scatter.
pub const LEARNING_RATE: f32 = 0.05;

/// What [`chroma`] keeps for [`chroma_backward`].
pub struct ChromaTape {
    /// The smoothed channels `s`.
    smoothed: Vec<Vec<f32>>,
    dims: [usize; 3],
    passes: usize,
}

fn smooth(v: &[f32], dims: [usize; 3], passes: usize) -> Vec<f32> {
    if passes == 0 {
        return v.to_vec();
    }
    let mut out = transport::tent_smooth_flat(v, 1, dims);
    let mut spare = vec![0.0; v.len()];
    for _ in 1..passes {
        transport::tent_smooth_into(&out, 1, dims, &mut spare);
        std::mem::swap(&mut out, &mut spare);
    }
    out
}

/// The colour `c` (three grids of `dims`) of the raw channels `raw`, smoothed
/// by `passes` tent passes first.
///
/// # Panics
/// If there are not three channels of the voxel count of `dims`.
pub fn chroma(raw: &[&[f32]], dims: [usize; 3], passes: usize) -> (Vec<Grid3>, ChromaTape) {
    assert_eq!(raw.len(), 3, "three colour channels");
    let smoothed: Vec<Vec<f32>> = raw.par_iter().map(|r| smooth(r, dims, passes)).collect();
    let n = smoothed[0].len();
    let mut color: Vec<Vec<f32>> = vec![vec![0.0; n]; 3];
    let [c0, c1, c2] = &mut color[..] else { unreachable!("three channels") };
    let (s0, s1, s2) = (&smoothed[0], &smoothed[1], &smoothed[2]);
    (c0.par_chunks_mut(CHUNK), c1.par_chunks_mut(CHUNK), c2.par_chunks_mut(CHUNK))
        .into_par_iter()
        .enumerate()
        .for_each(|(k, (r, g, b))| {
            let at = k * CHUNK;
            for i in 0..r.len() {
                let s = [s0[at + i], s1[at + i], s2[at + i]];
                let lum = LUMA[0] * s[0] + LUMA[1] * s[1] + LUMA[2] * s[2];
                (r[i], g[i], b[i]) = (s[0] / lum, s[1] / lum, s[2] / lum);
            }
        });
    let color = color.into_iter().map(|c| Grid3::from_vec(dims, c)).collect();
    (color, ChromaTape { smoothed, dims, passes })
}

/// Voxels per unit of parallel work in the per-voxel loops.
const CHUNK: usize = 1 << 14;

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
    let [g0, g1, g2] = &mut grad_s[..] else { unreachable!("three channels") };
    let gc = [&grad_color[0].data, &grad_color[1].data, &grad_color[2].data];
    (g0.par_chunks_mut(CHUNK), g1.par_chunks_mut(CHUNK), g2.par_chunks_mut(CHUNK))
        .into_par_iter()
        .enumerate()
        .for_each(|(k, (r, g, b))| {
            let at = k * CHUNK;
            for i in 0..r.len() {
                let j = at + i;
                let sv = [s[0][j], s[1][j], s[2][j]];
                let lum = LUMA[0] * sv[0] + LUMA[1] * sv[1] + LUMA[2] * sv[2];
                let gv = [gc[0][j], gc[1][j], gc[2][j]];
                let g_dot_c = (gv[0] * sv[0] + gv[1] * sv[1] + gv[2] * sv[2]) / lum;
                r[i] = (gv[0] - LUMA[0] * g_dot_c) / lum;
                g[i] = (gv[1] - LUMA[1] * g_dot_c) / lum;
                b[i] = (gv[2] - LUMA[2] * g_dot_c) / lum;
            }
        });
    grad_s.par_iter().map(|g| smooth(g, tape.dims, tape.passes)).collect()
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
        let (c, _) = chroma(&[&r[0], &r[1], &r[2]], DIMS, SMOOTH_PASSES);
        for i in 0..60 {
            let lum: f32 = (0..3).map(|ch| LUMA[ch] * c[ch].data[i]).sum();
            assert!((lum - 1.0).abs() < 1e-5, "voxel {i}: luminance {lum}");
        }
        let one = vec![0.7f32; 60];
        let (w, _) = chroma(&[&one, &one, &one], DIMS, SMOOTH_PASSES);
        // The tent is zero outside the grid, so borders smooth towards 0 in
        // every channel alike: still grey, still white after the division.
        assert!(w.iter().all(|g| g.data.iter().all(|v| (v - 1.0).abs() < 1e-5)));
    }

    /// Without smoothing and with the sequences' two passes.
    #[test]
    fn chroma_gradient_matches_finite_differences() {
        for passes in [0, SMOOTH_PASSES] {
            let r = raw();
            let y: Vec<f32> = pseudo_random(180, 80);
            let tape_of = |x: &[f32]| chroma(&[&x[..60], &x[60..120], &x[120..]], DIMS, passes);
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
            assert!(check.max_rel_err < 1e-2, "{passes} passes: {check:?}");
        }
    }
}
