//! Channels-last feature maps and the padded copies convolutions read.
//!
//! The network keeps activations as `(y, x, channel)` with channels fastest:
//! a Winograd tile then reads and writes whole 16-lane channel vectors, and
//! planar `nst3d_core::Image`s are produced only at the requested taps.

use nst3d_core::{FeatureView, Image, Layout};
use rayon::prelude::*;

use crate::simd::dispatch;

/// A `height x width x channels` activation, channels fastest:
/// index `(y * width + x) * channels + c`.
#[derive(Clone, Debug, PartialEq)]
pub struct FeatureMap {
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
    /// Channels per pixel.
    pub channels: usize,
    /// `height * width * channels` values.
    pub data: Vec<f32>,
}

impl FeatureMap {
    /// An all-zero map.
    pub fn zeros(height: usize, width: usize, channels: usize) -> Self {
        Self { height, width, channels, data: vec![0.0; height * width * channels] }
    }

    /// An all-zero map in a pooled buffer (see [`take_buffer`]).
    pub(crate) fn pooled_zeros(height: usize, width: usize, channels: usize) -> Self {
        let data =
            nst3d_core::fill::filled_into(take_buffer(height * width * channels), height * width * channels, 0.0);
        Self { height, width, channels, data }
    }

    /// Wraps channels-last data; panics if the length does not match
    /// (a programming error, never user input).
    pub fn from_vec(height: usize, width: usize, channels: usize, data: Vec<f32>) -> Self {
        assert_eq!(data.len(), height * width * channels, "feature map data length");
        Self { height, width, channels, data }
    }

    /// Channels-last copy of a planar image.
    pub fn from_image(img: &Image) -> Self {
        Self::from_planar(img.channels, img.height, img.width, &img.data)
    }

    /// Channels-last copy of planar `(C, H, W)` values, in a pooled buffer.
    fn from_planar(c: usize, height: usize, width: usize, planar: &[f32]) -> Self {
        let plane = height * width;
        let mut data = take_buffer(planar.len());
        // Rows of pixels in parallel; each pixel gathers its channels.
        data.spare_capacity_mut()[..planar.len()].par_chunks_mut((width * c).max(1)).enumerate().for_each(
            |(y, row)| {
                for x in 0..width {
                    let p = y * width + x;
                    for ch in 0..c {
                        row[x * c + ch].write(planar[ch * plane + p]);
                    }
                }
            },
        );
        // SAFETY: every element was written above.
        unsafe { data.set_len(planar.len()) };
        Self { height, width, channels: c, data }
    }

    /// Planar (PyTorch `(C, H, W)`) copy.
    pub fn to_image(&self) -> Image {
        let (c, plane) = (self.channels, self.height * self.width);
        // Not pooled: the image leaves the crate. Not zeroed either: every
        // value is written below.
        let mut data: Vec<f32> = Vec::with_capacity(self.data.len());
        // Blocks of channels in parallel so each output plane is written by
        // one task; pixels in runs of 64 so the reads of a run stay in cache.
        let chunk = 16.min(c.max(1));
        data.spare_capacity_mut()[..self.data.len()].par_chunks_mut((plane * chunk).max(1)).enumerate().for_each(
            |(blk, out)| {
                let c0 = blk * chunk;
                let nc = out.len() / plane.max(1);
                for p in 0..plane {
                    let src = &self.data[p * c + c0..p * c + c0 + nc];
                    for (k, v) in src.iter().enumerate() {
                        out[k * plane + p].write(*v);
                    }
                }
            },
        );
        // SAFETY: every element was written above.
        unsafe { data.set_len(self.data.len()) };
        Image::from_vec(c, self.height, self.width, data)
    }

    /// Hands the storage back to the buffer pool (see [`take_buffer`]).
    pub(crate) fn recycle(self) {
        recycle(self.data);
    }

    /// This map as the `C x P` feature matrix of a loss (channels-last).
    pub fn view(&self) -> FeatureView<'_> {
        FeatureView {
            channels: self.channels,
            height: self.height,
            width: self.width,
            layout: Layout::ChannelsLast,
            data: &self.data,
        }
    }

    /// A channels-last copy of `v` in a pooled buffer, whatever its layout.
    pub(crate) fn from_view(v: FeatureView<'_>) -> Self {
        match v.layout {
            Layout::ChannelsLast => {
                let mut data = take_buffer(v.data.len());
                data.extend_from_slice(v.data);
                Self { height: v.height, width: v.width, channels: v.channels, data }
            }
            Layout::Planar => Self::from_planar(v.channels, v.height, v.width, v.data),
        }
    }

    /// Adds channels-last values element-wise (same shape).
    pub(crate) fn add_assign_slice(&mut self, other: &[f32]) {
        assert_eq!(self.data.len(), other.len(), "feature map shapes differ");
        self.data.par_chunks_mut(1 << 14).zip(other.par_chunks(1 << 14)).for_each(|(a, b)| {
            for (x, y) in a.iter_mut().zip(b) {
                *x += y;
            }
        });
    }
}

/// How a 3x3 convolution sees pixels outside the map.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Padding {
    /// Zeros (torchvision VGG).
    Zero,
    /// Mirror without repeating the edge (`nn.ReflectionPad2d`, the Gatys VGG).
    Reflect,
}

