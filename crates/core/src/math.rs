//! Fixed-size vector helpers and the seeded random generator the renderers,
//! camera samplers and strand stages share.
//!
//! Every helper spells out its arithmetic in one fixed order (`dot` is
//! `a₀b₀ + a₁b₁ + a₂b₂`, `norm` is `dot(a, a).sqrt()`), because saved
//! outputs are compared bit for bit: a helper that summed in another order or
//! used `hypot` would change every render downstream of it.

use std::ops::{Add, Div, Mul, Sub};

/// A point or direction in single precision, the layout of groom and mesh
/// points.
pub type V3 = [f32; 3];

/// The two float widths the helpers serve: `f32` for per-point geometry,
/// `f64` for camera maths where a few extra digits are free.
pub trait Real:
    Copy + PartialOrd + Add<Output = Self> + Sub<Output = Self> + Mul<Output = Self> + Div<Output = Self>
{
    /// IEEE square root (never `hypot`-style rescaling, see the module notes).
    fn sqrt(self) -> Self;
    /// Neither infinite nor NaN.
    fn is_finite(self) -> bool;
}

impl Real for f32 {
    #[inline]
    fn sqrt(self) -> Self {
        f32::sqrt(self)
    }
    #[inline]
    fn is_finite(self) -> bool {
        f32::is_finite(self)
    }
}

impl Real for f64 {
    #[inline]
    fn sqrt(self) -> Self {
        f64::sqrt(self)
    }
    #[inline]
    fn is_finite(self) -> bool {
        f64::is_finite(self)
    }
}

