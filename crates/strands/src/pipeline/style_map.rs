//! Style maps: several paintings on one groom, each strand with its share
//! of each (the beard unlike the scalp). Both papers stylize toward one
//! painting; this is the spatial control of 2D style transfer (guided
//! targets per region) carried to strands:
//!
//! - **Shares.** Each guide's map value says how much of each painting it
//!   takes: a float in `[0, 1]` blends two paintings (0 the first, 1 the
//!   second), a label `k` picks painting `k` alone. A proxy takes its
//!   guides' blend of the shares (the same weights that shaped it), or with
//!   labels the label of its heaviest guide, so a hard map keeps a hard
//!   boundary among the proxies too.
//! - **Targets** (eq. 2 per region). Each view's render is matched to
//!   every painting, and the map is drawn from the same camera (the
//!   strands in their shares' colours over the same strands in white): the
//!   share of each painting at each hyper-column. The view's targets are
//!   the shares' blend of the paintings' matches
//!   ([`NnstMatch::blend`](nst3d_loss::nnst::NnstMatch::blend)), so eq. 3
//!   descends each region toward its own painting, with both at a soft
//!   boundary.
//! - **Orientation term.** Each painting's stroke field pulls each segment
//!   by its strand's share (the term is linear in the field).
//!
//! The map belongs to the strands, not to the picture: it moves with them,
//! and a sequence's strands keep their shares from frame to frame.

use nst3d_core::Image;
use nst3d_features::Vgg19;
use nst3d_loss::nnst::{NnstMatch, NnstParams, NnstTarget};
use nst3d_splat::{render, SplatCamera, StrandStyle};

use crate::strands::FlatStrands;
use crate::StrandError;

use super::orientation::StrokeField;
use super::views::style_target;
use super::{PipelineError, StrandScene, StylizeParams};

/// The paintings of a stylization at one scale's style size: their NNST
/// targets and (with the orientation term) stroke fields, and the map
/// that shares them among the strands.
pub struct PaintingTargets<'a> {
    /// Each painting's hyper-columns.
    pub targets: Vec<NnstTarget>,
    /// Each painting's stroke field; empty without the orientation term.
    pub strokes: Vec<StrokeField>,
    /// The strands' shares of the paintings.
    pub shares: &'a StrandShares,
}

impl<'a> PaintingTargets<'a> {
    /// `paintings` (RGB in `[0, 1]`; the luminance is matched) at scale
    /// `l`'s style size, shared by `shares`.
    pub fn new(
        vgg: &Vgg19,
        paintings: &[&Image],
        shares: &'a StrandShares,
        params: &StylizeParams,
        l: usize,
    ) -> Result<Self, PipelineError> {
        if paintings.len() != shares.paintings() {
            return Err(StrandError::Mismatch {
                what: "paintings of the style map",
                expected: shares.paintings(),
                got: paintings.len(),
            }
            .into());
        }
        let height = params.style_height(l);
        let targets = paintings.iter().map(|p| style_target(vgg, p, height)).collect::<Result<Vec<_>, _>>()?;
        let strokes = match params.orientation > 0.0 {
            true => paintings.iter().map(|p| scale_strokes(p, params, l)).collect(),
            false => Vec::new(),
        };
        Ok(Self { targets, strokes, shares })
    }

    /// The targets of a view (eq. 2): `taps` (VGG features of `strands`
    /// drawn through `cam`) matched to each painting, blended by the map
    /// drawn on the same strands.
    pub fn match_on(
        &self,
        scene: &StrandScene,
        strands: &FlatStrands,
        taps: &[Image],
        cam: &SplatCamera,
    ) -> Result<NnstMatch, PipelineError> {
        if self.targets.len() == 1 {
            return Ok(self.targets[0].match_content(taps)?);
        }
        // Each painting is matched where it has a share: with labels, each
        // column once in all, as with one painting.
        let grid = nst3d_loss::nnst::common_grid(taps, &NnstParams::default())?;
        let shares = self.shares.column_shares(scene, strands, cam, grid)?;
        let parts = self
            .targets
            .iter()
            .zip(&shares)
            .map(|(t, w)| t.match_content_where(taps, &w.iter().map(|&w| w > 0.0).collect::<Vec<_>>()))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(NnstMatch::blend(&parts.iter().collect::<Vec<_>>(), &shares)?)
    }
}

