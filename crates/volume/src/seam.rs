//! How a style map's boundary looks in a result: a soft map should give a
//! soft transition between the paintings, a hard (label) map a clean one,
//! neither a halo (a band along the boundary brighter in strokes, or
//! emptier of them, than both sides).
//!
//! Measured on one view's pictures: the texture the stylization added is
//! the local gradient energy of result − input (`e = |∇(R − I)|²`, per
//! pixel, where the pixel and its four neighbours show smoke). Every smoke
//! pixel gets its signed distance to the map's boundary in the picture
//! (where the rendered share of the second painting crosses 1/2; negative
//! on the first painting's side), and the pixels are binned by it, one
//! pixel a bin. Across the bins:
//! - the map's own transition width: bins whose mean share is between 0.1
//!   and 0.9 (a label map's boundary is blurred only by the transmittance);
//! - the texture's: the width of the ramp from one level to another that
//!   fits the binned energy best (least squares over every width);
//! - the strokes' orientation's: the same fit to the binned share of the
//!   energy across the picture's columns against its rows, which tells two
//!   paintings apart when their strokes lie differently (level stripes
//!   against upright ones) even where their energies match;
//! - the step: the mean energy in the [`STEP`] pixels on the second
//!   painting's side less that on the first's, over the levels' mean (a
//!   hard seam is a step; a soft map should have none);
//! - the halo: in a band around the boundary (half the wider of the two
//!   widths plus [`BAND`] pixels), the largest rise of the energy (three
//!   bins averaged) above both fitted levels and the largest dip below
//!   both, as fractions of the levels' mean; beside it the largest
//!   departure from the fit outside the band.
//!
//! The smoke's own structure moves these numbers too (dense flat smoke
//! takes fainter strokes whatever the painting), so a result is read
//! beside controls: the same frame stylized with each painting alone,
//! measured across the same boundary. A halo is a rise or dip beyond
//! theirs, a seam a step beyond theirs.

use nst3d_core::Image;

/// Pixels on either side of the two transitions still counted as the
/// boundary's band.
pub const BAND: f32 = 3.0;

/// A bin needs this many pixels with an energy to count; the profile ends
/// at the first bin on each side with fewer.
pub const MIN_PIXELS: usize = 8;

/// Pixels on each side of the boundary whose energies make the step.
pub const STEP: f32 = 4.0;

/// The seam of one view.
#[derive(Clone, Debug, PartialEq)]
pub struct Seam {
    /// Pixels over which the map's share goes from 0.1 to 0.9.
    pub map_width: f32,
    /// Width in pixels of the ramp that best fits the texture energy.
    pub texture_width: f32,
    /// The fitted energy on the first painting's side and the second's.
    pub levels: [f32; 2],
    /// The mean energy within [`STEP`] pixels on the second side less that
    /// on the first, over the levels' mean.
    pub step: f32,
    /// The largest rise above both levels in the band, over their mean.
    pub overshoot: f32,
    /// The largest dip below both levels in the band, over their mean.
    pub undershoot: f32,
    /// The largest departure from the fit outside the band, over the mean.
    pub elsewhere: f32,
    /// Width in pixels of the ramp that best fits the strokes' orientation
    /// across the boundary (see [`Seam::orientations`]).
    pub orientation_width: f32,
    /// The fitted orientation on the first side and the second:
    /// `(E_x − E_y) / (E_x + E_y)` of the energy across the picture's
    /// columns and rows, +1 for strokes all upright, −1 all level. Two
    /// paintings whose strokes lie differently show their boundary here.
    pub orientations: [f32; 2],
    /// Bins of the profile (pixels of distance covered).
    pub bins: usize,
}

impl Seam {
    /// `|level 1 − level 0|` over their mean: how much the two paintings'
    /// textures differ in energy (a width means little when this is small).
    pub fn contrast(&self) -> f32 {
        (self.levels[1] - self.levels[0]).abs() / (0.5 * (self.levels[0] + self.levels[1])).max(f32::MIN_POSITIVE)
    }
}

