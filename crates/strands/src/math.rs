//! Small fixed-size vector helpers; points are `[f32; 3]` like the groom
//! and mesh types, with `f64` used where sums of many terms need it.

pub(crate) type V3 = [f32; 3];

#[inline]
pub(crate) fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
#[inline]
pub(crate) fn add(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
#[inline]
pub(crate) fn scale(a: V3, s: f32) -> V3 {
    [a[0] * s, a[1] * s, a[2] * s]
}
#[inline]
pub(crate) fn dot(a: V3, b: V3) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
#[inline]
pub(crate) fn cross(a: V3, b: V3) -> V3 {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}
#[inline]
pub(crate) fn norm2(a: V3) -> f32 {
    dot(a, a)
}
#[inline]
pub(crate) fn norm(a: V3) -> f32 {
    dot(a, a).sqrt()
}
#[inline]
pub(crate) fn dist2(a: V3, b: V3) -> f32 {
    norm2(sub(a, b))
}
/// Unit vector along `a`, or `None` when `a` is (numerically) zero.
#[inline]
pub(crate) fn normalize(a: V3) -> Option<V3> {
    let l = norm(a);
    (l > 1e-20 && l.is_finite()).then(|| scale(a, 1.0 / l))
}
#[inline]
pub(crate) fn lerp(a: V3, b: V3, t: f32) -> V3 {
    add(a, scale(sub(b, a), t))
}

/// splitmix64: a seedable, dependency-free generator for the deterministic
/// samplers (densification roots, generators).
#[derive(Clone, Debug)]
pub(crate) struct Rng(u64);

impl Rng {
    pub(crate) fn new(seed: u64) -> Self {
        Rng(seed ^ 0x5DEE_CE66_D1CE_4E5B)
    }
    pub(crate) fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in `[0, 1)`.
    pub(crate) fn uniform(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }
    /// Uniform in `[0, 1)` with double precision (for CDF lookups).
    pub(crate) fn uniform_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Standard normal (Box–Muller).
    pub(crate) fn normal(&mut self) -> f32 {
        let u1 = (1.0 - self.uniform_f64()).max(1e-300);
        let u2 = self.uniform_f64();
        ((-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()) as f32
    }
    /// Uniform direction on the unit sphere.
    pub(crate) fn unit_vector(&mut self) -> V3 {
        loop {
            let v = [self.normal(), self.normal(), self.normal()];
            if let Some(u) = normalize(v) {
                return u;
            }
        }
    }
}
