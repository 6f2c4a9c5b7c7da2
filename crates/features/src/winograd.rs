//! Winograd F(4x4, 3x3) convolution on channels-last maps.
//!
//! Each 4x4 output tile costs 36 multiplies per (input, output) channel pair
//! instead of 144: the 6x6 input tile is transformed (`B^T d B`), multiplied
//! position-wise with the transformed kernel (`G g G^T`, precomputed once
//! since the weights are frozen) and transformed back (`A^T m A`). Over a
//! block of tiles the position-wise products become 36 dense products
//! `[tiles x cin] * [cin x cout]`, run by the register-blocked kernel in
//! [`crate::gemm`].

use rayon::prelude::*;

use crate::gemm::{self, Blocking, NR_MIN, ROW_ALIGN};
use crate::tensor::{take_buffer, FeatureMap, Source};

/// Channels per transform vector; Winograd layers need `cin % LANES == 0`.
pub(crate) const LANES: usize = 16;
const NPOS: usize = 36;
type V = [f32; LANES];

/// Kernel transform `G` (6x3) of F(4x4, 3x3).
const G: [[f64; 3]; 6] = [
    [1.0 / 4.0, 0.0, 0.0],
    [-1.0 / 6.0, -1.0 / 6.0, -1.0 / 6.0],
    [-1.0 / 6.0, 1.0 / 6.0, -1.0 / 6.0],
    [1.0 / 24.0, 1.0 / 12.0, 1.0 / 6.0],
    [1.0 / 24.0, -1.0 / 12.0, 1.0 / 6.0],
    [0.0, 0.0, 1.0],
];

/// Whether a convolution with these channel counts can take this path.
pub(crate) fn supports(cin: usize, cout: usize) -> bool {
    cin.is_multiple_of(LANES) && cout.is_multiple_of(NR_MIN) && cin > 0 && cout > 0
}

/// Transformed weights, packed as `[position][cout / nr][cin][nr]` (`nr`
/// from the layer's [`Blocking`]) so the product kernel streams each panel
/// contiguously.
pub(crate) struct WinogradWeights {
    cin: usize,
    cout: usize,
    bl: Blocking,
    v: Vec<f32>,
}

impl WinogradWeights {
    /// From PyTorch-layout `[cout][cin][3][3]` weights (correlation, as in CNNs).
    pub(crate) fn new(w: &[f32], cin: usize, cout: usize) -> Self {
        assert!(supports(cin, cout));
        let bl = Blocking::for_cout(cout);
        let (nr, np) = (bl.nr, cout / bl.nr);
        let mut v = vec![0.0f32; NPOS * cout * cin];
        for co in 0..cout {
            for ci in 0..cin {
                let g = &w[(co * cin + ci) * 9..(co * cin + ci) * 9 + 9];
                // t = G g (6x3), u = t G^T (6x6), in f64 so the only rounding is the final cast.
                let mut t = [[0f64; 3]; 6];
                for i in 0..6 {
                    for j in 0..3 {
                        t[i][j] = (0..3).map(|k| G[i][k] * g[k * 3 + j] as f64).sum();
                    }
                }
                for a in 0..6 {
                    for b in 0..6 {
                        let u: f64 = (0..3).map(|k| t[a][k] * G[b][k]).sum();
                        let p = a * 6 + b;
                        v[((p * np + co / nr) * cin + ci) * nr + co % nr] = u as f32;
                    }
                }
            }
        }
        Self { cin, cout, bl, v }
    }
}

/// `B^T x` for one column of six lane vectors.
#[inline(always)]
fn bt6(x: &[V; 6]) -> [V; 6] {
    let mut y = [[0.0; LANES]; 6];
    for l in 0..LANES {
        let (x0, x1, x2, x3, x4, x5) = (x[0][l], x[1][l], x[2][l], x[3][l], x[4][l], x[5][l]);
        y[0][l] = 4.0 * x0 - 5.0 * x2 + x4;
        y[1][l] = -4.0 * (x1 + x2) + x3 + x4;
        y[2][l] = 4.0 * (x1 - x2) - x3 + x4;
        y[3][l] = 2.0 * (x3 - x1) - x2 + x4;
        y[4][l] = 2.0 * (x1 - x3) - x2 + x4;
        y[5][l] = 4.0 * x1 - 5.0 * x3 + x5;
    }
    y
}