/// The orientation term's stroke field at scale `l`: the painting's
/// luminance at that scale's height, laid on the hair at `--style-scale`.
fn scale_strokes(style: &Image, params: &StylizeParams, l: usize) -> StrokeField {
    let grey = nst3d_io::image::resize_to_height(&style.luminance3(), params.style_height(l));
    StrokeField::from_grey(&grey).laid_at(params.style_scale)
}

/// Each painting's share of every strand of a scene's
/// [`StrandScene::rest`] (guides, then proxies); a strand's shares sum to 1.
#[derive(Clone, Debug, PartialEq)]
pub struct StrandShares {
    /// `[painting][strand]`.
    shares: Vec<Vec<f32>>,
}

/// How the guides' map values pick the paintings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MapKind {
    /// `[0, 1]` blends two paintings: 0 the first, 1 the second.
    Blend,
    /// An integer `k` picks painting `k` (0-based) alone.
    Labels,
}

impl StrandShares {
    /// One painting on every strand of `strands`.
    pub fn single(strands: usize) -> Self {
        Self { shares: vec![vec![1.0; strands]] }
    }

    /// The shares of `paintings` paintings from one map value per guide
    /// of `scene` (see the module notes); proxies follow their guides.
    pub fn from_guides(
        scene: &StrandScene,
        values: &[f32],
        kind: MapKind,
        paintings: usize,
    ) -> Result<Self, PipelineError> {
        let guides = guide_shares(values, kind, paintings, scene.guide_count)?;
        let mut shares = guides.clone();
        for blend in scene.proxy_blends() {
            let proxy: Vec<f32> = match kind {
                MapKind::Blend => {
                    (0..paintings).map(|k| blend.iter().map(|&(g, w)| w * guides[k][g as usize]).sum::<f32>()).collect()
                }
                MapKind::Labels => {
                    let heaviest =
                        blend.iter().fold((0u32, f32::NEG_INFINITY), |b, &(g, w)| if w > b.1 { (g, w) } else { b });
                    (0..paintings).map(|k| guides[k][heaviest.0 as usize]).collect()
                }
            };
            shares.iter_mut().zip(proxy).for_each(|(s, v)| s.push(v));
        }
        if shares[0].len() != scene.rest.strand_count() {
            return Err(StrandError::Mismatch {
                what: "style map strands",
                expected: scene.rest.strand_count(),
                got: shares[0].len(),
            }
            .into());
        }
        Ok(Self { shares })
    }

    /// Checks one map value per guide for `paintings` paintings (a blend's
    /// in `[0, 1]`, a label naming a painting) without a scene, so a front
    /// end can refuse a bad map before the slow set-up.
    pub fn check_values(values: &[f32], kind: MapKind, paintings: usize) -> Result<(), PipelineError> {
        guide_shares(values, kind, paintings, values.len()).map(|_| ())
    }

    /// Painting `k`'s share of strand `s` (the layout of [`StrandScene::rest`]).
    pub fn strand_share(&self, k: usize, s: usize) -> f32 {
        self.shares[k][s]
    }

    /// Number of paintings.
    pub fn paintings(&self) -> usize {
        self.shares.len()
    }

    /// Painting `k`'s share of every point of `strands` (the layout of
    /// [`StrandScene::rest`]).
    pub fn point_shares(&self, k: usize, strands: &FlatStrands) -> Vec<f32> {
        let mut out = Vec::with_capacity(strands.points.len());
        for (s, w) in strands.offsets.windows(2).enumerate() {
            out.extend(std::iter::repeat_n(self.shares[k][s], w[1] - w[0]));
        }
        out
    }

