//! Nearest-neighbour style loss (NNST, Kolkin et al. 2022) as used by strand
//! style transfer (paper Sec. 3, eq. 2–3): every hyper-column of the content
//! render's VGG features is replaced by its nearest style hyper-column under
//! the cosine distance of zero-centred features (eq. 2), and the render's
//! features are pulled towards those targets with an L2 loss (eq. 3).
//!
//! Hyper-columns follow NNST's construction (which the paper builds on):
//! - each layer is weighted so that wide deep layers do not dominate the
//!   cosine distance: NNST divides raw VGG-16 activations by the channel
//!   count `C`; on the Gatys-normalised VGG-19 we use, whose shallow layers
//!   are already the larger, `1/C` leaves relu1_1 half of the column's
//!   energy and relu4_1 a twelfth, so strokes and shapes barely count and
//!   grooms take the same clumps for any style. `1/√C` gives the four taps
//!   about equal shares and is the default ([`LayerWeight`]);
//! - every layer is resized (bilinear, `align_corners=True`, NNST's
//!   `scl_spatial`) to a common grid of `1/grid_divisor` of the image
//!   resolution — NNST uses a quarter, the relu3_1 grid of VGG — and the
//!   layers are concatenated per pixel. The image resolution is read from the
//!   first layer, which must therefore be a full-resolution tap (relu1_1).
//!
//! Matching centres content and style columns by their own means (`μ_c`, `μ_s`
//! in eq. 2, as NNST's `pairwise_distances_cos_center` does). Only the style
//! columns need unit length: scaling a content column does not change which
//! style column is its arg-max. The targets are the matched style columns as
//! they are (not centred, not normalised), the `Φ(I_s)_j` of eq. 2.
//!
//! The loss is the paper's L2 distance (eq. 3; NNST itself uses a cosine
//! loss), squared and averaged over content columns:
//! `L = 1/N_c · Σ_i ‖h_i − T_i‖²`. The targets are constants: no gradient
//! flows through the arg-max, as in NNST.

use std::sync::OnceLock;

use nst3d_core::bf16::{self, PackedB, KS, MB, NB};
use nst3d_core::microkernel::{self, Blocking};
use nst3d_core::{precision, Image};
use rayon::prelude::*;

/// Why an NNST target, match or loss could not be built from the given features.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum NnstError {
    /// No feature layers were given.
    #[error("nnst: no feature layers given")]
    NoLayers,
    /// The common-grid divisor is zero.
    #[error("nnst: grid divisor must be at least 1")]
    ZeroGridDivisor,
    /// A feature layer has no pixels or no channels.
    #[error("nnst: feature layer {layer} is empty ({channels} x {height} x {width})")]
    EmptyLayer {
        /// Layer index.
        layer: usize,
        /// Channels.
        channels: usize,
        /// Rows.
        height: usize,
        /// Columns.
        width: usize,
    },
    /// The features do not have as many layers as the style target.
    #[error("nnst: got {got} feature layers, the style target has {expected}")]
    LayerCount {
        /// Layers passed in.
        got: usize,
        /// Layers of the style target.
        expected: usize,
    },
    /// A layer's channel count differs from the style target's.
    #[error("nnst: layer {layer} has {got} channels, the style target has {expected}")]
    ChannelCount {
        /// Layer index.
        layer: usize,
        /// Channels passed in.
        got: usize,
        /// Channels of the style target's layer.
        expected: usize,
    },
    /// The render's hyper-column grid differs from the one its targets were matched on.
    #[error("nnst: features give a {got:?} hyper-column grid, the targets were matched on {expected:?}")]
    GridMismatch {
        /// Grid (rows, columns) of the features passed in.
        got: (usize, usize),
        /// Grid of the matched targets.
        expected: (usize, usize),
    },
}

/// How each layer is weighted in a hyper-column.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LayerWeight {
    /// `1/C`, NNST's rule for raw VGG-16 activations.
    InverseChannels,
    /// `1/√C`: equal shares of the column's energy for the Gatys-normalised
    /// VGG-19's relu1_1…relu4_1 (about 0.22 / 0.25 / 0.25 / 0.28, against
    /// 0.50 / 0.29 / 0.14 / 0.08 with `1/C`).
    InverseSqrtChannels,
}

impl LayerWeight {
    /// The factor a layer of `channels` channels is multiplied by.
    pub fn factor(self, channels: usize) -> f32 {
        match self {
            LayerWeight::InverseChannels => 1.0 / channels as f32,
            LayerWeight::InverseSqrtChannels => 1.0 / (channels as f32).sqrt(),
        }
    }
}

/// Settings of the hyper-column construction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NnstParams {
    /// The common grid is the first layer's size divided by this (rounded
    /// down, at least 1 pixel). NNST uses 4: the relu3_1 grid.
    pub grid_divisor: usize,
    /// Each layer's weight in the hyper-columns.
    pub layer_weight: LayerWeight,
}

impl Default for NnstParams {
    fn default() -> Self {
        Self { grid_divisor: 4, layer_weight: LayerWeight::InverseSqrtChannels }
    }
}

/// Content rows per matching task: the task's gathered hyper-columns
/// (`rows x D`, 370 KB at D = 960 in fp32) stay in L2 while every panel of
/// style columns streams past them. Never more than this many scores exist
/// at once: each block of them is reduced to its arg-max as it is made.
const MATCH_ROWS: usize = 96;
/// The fp32 matching kernel's blocking: 6 content rows x 64 style columns.
const MATCH_BLOCKING: Blocking = Blocking { mr: 6, nr: 64 };