/// The seams of several views in one line: the widths, contrast and step
/// as medians over the views that show the boundary, the band's rise and
/// dip and the variation elsewhere as their worst.
#[derive(Clone, Debug, PartialEq)]
pub struct SeamSummary {
    /// Views that show the boundary.
    pub views: usize,
    /// Median of [`Seam::map_width`].
    pub map_width: f32,
    /// Median of [`Seam::texture_width`].
    pub texture_width: f32,
    /// Median of [`Seam::contrast`].
    pub contrast: f32,
    /// Median of [`Seam::step`].
    pub step: f32,
    /// Median of [`Seam::orientation_width`].
    pub orientation_width: f32,
    /// Medians of [`Seam::orientations`].
    pub orientations: [f32; 2],
    /// Largest [`Seam::overshoot`].
    pub overshoot: f32,
    /// Largest [`Seam::undershoot`].
    pub undershoot: f32,
    /// Largest [`Seam::elsewhere`].
    pub elsewhere: f32,
}

impl SeamSummary {
    /// The summary of `seams` (one per view); `None` if no view shows a boundary.
    pub fn of(seams: &[Option<Seam>]) -> Option<Self> {
        let seen: Vec<&Seam> = seams.iter().flatten().collect();
        if seen.is_empty() {
            return None;
        }
        let median = |f: &dyn Fn(&Seam) -> f32| {
            let mut v: Vec<f32> = seen.iter().map(|s| f(s)).collect();
            v.sort_by(f32::total_cmp);
            v[v.len() / 2]
        };
        let worst = |f: &dyn Fn(&Seam) -> f32| seen.iter().map(|s| f(s)).fold(0.0f32, f32::max);
        Some(Self {
            views: seen.len(),
            map_width: median(&|s| s.map_width),
            texture_width: median(&|s| s.texture_width),
            contrast: median(&Seam::contrast),
            step: median(&|s| s.step),
            orientation_width: median(&|s| s.orientation_width),
            orientations: [median(&|s| s.orientations[0]), median(&|s| s.orientations[1])],
            overshoot: worst(&|s| s.overshoot),
            undershoot: worst(&|s| s.undershoot),
            elsewhere: worst(&|s| s.elsewhere),
        })
    }
}

impl std::fmt::Display for SeamSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "map width {:.0} px, texture width {:.0} px, contrast {:.2}, step {:+.2}, orientation {:+.2} to {:+.2} over {:.0} px (median of {} views); band rise {:.2} dip {:.2}, elsewhere {:.2} (worst)",
            self.map_width,
            self.texture_width,
            self.contrast,
            self.step,
            self.orientations[0],
            self.orientations[1],
            self.orientation_width,
            self.views,
            self.overshoot,
            self.undershoot,
            self.elsewhere
        )
    }
}

/// The seam between two regions seen in one view: `input` and `result`
/// are grey pictures (one channel) of the same size, `share` the second
/// painting's share of each pixel's light, `smoke` the pixels that show
/// smoke. `None` when the view shows no boundary or too few pixels.
pub fn seam(input: &Image, result: &Image, share: &[f32], smoke: &[bool]) -> Option<Seam> {
    let Profile { centre, energy: e, orientation, weight, share } = profile(input, result, share, smoke)?;
    let map_width = share.iter().filter(|m| (0.1..0.9).contains(*m)).count() as f32;
    let (texture_width, levels) = fit_ramp(&centre, &e, &weight);
    let (orientation_width, orientations) = fit_ramp(&centre, &orientation, &weight);
    let ramp = |c: f32| levels[0] + (levels[1] - levels[0]) * ramp_at(c, texture_width);
    let smooth: Vec<f32> = (0..e.len())
        .map(|i| {
            let (a, b) = (i.saturating_sub(1), (i + 1).min(e.len() - 1));
            e[a..=b].iter().sum::<f32>() / (b - a + 1) as f32
        })
        .collect();
    let band = 0.5 * map_width.max(texture_width) + BAND;
    let mean = (0.5 * (levels[0] + levels[1])).max(f32::MIN_POSITIVE);
    let (top, bottom) = (levels[0].max(levels[1]), levels[0].min(levels[1]));
    let side_mean = |inside: &dyn Fn(f32) -> bool| {
        let (sum, n) =
            centre.iter().zip(&e).filter(|(c, _)| inside(**c)).fold((0.0, 0), |(s, n), (_, e)| (s + e, n + 1));
        sum / n.max(1) as f32
    };
    // Bin centres are never 0: each side's first bin is centred half a pixel off.
    let step = (side_mean(&|c| (0.0..=STEP).contains(&c)) - side_mean(&|c| (-STEP..0.0).contains(&c))) / mean;
    let (mut overshoot, mut undershoot, mut elsewhere) = (0.0f32, 0.0f32, 0.0f32);
    for (i, &c) in centre.iter().enumerate() {
        if c.abs() <= band {
            overshoot = overshoot.max((smooth[i] - top) / mean);
            undershoot = undershoot.max((bottom - smooth[i]) / mean);
        } else {
            elsewhere = elsewhere.max((smooth[i] - ramp(c)).abs() / mean);
        }
    }
    let bins = centre.len();
    Some(Seam {
        map_width,
        texture_width,
        levels,
        step,
        overshoot,
        undershoot,
        elsewhere,
        orientation_width,
        orientations,
        bins,
    })
}

