//! Which kernel runs each product of a layer. The precision path says
//! which arithmetic the user asked for; within a bf16 path the layer's shape
//! decides, by measurement (docs/design/performance.md, "Which kernel runs
//! a layer"; `nst3d bench conv3d` takes the table again on any CPU): AMX
//! tiles fill one column of 16 where a layer has one output channel, and
//! there the direct AVX512-BF16 kernel is faster; with one input channel
//! half of every bf16 pair is padding, and fp32 is faster still.

use std::cell::Cell;

use nst3d_core::precision::Path;

use super::direct::Arith;
use super::{kernels, tiles, Conv3d};

/// The kernel one product runs on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Route {
    /// AMX tiles ([`tiles`]).
    Tiles,
    /// The direct AVX-512 kernels in this arithmetic.
    Direct(Arith),
    /// im2col products in the path's arithmetic.
    Im2col,
}

/// Fewest input channels a bf16 forward keeps in bf16 (fewer: fp32).
const BF16_MIN_CIN: usize = 2;

thread_local! {
    /// Set by tests that check a kernel on every shape it can run: the
    /// path's own kernel, whatever the shape.
    static BY_CAPABILITY: Cell<bool> = const { Cell::new(false) };
}

/// Runs `f` with routing by capability alone on this thread (tests).
#[cfg(test)]
pub fn by_capability<R>(f: impl FnOnce() -> R) -> R {
    BY_CAPABILITY.with(|c| c.set(true));
    let r = f();
    BY_CAPABILITY.with(|c| c.set(false));
    r
}

/// The forward's kernel (a stride-1 input gradient is a forward too).
pub fn forward(l: &Conv3d, path: Path, direct: Option<Arith>) -> Route {
    let by_speed = !BY_CAPABILITY.with(Cell::get);
    match direct {
        None => Route::Im2col,
        Some(Arith::Bf16) if by_speed && l.cin < BF16_MIN_CIN && kernels::unit().has_f32() => Route::Direct(Arith::F32),
        Some(Arith::Bf16) if by_speed && l.cout == 1 => Route::Direct(Arith::Bf16),
        Some(Arith::Bf16) if path == Path::Bf16Amx && tiles::takes_forward(l) => Route::Tiles,
        Some(arith) => Route::Direct(arith),
    }
}

/// The weight gradient's kernel.
pub fn weight_grad(l: &Conv3d, path: Path, direct: Option<Arith>) -> Route {
    let by_speed = !BY_CAPABILITY.with(Cell::get);
    match direct {
        None => Route::Im2col,
        Some(Arith::Bf16) if by_speed && l.cout == 1 => Route::Direct(Arith::Bf16),
        Some(Arith::Bf16) if path == Path::Bf16Amx && tiles::takes_weight_grad(l) => Route::Tiles,
        Some(arith) => Route::Direct(arith),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The measured table: on AMX the 3D network's wide layers run on tiles,
    /// its one-channel ends on the direct kernels; fp32 asked is fp32 kept.
    #[test]
    fn layers_take_the_measured_kernels() {
        if !(nst3d_core::bf16::amx::available() && kernels::unit().bf16) {
            eprintln!("no AMX here: the table is for AMX machines");
            return;
        }
        let amx = Some(Arith::Bf16);
        let f = |cin, cout, s| forward(&Conv3d::zeros(cin, cout, 3, s, 1), Path::Bf16Amx, amx);
        let w = |cin, cout, s| weight_grad(&Conv3d::zeros(cin, cout, 3, s, 1), Path::Bf16Amx, amx);
        assert_eq!(f(1, 16, 2), Route::Direct(Arith::F32));
        assert_eq!(f(3, 16, 1), Route::Tiles);
        assert_eq!(f(16, 1, 1), Route::Direct(Arith::Bf16));
        assert_eq!(f(16, 3, 1), Route::Tiles);
        assert_eq!(f(16, 32, 2), Route::Tiles);
        assert_eq!(w(16, 1, 1), Route::Direct(Arith::Bf16));
        assert_eq!(w(16, 16, 1), Route::Tiles);
        assert_eq!(w(16, 32, 2), Route::Direct(Arith::Bf16));
        assert_eq!(forward(&Conv3d::zeros(1, 16, 3, 1, 1), Path::Fp32, Some(Arith::F32)), Route::Direct(Arith::F32));
        by_capability(|| assert_eq!(f(1, 16, 2), Route::Tiles));
    }
}
