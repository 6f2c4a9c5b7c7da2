//! The micro-kernels of the direct convolution ([`super::direct`]), each in
//! an AVX-512 version and a scalar reference with the same contract, the
//! fp32 ones in an AVX2 + FMA version too (a 16-lane vector as two 8-lane
//! halves, for CPUs without AVX-512). The vector lanes run along x (16
//! output voxels of one row), so a tap is an offset into the padded input
//! and every output channel count fits.
//!
//! - forward: `acc[v][c][l] = Σ_{i, t} in[i · cs + offs[t] + bases[v] + l] · w[(i · taps + t) · NC + c]`,
//!   in fp32 (`i` a channel) or bf16 (`i` a channel pair, each lane a
//!   `u32` holding the pair, `vdpbf16ps` summing both products);
//! - weight gradient: `acc[c][j][l] += Σ_p g[c · gs + p.0 + l] · in[ioffs[j] + p.1 + l]`
//!   over the vector positions `p`, in fp32 (16 values a vector) or bf16
//!   (32 values a vector, lane `l` summing positions `2l` and `2l + 1`);
//!   the driver reads only the sum of each `acc[c][j]`'s lanes, so a
//!   kernel may gather its lanes' sums into fewer lanes (AVX2 does).
//!
//! Every kernel writes (forward) or adds (weight gradient) full 16-lane
//! vectors; the driver keeps what is inside the volume.

use nst3d_core::bf16::{from_f32, to_f32};

/// fp32 lanes of a vector.
pub const VL: usize = 16;

/// The operands of one forward tile (see the module docs).
pub struct FwdArgs<'a, T, const NV: usize> {
    /// Padded input: channels (or channel pairs) `cs` apart.
    pub inp: &'a [T],
    /// Channel (pair) stride.
    pub cs: usize,
    /// Channels (or pairs) summed.
    pub chans: usize,
    /// One offset per tap.
    pub offs: &'a [usize],
    /// Where each vector's row segment starts.
    pub bases: [usize; NV],
    /// Packed weights, `[i][t][NC]`.
    pub w: &'a [T],
}

/// The operands of one weight-gradient tile (see the module docs).
pub struct DwArgs<'a, T, const NCO: usize, const NT: usize> {
    /// Padded output gradient, `NCO` channels `gs` apart.
    pub g: &'a [T],
    /// Its channel stride.
    pub gs: usize,
    /// Padded input.
    pub inp: &'a [T],
    /// One input offset per `(channel, tap)` column.
    pub ioffs: [usize; NT],
    /// Vector positions: (output-gradient offset, input offset).
    pub pos: &'a [(usize, usize)],
}

/// Scalar forward tile (fp32): the reference.
pub fn fwd_f32_scalar<const NV: usize, const NC: usize>(a: &FwdArgs<f32, NV>, out: &mut [f32]) {
    let taps = a.offs.len();
    for v in 0..NV {
        for c in 0..NC {
            for l in 0..VL {
                let mut s = 0.0f32;
                for i in 0..a.chans {
                    for (t, &o) in a.offs.iter().enumerate() {
                        s += a.inp[i * a.cs + o + a.bases[v] + l] * a.w[(i * taps + t) * NC + c];
                    }
                }
                out[(v * NC + c) * VL + l] = s;
            }
        }
    }
}

/// The two products of a bf16 pair, summed in fp32 as `vdpbf16ps` does.
#[inline(always)]
fn dot_pair(a: u32, b: u32) -> f32 {
    let (al, ah) = (to_f32(a as u16), to_f32((a >> 16) as u16));
    let (bl, bh) = (to_f32(b as u16), to_f32((b >> 16) as u16));
    ah * bh + al * bl
}

/// Scalar forward tile (bf16 pairs): the reference.
pub fn fwd_bf16_scalar<const NV: usize, const NC: usize>(a: &FwdArgs<u32, NV>, out: &mut [f32]) {
    let taps = a.offs.len();
    for v in 0..NV {
        for c in 0..NC {
            for l in 0..VL {
                let mut s = 0.0f32;
                for i in 0..a.chans {
                    for (t, &o) in a.offs.iter().enumerate() {
                        s += dot_pair(a.inp[i * a.cs + o + a.bases[v] + l], a.w[(i * taps + t) * NC + c]);
                    }
                }
                out[(v * NC + c) * VL + l] = s;
            }
        }
    }
}