    /// The map drawn through `cam` on `strands`: the strands in each
    /// painting's shares and in white, on black.
    pub fn view_map(
        &self,
        scene: &StrandScene,
        strands: &FlatStrands,
        cam: &SplatCamera,
    ) -> Result<ViewMap, PipelineError> {
        let white = vec![[1.0f32; 3]; strands.points.len()];
        let coverage = map_render(scene, strands, &white, cam)?;
        let shares = (0..self.paintings())
            .map(|k| {
                let colors: Vec<[f32; 3]> = self.point_shares(k, strands).into_iter().map(|s| [s; 3]).collect();
                map_render(scene, strands, &colors, cam)
            })
            .collect::<Result<Vec<_>, _>>()?;
        let means = (0..self.paintings()).map(|k| self.mean(k)).collect();
        Ok(ViewMap { coverage, shares, means })
    }

    /// Each painting's share of every cell of `grid` in the view (see
    /// [`ViewMap::columns`]).
    pub fn column_shares(
        &self,
        scene: &StrandScene,
        strands: &FlatStrands,
        cam: &SplatCamera,
        grid: (usize, usize),
    ) -> Result<Vec<Vec<f32>>, PipelineError> {
        Ok(self.view_map(scene, strands, cam)?.columns(grid))
    }

    /// Painting `k`'s mean share over the strands.
    fn mean(&self, k: usize) -> f32 {
        let s = &self.shares[k];
        s.iter().sum::<f32>() / s.len().max(1) as f32
    }
}

/// A style map seen from one camera ([`StrandShares::view_map`]).
pub struct ViewMap {
    /// The strands in white: how much hair each pixel shows.
    coverage: Image,
    /// The strands in each painting's shares.
    shares: Vec<Image>,
    /// Each painting's mean share over the strands.
    means: Vec<f32>,
}

impl ViewMap {
    /// Each painting's share of every cell of `grid` (rows, columns over
    /// the picture, row-major): the hair's shares averaged by how much each
    /// strand shows. A cell with no hair belongs wholly to the painting
    /// with the largest share of the hair in view (the empty background
    /// looks alike to every painting, and a column with one painting is
    /// matched once, not once per painting).
    pub fn columns(&self, grid: (usize, usize)) -> Vec<Vec<f32>> {
        let coverage = cell_sums(&self.coverage, 0, grid);
        let total: f64 = coverage.iter().sum();
        let sums: Vec<Vec<f64>> = self.shares.iter().map(|img| cell_sums(img, 0, grid)).collect();
        let mean = |k: usize| if total > 0.0 { sums[k].iter().sum::<f64>() / total } else { self.means[k] as f64 };
        let main = (0..sums.len()).fold(0, |b, k| if mean(k) > mean(b) { k } else { b });
        sums.iter()
            .enumerate()
            .map(|(k, share)| {
                let empty = if k == main { 1.0 } else { 0.0 };
                share
                    .iter()
                    .zip(&coverage)
                    .map(|(&s, &c)| if c > 1e-6 { (s / c).clamp(0.0, 1.0) as f32 } else { empty })
                    .collect()
            })
            .collect()
    }

    /// The pixels of `hair` (row-major) where painting `k` holds at least
    /// half the hair: its region, whose box the orientation term lays the
    /// painting over.
    pub fn region(&self, k: usize, hair: &[bool]) -> Vec<bool> {
        let (cov, share) = (&self.coverage.data, &self.shares[k].data);
        hair.iter().enumerate().map(|(i, &on)| on && cov[i] > 1e-6 && share[i] >= 0.5 * cov[i]).collect()
    }
}