/// Floor on a style column's norm before normalising (NNST clamps the squared
/// norm at 1e-8), so constant style regions do not divide by zero.
const MIN_NORM: f32 = 1e-4;

/// Common hyper-column grid (rows, columns) of a feature list whose first
/// layer is at image resolution.
pub fn common_grid(feats: &[Image], params: &NnstParams) -> Result<(usize, usize), NnstError> {
    check_layers(feats)?;
    if params.grid_divisor == 0 {
        return Err(NnstError::ZeroGridDivisor);
    }
    let d = params.grid_divisor;
    Ok(((feats[0].height / d).max(1), (feats[0].width / d).max(1)))
}

fn check_layers(feats: &[Image]) -> Result<(), NnstError> {
    if feats.is_empty() {
        return Err(NnstError::NoLayers);
    }
    for (layer, f) in feats.iter().enumerate() {
        if f.data.is_empty() {
            return Err(NnstError::EmptyLayer { layer, channels: f.channels, height: f.height, width: f.width });
        }
    }
    Ok(())
}

/// One output sample of a 1-D `align_corners=True` bilinear resize:
/// `out = (1 − w)·in[i0] + w·in[i1]`.
#[derive(Clone, Copy)]
struct Tap {
    i0: usize,
    i1: usize,
    w: f32,
}

/// Taps of PyTorch's `align_corners=True` bilinear resize from `n` to `m`
/// samples (source position `y·(n−1)/(m−1)`, computed in `f32` as PyTorch does).
fn taps(n: usize, m: usize) -> Vec<Tap> {
    let scale = if m > 1 { (n - 1) as f32 / (m - 1) as f32 } else { 0.0 };
    (0..m)
        .map(|y| {
            let src = scale * y as f32;
            let i0 = (src as usize).min(n - 1);
            let i1 = (i0 + 1).min(n - 1);
            Tap { i0, i1, w: src - i0 as f32 }
        })
        .collect()
}

/// Separable bilinear resize of one plane, `scale · resize(src)`: rows first,
/// then columns. Same-size planes are copied, as the taps are exact then.
fn resize_plane(src: &[f32], (h, w): (usize, usize), dst: &mut [f32], (gh, gw): (usize, usize), scale: f32) {
    if (h, w) == (gh, gw) {
        dst.iter_mut().zip(src).for_each(|(d, s)| *d = scale * s);
        return;
    }
    let (ty, tx) = (taps(h, gh), taps(w, gw));
    let mut rows = vec![0.0f32; h * gw];
    for y in 0..h {
        let s = &src[y * w..(y + 1) * w];
        for (o, t) in rows[y * gw..(y + 1) * gw].iter_mut().zip(&tx) {
            *o = (1.0 - t.w) * s[t.i0] + t.w * s[t.i1];
        }
    }
    for (o, t) in dst.chunks_exact_mut(gw).zip(&ty) {
        let (r0, r1) = (&rows[t.i0 * gw..(t.i0 + 1) * gw], &rows[t.i1 * gw..(t.i1 + 1) * gw]);
        for x in 0..gw {
            o[x] = scale * ((1.0 - t.w) * r0[x] + t.w * r1[x]);
        }
    }
}

/// Backward of [`resize_plane`]: scatters `grad` (grid-sized) through the
/// transposed taps into `out` (source-sized, overwritten).
fn resize_plane_backward(grad: &[f32], (gh, gw): (usize, usize), out: &mut [f32], (h, w): (usize, usize), scale: f32) {
    if (h, w) == (gh, gw) {
        out.iter_mut().zip(grad).for_each(|(o, g)| *o = scale * g);
        return;
    }
    let (ty, tx) = (taps(h, gh), taps(w, gw));
    let mut rows = vec![0.0f32; h * gw];
    for (g, t) in grad.chunks_exact(gw).zip(&ty) {
        for x in 0..gw {
            rows[t.i0 * gw + x] += (1.0 - t.w) * g[x];
            rows[t.i1 * gw + x] += t.w * g[x];
        }
    }
    out.fill(0.0);
    for y in 0..h {
        let o = &mut out[y * w..(y + 1) * w];
        for (r, t) in rows[y * gw..(y + 1) * gw].iter().zip(&tx) {
            o[t.i0] += scale * (1.0 - t.w) * r;
            o[t.i1] += scale * t.w * r;
        }
    }
}

/// (layer, channel) of each hyper-column entry, in concatenation order.
fn channel_map(feats: &[Image]) -> Vec<(usize, usize)> {
    feats.iter().enumerate().flat_map(|(l, f)| (0..f.channels).map(move |c| (l, c))).collect()
}

/// Hyper-columns of `feats` on the `grid`: every layer scaled by its
/// `weight`, resized to the grid and concatenated along channels. Planar
/// `D x gh x gw` with `D = Σ C_l`, like `torch.cat(..., dim=0)`.
pub fn hypercolumns(feats: &[Image], grid: (usize, usize), weight: LayerWeight) -> Image {
    let map = channel_map(feats);
    let mut out = Image::zeros(map.len(), grid.0, grid.1);
    let plane = out.plane();
    if plane == 0 {
        return out;
    }
    out.data.par_chunks_mut(plane).zip(&map).for_each(|(dst, &(l, c))| {
        let f = &feats[l];
        resize_plane(f.channel(c), (f.height, f.width), dst, grid, weight.factor(f.channels));
    });
    out
}

