//! Temporal flicker of a stylised sequence: how much each frame's picture
//! differs from the previous frame's picture carried along the simulation
//! velocity, `mean_t mean_px |R(d*_t) − R(A(d*_{t−1}, u_{t−1}))|`. Smoke that
//! merely moves scores 0; patterns that jump or shimmer score high. The warp
//! is done on the density in 3D (one semi-Lagrangian step), so it is exact
//! for any camera.

use nst3d_core::{Grid3, Image};
use nst3d_transport as transport;

/// Mean absolute difference per pixel between consecutive renders after
/// carrying the earlier frame along its velocity. `velocities[t]` is `u_t` in
/// voxels per frame (`None`: the frame is compared unwarped).
pub fn flicker<E>(
    frames: &[Grid3],
    velocities: &[Option<Vec<[f32; 3]>>],
    render: impl Fn(&Grid3) -> Result<Image, E>,
) -> Result<f32, E> {
    flicker_of(frames, velocities, transport::advect_linear, render)
}

/// [`flicker`] of frames that carry colour: each frame is its
/// density and RGB colour grids, all carried alike, and `render` draws the
/// colour picture.
pub fn flicker_color<E>(
    frames: &[(Grid3, Vec<Grid3>)],
    velocities: &[Option<Vec<[f32; 3]>>],
    render: impl Fn(&(Grid3, Vec<Grid3>)) -> Result<Image, E>,
) -> Result<f32, E> {
    let warp = |(d, c): &(Grid3, Vec<Grid3>), back: &[[f32; 3]]| {
        (transport::advect_linear(d, back), c.iter().map(|g| transport::advect_linear(g, back)).collect())
    };
    flicker_of(frames, velocities, warp, render)
}

/// The metric over any frame type: `warp(frame, −u)` carries a frame one
/// step along `u` (a semi-Lagrangian read at `x − u`).
fn flicker_of<F: Clone, E>(
    frames: &[F],
    velocities: &[Option<Vec<[f32; 3]>>],
    warp: impl Fn(&F, &[[f32; 3]]) -> F,
    render: impl Fn(&F) -> Result<Image, E>,
) -> Result<f32, E> {
    if frames.len() < 2 {
        return Ok(0.0);
    }
    let mut total = 0.0f64;
    for t in 1..frames.len() {
        let prev = &frames[t - 1];
        let warped = match &velocities[t - 1] {
            Some(u) => {
                let back: Vec<[f32; 3]> = u.iter().map(|w| [-w[0], -w[1], -w[2]]).collect();
                warp(prev, &back)
            }
            None => prev.clone(),
        };
        let (a, b) = (render(&frames[t])?, render(&warped)?);
        let diff: f64 = a.data.iter().zip(&b.data).map(|(x, y)| (x - y).abs() as f64).sum();
        total += diff / a.data.len().max(1) as f64;
    }
    Ok((total / (frames.len() - 1) as f64) as f32)
}
