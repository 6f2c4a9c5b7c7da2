//! Summary statistics the judges and benchmarks share.

use std::cmp::Ordering;
use std::ops::{Add, Mul};

/// A float type [`median`] works on (`f32` or `f64`).
pub trait Float: Copy + Add<Output = Self> + Mul<Output = Self> {
    /// One half.
    const HALF: Self;
    /// Not a number: the median of nothing.
    const NAN: Self;
    /// IEEE total order (`f32::total_cmp`).
    fn total_order(&self, other: &Self) -> Ordering;
}

impl Float for f32 {
    const HALF: Self = 0.5;
    const NAN: Self = f32::NAN;
    fn total_order(&self, other: &Self) -> Ordering {
        self.total_cmp(other)
    }
}

impl Float for f64 {
    const HALF: Self = 0.5;
    const NAN: Self = f64::NAN;
    fn total_order(&self, other: &Self) -> Ordering {
        self.total_cmp(other)
    }
}

/// Median of `values` as Python's `statistics.median` computes it (the mean
/// of the middle two for an even count), so benchmark figures compare with
/// the PyTorch peers'; NaN for no values.
pub fn median<T: Float>(values: &[T]) -> T {
    let mut v = values.to_vec();
    v.sort_by(T::total_order);
    match v.len() {
        0 => T::NAN,
        n if n % 2 == 1 => v[n / 2],
        n => T::HALF * (v[n / 2 - 1] + v[n / 2]),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_of_odd_and_even_counts() {
        assert_eq!(median(&[3.0f32, 1.0, 2.0]), 2.0);
        assert_eq!(median(&[4.0f64, 1.0, 3.0, 2.0]), 2.5);
        assert!(median::<f32>(&[]).is_nan());
    }
}