/// Backward of [`hypercolumns`]: the gradient w.r.t. each layer of `feats`
/// (only their shapes are read) from the gradient `grad` w.r.t. the hyper-columns.
///
/// # Panics
/// If `grad` does not have `Σ C_l` channels (a programming error: it comes
/// from [`hypercolumns`]' output).
pub fn hypercolumns_backward(feats: &[Image], grad: &Image, weight: LayerWeight) -> Vec<Image> {
    let map = channel_map(feats);
    assert_eq!(grad.channels, map.len(), "hypercolumns_backward: channel count");
    let grid = (grad.height, grad.width);
    feats
        .iter()
        .enumerate()
        .map(|(l, f)| {
            let mut g = Image::zeros(f.channels, f.height, f.width);
            let first = map.iter().position(|&(ll, _)| ll == l).unwrap_or(0);
            let plane = f.plane();
            if plane > 0 {
                g.data.par_chunks_mut(plane).enumerate().for_each(|(c, dst)| {
                    resize_plane_backward(
                        grad.channel(first + c),
                        grid,
                        dst,
                        (f.height, f.width),
                        weight.factor(f.channels),
                    );
                });
            }
            g
        })
        .collect()
}

/// Per-channel mean over the pixels of a planar image, in `f64`.
fn channel_means(h: &Image) -> Vec<f32> {
    let n = h.plane().max(1) as f64;
    (0..h.channels).into_par_iter().map(|k| (h.channel(k).iter().map(|&v| v as f64).sum::<f64>() / n) as f32).collect()
}

/// The style image's side of eq. 2: its raw hyper-columns (the candidate
/// targets) and their zero-centred unit-length copies to match against.
#[derive(Clone, Debug)]
pub struct NnstTarget {
    channels: Vec<usize>,
    params: NnstParams,
    /// Raw style hyper-columns, planar `D x N_s`.
    columns: Image,
    /// Centred, unit style columns, planar `D x N_s`.
    unit: Vec<f32>,
    /// `unit` packed for the fp32 matching kernel, built on first use.
    panels: OnceLock<Vec<f32>>,
    /// `unit` packed for the bf16 block kernel, built on first use.
    packed16: OnceLock<PackedB>,
}

impl NnstTarget {
    /// Builds the style side from the style image's VGG taps `feats`
    /// (relu1_1 first, at the style image's resolution).
    pub fn from_style_features(feats: &[Image], params: &NnstParams) -> Result<Self, NnstError> {
        let grid = common_grid(feats, params)?;
        let columns = hypercolumns(feats, grid, params.layer_weight);
        let (d, ns) = (columns.channels, columns.plane());
        let mean = channel_means(&columns);
        // Column norms of the centred columns, accumulated plane by plane so
        // the planar layout is read contiguously.
        let mut norm2 = vec![0.0f32; ns];
        for (plane, m) in columns.data.chunks_exact(ns).zip(&mean) {
            norm2.iter_mut().zip(plane).for_each(|(n, v)| *n += (v - m) * (v - m));
        }
        let inv: Vec<f32> = norm2.iter().map(|n| 1.0 / n.sqrt().max(MIN_NORM)).collect();
        let mut unit = vec![0.0f32; d * ns];
        unit.par_chunks_mut(ns).zip(columns.data.par_chunks(ns)).zip(&mean).for_each(|((u, c), m)| {
            u.iter_mut().zip(c).zip(&inv).for_each(|((u, v), i)| *u = (v - m) * i);
        });
        Ok(Self {
            channels: feats.iter().map(|f| f.channels).collect(),
            params: *params,
            columns,
            unit,
            panels: OnceLock::new(),
            packed16: OnceLock::new(),
        })
    }

    /// Number of feature layers.
    pub fn layers(&self) -> usize {
        self.channels.len()
    }

    /// Hyper-column length `D = Σ C_l`.
    pub fn depth(&self) -> usize {
        self.columns.channels
    }

    /// The style hyper-column grid (rows, columns).
    pub fn style_grid(&self) -> (usize, usize) {
        (self.columns.height, self.columns.width)
    }

    /// The raw style hyper-columns, planar `D x rows x columns`.
    pub fn columns(&self) -> &Image {
        &self.columns
    }

    fn check(&self, feats: &[Image]) -> Result<(), NnstError> {
        check_layers(feats)?;
        if feats.len() != self.layers() {
            return Err(NnstError::LayerCount { got: feats.len(), expected: self.layers() });
        }
        for (layer, (f, &c)) in feats.iter().zip(&self.channels).enumerate() {
            if f.channels != c {
                return Err(NnstError::ChannelCount { layer, got: f.channels, expected: c });
            }
        }
        Ok(())
    }

    /// Eq. 2: the nearest style hyper-column (cosine distance of centred
    /// columns) of every hyper-column of the content render's features `content`.
    ///
    /// The `N_c x N_s` similarity matrix is never held: each block of it is
    /// made by a product kernel (fp32, or bf16 under `--precision bf16`) and
    /// folded into a running arg-max per content column at once. Ties go to
    /// the first style column; a NaN score never wins.
    pub fn match_content(&self, content: &[Image]) -> Result<NnstMatch, NnstError> {
        self.check(content)?;
        let grid = common_grid(content, &self.params)?;
        let h = hypercolumns(content, grid, self.params.layer_weight);
        let nc = h.plane();
        let mean = channel_means(&h);
        let mut centred = h;
        centred.data.par_chunks_mut(nc).zip(&mean).for_each(|(p, m)| p.iter_mut().for_each(|v| *v -= m));
        let indices = self.argmax(&centred);

        Ok(self.gather(grid, indices))
    }