/// `[painting][guide]` shares from the guides' map values.
fn guide_shares(
    values: &[f32],
    kind: MapKind,
    paintings: usize,
    guides: usize,
) -> Result<Vec<Vec<f32>>, PipelineError> {
    if values.len() != guides {
        return Err(StrandError::Mismatch { what: "style map values", expected: guides, got: values.len() }.into());
    }
    let bad =
        |i: usize, why: String| -> PipelineError { PipelineError::Parameter(format!("style map, strand {i}: {why}")) };
    let mut shares = vec![vec![0.0f32; guides]; paintings];
    for (i, &v) in values.iter().enumerate() {
        match kind {
            MapKind::Blend => {
                if paintings != 2 {
                    return Err(PipelineError::Parameter(format!(
                        "a blending style map takes two paintings, got {paintings} (use labels for more)"
                    )));
                }
                if !(0.0..=1.0).contains(&v) {
                    return Err(bad(i, format!("{v} is outside [0, 1]")));
                }
                (shares[0][i], shares[1][i]) = (1.0 - v, v);
            }
            MapKind::Labels => {
                if !(v.is_finite() && v.fract() == 0.0 && v >= 0.0 && (v as usize) < paintings) {
                    return Err(bad(i, format!("label {v} names no painting (0 to {})", paintings - 1)));
                }
                shares[v as usize][i] = 1.0;
            }
        }
    }
    Ok(shares)
}

/// `strands` drawn in `colors` through `cam` on black (the map's share
/// where the hair is, 0 elsewhere; white strands give the coverage).
fn map_render(
    scene: &StrandScene,
    strands: &FlatStrands,
    colors: &[[f32; 3]],
    cam: &SplatCamera,
) -> Result<Image, PipelineError> {
    let style = StrandStyle {
        background: [0.0; 3],
        width: scene.style.width * scene.render_size as f32 / cam.height as f32,
        ..scene.style
    };
    Ok(render(&scene.strands(strands, Some(colors)), cam, &style)?.0)
}

/// Channel `c` of `img` summed over each cell of `grid`.
fn cell_sums(img: &Image, c: usize, grid: (usize, usize)) -> Vec<f64> {
    let (h, w) = (img.height, img.width);
    let plane = &img.data[c * h * w..(c + 1) * h * w];
    let mut out = vec![0.0f64; grid.0 * grid.1];
    for y in 0..h {
        let gy = y * grid.0 / h;
        for x in 0..w {
            out[gy * grid.1 + x * grid.1 / w] += plane[y * w + x] as f64;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn guide_values_become_shares() {
        let s = guide_shares(&[0.0, 0.25, 1.0], MapKind::Blend, 2, 3).unwrap();
        assert_eq!(s, vec![vec![1.0, 0.75, 0.0], vec![0.0, 0.25, 1.0]]);
        let s = guide_shares(&[2.0, 0.0], MapKind::Labels, 3, 2).unwrap();
        assert_eq!(s, vec![vec![0.0, 1.0], vec![0.0, 0.0], vec![1.0, 0.0]]);
    }

    #[test]
    fn bad_map_values_are_errors_naming_the_strand() {
        let e = guide_shares(&[0.0, 1.5], MapKind::Blend, 2, 2).unwrap_err().to_string();
        assert!(e.contains("strand 1") && e.contains("outside [0, 1]"), "{e}");
        let e = guide_shares(&[0.0, 3.0], MapKind::Labels, 3, 2).unwrap_err().to_string();
        assert!(e.contains("strand 1") && e.contains("names no painting"), "{e}");
        assert!(guide_shares(&[0.5], MapKind::Labels, 2, 1).is_err());
        assert!(guide_shares(&[f32::NAN], MapKind::Blend, 2, 1).is_err());
        assert!(guide_shares(&[0.5], MapKind::Blend, 3, 1).is_err());
        assert!(guide_shares(&[0.5, 0.5], MapKind::Blend, 2, 3).is_err());
    }

    #[test]
    fn cells_sum_their_pixels() {
        let img = Image::from_vec(1, 4, 4, (0..16).map(|i| i as f32).collect());
        assert_eq!(cell_sums(&img, 0, (2, 2)), vec![10.0, 18.0, 42.0, 50.0]);
    }
}
