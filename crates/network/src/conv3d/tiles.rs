//! The convolution on AMX tiles: an implicit GEMM on the tall block of
//! `nst3d_core::bf16` (64 positions × 16 output channels a call, bf16
//! operands, fp32 sums), with no im2col.
//!
//! - **Forward**: the input is copied once into a zero-padded,
//!   channels-last bf16 layout. For one `(kz, ky)` the `k` x-taps of an
//!   output voxel read `k · cin` consecutive values, so the K dimension runs
//!   over them in slices of 32 (zero weights past the last tap), and the
//!   16 output voxels of an A tile are rows `stride · cin` values apart.
//!   Every tap is an offset into the copy.
//! - **Weight gradient** (stride 1): per tap, `dWₜᵀ = X shifted by t ·
//!   Gᵀ`, K running over output positions. The input is copied channel by
//!   channel into the padded grid, the output gradient spread over the
//!   same grid (zero where no output is) and packed in the tile's pair
//!   layout once; each A tile is 16 input channels at one tap, so a tap is
//!   again only an offset. Positions are summed in fixed groups, in order:
//!   the result does not depend on the thread count.
//!
//! The weight gradient of a strided layer, or of one whose input channels
//! are not whole tiles, stays on the AVX-512 kernels ([`takes_weight_grad`]).

use std::mem::MaybeUninit;

use nst3d_core::bf16::{amx, from_f32, Kernel, KS, TALL_MB, TALL_STEP};
use rayon::prelude::*;

use super::Conv3d;
use crate::activation::Act;
use crate::volume::Volume;

/// Positions of an A tile (rows of a tile).
const ROWS: usize = 16;
/// Tall blocks (64 positions each) one forward task computes.
const BLOCKS_PER_TASK: usize = 16;
/// K-slices of positions the weight gradient sums per block call (their
/// output gradient, 64 KB a 16-channel block, stays in cache across taps).
const DW_CHUNK_STEPS: usize = 64;
/// The weight gradient's chunks are split into this many fixed groups.
const DW_GROUPS: usize = 16;

/// Whether the forward of `l` runs on tiles: wherever AMX is. Even a
/// layer that fills a fifth of each K-slice (one input channel) or one
/// column of 16 (one output channel) is faster on tiles than on AVX-512:
/// the products are then a small part of the layer's time, next to the
/// copies in and out.
pub fn takes_forward(_l: &Conv3d) -> bool {
    amx::available()
}

/// Whether the weight gradient of `l` runs on tiles: stride 1 and input
/// channels in whole tiles of 16 (the A tiles are 16 channels at one tap).
pub fn takes_weight_grad(l: &Conv3d) -> bool {
    amx::available() && l.stride == 1 && l.cin.is_multiple_of(ROWS)
}

/// A raw pointer parallel tasks write disjoint elements through: the
/// forward's output (each position in one block) and the packed output
/// gradient (each position of each channel in one plane's task).
#[derive(Clone, Copy)]
struct Out<T>(*mut T);
// SAFETY: tasks write disjoint elements, as the callers of `write` promise.
unsafe impl<T> Send for Out<T> {}
unsafe impl<T> Sync for Out<T> {}

/// Where [`store_transposed`] writes: channel `j`'s first `n` positions at
/// `at + j · stride` of `out`.
#[derive(Clone, Copy)]
struct Rows {
    out: Out<f32>,
    at: usize,
    stride: usize,
    n: usize,
}

impl<T: Copy> Out<T> {
    /// Writes `v` at element `i`.
    ///
    /// # Safety
    /// `i` is inside the buffer and no other task writes it.
    unsafe fn write(&self, i: usize, v: T) {
        *self.0.add(i) = v;
    }
}

/// The padded input grid of a layer applied to `n` voxels.
struct Grid {
    s: usize,
    p: usize,
    n: [usize; 3],
    o: [usize; 3],
    /// Padded sides.
    px: usize,
    py: usize,
    pz: usize,
}

impl Grid {
    fn new(l: &Conv3d, n: [usize; 3]) -> Self {
        let p = l.pad;
        let [px, py, pz] = n.map(|v| v + 2 * p);
        Self { s: l.stride, p, n, o: l.out_dims(n), px, py, pz }
    }

    fn voxels(&self) -> usize {
        self.px * self.py * self.pz
    }