    /// [`Self::match_content`] for the content columns `wanted` marks only
    /// (row-major on the content grid), each matched exactly as the whole
    /// match matches it (centred by the means over every column); the
    /// others take style column 0. A style map's painting needs no target
    /// where it has no share, and matching is most of a map's cost.
    pub fn match_content_where(&self, content: &[Image], wanted: &[bool]) -> Result<NnstMatch, NnstError> {
        self.check(content)?;
        let grid = common_grid(content, &self.params)?;
        if wanted.len() != grid.0 * grid.1 {
            return Err(NnstError::GridMismatch { got: (wanted.len(), 1), expected: grid });
        }
        let h = hypercolumns(content, grid, self.params.layer_weight);
        let nc = h.plane();
        let mean = channel_means(&h);
        let picked: Vec<usize> = (0..nc).filter(|&i| wanted[i]).collect();
        let mut indices = vec![0u32; nc];
        if !picked.is_empty() {
            let n = picked.len();
            let mut centred = Image::zeros(h.channels, 1, n);
            centred.data.par_chunks_mut(n).zip(h.data.par_chunks(nc)).zip(&mean).for_each(|((c, src), m)| {
                c.iter_mut().zip(&picked).for_each(|(c, &i)| *c = src[i] - m);
            });
            for (&i, j) in picked.iter().zip(self.argmax(&centred)) {
                indices[i] = j;
            }
        }
        Ok(self.gather(grid, indices))
    }

    /// Arg-max of every centred content column over the style columns, on
    /// the dispatched precision's kernel.
    fn argmax(&self, centred: &Image) -> Vec<u32> {
        match precision::path().kernel() {
            Some(kernel) => self.argmax_bf16(kernel, centred),
            None => self.argmax_fp32(centred),
        }
    }

    /// The match whose content column `i` takes style column `indices[i]`.
    fn gather(&self, grid: (usize, usize), indices: Vec<u32>) -> NnstMatch {
        let (d, nc) = (self.depth(), grid.0 * grid.1);
        let mut targets = Image::zeros(d, grid.0, grid.1);
        targets.data.par_chunks_mut(nc).enumerate().for_each(|(k, t)| {
            let s = self.columns.channel(k);
            t.iter_mut().zip(&indices).for_each(|(t, &j)| *t = s[j as usize]);
        });
        NnstMatch { channels: self.channels.clone(), params: self.params, targets, indices }
    }

    /// Arg-max of `centred`'s columns against the unit style columns, fp32:
    /// content rows gathered pixel-major, style columns in panels of 64
    /// (`[panel][D][64]`, zero past `N_s`), 6 x 64 scores per kernel call.
    fn argmax_fp32(&self, centred: &Image) -> Vec<u32> {
        let (d, nc, ns) = (centred.channels, centred.plane(), self.columns.plane());
        let bl = MATCH_BLOCKING;
        let npanels = ns.div_ceil(bl.nr);
        let panels = self.panels.get_or_init(|| {
            let mut p = vec![0.0f32; npanels * d * bl.nr];
            p.par_chunks_mut(d * bl.nr).enumerate().for_each(|(pi, panel)| {
                for k in 0..d {
                    let row = &self.unit[k * ns..(k + 1) * ns];
                    for j in 0..bl.nr.min(ns - pi * bl.nr) {
                        panel[k * bl.nr + j] = row[pi * bl.nr + j];
                    }
                }
            });
            p
        });
        let mut indices = vec![0u32; nc];
        indices.par_chunks_mut(MATCH_ROWS).enumerate().for_each(|(b, idx)| {
            let (i0, n) = (b * MATCH_ROWS, idx.len());
            let rows = n.div_ceil(bl.mr) * bl.mr;
            let block = gather_rows(centred, i0, n, rows, d, |v| v);
            let mut best = vec![f32::NEG_INFINITY; n];
            let mut c = [0.0f32; 6 * 64];
            for pi in 0..npanels {
                let panel = &panels[pi * d * bl.nr..(pi + 1) * d * bl.nr];
                let cols = bl.nr.min(ns - pi * bl.nr);
                for r0 in (0..rows).step_by(bl.mr) {
                    // SAFETY: block holds `rows` rows of d; panel d x nr; c mr x nr.
                    unsafe {
                        microkernel::kernel(bl, block.as_ptr().add(r0 * d), d, panel.as_ptr(), d, c.as_mut_ptr(), bl.nr)
                    };
                    for r in 0..bl.mr.min(n.saturating_sub(r0)) {
                        fold_argmax(&c[r * bl.nr..r * bl.nr + cols], pi * bl.nr, &mut best[r0 + r], &mut idx[r0 + r]);
                    }
                }
            }
        });
        indices
    }

