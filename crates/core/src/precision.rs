//! Which arithmetic the heavy products run in: the one `--precision`
//! setting (`auto`, `bf16`, `fp32`) of every front end, resolved against
//! what this CPU and kernel grant.
//!
//! `bf16` means bf16 operands with fp32 accumulation (`bf16 × bf16 → f32`
//! sums): AMX-BF16 tiles where the CPU has them and Linux grants the tile
//! data (`arch_prctl`), AVX512-BF16 dot products where only those exist,
//! and a portable emulation (same roundings, scalar loops) elsewhere —
//! slow, but it lets a blade without either run and test the bf16 numerics.
//! `auto` is bf16 where the CPU has AMX and fp32 otherwise: on a CPU with
//! AVX512-BF16 but no AMX the bf16 path was measured 1.3–2.7x *slower*
//! than fp32 (the fp32 convolutions are Winograd, `vdpbf16ps` only doubles
//! the FMA's width; docs/design/performance.md), so there
//! `bf16` must be asked for. The 3D network's convolutions are the
//! exception ([`path_for`]): their direct bf16 kernels beat fp32 on
//! AVX512-BF16 as well.
//! `fp32` is the reference every finite-difference check runs on.
//!
//! The setting is process-wide (a job runs one precision); a thread may
//! override it for the calls it makes ([`scoped`]), which is how tests
//! compare both paths in one process. `NST3D_PRECISION` sets the process
//! default for wrappers that cannot pass a flag; `NST3D_NO_AMX` hides the
//! tiles (to exercise the AVX512-BF16 path on an AMX machine) and
//! `NST3D_NO_AVX512` hides AVX-512 as it does for the fp32 kernels.

use std::cell::Cell;
use std::fmt;
use std::str::FromStr;
use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::OnceLock;

/// The user's choice.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Precision {
    /// bf16 where the CPU has AMX-BF16 tiles, fp32 otherwise (AVX512-BF16
    /// alone is slower than fp32 here), except the 3D network's
    /// convolutions, bf16 on any bf16 unit ([`path_for`]).
    #[default]
    Auto,
    /// bf16 operands, fp32 accumulation, on whatever path the CPU has
    /// (emulated where it has none).
    Bf16,
    /// fp32 everywhere: the reference.
    Fp32,
}

impl Precision {
    /// Every accepted value, as written on the command line.
    pub const NAMES: [&'static str; 3] = ["auto", "bf16", "fp32"];

    fn code(self) -> u8 {
        match self {
            Precision::Auto => 1,
            Precision::Bf16 => 2,
            Precision::Fp32 => 3,
        }
    }

    fn from_code(c: u8) -> Option<Self> {
        match c {
            1 => Some(Precision::Auto),
            2 => Some(Precision::Bf16),
            3 => Some(Precision::Fp32),
            _ => None,
        }
    }

    /// The path this choice runs on this machine.
    pub fn resolve(self) -> Path {
        let hw = hardware();
        match self {
            Precision::Fp32 => Path::Fp32,
            Precision::Auto => match hw {
                Some(Path::Bf16Amx) => Path::Bf16Amx,
                _ => Path::Fp32,
            },
            Precision::Bf16 => hw.unwrap_or(Path::Bf16Portable),
        }
    }
}

impl fmt::Display for Precision {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(Self::NAMES[self.code() as usize - 1])
    }
}

impl FromStr for Precision {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "auto" => Ok(Precision::Auto),
            "bf16" => Ok(Precision::Bf16),
            "fp32" => Ok(Precision::Fp32),
            _ => Err(format!("unknown precision '{s}' (expected one of: auto, bf16, fp32)")),
        }
    }
}

/// The arithmetic a product actually runs in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Path {
    /// fp32 kernels (AVX-512 or portable): the reference.
    Fp32,
    /// bf16 on AMX tiles (`tdpbf16ps`).
    Bf16Amx,
    /// bf16 on AVX512-BF16 dot products (`vdpbf16ps`).
    Bf16Avx512,
    /// bf16 roundings emulated in scalar code (no bf16 unit).
    Bf16Portable,
}

impl Path {
    /// The bf16 block kernel this path runs on (`None` for fp32).
    pub fn kernel(self) -> Option<crate::bf16::Kernel> {
        use crate::bf16::Kernel;
        match self {
            Path::Fp32 => None,
            Path::Bf16Amx => Some(Kernel::Amx),
            Path::Bf16Avx512 => Some(Kernel::Avx512),
            Path::Bf16Portable => Some(Kernel::without_unit()),
        }
    }

    /// Whether operands are rounded to bf16.
    pub fn is_bf16(self) -> bool {
        self != Path::Fp32
    }

    /// What a run's header says.
    pub fn describe(self) -> &'static str {
        match self {
            Path::Fp32 => "fp32",
            Path::Bf16Amx => "bf16 (AMX-BF16 tiles, fp32 accumulation)",
            Path::Bf16Avx512 => "bf16 (AVX512-BF16, fp32 accumulation)",
            Path::Bf16Portable => "bf16 (emulated: this CPU has no bf16 unit, so no faster than fp32)",
        }
    }
}