/// Scalar weight-gradient tile (fp32): the reference. `acc` is
/// `[NCO][NT][VL]` at row stride `lda` (between `c`s).
pub fn dw_f32_scalar<const NCO: usize, const NT: usize>(a: &DwArgs<f32, NCO, NT>, acc: &mut [f32], lda: usize) {
    for c in 0..NCO {
        for j in 0..NT {
            for l in 0..VL {
                let s: f32 = a.pos.iter().map(|p| a.g[c * a.gs + p.0 + l] * a.inp[a.ioffs[j] + p.1 + l]).sum();
                acc[c * lda + j * VL + l] += s;
            }
        }
    }
}

/// Scalar weight-gradient tile (bf16, 32 values a vector): the reference.
pub fn dw_bf16_scalar<const NCO: usize, const NT: usize>(a: &DwArgs<u16, NCO, NT>, acc: &mut [f32], lda: usize) {
    for c in 0..NCO {
        for j in 0..NT {
            for l in 0..VL {
                let s: f32 = a
                    .pos
                    .iter()
                    .map(|p| {
                        let (g, x) = (&a.g[c * a.gs + p.0 + 2 * l..], &a.inp[a.ioffs[j] + p.1 + 2 * l..]);
                        dot_pair(g[0] as u32 | (g[1] as u32) << 16, x[0] as u32 | (x[1] as u32) << 16)
                    })
                    .sum();
                acc[c * lda + j * VL + l] += s;
            }
        }
    }
}

/// AVX-512 forward tile (fp32).
///
/// # Safety
/// The CPU must have AVX-512F; every address the contract reads must lie in
/// `a.inp` and `a.w`; `out` must hold `NV · NC · VL` values.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
pub unsafe fn fwd_f32_avx512<const NV: usize, const NC: usize>(a: &FwdArgs<f32, NV>, out: &mut [f32]) {
    use std::arch::x86_64::*;
    let taps = a.offs.len();
    let mut acc = [[_mm512_setzero_ps(); NC]; NV];
    let (inp, w) = (a.inp.as_ptr(), a.w.as_ptr());
    for i in 0..a.chans {
        for (t, &o) in a.offs.iter().enumerate() {
            let src = inp.add(i * a.cs + o);
            let wt = w.add((i * taps + t) * NC);
            let x: [__m512; NV] = std::array::from_fn(|v| _mm512_loadu_ps(src.add(a.bases[v])));
            for c in 0..NC {
                let wc = _mm512_set1_ps(*wt.add(c));
                for v in 0..NV {
                    acc[v][c] = _mm512_fmadd_ps(x[v], wc, acc[v][c]);
                }
            }
        }
    }
    for v in 0..NV {
        for c in 0..NC {
            _mm512_storeu_ps(out.as_mut_ptr().add((v * NC + c) * VL), acc[v][c]);
        }
    }
}

/// AVX512-BF16 forward tile (bf16 pairs, `vdpbf16ps`).
///
/// # Safety
/// As [`fwd_f32_avx512`], and the CPU must have AVX512-BF16.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bf16")]
pub unsafe fn fwd_bf16_avx512<const NV: usize, const NC: usize>(a: &FwdArgs<u32, NV>, out: &mut [f32]) {
    use std::arch::x86_64::*;
    let taps = a.offs.len();
    let mut acc = [[_mm512_setzero_ps(); NC]; NV];
    let (inp, w) = (a.inp.as_ptr(), a.w.as_ptr());
    for i in 0..a.chans {
        for (t, &o) in a.offs.iter().enumerate() {
            let src = inp.add(i * a.cs + o);
            let wt = w.add((i * taps + t) * NC);
            let x: [__m512bh; NV] =
                std::array::from_fn(|v| std::mem::transmute(_mm512_loadu_si512(src.add(a.bases[v]) as *const _)));
            for c in 0..NC {
                let wc: __m512bh = std::mem::transmute(_mm512_set1_epi32(*wt.add(c) as i32));
                for v in 0..NV {
                    acc[v][c] = _mm512_dpbf16_ps(acc[v][c], x[v], wc);
                }
            }
        }
    }
    for v in 0..NV {
        for c in 0..NC {
            _mm512_storeu_ps(out.as_mut_ptr().add((v * NC + c) * VL), acc[v][c]);
        }
    }
}