    /// [`Self::argmax_fp32`] on the bf16 block kernel: content rows and style
    /// columns rounded to bf16, scores summed in fp32, 32 x 32 per call.
    fn argmax_bf16(&self, kernel: bf16::Kernel, centred: &Image) -> Vec<u32> {
        let (d, nc, ns) = (centred.channels, centred.plane(), self.columns.plane());
        let steps = d.div_ceil(KS);
        let dp = steps * KS;
        let packed = self.packed16.get_or_init(|| {
            PackedB::new(steps, ns, |s, k, n| {
                let kk = s * KS + k;
                if kk < d {
                    self.unit[kk * ns + n]
                } else {
                    0.0
                }
            })
        });
        let offs: Vec<usize> = (0..steps).map(|s| s * KS).collect();
        // Tasks of several 32-row blocks, so each pair of style columns
        // (steps x 2 KB) is read once per task and reused from cache.
        let task_rows = 8 * MB;
        let mut indices = vec![0u32; nc];
        indices.par_chunks_mut(task_rows).enumerate().for_each(|(b, idx)| {
            let (i0, n) = (b * task_rows, idx.len());
            let rows = n.div_ceil(MB) * MB;
            let block = gather_rows(centred, i0, n, rows, dp, bf16::from_f32);
            let mut best = vec![f32::NEG_INFINITY; n];
            let mut c = [0.0f32; MB * NB];
            kernel.run(|ready| {
                for pair in 0..packed.npairs {
                    let bp = packed.pair(pair).as_ptr();
                    let cols = NB.min(ns - pair * NB);
                    for r0 in (0..rows).step_by(MB) {
                        let a0 = block.as_ptr().wrapping_add(r0 * dp);
                        // SAFETY: block holds `rows` rows of dp values; the
                        // pair holds `steps` steps; c is 32 x 32.
                        unsafe { ready.block(a0, a0.add(16 * dp), dp, &offs, bp, c.as_mut_ptr(), NB) };
                        for r in 0..MB.min(n.saturating_sub(r0)) {
                            fold_argmax(&c[r * NB..r * NB + cols], pair * NB, &mut best[r0 + r], &mut idx[r0 + r]);
                        }
                    }
                }
            });
        });
        indices
    }
}

/// Content columns `i0 .. i0 + n` of the planar `centred` map, pixel-major
/// (`rows x stride`, converted by `conv`, zero past `n` rows and `D` values).
fn gather_rows<T: Copy + Default>(
    centred: &Image,
    i0: usize,
    n: usize,
    rows: usize,
    stride: usize,
    conv: impl Fn(f32) -> T,
) -> Vec<T> {
    let nc = centred.plane();
    let mut block = vec![T::default(); rows * stride];
    for (k, plane) in centred.data.chunks_exact(nc).enumerate() {
        for (r, v) in plane[i0..i0 + n].iter().enumerate() {
            block[r * stride + k] = conv(*v);
        }
    }
    block
}

/// Folds one row of scores (style columns `j0 ..`) into a running arg-max:
/// strictly greater wins, so ties keep the first column.
#[inline(always)]
fn fold_argmax(scores: &[f32], j0: usize, best: &mut f32, index: &mut u32) {
    for (j, &v) in scores.iter().enumerate() {
        if v > *best {
            *best = v;
            *index = (j0 + j) as u32;
        }
    }
}

/// The stylized target features `T` of eq. 2 for one content render: the
/// matched style hyper-column of every content hyper-column.
#[derive(Clone, Debug)]
pub struct NnstMatch {
    channels: Vec<usize>,
    params: NnstParams,
    targets: Image,
    indices: Vec<u32>,
}

impl NnstMatch {
    /// Targets `T`, planar `D x rows x columns` on the content's grid.
    pub fn targets(&self) -> &Image {
        &self.targets
    }

    /// For each content hyper-column (row-major on the content grid), the
    /// index of its style hyper-column (row-major on the style grid).
    pub fn indices(&self) -> &[u32] {
        &self.indices
    }

    /// The content hyper-column grid (rows, columns).
    pub fn grid(&self) -> (usize, usize) {
        (self.targets.height, self.targets.width)
    }

    /// Several paintings' matches of one render blended column by column:
    /// `T_i = Σ_k w_k(i) T_k(i)` with `weights[k]` the share of match `k`
    /// at each content column (row-major on the grid; the shares of a
    /// column sum to 1). Since `Σ_k w_k ‖h − T_k‖² = ‖h − T‖² + const`, eq. 3
    /// against the blend has exactly the gradient of the shares' mix of the
    /// paintings' losses: a column inside one painting's region is matched
    /// to that painting alone, a soft boundary pulls towards both. A column's
    /// index is the one of its largest share.
    pub fn blend(parts: &[&NnstMatch], weights: &[Vec<f32>]) -> Result<NnstMatch, NnstError> {
        let first = parts.first().ok_or(NnstError::NoLayers)?;
        let nc = first.targets.plane();
        if weights.len() != parts.len() {
            return Err(NnstError::LayerCount { got: weights.len(), expected: parts.len() });
        }
        for (p, w) in parts.iter().zip(weights) {
            if p.grid() != first.grid() || p.channels != first.channels {
                return Err(NnstError::GridMismatch { got: p.grid(), expected: first.grid() });
            }
            if w.len() != nc {
                return Err(NnstError::GridMismatch { got: (w.len(), 1), expected: first.grid() });
            }
        }
        let mut targets = Image::zeros(first.targets.channels, first.targets.height, first.targets.width);
        targets.data.par_chunks_mut(nc).enumerate().for_each(|(k, t)| {
            for (p, w) in parts.iter().zip(weights) {
                let src = &p.targets.data[k * nc..(k + 1) * nc];
                t.iter_mut().zip(src).zip(w).for_each(|((t, s), w)| *t += w * s);
            }
        });
        let indices = (0..nc)
            .map(|i| {
                let best = (0..parts.len()).fold(0, |b, k| if weights[k][i] > weights[b][i] { k } else { b });
                parts[best].indices[i]
            })
            .collect();
        Ok(NnstMatch { channels: first.channels.clone(), params: first.params, targets, indices })
    }
}