/// `A^T m` for one column of six lane vectors.
#[inline(always)]
fn at6(m: &[V; 6]) -> [V; 4] {
    let mut y = [[0.0; LANES]; 4];
    for l in 0..LANES {
        let (m0, m1, m2, m3, m4, m5) = (m[0][l], m[1][l], m[2][l], m[3][l], m[4][l], m[5][l]);
        let (s12, d12, s34, d34) = (m1 + m2, m1 - m2, m3 + m4, m3 - m4);
        y[0][l] = m0 + s12 + s34;
        y[1][l] = d12 + 2.0 * d34;
        y[2][l] = s12 + 4.0 * s34;
        y[3][l] = d12 + 8.0 * d34 + m5;
    }
    y
}

#[inline(always)]
fn load(s: &[f32]) -> V {
    s[..LANES].try_into().unwrap()
}

/// Channels `c0..c0 + LANES` of source pixel `(y, x)` (zeros for `None`),
/// masked by the ReLU-backward `mask` when given.
#[inline(always)]
fn load_source(map: &FeatureMap, mask: Option<&FeatureMap>, y: Option<usize>, x: Option<usize>, c0: usize) -> V {
    let (Some(y), Some(x)) = (y, x) else { return [0.0; LANES] };
    let s = (y * map.width + x) * map.channels + c0;
    let mut v = load(&map.data[s..]);
    if let Some(m) = mask {
        let mv = load(&m.data[s..]);
        for l in 0..LANES {
            if mv[l] <= 0.0 {
                v[l] = 0.0;
            }
        }
    }
    v
}

/// Calls a transform, through its AVX-512-compiled copy when the machine
/// has it, else its AVX2 one. A plain function, not a closure, is inlined
/// into the `#[target_feature]` wrapper: the closure version stayed an SSE
/// function (~20% of a pass in profiles).
macro_rules! dispatch_transform {
    ($plain:ident, $fast:ident, $avx2:ident, ($($arg:expr),* $(,)?)) => {{
        #[cfg(target_arch = "x86_64")]
        if crate::gemm::has_avx512() {
            unsafe { $fast($($arg),*) }
        } else if crate::gemm::has_avx2() {
            unsafe { $avx2($($arg),*) }
        } else {
            unsafe { $plain($($arg),*) }
        }
        #[cfg(not(target_arch = "x86_64"))]
        unsafe {
            $plain($($arg),*)
        }
    }};
}

/// Defines a transform's copies compiled for AVX-512 and for AVX2, each a
/// wrapper the plain function inlines into.
macro_rules! wide_copies {
    ($plain:ident => $avx512:ident, $avx2:ident, ($($arg:ident: $ty:ty),* $(,)?)) => {
        #[doc = concat!("[`", stringify!($plain), "`] compiled for AVX-512.")]
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx512f,avx2,fma")]
        #[allow(clippy::too_many_arguments)]
        unsafe fn $avx512($($arg: $ty),*) {
            $plain($($arg),*)
        }

        #[doc = concat!("[`", stringify!($plain), "`] compiled for AVX2.")]
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2,fma")]
        #[allow(clippy::too_many_arguments)]
        unsafe fn $avx2($($arg: $ty),*) {
            $plain($($arg),*)
        }
    };
}

wide_copies!(input_tile => input_tile_avx512, input_tile_avx2, (
    map: &FeatureMap,
    mask: Option<&FeatureMap>,
    ty6: &[Option<usize>],
    tx6: &[Option<usize>],
    u: *mut f32,
    pos_stride: usize,
));

wide_copies!(output_tile => output_tile_avx512, output_tile_avx2, (
    m: *const f32,
    pos_stride: usize,
    cout: usize,
    bias: Option<&[f32]>,
    relu: bool,
    out: *mut f32,
    out_stride: usize,
    ny: usize,
    nx: usize,
));