/// The smoke pixels binned by signed distance to the boundary, one pixel a
/// bin: each bin's centre, mean energy, orientation, pixel count and mean
/// share, over the bins contiguous with the boundary that hold
/// [`MIN_PIXELS`] pixels with an energy.
struct Profile {
    centre: Vec<f32>,
    energy: Vec<f32>,
    orientation: Vec<f32>,
    weight: Vec<f32>,
    share: Vec<f32>,
}

fn profile(input: &Image, result: &Image, share: &[f32], smoke: &[bool]) -> Option<Profile> {
    let (h, w) = (input.height, input.width);
    let energy = change_energy(input, result, smoke);
    let side = |p: usize| share[p] >= 0.5;
    // Midpoints between 4-neighbours on either side of the boundary.
    let mut crossings = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            for (q, mid) in [
                (x + 1 < w).then(|| (p + 1, [x as f32 + 0.5, y as f32])),
                (y + 1 < h).then(|| (p + w, [x as f32, y as f32 + 0.5])),
            ]
            .into_iter()
            .flatten()
            {
                if smoke[p] && smoke[q] && side(p) != side(q) {
                    crossings.push(mid);
                }
            }
        }
    }
    if crossings.is_empty() {
        return None;
    }
    // Bin i holds signed distances [i − n, i − n + 1): sums of the energy
    // across the columns and the rows, pixels with an energy, share, pixels.
    let n = h.max(w);
    let mut sums = vec![[0.0f64; 5]; 2 * n];
    for p in (0..h * w).filter(|&p| smoke[p]) {
        let (x, y) = ((p % w) as f32, (p / w) as f32);
        let d2 = crossings.iter().map(|c| (c[0] - x).powi(2) + (c[1] - y).powi(2)).fold(f32::INFINITY, f32::min);
        let d = if side(p) { d2.sqrt() } else { -d2.sqrt() };
        let bin = &mut sums[(d.floor() as i64 + n as i64).clamp(0, 2 * n as i64 - 1) as usize];
        if let Some([gx, gy]) = energy[p] {
            (bin[0], bin[1], bin[2]) = (bin[0] + gx as f64, bin[1] + gy as f64, bin[2] + 1.0);
        }
        (bin[3], bin[4]) = (bin[3] + share[p] as f64, bin[4] + 1.0);
    }
    let enough = |b: usize| sums[b][2] >= MIN_PIXELS as f64;
    let lo = (0..n).rev().take_while(|&b| enough(b)).last()?;
    let hi = (n..2 * n).take_while(|&b| enough(b)).last()?;
    let bins = &sums[lo..=hi];
    let of = |f: &dyn Fn(&[f64; 5]) -> f64| bins.iter().map(|b| f(b) as f32).collect::<Vec<f32>>();
    Some(Profile {
        centre: (lo..=hi).map(|b| b as f32 - n as f32 + 0.5).collect(),
        energy: of(&|b| (b[0] + b[1]) / b[2]),
        orientation: of(&|b| if b[0] + b[1] > 0.0 { (b[0] - b[1]) / (b[0] + b[1]) } else { 0.0 }),
        weight: of(&|b| b[2]),
        share: of(&|b| b[3] / b[4]),
    })
}