    /// Padded index of input voxel `(x, y, z)`.
    fn at(&self, x: usize, y: usize, z: usize) -> usize {
        ((z + self.p) * self.py + y + self.p) * self.px + x + self.p
    }

    /// Offset of tap `(kz, ky, kx)` in padded voxels.
    fn tap(&self, kz: usize, ky: usize, kx: usize) -> usize {
        (kz * self.py + ky) * self.px + kx
    }
}

/// `conv3d(x, W) + b` on tiles; the caller checked [`takes_forward`].
pub fn forward(l: &Conv3d, x: &Volume, act: Act) -> Volume {
    let g = Grid::new(l, x.dims);
    let [ox, oy, oz] = g.o;
    // Channels in pairs (one u32 of the copy), an odd count padded with a zero channel.
    let cp = l.cin.next_multiple_of(2);
    let slices = (l.k * cp).div_ceil(KS);
    let offs: Vec<usize> = (0..l.k * l.k * slices)
        .map(|st| g.tap(st / slices / l.k, st / slices % l.k, 0) * cp + st % slices * KS)
        .collect();
    let w = pack_forward_weights(l, cp, slices);
    // Output positions m = (z · oy + y) · xb + x, rows of xb so no tile of
    // 16 crosses a row; x ≥ ox are computed and dropped.
    let xb = ox.next_multiple_of(ROWS);
    let count = (oz * oy * xb).next_multiple_of(TALL_MB);
    let input = |m: usize| {
        let (z, y, xx) = (m / (oy * xb), m / xb % oy, m % xb);
        ((g.s * z * g.py + g.s * y) * g.px + g.s * xx) * cp
    };
    let max_read = input(count - ROWS) + (ROWS - 1) * g.s * cp + offs.iter().max().unwrap_or(&0) + KS;
    let xin = channels_last(&g, x, max_read.div_ceil(2));
    let n_out = oz * oy * ox;
    // Not zeroed first: the blocks below write every value once.
    let mut y: Vec<f32> = Vec::with_capacity(l.cout * n_out);
    let out = Out(y.as_mut_ptr());
    let nblk = l.cout.div_ceil(16);
    let blocks = count / TALL_MB;
    (0..blocks.div_ceil(BLOCKS_PER_TASK)).into_par_iter().for_each(|task| {
        let mut c = [0f32; TALL_MB * 16];
        let base = xin.as_ptr() as *const u16;
        Kernel::Amx.run(|ready| {
            for b in task * BLOCKS_PER_TASK..blocks.min((task + 1) * BLOCKS_PER_TASK) {
                let m0 = b * TALL_MB;
                // SAFETY: every tile row reads KS values at most max_read, inside the copy.
                let a = std::array::from_fn(|i| unsafe { base.add(input(m0 + i * ROWS)) });
                for nb in 0..nblk {
                    let wb = &w[nb * offs.len() * TALL_STEP..][..offs.len() * TALL_STEP];
                    // SAFETY: as above; wb holds offs.len() steps; c is 64 x 16.
                    unsafe { ready.block_tall(a, g.s * cp, &offs, wb.as_ptr(), c.as_mut_ptr(), 16) };
                    for t in 0..TALL_MB / ROWS {
                        let m = m0 + t * ROWS;
                        let (z, yy, x0) = (m / (oy * xb), m / xb % oy, m % xb);
                        if z >= oz || x0 >= ox {
                            continue;
                        }
                        let (v0, n) = ((z * oy + yy) * ox + x0, ROWS.min(ox - x0));
                        let channels = nb * 16..l.cout.min(nb * 16 + 16);
                        let tile: &[f32; ROWS * 16] =
                            c[t * ROWS * 16..][..ROWS * 16].try_into().expect("a 16 x 16 tile");
                        // SAFETY: positions v0 .. v0 + n of these channels, written by this block only.
                        unsafe {
                            store_transposed(
                                tile,
                                (&l.bias[channels.clone()], act),
                                Rows { out, at: channels.start * n_out + v0, stride: n_out, n },
                            )
                        };
                    }
                }
            }
        })
    });
    // SAFETY: the blocks cover every (z, y, x < ox) of every channel, each written above.
    unsafe { y.set_len(l.cout * n_out) };
    Volume::from_vec(l.cout, g.o, y)
}