/// Eq. 3 against fixed targets: `L = 1/N_c · Σ_i ‖h_i − T_i‖²` with `h` the
/// hyper-columns of the render's features `feats`; returns `L` and `dL/dF_l`
/// per layer (shapes of `feats`) for the feature network's backward pass.
///
/// This is the paper's use: `matched` comes from the unstylized render
/// `R_θ(x_0)` of the same view, while `feats` come from the current render.
pub fn nnst_loss_matched(feats: &[Image], matched: &NnstMatch) -> Result<(f32, Vec<Image>), NnstError> {
    check_layers(feats)?;
    if feats.len() != matched.channels.len() {
        return Err(NnstError::LayerCount { got: feats.len(), expected: matched.channels.len() });
    }
    for (layer, (f, &c)) in feats.iter().zip(&matched.channels).enumerate() {
        if f.channels != c {
            return Err(NnstError::ChannelCount { layer, got: f.channels, expected: c });
        }
    }
    let grid = common_grid(feats, &matched.params)?;
    if grid != matched.grid() {
        return Err(NnstError::GridMismatch { got: grid, expected: matched.grid() });
    }
    // Forward and backward of the squared distance in one pass.
    let mut h = hypercolumns(feats, grid, matched.params.layer_weight);
    let nc = h.plane();
    let scale = 2.0 / nc as f32;
    let sum: f64 = h
        .data
        .par_chunks_mut(nc)
        .zip(matched.targets.data.par_chunks(nc))
        .map(|(hk, tk)| {
            let mut s = 0.0f64;
            for (v, t) in hk.iter_mut().zip(tk) {
                let r = *v - t;
                s += (r * r) as f64;
                *v = scale * r;
            }
            s
        })
        .sum();
    let loss = (sum / nc as f64) as f32;
    Ok((loss, hypercolumns_backward(feats, &h, matched.params.layer_weight)))
}

/// [`nnst_loss_matched`]'s value over a subset of the hyper-columns: the
/// mean of `‖h_i − T_i‖²` over the columns `i` where `columns[i]` is set
/// (row-major on the matched grid), for measuring a stylization where it
/// acts (the strands' hair, not the empty background every view shares).
/// `NaN` when no column is set.
pub fn nnst_loss_over(feats: &[Image], matched: &NnstMatch, columns: &[bool]) -> Result<f32, NnstError> {
    let grid = common_grid(feats, &matched.params)?;
    if grid != matched.grid() {
        return Err(NnstError::GridMismatch { got: grid, expected: matched.grid() });
    }
    if columns.len() != grid.0 * grid.1 {
        return Err(NnstError::GridMismatch { got: (columns.len(), 1), expected: grid });
    }
    let h = hypercolumns(feats, grid, matched.params.layer_weight);
    let nc = h.plane();
    let sum: f64 = h
        .data
        .par_chunks(nc)
        .zip(matched.targets.data.par_chunks(nc))
        .map(|(hk, tk)| {
            hk.iter()
                .zip(tk)
                .zip(columns)
                .filter(|(_, &on)| on)
                .map(|((v, t), _)| ((v - t) * (v - t)) as f64)
                .sum::<f64>()
        })
        .sum();
    let n = columns.iter().filter(|&&c| c).count();
    Ok((sum / n as f64) as f32)
}