/// Input transform `B^T d B` of one tile: reads the 6x6 source pixels
/// (through padding and mask) and writes position `p`'s row at
/// `u + p * pos_stride`, channels contiguous.
#[inline(always)]
unsafe fn input_tile(
    map: &FeatureMap,
    mask: Option<&FeatureMap>,
    ty6: &[Option<usize>],
    tx6: &[Option<usize>],
    u: *mut f32,
    pos_stride: usize,
) {
    for c0 in (0..map.channels).step_by(LANES) {
        // Array literals of inlined calls rather than `array::from_fn` or a
        // zeroed array filled in loops: those did not inline and cost a 2 KB
        // memset per channel block.
        macro_rules! row {
            ($i:expr) => {{
                let y = ty6[$i];
                bt6(&[
                    load_source(map, mask, y, tx6[0], c0),
                    load_source(map, mask, y, tx6[1], c0),
                    load_source(map, mask, y, tx6[2], c0),
                    load_source(map, mask, y, tx6[3], c0),
                    load_source(map, mask, y, tx6[4], c0),
                    load_source(map, mask, y, tx6[5], c0),
                ])
            }};
        }
        // Rows of B^T d B: transform along x first.
        let rows = [row!(0), row!(1), row!(2), row!(3), row!(4), row!(5)];
        for b in 0..6 {
            let y = bt6(&[rows[0][b], rows[1][b], rows[2][b], rows[3][b], rows[4][b], rows[5][b]]);
            for (a, ya) in y.iter().enumerate() {
                std::ptr::copy_nonoverlapping(ya.as_ptr(), u.add((a * 6 + b) * pos_stride + c0), LANES);
            }
        }
    }
}

/// Output transform `A^T m A` of one tile plus bias and optional ReLU:
/// reads position `p`'s row at `m + p * pos_stride` and writes the tile's
/// `ny x nx` pixels at `out` (row stride `out_stride`).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
unsafe fn output_tile(
    m: *const f32,
    pos_stride: usize,
    cout: usize,
    bias: Option<&[f32]>,
    relu: bool,
    out: *mut f32,
    out_stride: usize,
    ny: usize,
    nx: usize,
) {
    for c0 in (0..cout).step_by(LANES) {
        macro_rules! ld {
            ($a:expr, $b:expr) => {
                *(m.add(($a * 6 + $b) * pos_stride + c0) as *const V)
            };
        }
        macro_rules! row {
            ($a:expr) => {
                at6(&[ld!($a, 0), ld!($a, 1), ld!($a, 2), ld!($a, 3), ld!($a, 4), ld!($a, 5)])
            };
        }
        let rows = [row!(0), row!(1), row!(2), row!(3), row!(4), row!(5)];
        let bv: V = match bias {
            Some(b) => load(&b[c0..]),
            None => [0.0; LANES],
        };
        for j in 0..nx {
            let y = at6(&[rows[0][j], rows[1][j], rows[2][j], rows[3][j], rows[4][j], rows[5][j]]);
            for (i, yi) in y.iter().enumerate().take(ny) {
                let mut v = *yi;
                for l in 0..LANES {
                    v[l] += bv[l];
                    if relu {
                        v[l] = v[l].max(0.0);
                    }
                }
                std::ptr::copy_nonoverlapping(v.as_ptr(), out.add(i * out_stride + j * cout + c0), LANES);
            }
        }
    }
}

/// Output pointer shared by tasks that write disjoint pixels.
#[derive(Clone, Copy)]
struct OutPtr(*mut f32);
// SAFETY: tasks write disjoint ranges (distinct tiles or positions).
unsafe impl Send for OutPtr {}
unsafe impl Sync for OutPtr {}
impl OutPtr {
    fn get(self) -> *mut f32 {
        self.0
    }
}

/// Tiles per block: the transformed block `36 x tiles x channels` stays
/// within a few MB (shared L3) while the weights are read once per block.
fn block_tiles(ntiles: usize, cin: usize, cout: usize) -> usize {
    let cap = (4 << 20) / (NPOS * 4 * (cin + cout));
    let tb = cap.clamp(ROW_ALIGN, 1024).min(ntiles.div_ceil(ROW_ALIGN) * ROW_ALIGN);
    tb / ROW_ALIGN * ROW_ALIGN
}