/// A padded channels-last copy: the input of a "valid" 3x3 convolution.
/// It may be larger than needed (zeros beyond) so Winograd tiles never read
/// out of bounds.
pub(crate) struct Padded {
    pub w: usize,
    pub data: Vec<f32>,
}

/// Source index of padded coordinate `p` in a map of size `n` padded by `pad`.
fn source(p: usize, n: usize, pad: usize, mode: Padding) -> Option<usize> {
    let s = p as isize - pad as isize;
    let n = n as isize;
    let r = if (0..n).contains(&s) {
        s
    } else {
        match mode {
            Padding::Zero => return None,
            Padding::Reflect if s < 0 && s >= -(pad as isize) => -s,
            Padding::Reflect if s >= n && s < n + pad as isize => 2 * n - 2 - s,
            Padding::Reflect => return None,
        }
    };
    Some(r as usize)
}

/// What a 3x3 convolution reads: `map` seen through `pad` border pixels of
/// `mode` on every side, with the ReLU backward applied on the fly when
/// `mask` is given (values read as zero where `mask <= 0`).
#[derive(Clone, Copy)]
pub(crate) struct Source<'a> {
    pub map: &'a FeatureMap,
    pub pad: usize,
    pub mode: Padding,
    pub mask: Option<&'a FeatureMap>,
}

impl Source<'_> {
    /// Source row (or column, with `n` the width) of each of the first `len`
    /// padded coordinates; `None` reads as zero.
    pub fn axis_map(&self, len: usize, n: usize) -> Vec<Option<usize>> {
        (0..len).map(|p| source(p, n, self.pad, self.mode)).collect()
    }
}

/// Pads `src` into a `ph x pw` buffer (zeros beyond): the input of the
/// direct convolution (the Winograd path reads the [`Source`] in place).
pub(crate) fn pad(src: Source<'_>, ph: usize, pw: usize) -> Padded {
    let (map, mask) = (src.map, src.mask);
    let c = map.channels;
    let mut data = vec![0.0f32; ph * pw * c];
    let xs = src.axis_map(pw, map.width);
    data.par_chunks_mut(pw * c).enumerate().for_each(|(py, row)| {
        let Some(sy) = source(py, map.height, src.pad, src.mode) else { return };
        dispatch(
            #[inline(always)]
            || {
                for (px, sx) in xs.iter().enumerate() {
                    let Some(sx) = *sx else { continue };
                    let s = (sy * map.width + sx) * c;
                    let dst = &mut row[px * c..px * c + c];
                    match mask {
                        None => dst.copy_from_slice(&map.data[s..s + c]),
                        Some(m) => {
                            for ((d, v), mv) in dst.iter_mut().zip(&map.data[s..s + c]).zip(&m.data[s..s + c]) {
                                *d = if *mv > 0.0 { *v } else { 0.0 };
                            }
                        }
                    }
                }
            },
        )
    });
    Padded { w: pw, data }
}

/// Freed activation buffers, reused by the next pass: every forward and
/// backward allocates the same few dozen multi-MB maps, and fresh ones cost
/// page faults and kernel zeroing (~5-10% of a pass in profiles).
static POOL: std::sync::Mutex<Vec<Vec<f32>>> = std::sync::Mutex::new(Vec::new());
/// Most buffers the pool keeps (a VGG-19 pass to relu4_1 holds ~30 at once).
const POOL_MAX: usize = 48;

/// An empty vector with capacity for at least `len` values, from the pool
/// when a buffer of fitting size is there. The caller writes every element
/// (through `spare_capacity_mut`) and then sets the length.
pub(crate) fn take_buffer(len: usize) -> Vec<f32> {
    if let Ok(mut pool) = POOL.lock() {
        // Best fit, and never more than twice the request, so small maps do
        // not pin the big buffers.
        let best = pool
            .iter()
            .enumerate()
            .filter(|(_, b)| b.capacity() >= len && b.capacity() <= 2 * len.max(1024))
            .min_by_key(|(_, b)| b.capacity())
            .map(|(i, _)| i);
        if let Some(i) = best {
            let mut b = pool.swap_remove(i);
            b.clear();
            return b;
        }
    }
    Vec::with_capacity(len)
}

/// Returns a buffer to the pool (dropped if the pool is full).
pub(crate) fn recycle(buf: Vec<f32>) {
    if buf.capacity() < 1024 {
        return;
    }
    if let Ok(mut pool) = POOL.lock() {
        if pool.len() < POOL_MAX {
            pool.push(buf);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::pseudo_random;

    #[test]
    fn image_round_trip() {
        let img = Image::from_vec(5, 3, 4, pseudo_random(60, 3));
        let fm = FeatureMap::from_image(&img);
        assert_eq!(fm.data[(1 * 4 + 2) * 5 + 3], img.data[(3 * 3 + 1) * 4 + 2]);
        assert_eq!(fm.to_image(), img);
    }

    #[test]
    fn reflect_source_matches_reflection_pad() {
        // nn.ReflectionPad2d(1) on [a b c d]: [b a b c d c].
        let got: Vec<_> = (0..6).map(|p| source(p, 4, 1, Padding::Reflect)).collect();
        assert_eq!(got, vec![Some(1), Some(0), Some(1), Some(2), Some(3), Some(2)]);
        assert_eq!(source(0, 4, 1, Padding::Zero), None);
    }
}