/// AVX-512 weight-gradient tile (fp32).
///
/// # Safety
/// The CPU must have AVX-512F; every address read must lie in `a.g` and
/// `a.inp`; `acc` must hold `NCO` rows of `NT · VL` values `lda` apart.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
pub unsafe fn dw_f32_avx512<const NCO: usize, const NT: usize>(a: &DwArgs<f32, NCO, NT>, acc: &mut [f32], lda: usize) {
    use std::arch::x86_64::*;
    let mut s = [[_mm512_setzero_ps(); NT]; NCO];
    let (g, inp) = (a.g.as_ptr(), a.inp.as_ptr());
    for &(pg, pi) in a.pos {
        let gv: [__m512; NCO] = std::array::from_fn(|c| _mm512_loadu_ps(g.add(c * a.gs + pg)));
        for j in 0..NT {
            let x = _mm512_loadu_ps(inp.add(a.ioffs[j] + pi));
            for c in 0..NCO {
                s[c][j] = _mm512_fmadd_ps(gv[c], x, s[c][j]);
            }
        }
    }
    let dst = acc.as_mut_ptr();
    for c in 0..NCO {
        for j in 0..NT {
            let d = dst.add(c * lda + j * VL);
            _mm512_storeu_ps(d, _mm512_add_ps(_mm512_loadu_ps(d), s[c][j]));
        }
    }
}

/// AVX512-BF16 weight-gradient tile (32 bf16 values a vector).
///
/// # Safety
/// As [`dw_f32_avx512`], and the CPU must have AVX512-BF16.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bf16")]
pub unsafe fn dw_bf16_avx512<const NCO: usize, const NT: usize>(a: &DwArgs<u16, NCO, NT>, acc: &mut [f32], lda: usize) {
    use std::arch::x86_64::*;
    let mut s = [[_mm512_setzero_ps(); NT]; NCO];
    let (g, inp) = (a.g.as_ptr(), a.inp.as_ptr());
    for &(pg, pi) in a.pos {
        let gv: [__m512bh; NCO] =
            std::array::from_fn(|c| std::mem::transmute(_mm512_loadu_si512(g.add(c * a.gs + pg) as *const _)));
        for j in 0..NT {
            let x: __m512bh = std::mem::transmute(_mm512_loadu_si512(inp.add(a.ioffs[j] + pi) as *const _));
            for c in 0..NCO {
                s[c][j] = _mm512_dpbf16_ps(s[c][j], gv[c], x);
            }
        }
    }
    let dst = acc.as_mut_ptr();
    for c in 0..NCO {
        for j in 0..NT {
            let d = dst.add(c * lda + j * VL);
            _mm512_storeu_ps(d, _mm512_add_ps(_mm512_loadu_ps(d), s[c][j]));
        }
    }
}

/// AVX2 forward tile (fp32): each 16-lane vector as two 8-lane halves, so
/// `2 · NV · NC` accumulators (at most 12 of AVX2's 16 registers).
///
/// # Safety
/// The CPU must have AVX2 and FMA; otherwise as [`fwd_f32_avx512`].
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
pub unsafe fn fwd_f32_avx2<const NV: usize, const NC: usize>(a: &FwdArgs<f32, NV>, out: &mut [f32]) {
    use std::arch::x86_64::*;
    let taps = a.offs.len();
    let mut acc = [[[_mm256_setzero_ps(); 2]; NC]; NV];
    let (inp, w) = (a.inp.as_ptr(), a.w.as_ptr());
    for i in 0..a.chans {
        for (t, &o) in a.offs.iter().enumerate() {
            let src = inp.add(i * a.cs + o);
            let wt = w.add((i * taps + t) * NC);
            let x: [[__m256; 2]; NV] = std::array::from_fn(|v| {
                let p = src.add(a.bases[v]);
                [_mm256_loadu_ps(p), _mm256_loadu_ps(p.add(8))]
            });
            for c in 0..NC {
                let wc = _mm256_broadcast_ss(&*wt.add(c));
                for v in 0..NV {
                    acc[v][c][0] = _mm256_fmadd_ps(x[v][0], wc, acc[v][c][0]);
                    acc[v][c][1] = _mm256_fmadd_ps(x[v][1], wc, acc[v][c][1]);
                }
            }
        }
    }
    for v in 0..NV {
        for c in 0..NC {
            let d = out.as_mut_ptr().add((v * NC + c) * VL);
            _mm256_storeu_ps(d, acc[v][c][0]);
            _mm256_storeu_ps(d.add(8), acc[v][c][1]);
        }
    }
}

