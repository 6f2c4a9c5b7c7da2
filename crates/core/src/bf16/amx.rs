//! AMX-BF16 from stable Rust: the instructions written out in `asm!`
//! (their intrinsics are not stable), as `../shared/notes/amx.md` verified.
//!
//! Linux hands tile data to a process only on request
//! (`arch_prctl(ARCH_REQ_XCOMP_PERM, XFEATURE_XTILEDATA)`), once; without it
//! the first tile instruction faults, so [`available`] asks before saying
//! yes. Every tile this module names is configured the same way, 16 rows of
//! 64 bytes (16 × 16 f32 accumulators, 16 × 32 bf16 operands), so one
//! `ldtilecfg` per task serves every block:
//!
//! - `tmm0..tmm3`: the 2 × 2 accumulators of a 32 × 32 block,
//! - `tmm4, tmm5`: the two A halves (16 rows × 32 bf16 each),
//! - `tmm6, tmm7`: the two B tiles (VNNI pairs, 16 columns each).

/// Whether AMX-BF16 may be used: the CPU has it and Linux granted the tile
/// data to this process (asked once).
pub fn available() -> bool {
    #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
    {
        use std::sync::OnceLock;
        static OK: OnceLock<bool> = OnceLock::new();
        *OK.get_or_init(|| cpu_has_amx_bf16() && request_tile_data())
    }
    #[cfg(not(all(target_arch = "x86_64", target_os = "linux")))]
    {
        false
    }
}

/// CPUID leaf 7: EDX bit 22 (AMX-BF16) and bit 24 (AMX-TILE).
#[cfg(target_arch = "x86_64")]
fn cpu_has_amx_bf16() -> bool {
    use std::arch::x86_64::{__cpuid, __cpuid_count};
    // SAFETY: CPUID exists on every x86_64 CPU.
    let max_leaf = __cpuid(0).eax;
    if max_leaf < 7 {
        return false;
    }
    let edx = __cpuid_count(7, 0).edx;
    edx & (1 << 22) != 0 && edx & (1 << 24) != 0
}

/// `arch_prctl(ARCH_REQ_XCOMP_PERM, XFEATURE_XTILEDATA)`; true when granted.
#[cfg(all(target_arch = "x86_64", target_os = "linux"))]
fn request_tile_data() -> bool {
    const SYS_ARCH_PRCTL: i64 = 158;
    const ARCH_REQ_XCOMP_PERM: i64 = 0x1023;
    const XFEATURE_XTILEDATA: i64 = 18;
    let ret: i64;
    // SAFETY: a plain system call with integer arguments; it changes only
    // this process's permission to use tile state.
    unsafe {
        std::arch::asm!(
            "syscall",
            inlateout("rax") SYS_ARCH_PRCTL => ret,
            in("rdi") ARCH_REQ_XCOMP_PERM,
            in("rsi") XFEATURE_XTILEDATA,
            lateout("rcx") _,
            lateout("r11") _,
            options(nostack),
        );
    }
    ret == 0
}

/// The palette-1 configuration: all eight tiles 16 rows × 64 bytes.
#[repr(C, align(64))]
struct TileConfig([u8; 64]);

const CONFIG: TileConfig = {
    let mut c = [0u8; 64];
    c[0] = 1;
    let mut t = 0;
    while t < 8 {
        c[16 + 2 * t] = 64;
        c[48 + t] = 16;
        t += 1;
    }
    TileConfig(c)
};

/// Runs `f` with the tiles configured on this thread, releasing them after
/// (also when `f` panics). Callers have checked [`available`].
pub(crate) fn with_tiles<R>(f: impl FnOnce() -> R) -> R {
    assert!(available(), "AMX used without permission");
    struct Release;
    impl Drop for Release {
        fn drop(&mut self) {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: releasing tiles is always allowed once configured.
            unsafe {
                std::arch::asm!("tilerelease", options(nostack, nomem));
            }
        }
    }
    #[cfg(target_arch = "x86_64")]
    // SAFETY: AMX is available and permitted (checked above); CONFIG is a
    // valid 64-byte, 64-aligned palette-1 configuration.
    unsafe {
        std::arch::asm!("ldtilecfg [{}]", in(reg) &CONFIG as *const TileConfig, options(nostack, readonly));
    }
    let _release = Release;
    f()
}

