//! How much memory this process may still use, so a job whose working set
//! would not fit says so before it starts instead of being killed by the
//! kernel half-way through.

/// How long the allocator (mimalloc, the binary's and the Python module's)
/// keeps freed memory before handing it back to the kernel, in
/// milliseconds. Its default, one second, is shorter than one strand
/// iteration at Short Hair size (~2.3 s): every iteration's feature maps went
/// back and were faulted in and zeroed again: 13 % of a Short Hair frame's
/// CPU time in the kernel's page clearing (docs/design/performance.md). Ten seconds covers any iteration and still
/// returns the memory of a finished job soon after.
pub const ALLOCATOR_PURGE_DELAY_MS: i64 = 10_000;

/// mimalloc's index of its `purge_delay` option (`mi_option_purge_delay`
/// in the v3 `mimalloc.h` that `libmimalloc-sys` 0.1.49 builds; the crate
/// names the options on either side of it, 14 and 16, but not this one).
/// The CLI's tests check that the option at this index starts at
/// mimalloc's documented default of 1000 ms.
pub const MIMALLOC_OPTION_PURGE_DELAY: i32 = 15;

/// Bytes available to this process: the kernel's `MemAvailable`, lowered to
/// what is left under a cgroup v2 `memory.max` (a container or a Slurm job
/// limit) when there is one, and to `NST3D_MEMORY_LIMIT` when set (bytes,
/// or with a K/M/G suffix: a farm slot's share of a blade that has no
/// cgroup limits). `None` where none of these can be read.
pub fn available() -> Option<u64> {
    let limit = std::env::var("NST3D_MEMORY_LIMIT").ok().and_then(|v| parse_size(&v));
    smaller(machine_available(), limit)
}

/// The smaller of two limits, either of which may be unknown.
fn smaller(a: Option<u64>, b: Option<u64>) -> Option<u64> {
    match (a, b) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    }
}

/// `1234`, `512M`, `2G`, `1.5G` (powers of 1000, like the messages print).
fn parse_size(s: &str) -> Option<u64> {
    let s = s.trim();
    let (num, mul) = match s.char_indices().last()? {
        (i, 'K' | 'k') => (&s[..i], 1e3),
        (i, 'M' | 'm') => (&s[..i], 1e6),
        (i, 'G' | 'g') => (&s[..i], 1e9),
        (i, 'T' | 't') => (&s[..i], 1e12),
        _ => (s, 1.0),
    };
    let v: f64 = num.trim().parse().ok()?;
    (v.is_finite() && v >= 0.0).then_some((v * mul) as u64)
}

fn machine_available() -> Option<u64> {
    let meminfo = std::fs::read_to_string("/proc/meminfo").ok();
    let avail = meminfo.as_deref().and_then(|m| {
        m.lines().find(|l| l.starts_with("MemAvailable:"))?.split_whitespace().nth(1)?.parse::<u64>().ok()
    });
    let avail = avail.map(|kib| kib * 1024);
    let read = |p: &str| std::fs::read_to_string(p).ok().and_then(|s| s.trim().parse::<u64>().ok());
    let cgroup = match (read("/sys/fs/cgroup/memory.max"), read("/sys/fs/cgroup/memory.current")) {
        (Some(max), Some(cur)) => Some(max.saturating_sub(cur)),
        _ => None,
    };
    smaller(avail, cgroup)
}

/// `Err` with a message naming both figures when `needed` bytes (an
/// estimate of the job's peak) exceed what is [`available`]; `what` says
/// what the estimate covers and `lower` which settings bring it down.
pub fn check_fits(needed: u64, what: &str, lower: &str) -> Result<(), String> {
    match available() {
        Some(avail) if needed > avail => Err(format!(
            "{what} needs about {:.1} GB of memory at its peak (estimated), {:.1} GB is available: {lower}",
            needed as f64 / 1e9,
            avail as f64 / 1e9
        )),
        _ => Ok(()),
    }
}

/// Peak resident memory of this process in MiB (Linux `VmHWM`), for the
/// benchmarks' memory comparison with their PyTorch peers; 0 where the
/// kernel does not say.
pub fn peak_rss_mb() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1).and_then(|kb| kb.parse::<f64>().ok()))
        })
        .map_or(0.0, |kb| kb / 1024.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_with_suffixes() {
        assert_eq!(parse_size("1234"), Some(1234));
        assert_eq!(parse_size("512M"), Some(512_000_000));
        assert_eq!(parse_size("1.5G"), Some(1_500_000_000));
        assert_eq!(parse_size("lots"), None);
        assert_eq!(parse_size("-1G"), None);
    }

    #[test]
    fn a_need_beyond_the_machine_is_refused_naming_both_figures() {
        let avail = available().expect("this platform reports available memory");
        assert!(avail > 0);
        assert!(check_fits(1 << 20, "a small job", "").is_ok());
        let e = check_fits(u64::MAX / 2, "this job", "lower --render-size").unwrap_err();
        assert!(e.contains("needs about") && e.contains("GB is available: lower --render-size"), "{e}");
    }
}