/// The fastest bf16 path this process may use, if any (probed once).
pub fn hardware() -> Option<Path> {
    static HW: OnceLock<Option<Path>> = OnceLock::new();
    *HW.get_or_init(|| {
        use crate::bf16::{self, Kernel};
        let no_avx512 = std::env::var_os("NST3D_NO_AVX512").is_some();
        if !no_avx512
            && std::env::var_os("NST3D_NO_AMX").is_none()
            && bf16::amx::available()
            && bf16::self_check(Kernel::Amx)
        {
            Some(Path::Bf16Amx)
        } else if !no_avx512 && bf16::avx512_bf16_available() && bf16::self_check(Kernel::Avx512) {
            Some(Path::Bf16Avx512)
        } else {
            None
        }
    })
}

static PROCESS: AtomicU8 = AtomicU8::new(0);
thread_local! {
    static THIS_THREAD: Cell<u8> = const { Cell::new(0) };
}

/// Sets the process-wide choice (front ends, once, before a job).
pub fn set(p: Precision) {
    PROCESS.store(p.code(), Ordering::Relaxed);
}

/// The choice in force for calls made on this thread: a [`scoped`]
/// override, else [`set`], else `NST3D_PRECISION`, else `auto`.
pub fn current() -> Precision {
    if let Some(p) = Precision::from_code(THIS_THREAD.with(Cell::get)) {
        return p;
    }
    if let Some(p) = Precision::from_code(PROCESS.load(Ordering::Relaxed)) {
        return p;
    }
    from_env().unwrap_or_default()
}

/// `NST3D_PRECISION`, if set to a valid value (read once). An invalid value
/// is reported by [`check_env`].
fn from_env() -> Option<Precision> {
    static ENV: OnceLock<Option<Precision>> = OnceLock::new();
    *ENV.get_or_init(|| std::env::var("NST3D_PRECISION").ok().and_then(|v| v.parse().ok()))
}

/// An error naming a bad `NST3D_PRECISION` (front ends call this at start).
pub fn check_env() -> Result<(), String> {
    match std::env::var("NST3D_PRECISION") {
        Ok(v) => v.parse::<Precision>().map(|_| ()).map_err(|e| format!("NST3D_PRECISION: {e}")),
        Err(_) => Ok(()),
    }
}

/// The path the current choice runs on.
pub fn path() -> Path {
    current().resolve()
}

/// Products whose `auto` differs from the other products'
/// (docs/design/performance.md).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Product {
    /// The 3D network's convolutions: direct kernels on `vdpbf16ps`, which
    /// measured faster than their fp32 twins on an AVX512-BF16 CPU without
    /// AMX too, so `auto` takes bf16 wherever the CPU has a bf16 unit.
    Conv3d,
}

/// The path `product` runs on: [`path`], except that `auto` runs the 3D
/// network's convolutions in bf16 on any bf16 unit (AMX or AVX512-BF16).
pub fn path_for(product: Product) -> Path {
    match (current(), product) {
        (Precision::Auto, Product::Conv3d) => hardware().unwrap_or(Path::Fp32),
        (p, _) => p.resolve(),
    }
}

/// Runs `f` with this thread's choice overridden (for tests and for a
/// caller comparing precisions). Work `f` hands to other threads sees the
/// process-wide choice unless the kernel decided on this thread first, as
/// every nst3d kernel does.
pub fn scoped<R>(p: Precision, f: impl FnOnce() -> R) -> R {
    struct Restore(u8);
    impl Drop for Restore {
        fn drop(&mut self) {
            THIS_THREAD.with(|c| c.set(self.0));
        }
    }
    let _restore = Restore(THIS_THREAD.with(|c| c.replace(p.code())));
    f()
}

/// [`scoped`] to fp32: how a test of the fp32 reference (a finite-difference
/// check, a PyTorch fixture) pins its path whatever the process runs.
pub fn fp32<R>(f: impl FnOnce() -> R) -> R {
    scoped(Precision::Fp32, f)
}

#[cfg(test)]
mod tests {
    #[test]
    fn auto_runs_the_3d_network_on_any_bf16_unit() {
        use super::*;
        assert_eq!(scoped(Precision::Auto, || path_for(Product::Conv3d)), hardware().unwrap_or(Path::Fp32));
        assert_eq!(scoped(Precision::Fp32, || path_for(Product::Conv3d)), Path::Fp32);
        assert_eq!(scoped(Precision::Bf16, || path_for(Product::Conv3d)), Precision::Bf16.resolve());
        assert_ne!(Precision::Bf16.resolve(), Path::Fp32);
    }

    use super::*;

    #[test]
    fn parses_and_prints_every_name() {
        for n in Precision::NAMES {
            assert_eq!(n.parse::<Precision>().unwrap().to_string(), n);
        }
        assert!("half".parse::<Precision>().unwrap_err().contains("auto, bf16, fp32"));
    }

    #[test]
    fn fp32_is_always_fp32_and_bf16_always_bf16() {
        assert_eq!(Precision::Fp32.resolve(), Path::Fp32);
        assert!(Precision::Bf16.resolve().is_bf16());
        assert_eq!(Precision::Auto.resolve().is_bf16(), hardware() == Some(Path::Bf16Amx));
    }

    #[test]
    fn scoped_overrides_and_restores() {
        let before = current();
        scoped(Precision::Fp32, || {
            assert_eq!(path(), Path::Fp32);
            scoped(Precision::Bf16, || assert!(path().is_bf16()));
            assert_eq!(current(), Precision::Fp32);
        });
        assert_eq!(current(), before);
    }
}