/// Writes a 16 × 16 result tile (`tile[r · 16 + j]`: position `r`, channel
/// `j`) plus the bias, through `act`, into channels-first output ([`Rows`]),
/// for the `bias.len()` channels there are. On AVX-512 the tile is
/// transposed in registers, so each channel's row is one (masked) store.
///
/// # Safety
/// Every written element is inside the output and written by this caller only.
unsafe fn store_transposed(tile: &[f32; ROWS * 16], (bias, act): (&[f32], Act), to: Rows) {
    #[cfg(target_arch = "x86_64")]
    if nst3d_core::bf16::has_avx512f() {
        return store_transposed_avx512(tile, (bias, act), to);
    }
    let Rows { out, at, stride, n } = to;
    for (j, b) in bias.iter().enumerate() {
        for r in 0..n {
            out.write(at + j * stride + r, act.apply(tile[r * 16 + j] + b));
        }
    }
}

/// [`store_transposed`] on AVX-512: four stages of swapping the off-diagonal
/// `b x b` blocks (b = 8, 4, 2, 1) of row pairs `(i, i + b)` transpose the tile.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn store_transposed_avx512(tile: &[f32; ROWS * 16], (bias, act): (&[f32], Act), to: Rows) {
    use std::arch::x86_64::*;
    let Rows { out, at, stride, n } = to;
    let mut m: [__m512; 16] = std::array::from_fn(|r| _mm512_loadu_ps(tile.as_ptr().add(r * 16)));
    for b in [8usize, 4, 2, 1] {
        let lo: [i32; 16] = std::array::from_fn(|c| if c & b == 0 { c as i32 } else { (16 + c - b) as i32 });
        let hi: [i32; 16] = std::array::from_fn(|c| if c & b == 0 { (c + b) as i32 } else { (16 + c) as i32 });
        let (lo, hi) = (_mm512_loadu_si512(lo.as_ptr().cast()), _mm512_loadu_si512(hi.as_ptr().cast()));
        for i in (0..16).filter(|i| i & b == 0) {
            let (a, c) = (m[i], m[i + b]);
            m[i] = _mm512_permutex2var_ps(a, lo, c);
            m[i + b] = _mm512_permutex2var_ps(a, hi, c);
        }
    }
    let mask: __mmask16 = if n >= 16 { 0xffff } else { (1u16 << n) - 1 };
    let slope = _mm512_set1_ps(crate::activation::LEAKY_SLOPE);
    for (j, &b) in bias.iter().enumerate() {
        let mut v = _mm512_add_ps(m[j], _mm512_set1_ps(b));
        if act == Act::LeakyRelu {
            // The negative lanes times the slope: `leaky`'s own product, so the same bits.
            v = _mm512_mask_mul_ps(v, _mm512_cmp_ps_mask::<_CMP_LT_OQ>(v, _mm512_setzero_ps()), v, slope);
        }
        _mm512_mask_storeu_ps(out.0.add(at + j * stride), mask, v);
    }
}

/// The weights as `[16 output channels][step][k / 2][2 · channel + k % 2]`,
/// step `(kz, ky, slice)`, slice element `q` the tap `kx = q / cp` of
/// channel `q % cp` (zero past the last tap and channel).
fn pack_forward_weights(l: &Conv3d, cp: usize, slices: usize) -> Vec<u16> {
    let k3 = l.k * l.k * l.k;
    let steps = l.k * l.k * slices;
    let mut w = vec![0u16; l.cout.div_ceil(16) * steps * TALL_STEP];
    for co in 0..l.cout {
        for st in 0..steps {
            let (kz, ky, slice) = (st / slices / l.k, st / slices % l.k, st % slices);
            for kk in 0..KS {
                let q = slice * KS + kk;
                let (kx, ci) = (q / cp, q % cp);
                if kx < l.k && ci < l.cin {
                    let v = l.weight[(co * l.cin + ci) * k3 + (kz * l.k + ky) * l.k + kx];
                    w[((co / 16) * steps + st) * TALL_STEP + kk / 2 * KS + 2 * (co % 16) + kk % 2] = from_f32(v);
                }
            }
        }
    }
    w
}

