//! Reading the small PyTorch fixtures tests compare against: raw
//! little-endian `f32` files under a crate's `tests/fixtures/`, made once by a
//! script in `tools/fixtures/`.

use std::path::Path;

/// Reads `<crate_dir>/tests/fixtures/<name>` as `f32` values. Panics with the
/// script to run when the file is missing: a test never skips silently.
pub fn load_f32(crate_dir: &str, name: &str, script: &str) -> Vec<f32> {
    let path = Path::new(crate_dir).join("tests/fixtures").join(name);
    let bytes =
        std::fs::read(&path).unwrap_or_else(|e| panic!("missing fixture {} ({e}); run {script}", path.display()));
    bytes.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect()
}

/// Splits `data` into consecutive arrays of the given lengths (the fixture's
/// sections); panics if the lengths do not add up to the whole file.
pub fn split<'a>(mut data: &'a [f32], lens: &[usize]) -> Vec<&'a [f32]> {
    assert_eq!(data.len(), lens.iter().sum::<usize>(), "fixture size");
    lens.iter()
        .map(|&n| {
            let (a, b) = data.split_at(n);
            data = b;
            a
        })
        .collect()
}

/// Asserts `|got - want| <= tol · (1 + |want|)` element-wise.
pub fn assert_close(got: &[f32], want: &[f32], tol: f32, what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    for (i, (a, b)) in got.iter().zip(want).enumerate() {
        assert!((a - b).abs() <= tol * (1.0 + b.abs()), "{what}[{i}]: {a} vs torch {b}");
    }
}
