//! libFuzzer entry: the reader named by `NST3D_FUZZ_TARGET` (one of
//! `nst3d_fuzz::TARGETS`) on each input.
#![no_main]

use std::sync::OnceLock;

static TARGET: OnceLock<fn(&[u8])> = OnceLock::new();

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let run = TARGET.get_or_init(|| {
        let name = std::env::var("NST3D_FUZZ_TARGET").unwrap_or_default();
        nst3d_fuzz::target(&name).unwrap_or_else(|| {
            let names: Vec<&str> = nst3d_fuzz::TARGETS.iter().map(|t| t.0).collect();
            eprintln!("NST3D_FUZZ_TARGET must name a reader: {}", names.join(", "));
            std::process::exit(2)
        })
    });
    run(data)
});