/// `a + b`.
#[inline]
pub fn add<T: Real>(a: [T; 3], b: [T; 3]) -> [T; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// `a − b`.
#[inline]
pub fn sub<T: Real>(a: [T; 3], b: [T; 3]) -> [T; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// `a · s`, each component multiplied (not divided by `1/s`).
#[inline]
pub fn scale<T: Real>(a: [T; 3], s: T) -> [T; 3] {
    [a[0] * s, a[1] * s, a[2] * s]
}

/// `a₀b₀ + a₁b₁ + a₂b₂`, summed left to right.
#[inline]
pub fn dot<T: Real>(a: [T; 3], b: [T; 3]) -> T {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Right-handed `a × b`.
#[inline]
pub fn cross<T: Real>(a: [T; 3], b: [T; 3]) -> [T; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

/// Squared length, for comparisons that need no square root.
#[inline]
pub fn norm2<T: Real>(a: [T; 3]) -> T {
    dot(a, a)
}

/// Euclidean length, `dot(a, a).sqrt()`.
#[inline]
pub fn norm<T: Real>(a: [T; 3]) -> T {
    dot(a, a).sqrt()
}

/// Squared distance between two points.
#[inline]
pub fn dist2<T: Real>(a: [T; 3], b: [T; 3]) -> T {
    norm2(sub(a, b))
}

/// `a + (b − a) t`.
#[inline]
pub fn lerp<T: Real>(a: [T; 3], b: [T; 3], t: T) -> [T; 3] {
    add(a, scale(sub(b, a), t))
}

/// `a / |a|`, every component divided, with no check: for callers that have
/// already ruled out a zero vector (a NaN result tells them they did not).
#[inline]
pub fn unit<T: Real>(a: [T; 3]) -> [T; 3] {
    let n = norm(a);
    a.map(|x| x / n)
}

/// `a / |a|`, every component divided, or `None` when `|a|` is at most
/// `min_norm` or not finite. Each caller picks the threshold below which its
/// input means "no direction" (a camera basis and a splat camera use
/// different ones).
#[inline]
pub fn try_unit<T: Real>(a: [T; 3], min_norm: T) -> Option<[T; 3]> {
    let n = norm(a);
    (n > min_norm && n.is_finite()).then(|| a.map(|x| x / n))
}

/// Unit vector along `a` as `a · (1/|a|)`, or `None` when `a` is
/// (numerically) zero. Multiplying by the reciprocal rounds differently from
/// [`try_unit`]'s division in the last bit; the strand stages have always
/// used this form, and their saved grooms stay bit-identical only with it.
#[inline]
pub fn normalize(a: V3) -> Option<V3> {
    let l = norm(a);
    (l > 1e-20 && l.is_finite()).then(|| scale(a, 1.0 / l))
}

/// `Σ aᵢ bᵢ` in f64 over 8 interleaved lanes (lane `i % 8`), the lanes then
/// added in order: one fixed order (the same bits on every run and thread
/// count) and 8 independent chains, where one sum in order waits on each
/// add. With `b = None`, `Σ aᵢ`.
pub fn lane_sum(a: &[f32], b: Option<&[f32]>) -> f64 {
    let mut lanes = [0.0f64; 8];
    let whole = a.len() / 8 * 8;
    let rest: f64 = match b {
        None => {
            for c in a.chunks_exact(8) {
                lanes.iter_mut().zip(c).for_each(|(l, &x)| *l += x as f64);
            }
            a[whole..].iter().map(|&x| x as f64).sum()
        }
        Some(b) => {
            assert_eq!(a.len(), b.len(), "lane_sum: operand lengths differ");
            for (c, d) in a.chunks_exact(8).zip(b.chunks_exact(8)) {
                lanes.iter_mut().zip(c.iter().zip(d)).for_each(|(l, (&x, &y))| *l += x as f64 * y as f64);
            }
            a[whole..].iter().zip(&b[whole..]).map(|(&x, &y)| x as f64 * y as f64).sum()
        }
    };
    lanes.iter().sum::<f64>() + rest
}

/// SplitMix64 (Steele, Lea & Flood 2014): a tiny, well-mixed, seedable
/// generator, so camera sets and grown strands are reproducible from a seed
/// without an RNG crate. The stream for a seed is part of the saved outputs,
/// so neither the mixing nor the float conversions below may change.
#[derive(Clone, Debug)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    /// Starts the stream at state `seed` (no scrambling; callers that want
    /// unrelated streams for equal seeds xor in their own constant).
    pub fn new(seed: u64) -> Self {
        SplitMix64(seed)
    }

    /// The generator's state: `SplitMix64::new(state())` continues the same
    /// stream (for checkpoints).
    pub fn state(&self) -> u64 {
        self.0
    }

    /// Next 64 random bits.
    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `[0, 1)` from the top 24 bits, exact in `f32`.
    #[inline]
    pub fn uniform_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Uniform in `[0, 1)` from the top 53 bits, exact in `f64` (for CDF
    /// look-ups and sphere sampling, where 24 bits would show as banding).
    #[inline]
    pub fn uniform_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Standard normal (Box–Muller in `f64`, one draw per call).
    pub fn normal(&mut self) -> f32 {
        let u1 = (1.0 - self.uniform_f64()).max(1e-300);
        let u2 = self.uniform_f64();
        ((-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()) as f32
    }

    /// Uniform direction on the unit sphere (a normalised Gaussian triple,
    /// redrawn in the vanishingly rare zero case).
    pub fn unit_vector(&mut self) -> V3 {
        loop {
            let v = [self.normal(), self.normal(), self.normal()];
            if let Some(u) = normalize(v) {
                return u;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    /// The lane sum agrees with a plain f64 sum and dot product, with and
    /// without a remainder past the last 8.
    #[test]
    fn lane_sum_is_the_sum() {
        for n in [0usize, 5, 8, 29] {
            let a: Vec<f32> = (0..n).map(|i| 0.3 * i as f32 - 2.0).collect();
            let b: Vec<f32> = (0..n).map(|i| 1.0 / (1.0 + i as f32)).collect();
            let sum: f64 = a.iter().map(|&x| x as f64).sum();
            let dot: f64 = a.iter().zip(&b).map(|(&x, &y)| x as f64 * y as f64).sum();
            assert!((lane_sum(&a, None) - sum).abs() < 1e-9, "{n}");
            assert!((lane_sum(&a, Some(&b)) - dot).abs() < 1e-9, "{n}");
        }
    }

    use super::*;

    /// The reference SplitMix64 output for seed 1234567 (Vigna's
    /// `splitmix64.c`), so the stream cannot drift.
    #[test]
    fn splitmix64_matches_reference_stream() {
        let mut r = SplitMix64::new(1234567);
        let got: Vec<u64> = (0..5).map(|_| r.next_u64()).collect();
        assert_eq!(
            got,
            [6457827717110365317, 3203168211198807973, 9817491932198370423, 4593380528125082431, 16408922859458223821]
        );
    }

    /// The camera sampler used to convert with `* (1 / 2^53)` and the strand
    /// sampler with `/ 2^53`. Both are exact (a 53-bit integer is exact in
    /// `f64` and scaling by a power of two only moves the exponent), so
    /// [`SplitMix64::uniform_f64`] serves both; this pins that equality.
    #[test]
    fn uniform_f64_equals_multiplication_by_two_to_minus_53() {
        let mut r = SplitMix64::new(42);
        let edge = [0u64, 1 << 11, u64::MAX, u64::MAX - (1 << 11), 1 << 63];
        for x in edge.into_iter().chain((0..200_000).map(|_| r.next_u64())) {
            let div = (x >> 11) as f64 / (1u64 << 53) as f64;
            let mul = (x >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
            assert_eq!(div.to_bits(), mul.to_bits(), "{x}");
        }
    }

    #[test]
    fn normalize_and_try_unit() {
        assert_eq!(normalize([0.0; 3]), None);
        assert_eq!(try_unit([1e-7f32, 0.0, 0.0], 1e-6), None);
        assert_eq!(try_unit([3.0f64, 0.0, 4.0], 1e-12), Some([0.6, 0.0, 0.8]));
        assert_eq!(normalize([0.0, 2.0, 0.0]), Some([0.0, 1.0, 0.0]));
    }
}