/// AVX2 weight-gradient tile (fp32). The driver sums a vector's 16 lanes,
/// so both halves of a position add into one 8-lane accumulator (lanes
/// 8..16 of each `acc` vector are left as they were): `NCO · NT`
/// accumulators, at most 12.
///
/// # Safety
/// The CPU must have AVX2 and FMA; otherwise as [`dw_f32_avx512`].
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
pub unsafe fn dw_f32_avx2<const NCO: usize, const NT: usize>(a: &DwArgs<f32, NCO, NT>, acc: &mut [f32], lda: usize) {
    use std::arch::x86_64::*;
    let mut s = [[_mm256_setzero_ps(); NT]; NCO];
    let (g, inp) = (a.g.as_ptr(), a.inp.as_ptr());
    for &(pg, pi) in a.pos {
        for h in [0, 8] {
            let gv: [__m256; NCO] = std::array::from_fn(|c| _mm256_loadu_ps(g.add(c * a.gs + pg + h)));
            for j in 0..NT {
                let x = _mm256_loadu_ps(inp.add(a.ioffs[j] + pi + h));
                for c in 0..NCO {
                    s[c][j] = _mm256_fmadd_ps(gv[c], x, s[c][j]);
                }
            }
        }
    }
    let dst = acc.as_mut_ptr();
    for c in 0..NCO {
        for j in 0..NT {
            let d = dst.add(c * lda + j * VL);
            _mm256_storeu_ps(d, _mm256_add_ps(_mm256_loadu_ps(d), s[c][j]));
        }
    }
}

/// The vector instruction set of the fp32 kernels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Isa {
    /// AVX-512F.
    Avx512,
    /// AVX2 + FMA.
    Avx2,
}

/// Which kernels this machine runs: the widest ones the CPU has that agree
/// with the scalar references on a fixed problem ([`self_check`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Unit {
    /// The fp32 kernels, if any (`None`: the scalar references).
    pub f32: Option<Isa>,
    /// The AVX512-BF16 kernels.
    pub bf16: bool,
}

impl Unit {
    /// Whether fp32 runs on vector kernels.
    pub fn has_f32(self) -> bool {
        self.f32.is_some()
    }
}

/// Tests set this to run the scalar references through the same drivers.
#[cfg(test)]
pub static SCALAR_ONLY: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
/// Tests set this to run the AVX2 kernels (where the CPU has AVX2) on an
/// AVX-512 machine too.
#[cfg(test)]
pub static AVX2_ONLY: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// The kernels this process may use (probed and checked once).
pub fn unit() -> Unit {
    #[cfg(test)]
    {
        use std::sync::atomic::Ordering::Relaxed;
        if SCALAR_ONLY.load(Relaxed) {
            return Unit { f32: None, bf16: false };
        }
        if AVX2_ONLY.load(Relaxed) && has_avx2() {
            return Unit { f32: Some(Isa::Avx2), bf16: false };
        }
    }
    static UNIT: std::sync::OnceLock<Unit> = std::sync::OnceLock::new();
    *UNIT.get_or_init(|| {
        let f32 = if nst3d_core::bf16::has_avx512f() && self_check(Isa::Avx512, false) {
            Some(Isa::Avx512)
        } else if nst3d_core::microkernel::has_avx2() && self_check(Isa::Avx2, false) {
            Some(Isa::Avx2)
        } else {
            None
        };
        let bf16 =
            f32 == Some(Isa::Avx512) && nst3d_core::bf16::avx512_bf16_available() && self_check(Isa::Avx512, true);
        Unit { f32, bf16 }
    })
}