/// `x` as bf16 in the padded grid, channels last in pairs (a `u32` holds
/// channels `2i`, `2i + 1`), zero-padded to `len` pairs at least. Only the
/// padding is zeroed, each plane by its own task (see [`nst3d_core::fill`]).
fn channels_last(g: &Grid, x: &Volume, len: usize) -> Vec<u32> {
    let (pairs, [nx, ny, _]) = (x.channels.div_ceil(2), g.n);
    let (row, plane) = (g.px * pairs, g.py * g.px * pairs);
    let total = len.max(g.voxels() * pairs);
    let zero = MaybeUninit::new(0u32);
    let mut buf = Vec::with_capacity(total);
    buf.spare_capacity_mut()[..total].par_chunks_mut(plane).enumerate().for_each_init(Vec::new, |tmp, (zz, dst)| {
        if zz < g.p || zz >= g.p + g.n[2] || dst.len() < plane {
            return dst.fill(zero);
        }
        let z = zz - g.p;
        tmp.resize(pairs * nx, 0);
        dst[..g.p * row].fill(zero);
        dst[(g.p + ny) * row..].fill(zero);
        for yy in 0..ny {
            let at = (z * ny + yy) * nx;
            for (i, t) in tmp.chunks_mut(nx).enumerate() {
                let b = (2 * i + 1 < x.channels).then(|| &x.channel(2 * i + 1)[at..][..nx]);
                super::direct::pairs_row(&x.channel(2 * i)[at..][..nx], b, t);
            }
            let (left, rest) = dst[(yy + g.p) * row..][..row].split_at_mut(g.p * pairs);
            let (body, right) = rest.split_at_mut(nx * pairs);
            left.fill(zero);
            right.fill(zero);
            for (xx, d) in body.chunks_exact_mut(pairs).enumerate() {
                d.iter_mut().enumerate().for_each(|(i, d)| *d = MaybeUninit::new(tmp[i * nx + xx]));
            }
        }
    });
    // SAFETY: every plane above wrote all its values: padding zeros, the rest `x`.
    unsafe { buf.set_len(total) };
    buf
}

/// The weight gradient on tiles; the caller checked [`takes_weight_grad`].
pub fn weight_grad(l: &Conv3d, x: &Volume, grad_out: &Volume) -> Vec<f32> {
    let g = Grid::new(l, x.dims);
    let k3 = l.k * l.k * l.k;
    // K runs over padded positions f = (z · py + y) · px + x of the outputs' planes.
    let steps = (g.o[2] * g.py * g.px).div_ceil(KS);
    let taps: Vec<usize> = (0..k3).map(|t| g.tap(t / (l.k * l.k), t / l.k % l.k, t % l.k)).collect();
    let cblocks = l.cin / ROWS;
    // A tiles: (tap, block of 16 input channels), four a call (the last call repeats its last tile).
    let tiles: Vec<usize> = (0..k3 * cblocks).map(|i| i % cblocks * ROWS * g.voxels() + taps[i / cblocks]).collect();
    let xs = channel_major(&g, x, (l.cin - 1) * g.voxels() + steps * KS + taps[k3 - 1] + KS);
    let gp = pack_gradient(l, &g, grad_out, steps);
    let nblk = l.cout.div_ceil(16);
    let chunks = steps.div_ceil(DW_CHUNK_STEPS);
    let per_group = chunks.div_ceil(DW_GROUPS);
    let partial: Vec<Vec<f32>> = (0..chunks.div_ceil(per_group))
        .into_par_iter()
        .map(|grp| {
            let mut acc = vec![0f32; tiles.len() * ROWS * l.cout];
            let mut c = [0f32; TALL_MB * 16];
            Kernel::Amx.run(|ready| {
                for ch in grp * per_group..chunks.min((grp + 1) * per_group) {
                    let s0 = ch * DW_CHUNK_STEPS;
                    let offs: Vec<usize> = (s0..steps.min(s0 + DW_CHUNK_STEPS)).map(|s| s * KS).collect();
                    for quad in (0..tiles.len()).step_by(4) {
                        let idx: [usize; 4] = std::array::from_fn(|i| (quad + i).min(tiles.len() - 1));
                        // SAFETY: xs holds every row a tile reads (sized above).
                        let a = idx.map(|t| unsafe { xs.as_ptr().add(tiles[t]) });
                        for nb in 0..nblk {
                            let b = &gp[(nb * steps + s0) * TALL_STEP / 2..][..offs.len() * TALL_STEP / 2];
                            // SAFETY: as above; b holds offs.len() steps; c is 64 x 16.
                            unsafe {
                                ready.block_tall(a, g.voxels(), &offs, b.as_ptr() as *const u16, c.as_mut_ptr(), 16)
                            };
                            for (i, &t) in idx.iter().enumerate().take(tiles.len() - quad) {
                                for r in 0..ROWS {
                                    let dst = &mut acc[(t * ROWS + r) * l.cout + nb * 16..];
                                    let n = 16.min(l.cout - nb * 16);
                                    dst[..n].iter_mut().zip(&c[(i * ROWS + r) * 16..][..n]).for_each(|(d, v)| *d += v);
                                }
                            }
                        }
                    }
                }
            });
            acc
        })
        .collect();
    // acc row (tap, channel block, row r) = input channel block · 16 + r at that tap.
    let mut dw = vec![0f32; l.cout * l.cin * k3];
    for acc in &partial {
        for (t_cb, rows) in acc.chunks(ROWS * l.cout).enumerate() {
            let (t, cb) = (t_cb / cblocks, t_cb % cblocks);
            for r in 0..ROWS {
                let ci = cb * ROWS + r;
                for co in 0..l.cout {
                    dw[(co * l.cin + ci) * k3 + t] += rows[r * l.cout + co];
                }
            }
        }
    }
    dw
}