/// NNST loss of `content` against the style `target`, matching the
/// hyper-columns of `content` themselves (NNST's scheme when the content is
/// the current iterate); the matches are held constant for the gradient.
pub fn nnst_loss(content: &[Image], target: &NnstTarget) -> Result<(f32, Vec<Image>), NnstError> {
    let matched = target.match_content(content)?;
    nnst_loss_matched(content, &matched)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::{check_gradient, dot, pseudo_random};

    fn image(c: usize, h: usize, w: usize, seed: u64) -> Image {
        Image::from_vec(c, h, w, pseudo_random(c * h * w, seed))
    }

    #[test]
    fn resize_matches_definition() {
        // 5 -> 3 with align_corners: samples at 0, 2, 4 exactly.
        let src: Vec<f32> = (0..5).map(|v| v as f32).collect();
        let mut dst = vec![0.0; 3];
        resize_plane(&src, (1, 5), &mut dst, (1, 3), 1.0);
        assert_eq!(dst, vec![0.0, 2.0, 4.0]);
        // 2 -> 3: midpoint.
        let mut dst = vec![0.0; 3];
        resize_plane(&[1.0, 3.0], (1, 2), &mut dst, (1, 3), 1.0);
        assert_eq!(dst, vec![1.0, 2.0, 3.0]);
    }

    #[test]
    fn hypercolumns_backward_gradcheck() {
        let feats = vec![image(3, 9, 7, 1), image(4, 5, 4, 2), image(2, 2, 3, 3)];
        let grid = (4, 5);
        let d = 9;
        let wgt = pseudo_random(d * 20, 4);
        for weight in [LayerWeight::InverseChannels, LayerWeight::InverseSqrtChannels] {
            let grads = hypercolumns_backward(&feats, &Image::from_vec(d, 4, 5, wgt.clone()), weight);
            for l in 0..feats.len() {
                let f = &feats[l];
                let probe = |x: &[f32]| {
                    let mut fs = feats.clone();
                    fs[l] = Image::from_vec(f.channels, f.height, f.width, x.to_vec());
                    dot(&wgt, &hypercolumns(&fs, grid, weight).data)
                };
                let r = check_gradient(&f.data, &grads[l].data, probe, 1e-2, 200, 1e-3);
                assert!(r.max_rel_err < 1e-2, "{weight:?} layer {l}: {r:?}");
            }
        }
    }

    /// `1/√C` scales layer `l` of every column by `√C_l` against `1/C`.
    #[test]
    fn layer_weights_scale_each_layer() {
        let feats = vec![image(4, 6, 6, 1), image(9, 3, 3, 2)];
        let grid = (3, 3);
        let a = hypercolumns(&feats, grid, LayerWeight::InverseChannels);
        let b = hypercolumns(&feats, grid, LayerWeight::InverseSqrtChannels);
        for k in 0..13 {
            let c = if k < 4 { 4.0f32 } else { 9.0 };
            for (x, y) in a.channel(k).iter().zip(b.channel(k)) {
                assert!((x * c.sqrt() - y).abs() < 1e-6, "channel {k}");
            }
        }
    }

    /// The loss is quadratic in the features, so a long chord is exact and
    /// keeps the f32 loss's rounding out of the slope.
    #[test]
    fn loss_gradcheck_fixed_targets() {
        for layer_weight in [LayerWeight::InverseChannels, LayerWeight::InverseSqrtChannels] {
            loss_gradcheck_with(NnstParams { grid_divisor: 2, layer_weight });
        }
    }

    fn loss_gradcheck_with(params: NnstParams) {
        let style = vec![image(3, 10, 12, 10), image(5, 5, 6, 11), image(6, 3, 3, 12)];
        let content = vec![image(3, 12, 8, 20), image(5, 6, 4, 21), image(6, 3, 2, 22)];
        let target = NnstTarget::from_style_features(&style, &params).unwrap();
        let matched = target.match_content(&content).unwrap();
        // The current render differs from the one the targets were matched on.
        let feats = vec![image(3, 12, 8, 30), image(5, 6, 4, 31), image(6, 3, 2, 32)];
        let (_, grads) = nnst_loss_matched(&feats, &matched).unwrap();
        for l in 0..feats.len() {
            let f = &feats[l];
            let probe = |x: &[f32]| {
                let mut fs = feats.clone();
                fs[l] = Image::from_vec(f.channels, f.height, f.width, x.to_vec());
                nnst_loss_matched(&fs, &matched).unwrap().0 as f64
            };
            let r = check_gradient(&f.data, &grads[l].data, probe, 0.1, 150, 1e-4);
            assert!(r.max_rel_err < 2e-2, "{params:?} layer {l}: {r:?}");
        }
    }

    /// The blend's loss differs from the shares' mix of the paintings'
    /// losses by a constant, so its gradient is the mix of theirs; a
    /// one-hot share is the painting's own match.
    #[test]
    fn a_blend_of_matches_has_the_gradient_of_the_mixed_losses() {
        let params = NnstParams { grid_divisor: 2, ..NnstParams::default() };
        let style_a = vec![image(3, 10, 12, 10), image(5, 5, 6, 11), image(6, 3, 3, 12)];
        let style_b = vec![image(3, 8, 8, 40), image(5, 4, 4, 41), image(6, 2, 2, 42)];
        let content = vec![image(3, 12, 8, 20), image(5, 6, 4, 21), image(6, 3, 2, 22)];
        let a = NnstTarget::from_style_features(&style_a, &params).unwrap().match_content(&content).unwrap();
        let b = NnstTarget::from_style_features(&style_b, &params).unwrap().match_content(&content).unwrap();
        let nc = a.targets().plane();
        let wa: Vec<f32> = (0..nc).map(|i| i as f32 / (nc - 1) as f32).collect();
        let wb: Vec<f32> = wa.iter().map(|w| 1.0 - w).collect();
        let mixed = NnstMatch::blend(&[&a, &b], &[wa.clone(), wb.clone()]).unwrap();
        let feats = vec![image(3, 12, 8, 30), image(5, 6, 4, 31), image(6, 3, 2, 32)];
        let (_, g) = nnst_loss_matched(&feats, &mixed).unwrap();
        // The mix of the two losses, column by column, by hand.
        let h = hypercolumns(&feats, mixed.grid(), params.layer_weight);
        let mut r = Image::zeros(h.channels, h.height, h.width);
        for k in 0..h.channels {
            for i in 0..nc {
                let v = h.data[k * nc + i];
                let (ta, tb) = (a.targets().data[k * nc + i], b.targets().data[k * nc + i]);
                r.data[k * nc + i] = 2.0 / nc as f32 * (wa[i] * (v - ta) + wb[i] * (v - tb));
            }
        }
        let want = hypercolumns_backward(&feats, &r, params.layer_weight);
        for (l, (g, w)) in g.iter().zip(&want).enumerate() {
            let err = g.data.iter().zip(&w.data).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
            assert!(err < 1e-5, "layer {l}: {err}");
        }
        let one_hot = NnstMatch::blend(&[&a, &b], &[vec![1.0; nc], vec![0.0; nc]]).unwrap();
        assert_eq!(one_hot.targets().data, a.targets().data);
        assert_eq!(one_hot.indices(), a.indices());
        assert!(NnstMatch::blend(&[&a, &b], &[vec![1.0; nc]]).is_err());
        assert!(NnstMatch::blend(&[&a, &b], &[vec![1.0; nc], vec![0.0; nc - 1]]).is_err());
    }

    /// A match of some columns is the whole match on those columns.
    #[test]
    fn a_match_of_some_columns_is_the_whole_match_there() {
        let params = NnstParams { grid_divisor: 2, ..NnstParams::default() };
        let style = vec![image(8, 40, 36, 1), image(16, 20, 18, 2), image(8, 10, 9, 3)];
        let content = vec![image(8, 48, 40, 4), image(16, 24, 20, 5), image(8, 12, 10, 6)];
        let target = NnstTarget::from_style_features(&style, &params).unwrap();
        let whole = target.match_content(&content).unwrap();
        let nc = whole.indices().len();
        let wanted: Vec<bool> = (0..nc).map(|i| (i * 7) % 3 == 0).collect();
        let some = target.match_content_where(&content, &wanted).unwrap();
        let d = whole.targets().channels;
        for i in (0..nc).filter(|&i| wanted[i]) {
            assert_eq!(some.indices()[i], whole.indices()[i], "column {i}");
            for k in 0..d {
                assert_eq!(some.targets().data[k * nc + i], whole.targets().data[k * nc + i]);
            }
        }
        let none = target.match_content_where(&content, &vec![false; nc]).unwrap();
        assert!(none.indices().iter().all(|&j| j == 0));
        assert!(target.match_content_where(&content, &wanted[1..]).is_err());
    }

    #[test]
    fn identical_content_and_style_match_themselves() {
        let params = NnstParams { grid_divisor: 2, ..NnstParams::default() };
        // Large enough to take several matching blocks and the parallel path.
        let feats = vec![image(8, 64, 48, 1), image(16, 32, 24, 2), image(8, 16, 12, 3)];
        let target = NnstTarget::from_style_features(&feats, &params).unwrap();
        let matched = target.match_content(&feats).unwrap();
        assert!(matched.indices().iter().enumerate().all(|(i, &j)| i as u32 == j));
        let (loss, grads) = nnst_loss(&feats, &target).unwrap();
        assert_eq!(loss, 0.0);
        assert!(grads.iter().all(|g| g.data.iter().all(|v| *v == 0.0)));
    }

    /// Exact (f64) scores of centred content columns against the target's
    /// unit style columns, and the first arg-max of each content column.
    fn brute_force(target: &NnstTarget, centred: &Image) -> (Vec<Vec<f64>>, Vec<u32>) {
        let (d, nc, ns) = (centred.channels, centred.plane(), target.columns.plane());
        let scores: Vec<Vec<f64>> = (0..nc)
            .map(|i| {
                (0..ns)
                    .map(|j| (0..d).map(|k| centred.data[k * nc + i] as f64 * target.unit[k * ns + j] as f64).sum())
                    .collect()
            })
            .collect();
        let best =
            scores.iter().map(|row| (0..ns).fold(0, |b, j| if row[j] > row[b] { j } else { b }) as u32).collect();
        (scores, best)
    }

    /// The fused fp32 matching and every bf16 kernel against brute force, on
    /// sizes that leave partial blocks everywhere (D = 40, N_s = 143,
    /// N_c = 221). fp32 picks the exact best up to rounding; bf16 picks a
    /// column whose exact score is within its tolerance of the best (a near
    /// tie may go either way), and agrees with fp32 on almost every column.
    #[test]
    fn fused_matching_matches_brute_force() {
        let target = NnstTarget::from_style_features(
            &[image(40, 11, 13, 1)],
            &NnstParams { grid_divisor: 1, ..NnstParams::default() },
        )
        .unwrap();
        let centred = image(40, 13, 17, 2);
        let (scores, want) = brute_force(&target, &centred);
        let scale = scores.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
        let fp32 = target.argmax_fp32(&centred);
        for (i, (&g, &w)) in fp32.iter().zip(&want).enumerate() {
            assert!(scores[i][g as usize] >= scores[i][w as usize] - 1e-5 * scale, "fp32 column {i}: {g} vs {w}");
        }
        for k in bf16::Kernel::all_here() {
            let got = target.argmax_bf16(k, &centred);
            let mut same = 0;
            for (i, (&g, &w)) in got.iter().zip(&want).enumerate() {
                assert!(scores[i][g as usize] >= scores[i][w as usize] - 2e-2 * scale, "{k:?} column {i}: {g} vs {w}");
                same += usize::from(g == fp32[i]);
            }
            assert!(same * 100 >= got.len() * 90, "{k:?}: {same} of {} columns as fp32", got.len());
        }
    }

    #[test]
    fn bad_inputs_are_errors() {
        let p = NnstParams::default();
        assert_eq!(NnstTarget::from_style_features(&[], &p).unwrap_err(), NnstError::NoLayers);
        assert_eq!(
            NnstTarget::from_style_features(
                &[image(2, 4, 4, 1)],
                &NnstParams { grid_divisor: 0, ..NnstParams::default() }
            )
            .unwrap_err(),
            NnstError::ZeroGridDivisor
        );
        assert!(matches!(
            NnstTarget::from_style_features(&[Image::zeros(2, 0, 4)], &p),
            Err(NnstError::EmptyLayer { layer: 0, .. })
        ));
        let style = vec![image(2, 8, 8, 1), image(3, 4, 4, 2)];
        let t = NnstTarget::from_style_features(&style, &p).unwrap();
        assert_eq!(t.match_content(&style[..1]).unwrap_err(), NnstError::LayerCount { got: 1, expected: 2 });
        assert_eq!(
            nnst_loss(&[style[0].clone(), image(4, 4, 4, 3)], &t).unwrap_err(),
            NnstError::ChannelCount { layer: 1, got: 4, expected: 3 }
        );
        let m = t.match_content(&style).unwrap();
        let bigger = vec![image(2, 16, 16, 1), image(3, 8, 8, 2)];
        assert_eq!(
            nnst_loss_matched(&bigger, &m).unwrap_err(),
            NnstError::GridMismatch { got: (4, 4), expected: (2, 2) }
        );
        assert!(!NnstError::NoLayers.to_string().contains('\n'));
    }
}
