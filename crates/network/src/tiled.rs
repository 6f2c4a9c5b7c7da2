//! Tiled inference (paper Sec. 5.2, "High-resolution view-independent
//! stylization"): a volume of any size is cut into tiles, each run through
//! the network with a margin of real neighbouring voxels around it, and only
//! the tile's own voxels are kept. Memory then follows the tile size, not
//! the volume's. Where the margin covers the network's receptive field and
//! tiles sit on the network's stride lattice (multiples of 4), the result is
//! the untiled one to float rounding.

use crate::feedforward::FeedForward;
use crate::volume::Volume;

/// A margin that covers the network's receptive field, in voxels. Measured
/// on a width-2 network with tiles of 24: the largest difference to untiled
/// inference is 2e-4 with a margin of 20, 6e-6 with 24 and exactly 0 from 28
/// on; 32 leaves a lattice step to spare.
pub const RECEPTIVE_RADIUS: usize = 32;

/// The network's output for `x` (one channel, any size), computed tile by
/// tile: tiles of `tile³` voxels, each with `margin` voxels of context on
/// every side. Both are rounded up to multiples of 4, the network's stride.
///
/// # Panics
/// If `x` is not one channel or `tile` is 0.
pub fn infer_tiled(net: &FeedForward, x: &Volume, tile: usize, margin: usize) -> Volume {
    assert!(x.channels == 1, "tiled inference takes one channel");
    let dims = x.dims;
    let out_c = net.out_channels();
    let mut out = Volume::zeros(out_c, dims);
    let read = |from: [usize; 3], size: [usize; 3]| {
        let mut region = Volume::zeros(1, size);
        let to: [usize; 3] = std::array::from_fn(|a| (from[a] + size[a]).min(dims[a]));
        for z in from[2]..to[2] {
            for y in from[1]..to[1] {
                let src = (z * dims[1] + y) * dims[0];
                let dst = ((z - from[2]) * size[1] + (y - from[1])) * size[0];
                region.data[dst..dst + to[0] - from[0]].copy_from_slice(&x.data[src + from[0]..src + to[0]]);
            }
        }
        Some(region)
    };
    let n_out = dims.iter().product::<usize>();
    infer_tiles(net, dims, tile, margin, read, |t: &Tile, _input: &Volume, o: &Volume| {
        let n_reg = t.size.iter().product::<usize>();
        for c in 0..out_c {
            for z in t.lo[2]..t.hi[2] {
                for y in t.lo[1]..t.hi[1] {
                    let dst = c * n_out + (z * dims[1] + y) * dims[0];
                    let src = c * n_reg + ((z - t.from[2]) * t.size[1] + (y - t.from[1])) * t.size[0];
                    let (a, b) = (t.lo[0] - t.from[0], t.hi[0] - t.from[0]);
                    out.data[dst + t.lo[0]..dst + t.hi[0]].copy_from_slice(&o.data[src + a..src + b]);
                }
            }
        }
    });
    out
}

/// One tile of [`infer_tiles`], in voxels of the whole volume.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Tile {
    /// The tile's own voxels: `lo` (inclusive) to `hi` (exclusive).
    pub lo: [usize; 3],
    /// See `lo`.
    pub hi: [usize; 3],
    /// Corner of the region the network ran on: the tile plus its margin,
    /// clipped at 0 on the low side.
    pub from: [usize; 3],
    /// Size of that region, a multiple of 4 on every axis (zeros beyond the
    /// volume).
    pub size: [usize; 3],
}

/// Tiled inference over a volume of `dims` voxels that is never held
/// whole: `read(from, size)` returns the one-channel input region of `size`
/// voxels at `from` (zeros beyond the volume), or `None` to skip the tile
/// (a caller that knows the tile's output is not needed, e.g. no smoke in
/// reach), and `emit(tile, input, output)` receives each tile with the region it read and the network's
/// output on it, of which only `tile.lo .. tile.hi` is exact. Tiles and
/// margin are rounded up to multiples of 4 (the network's stride), and
/// tiles start at multiples of `tile` from 0, so they sit on the untiled
/// network's stride lattice; memory is one region's activations.
///
/// # Panics
/// If `tile` is 0.
pub fn infer_tiles(
    net: &FeedForward,
    dims: [usize; 3],
    tile: usize,
    margin: usize,
    mut read: impl FnMut([usize; 3], [usize; 3]) -> Option<Volume>,
    mut emit: impl FnMut(&Tile, &Volume, &Volume),
) {
    assert!(tile > 0, "tiled inference needs a tile size");
    let (tile, margin) = (tile.next_multiple_of(4), margin.next_multiple_of(4));
    let starts = |n: usize| (0..n).step_by(tile).collect::<Vec<_>>();
    for &z0 in &starts(dims[2]) {
        for &y0 in &starts(dims[1]) {
            for &x0 in &starts(dims[0]) {
                let lo = [x0, y0, z0];
                // The tile plus margin, clipped to the volume on the low side
                // (a multiple of 4 from 0, so the stride lattice is the same as
                // untiled) and padded with zeros to a multiple of 4.
                let from: [usize; 3] = std::array::from_fn(|a| lo[a].saturating_sub(margin));
                let to: [usize; 3] = std::array::from_fn(|a| (lo[a] + tile + margin).min(dims[a]));
                let size: [usize; 3] = std::array::from_fn(|a| (to[a] - from[a]).next_multiple_of(4));
                let hi: [usize; 3] = std::array::from_fn(|a| (lo[a] + tile).min(dims[a]));
                let Some(input) = read(from, size) else { continue };
                let o = net.infer(&input);
                emit(&Tile { lo, hi, from, size }, &input, &o);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::pseudo_random;

    /// Tiles with a margin of the receptive radius give the untiled result to
    /// float rounding; a margin of 4 does not (so the test can fail).
    #[test]
    fn tiles_match_the_whole_volume() {
        let net = FeedForward::new(2, 3, 5);
        let dims = [72, 40, 76];
        let n: usize = dims.iter().product();
        let x = Volume::from_vec(1, dims, pseudo_random(n, 6).iter().map(|v| v.abs()).collect());
        let whole = net.infer(&x);
        let max_diff =
            |a: &Volume, b: &Volume| a.data.iter().zip(&b.data).map(|(p, q)| (p - q).abs()).fold(0.0, f32::max);
        let tiled = infer_tiled(&net, &x, 24, RECEPTIVE_RADIUS);
        assert!(max_diff(&whole, &tiled) < 1e-5, "margin {RECEPTIVE_RADIUS}: {}", max_diff(&whole, &tiled));
        let thin = infer_tiled(&net, &x, 24, 4);
        assert!(max_diff(&whole, &thin) > 1e-3, "a thin margin should show the seams");
    }
}