/// `x` as bf16 in the padded grid, one channel after another
/// (`g.voxels()` apart), zero-padded to `len` values at least.
fn channel_major(g: &Grid, x: &Volume, len: usize) -> Vec<u16> {
    let [nx, ny, nz] = g.n;
    let total = len.max(x.channels * g.voxels());
    let zero = MaybeUninit::new(0u16);
    let mut buf = Vec::with_capacity(total);
    buf.spare_capacity_mut()[..total].par_chunks_mut(g.voxels()).enumerate().for_each_init(
        || vec![0u16; nx],
        |row, (ci, dst)| {
            if ci >= x.channels {
                return dst.fill(zero);
            }
            // The padding between the rows (and before the first, after the last) zeroed as it goes.
            let mut done = 0;
            for z in 0..nz {
                for y in 0..ny {
                    let at = g.at(0, y, z);
                    dst[done..at].fill(zero);
                    nst3d_core::bf16::convert(&x.channel(ci)[(z * ny + y) * nx..][..nx], row);
                    dst[at..at + nx].iter_mut().zip(row.iter()).for_each(|(d, &v)| *d = MaybeUninit::new(v));
                    done = at + nx;
                }
            }
            dst[done..].fill(zero);
        },
    );
    // SAFETY: each channel's chunk was written whole: its rows and the zeros around them.
    unsafe { buf.set_len(total) };
    buf
}

/// The output gradient on the padded positions `f = (z · py + y) · px + x`
/// (zero where no output is), packed as the tall block's B (`u32` pairs):
/// `[16 output channels][step][k / 2][2 · channel + k % 2]`. One task a
/// plane of 16 channels: their rows are converted to bf16, then each
/// position's 16 values go to their 64 bytes of the step's tile.
fn pack_gradient(l: &Conv3d, g: &Grid, grad_out: &Volume, steps: usize) -> Vec<u32> {
    let [ox, oy, oz] = g.o;
    let nblk = l.cout.div_ceil(16);
    let mut out = nst3d_core::fill::filled(nblk * steps * TALL_STEP / 2, 0u32);
    let dst = Out(out.as_mut_ptr() as *mut u16);
    (0..nblk * oz).into_par_iter().for_each_init(
        || vec![0u16; 16 * ox],
        |rows, bz| {
            let (nb, z) = (bz / oz, bz % oz);
            let channels = 16.min(l.cout - nb * 16);
            for y in 0..oy {
                for j in 0..channels {
                    let src = &grad_out.channel(nb * 16 + j)[(z * oy + y) * ox..][..ox];
                    nst3d_core::bf16::convert(src, &mut rows[j * ox..][..ox]);
                }
                let f0 = (z * g.py + y) * g.px;
                for x in 0..ox {
                    let f = f0 + x;
                    let at = (nb * steps + f / KS) * TALL_STEP + f % KS / 2 * KS + f % 2;
                    for j in 0..channels {
                        // SAFETY: position f of channel nb · 16 + j, inside the
                        // buffer (f < steps · KS) and written by this task only.
                        unsafe { dst.write(at + 2 * j, rows[j * ox + x]) };
                    }
                }
            }
        },
    );
    out
}