/// The 32 × 32 block of [`super::Ready::block`] on tiles.
///
/// # Safety
/// Inside [`with_tiles`] on this thread; operands as [`super::Ready::block`].
#[cfg(target_arch = "x86_64")]
#[inline]
pub(crate) unsafe fn block(
    a0: *const u16,
    a1: *const u16,
    lda: usize,
    offs: &[usize],
    b: *const u16,
    c: *mut f32,
    ldc: usize,
) {
    use std::arch::asm;
    asm!("tilezero tmm0", "tilezero tmm1", "tilezero tmm2", "tilezero tmm3", options(nostack, nomem));
    let lda_bytes = lda * 2;
    let mut bp = b;
    for &o in offs {
        asm!(
            "tileloadd tmm4, [{a0} + {lda}*1]",
            "tileloadd tmm6, [{b0} + {ldb}*1]",
            "tdpbf16ps tmm0, tmm4, tmm6",
            "tileloadd tmm5, [{a1} + {lda}*1]",
            "tdpbf16ps tmm2, tmm5, tmm6",
            "tileloadd tmm7, [{b1} + {ldb}*1]",
            "tdpbf16ps tmm1, tmm4, tmm7",
            "tdpbf16ps tmm3, tmm5, tmm7",
            a0 = in(reg) a0.add(o),
            a1 = in(reg) a1.add(o),
            lda = in(reg) lda_bytes,
            b0 = in(reg) bp,
            b1 = in(reg) bp.add(16 * super::KS),
            ldb = in(reg) 2 * super::KS,
            options(nostack, readonly),
        );
        bp = bp.add(super::B_STEP);
    }
    let ldc_bytes = ldc * 4;
    asm!(
        "tilestored [{c00} + {ldc}*1], tmm0",
        "tilestored [{c01} + {ldc}*1], tmm1",
        "tilestored [{c10} + {ldc}*1], tmm2",
        "tilestored [{c11} + {ldc}*1], tmm3",
        c00 = in(reg) c,
        c01 = in(reg) c.add(16),
        c10 = in(reg) c.add(16 * ldc),
        c11 = in(reg) c.add(16 * ldc + 16),
        ldc = in(reg) ldc_bytes,
        options(nostack),
    );
}

/// The 64 × 16 block of [`super::Ready::block_tall`] on tiles: one B tile
/// a step against four A tiles (`tmm4`, `tmm5`, `tmm7` in turn, so a load
/// need not wait for the product that read the tile before).
///
/// # Safety
/// Inside [`with_tiles`] on this thread; operands as
/// [`super::Ready::block_tall`].
#[cfg(target_arch = "x86_64")]
#[inline]
pub(crate) unsafe fn block_tall(
    a: [*const u16; 4],
    lda: usize,
    offs: &[usize],
    b: *const u16,
    c: *mut f32,
    ldc: usize,
) {
    use std::arch::asm;
    asm!("tilezero tmm0", "tilezero tmm1", "tilezero tmm2", "tilezero tmm3", options(nostack, nomem));
    let lda_bytes = lda * 2;
    let mut bp = b;
    for &o in offs {
        asm!(
            "tileloadd tmm6, [{b} + {ldb}*1]",
            "tileloadd tmm4, [{a0} + {lda}*1]",
            "tdpbf16ps tmm0, tmm4, tmm6",
            "tileloadd tmm5, [{a1} + {lda}*1]",
            "tdpbf16ps tmm1, tmm5, tmm6",
            "tileloadd tmm7, [{a2} + {lda}*1]",
            "tdpbf16ps tmm2, tmm7, tmm6",
            "tileloadd tmm4, [{a3} + {lda}*1]",
            "tdpbf16ps tmm3, tmm4, tmm6",
            a0 = in(reg) a[0].add(o),
            a1 = in(reg) a[1].add(o),
            a2 = in(reg) a[2].add(o),
            a3 = in(reg) a[3].add(o),
            lda = in(reg) lda_bytes,
            b = in(reg) bp,
            ldb = in(reg) 2 * super::KS,
            options(nostack, readonly),
        );
        bp = bp.add(super::TALL_STEP);
    }
    let ldc_bytes = ldc * 4;
    asm!(
        "tilestored [{c0} + {ldc}*1], tmm0",
        "tilestored [{c1} + {ldc}*1], tmm1",
        "tilestored [{c2} + {ldc}*1], tmm2",
        "tilestored [{c3} + {ldc}*1], tmm3",
        c0 = in(reg) c,
        c1 = in(reg) c.add(16 * ldc),
        c2 = in(reg) c.add(32 * ldc),
        c3 = in(reg) c.add(48 * ldc),
        ldc = in(reg) ldc_bytes,
        options(nostack),
    );
}