/// The share of the second level at signed distance `c` on a ramp of
/// `width` pixels centred on the boundary (a step for width 0).
fn ramp_at(c: f32, width: f32) -> f32 {
    if width <= 0.0 {
        (c > 0.0) as u8 as f32
    } else {
        (c / width + 0.5).clamp(0.0, 1.0)
    }
}

/// The ramp width (whole pixels, 0 to the profile's span) and two levels
/// that fit `e` at bin centres `c` best, weighted by `weight`.
fn fit_ramp(c: &[f32], e: &[f32], weight: &[f32]) -> (f32, [f32; 2]) {
    let span = (c[c.len() - 1] - c[0]).ceil() as usize;
    let mut best = (f64::INFINITY, 0.0, [0.0, 0.0]);
    for width in 0..=span {
        let r: Vec<f64> = c.iter().map(|&c| ramp_at(c, width as f32) as f64).collect();
        // Weighted least squares of e ≈ a + b r.
        let (mut sw, mut sr, mut se, mut srr, mut sre) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for i in 0..c.len() {
            let (wt, ri, ei) = (weight[i] as f64, r[i], e[i] as f64);
            (sw, sr, se, srr, sre) = (sw + wt, sr + wt * ri, se + wt * ei, srr + wt * ri * ri, sre + wt * ri * ei);
        }
        let det = sw * srr - sr * sr;
        if det.abs() < 1e-12 {
            continue;
        }
        let b = (sw * sre - sr * se) / det;
        let a = (se - b * sr) / sw;
        let sse: f64 = (0..c.len()).map(|i| weight[i] as f64 * (e[i] as f64 - a - b * r[i]).powi(2)).sum();
        if sse < best.0 {
            best = (sse, width as f32, [a as f32, (a + b) as f32]);
        }
    }
    (best.1, best.2)
}