/// 3x3 convolution of `src` (read through its padding and mask) producing
/// `out_h x out_w` ("valid" over the padded map), with optional bias and
/// fused ReLU.
pub(crate) fn conv(
    src: Source<'_>,
    out_h: usize,
    out_w: usize,
    ww: &WinogradWeights,
    bias: Option<&[f32]>,
    relu: bool,
) -> FeatureMap {
    let (cin, cout, bl) = (ww.cin, ww.cout, ww.bl);
    let (map, mask) = (src.map, src.mask);
    assert_eq!(map.channels, cin);
    let (th, tw) = (out_h.div_ceil(4), out_w.div_ceil(4));
    // Padded coordinate -> source pixel, once per axis; border tiles read
    // zeros or mirrored pixels from these instead of a padded copy.
    let (ys, xs) = (src.axis_map(th * 4 + 2, map.height), src.axis_map(tw * 4 + 2, map.width));
    let ntiles = th * tw;
    let tb = block_tiles(ntiles, cin, cout);
    // Every output value is written exactly once below (through raw
    // pointers, no slice over the uninitialised part): no zeroing.
    let mut data = take_buffer(out_h * out_w * cout);
    let outp = OutPtr(data.as_mut_ptr());
    // Block scratch is reused across calls: fresh multi-MB buffers cost a
    // memset or page faults each time (seen at ~10% in profiles).
    let mut scratch = SCRATCH.lock().map(|mut s| std::mem::take(&mut *s)).unwrap_or_default();
    scratch.resize(NPOS * tb * (cin + cout), 0.0);
    let (u, m) = scratch.split_at_mut(NPOS * tb * cin);
    let (up, mp) = (OutPtr(u.as_mut_ptr()), OutPtr(m.as_mut_ptr()));
    let np = cout / bl.nr;

    for t0 in (0..ntiles).step_by(tb) {
        let nt = tb.min(ntiles - t0);
        // Input transform, tiles in parallel.
        (0..nt).into_par_iter().with_min_len(4).for_each(|t| {
            let (ty, tx) = ((t0 + t) / tw, (t0 + t) % tw);
            let (ty6, tx6) = (&ys[ty * 4..ty * 4 + 6], &xs[tx * 4..tx * 4 + 6]);
            // SAFETY: (p, t) rows of u are owned by this task.
            dispatch_transform!(
                input_tile,
                input_tile_avx512,
                input_tile_avx2,
                (map, mask, ty6, tx6, up.get().add(t * cin), tb * cin)
            );
        });
        // 36 independent products, one task per position.
        let rows = nt.div_ceil(bl.mr) * bl.mr;
        (0..NPOS).into_par_iter().for_each(|p| {
            for jp in 0..np {
                let panel = &ww.v[(p * np + jp) * cin * bl.nr..(p * np + jp + 1) * cin * bl.nr];
                for r0 in (0..rows).step_by(bl.mr) {
                    // SAFETY: u/m hold tb >= rows rows per position; panel holds cin * nr.
                    unsafe {
                        gemm::kernel(
                            bl,
                            up.get().add((p * tb + r0) * cin),
                            cin,
                            panel.as_ptr(),
                            cin,
                            mp.get().add((p * tb + r0) * cout + jp * bl.nr),
                            cout,
                        );
                    }
                }
            }
        });
        // Output transform, tiles in parallel; bias and ReLU fused.
        (0..nt).into_par_iter().with_min_len(4).for_each(|t| {
            let (ty, tx) = ((t0 + t) / tw, (t0 + t) % tw);
            let (ny, nx) = (4.min(out_h - ty * 4), 4.min(out_w - tx * 4));
            // SAFETY: the products wrote row t of every position; each tile
            // writes only its own ny x nx pixels.
            dispatch_transform!(
                output_tile,
                output_tile_avx512,
                output_tile_avx2,
                (
                    mp.get().add(t * cout),
                    tb * cout,
                    cout,
                    bias,
                    relu,
                    outp.get().add((ty * 4 * out_w + tx * 4) * cout),
                    out_w * cout,
                    ny,
                    nx
                )
            );
        });
    }
    if let Ok(mut s) = SCRATCH.lock() {
        *s = scratch;
    }
    // SAFETY: the output transform wrote all out_h * out_w pixels x cout channels.
    unsafe { data.set_len(out_h * out_w * cout) };
    FeatureMap::from_vec(out_h, out_w, cout, data)
}

/// Scratch of the last finished convolution, handed to the next one.
static SCRATCH: std::sync::Mutex<Vec<f32>> = std::sync::Mutex::new(Vec::new());