/// Whether the CPU has AVX2 and FMA (whatever hides them from the jobs).
#[cfg(test)]
fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Fixed pseudo-random values in `[-0.5, 0.5)`.
fn vals(n: usize, seed: u32) -> Vec<f32> {
    (0..n)
        .map(|i| ((i as u32).wrapping_mul(2654435761).wrapping_add(seed) >> 8) as f32 / (1 << 24) as f32 - 0.5)
        .collect()
}

fn close(a: &[f32], b: &[f32]) -> bool {
    a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 1e-4 * (1.0 + y.abs()))
}

/// Runs the `isa` kernels (`bf16`: the AVX512-BF16 ones) on fixed operands
/// with odd offsets and compares them with the scalar references. Cost:
/// microseconds, once per process.
pub fn self_check(isa: Isa, bf16: bool) -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        let offs = [0usize, 7, 33];
        let (cs, chans) = (70usize, 3usize);
        let inp = vals(cs * chans + 64, 1);
        let w = vals(chans * offs.len() * 8, 2);
        let pos = [(0usize, 5usize), (19, 2), (40, 11)];
        let (mut want, mut got) = (vec![0.0f32; 3 * 8 * VL], vec![0.0f32; 3 * 8 * VL]);
        let (mut dwant, mut dgot) = (vec![0.0f32; 2 * 3 * VL], vec![0.0f32; 2 * 3 * VL]);
        if bf16 {
            let pairs: Vec<u32> =
                inp.chunks(2).map(|p| from_f32(p[0]) as u32 | (from_f32(p[1]) as u32) << 16).collect();
            let wp: Vec<u32> = w
                .iter()
                .zip(&vals(w.len(), 3))
                .map(|(a, b)| from_f32(*a) as u32 | (from_f32(*b) as u32) << 16)
                .collect();
            let a = FwdArgs { inp: &pairs, cs: cs / 2, chans, offs: &offs, bases: [0, 3, 9], w: &wp };
            fwd_bf16_scalar::<3, 8>(&a, &mut want);
            // SAFETY: bf16 is only checked where the CPU has the unit; the operands are in bounds.
            unsafe { fwd_bf16_avx512::<3, 8>(&a, &mut got) };
            let h: Vec<u16> = inp.iter().map(|v| from_f32(*v)).collect();
            let d = DwArgs { g: &h, gs: 50, inp: &h, ioffs: [1, 30, 64], pos: &pos };
            dw_bf16_scalar::<2, 3>(&d, &mut dwant, 3 * VL);
            // SAFETY: as above.
            unsafe { dw_bf16_avx512::<2, 3>(&d, &mut dgot, 3 * VL) };
        } else {
            let a = FwdArgs { inp: &inp, cs, chans, offs: &offs, bases: [0, 3, 9], w: &w };
            fwd_f32_scalar::<3, 8>(&a, &mut want);
            let d = DwArgs { g: &inp, gs: 50, inp: &inp, ioffs: [1, 30, 64], pos: &pos };
            dw_f32_scalar::<2, 3>(&d, &mut dwant, 3 * VL);
            // SAFETY: each isa is only checked where the CPU has it; the operands are in bounds.
            unsafe {
                match isa {
                    Isa::Avx512 => {
                        fwd_f32_avx512::<3, 8>(&a, &mut got);
                        dw_f32_avx512::<2, 3>(&d, &mut dgot, 3 * VL);
                    }
                    Isa::Avx2 => {
                        fwd_f32_avx2::<3, 8>(&a, &mut got);
                        dw_f32_avx2::<2, 3>(&d, &mut dgot, 3 * VL);
                    }
                }
            }
        }
        // The weight gradient's contract is the sum of each vector's lanes.
        let sums = |v: &[f32]| v.chunks(VL).map(|c| c.iter().sum()).collect::<Vec<f32>>();
        close(&got, &want) && close(&sums(&dgot), &sums(&dwant))
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (isa, bf16);
        false
    }
}