/// `|∇(result − input)|²` per pixel (central differences) in its two
/// parts, across the columns (`x`) and across the rows (`y`), where the
/// pixel and its four neighbours all show smoke.
fn change_energy(input: &Image, result: &Image, smoke: &[bool]) -> Vec<Option<[f32; 2]>> {
    let (h, w) = (input.height, input.width);
    let c = |p: usize| result.data[p] - input.data[p];
    (0..h * w)
        .map(|p| {
            let (x, y) = (p % w, p / w);
            if x == 0 || y == 0 || x + 1 == w || y + 1 == h {
                return None;
            }
            let near = [p - 1, p + 1, p - w, p + w];
            if !smoke[p] || near.iter().any(|&q| !smoke[q]) {
                return None;
            }
            let (gx, gy) = (0.5 * (c(p + 1) - c(p - 1)), 0.5 * (c(p + w) - c(p - w)));
            Some([gx * gx, gy * gy])
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A picture split at row `h / 2`: stripes of amplitude `amp(y)` added
    /// to a flat input, the share `share(y)`, all smoke.
    fn split(h: usize, w: usize, amp: impl Fn(usize) -> f32, share: impl Fn(usize) -> f32) -> Option<Seam> {
        let input = Image::from_vec(1, h, w, vec![0.5; h * w]);
        let mut result = input.clone();
        for y in 0..h {
            for x in 0..w {
                // A checkerboard of 2-pixel cells: energy independent of the row.
                result.data[y * w + x] += amp(y) * if (x / 2 + y / 2) % 2 == 0 { 1.0 } else { -1.0 };
            }
        }
        let share: Vec<f32> = (0..h * w).map(|p| share(p / w)).collect();
        seam(&input, &result, &share, &vec![true; h * w])
    }

    /// A hard map whose two textures meet cleanly: a narrow map, a narrow
    /// texture step, the two levels in the ratio of the amplitudes squared,
    /// no halo.
    #[test]
    fn a_clean_boundary_is_narrow_and_has_no_halo() {
        let s = split(80, 40, |y| if y < 40 { 0.1 } else { 0.2 }, |y| (y >= 40) as u8 as f32).unwrap();
        assert!(s.map_width <= 1.0 && s.texture_width <= 2.0, "{s:?}");
        assert!((s.levels[1] / s.levels[0] - 4.0).abs() < 0.5, "{s:?}");
        assert!(s.overshoot < 0.1 && s.undershoot < 0.1, "{s:?}");
        // Levels 1 and 4 (times 2 amp²): a step of 3 over their mean 2.5,
        // less where the central differences straddle the boundary's row.
        assert!(s.step > 0.9 && s.step <= 1.2, "{s:?}");
    }

    /// A soft map and texture that blend over 40 rows: both widths wide.
    #[test]
    fn a_soft_blend_is_wide() {
        let t = |y: usize| ((y as f32 - 20.0) / 40.0).clamp(0.0, 1.0);
        let s = split(80, 40, |y| 0.1 + 0.1 * t(y), t).unwrap();
        assert!(s.map_width >= 25.0 && s.texture_width >= 20.0, "{s:?}");
        assert!(s.step.abs() < 0.3 && s.overshoot < 0.1 && s.undershoot < 0.1, "{s:?}");
    }

    /// Strokes twice as strong in four rows along a hard boundary are a
    /// halo; an empty band there is one too.
    #[test]
    fn a_band_along_the_boundary_is_a_halo() {
        let hard = |y: usize| (y >= 40) as u8 as f32;
        // 0.1 above the boundary, 0.15 below, `v` in the rows `band`.
        let with_band = |band: std::ops::Range<usize>, v: f32| {
            move |y: usize| {
                if band.contains(&y) {
                    v
                } else if y < 40 {
                    0.1
                } else {
                    0.15
                }
            }
        };
        let s = split(80, 40, with_band(38..42, 0.3), hard).unwrap();
        assert!(s.overshoot > 1.0 && s.overshoot > 2.0 * s.elsewhere, "{s:?}");
        let s = split(80, 40, with_band(37..43, 0.0), hard).unwrap();
        assert!(s.undershoot > 0.5 && s.undershoot > 2.0 * s.elsewhere, "{s:?}");
    }

    /// Level stripes on one side and upright ones on the other, of the same
    /// energy: no step in energy, but the orientation turns from −1 to +1
    /// at a hard boundary and over the blend's width at a soft one.
    #[test]
    fn stripes_that_turn_show_the_transition() {
        let (h, w) = (80, 40);
        let run = |t: &dyn Fn(usize) -> f32| {
            let input = Image::from_vec(1, h, w, vec![0.5; h * w]);
            let mut result = input.clone();
            for y in 0..h {
                for x in 0..w {
                    // Stripes of period 4, level (varying along y) and upright (along x), mixed by t.
                    let (level, upright) =
                        (if (y / 2) % 2 == 0 { 0.1 } else { -0.1 }, if (x / 2) % 2 == 0 { 0.1 } else { -0.1 });
                    result.data[y * w + x] += (1.0 - t(y)) * level + t(y) * upright;
                }
            }
            let share: Vec<f32> = (0..h * w).map(|p| t(p / w)).collect();
            seam(&input, &result, &share, &vec![true; h * w]).unwrap()
        };
        let hard = run(&|y| (y >= 40) as u8 as f32);
        assert!(hard.orientations[0] < -0.9 && hard.orientations[1] > 0.9, "{hard:?}");
        assert!(hard.orientation_width <= 3.0 && hard.contrast() < 0.1, "{hard:?}");
        let soft = run(&|y| ((y as f32 - 20.0) / 40.0).clamp(0.0, 1.0));
        assert!(soft.orientation_width >= 20.0 && soft.map_width >= 25.0, "{soft:?}");
    }

    /// No boundary in view: nothing to measure.
    #[test]
    fn one_region_has_no_seam() {
        assert!(split(40, 40, |_| 0.1, |_| 0.0).is_none());
    }
}
