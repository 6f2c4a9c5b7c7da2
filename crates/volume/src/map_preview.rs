//! The preview of a style map's job: input | map | result | the paintings.
//! The map is drawn as the smoke is (the input's emission and
//! transmittance, from the same camera) with each painting's region in a
//! tint of its own, so a soft map shows its blend as a mix of the tints;
//! each painting's panel carries its tint as a bar along its foot.

use std::path::Path;

use anyhow::Result;
use nst3d_core::{Grid3, Image};
use nst3d_io::image::{resize_to_height, side_by_side, write_png};
use nst3d_stylize::{color_view_image, ViewLoss, ViewSpec};

use crate::look::{display, PREVIEW_HEIGHT};

/// The tint of painting `k` in the map panel, in the `--style` order
/// (after the sixth they repeat): orange, blue, green, magenta, yellow, cyan.
pub const TINTS: [[f32; 3]; 6] =
    [[1.0, 0.45, 0.1], [0.15, 0.55, 1.0], [0.3, 0.85, 0.25], [0.85, 0.25, 0.85], [1.0, 0.9, 0.15], [0.2, 0.9, 0.9]];

/// Rows of the tint bar at the foot of each painting's panel.
const BAR: usize = 12;

/// The tint of painting `k`.
pub fn tint(k: usize) -> [f32; 3] {
    TINTS[k % TINTS.len()]
}

/// The map seen from `view`: `d` rendered in colour, each voxel's colour
/// its regions' tints weighted by its weights (`regions`, one grid per
/// painting, summing to 1), upsampled 2x as the other panels are.
pub fn map_picture(d: &Grid3, regions: &[Grid3], view: &ViewSpec) -> Result<Image> {
    let color: Vec<Grid3> = (0..3)
        .map(|c| {
            let mut g = Grid3::zeros(d.dims);
            for (k, r) in regions.iter().enumerate() {
                let t = tint(k)[c];
                g.data.iter_mut().zip(&r.data).for_each(|(a, w)| *a += t * w);
            }
            g
        })
        .collect();
    Ok(nst3d_render::upsample2x(&color_view_image(d, &color, view)?))
}

/// `picture` with its bottom rows painted in painting `k`'s tint.
fn with_bar(picture: &Image, k: usize) -> Image {
    let mut out = if picture.channels == 3 { picture.clone() } else { nst3d_stylize::view::grey_to_rgb(picture) };
    let (h, w) = (out.height, out.width);
    for (c, t) in tint(k).iter().enumerate() {
        for y in h.saturating_sub(BAR)..h {
            out.data[(c * h + y) * w..][..w].iter_mut().for_each(|v| *v = *t);
        }
    }
    out
}

/// Writes input | map | result | the paintings (each with its tint bar),
/// every panel [`PREVIEW_HEIGHT`] pixels tall, from `view`: `grids` are the
/// input, its regions, the result and the result's colour (drawn grey
/// without); `grey` draws grey pictures as the loss sees them.
pub fn write_map_preview(
    path: &Path,
    grey: &ViewLoss,
    view: &ViewSpec,
    (input, regions, density, color): (&Grid3, &[Grid3], &Grid3, Option<&[Grid3]>),
    paintings: &[Image],
) -> Result<()> {
    let h = PREVIEW_HEIGHT;
    let result = match color {
        None => display(grey, density, view)?,
        Some(c) => nst3d_render::upsample2x(&color_view_image(density, c, view)?),
    };
    let mut panels = vec![
        resize_to_height(&display(grey, input, view)?, h),
        resize_to_height(&map_picture(input, regions, view)?, h),
        resize_to_height(&result, h),
    ];
    panels.extend(paintings.iter().enumerate().map(|(k, p)| with_bar(&resize_to_height(p, h), k)));
    write_png(path, &side_by_side(&panels.iter().collect::<Vec<_>>()))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One region takes its tint, a half-and-half blend the mean of two,
    /// in the colour of the smoke's own light.
    #[test]
    fn the_map_is_the_smoke_in_each_regions_tint() {
        let d = nst3d_stylize::bench::synthetic_smoke(16, 2);
        let cam = nst3d_render::Camera::front(d.dims);
        let view = ViewSpec { camera: Some(cam), gamma: 0.2, exposure: 0.2, equalize: false };
        let grey = nst3d_render::upsample2x(&nst3d_stylize::view_image(&d, &view).unwrap());
        let ones = Grid3::from_vec(d.dims, vec![1.0; d.len()]);
        let half = Grid3::from_vec(d.dims, vec![0.5; d.len()]);
        let first = map_picture(&d, &[ones.clone(), Grid3::zeros(d.dims)], &view).unwrap();
        let blend = map_picture(&d, &[half.clone(), half], &view).unwrap();
        let plane = grey.plane();
        for p in (0..plane).filter(|p| grey.data[*p] > 0.05) {
            for c in 0..3 {
                let want = grey.data[p] * tint(0)[c];
                assert!((first.data[c * plane + p] - want).abs() < 1e-4, "pixel {p} channel {c}");
                let mean = grey.data[p] * 0.5 * (tint(0)[c] + tint(1)[c]);
                assert!((blend.data[c * plane + p] - mean).abs() < 1e-4);
            }
        }
    }
}
