//! The three checkpoint formats, read against values PyTorch wrote
//! (tools/fixtures/weights_formats.py), and robustness against corrupt input.

use std::path::{Path, PathBuf};

use nst3d_weights::{detect_format, load_tensors, parse_as, parse_tensors, TensorMap, WeightsError, WeightsFormat};

fn fixture(name: &str) -> PathBuf {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures").join(name);
    assert!(path.is_file(), "fixture {} missing: run `python tools/fixtures/weights_formats.py`", path.display());
    path
}

fn read(name: &str) -> Vec<u8> {
    std::fs::read(fixture(name)).expect("fixture readable")
}

/// `state_expected.json`: shape and f32 bit patterns per key.
fn expected() -> Vec<(String, Vec<usize>, Vec<u32>)> {
    let text = std::fs::read_to_string(fixture("state_expected.json")).expect("fixture readable");
    let json: serde_json::Map<String, serde_json::Value> = serde_json::from_str(&text).expect("valid JSON");
    json.into_iter()
        .map(|(k, v)| {
            let nums = |f: &str| -> Vec<u64> { v[f].as_array().unwrap().iter().map(|x| x.as_u64().unwrap()).collect() };
            let shape = nums("shape").into_iter().map(|n| n as usize).collect();
            let bits = nums("bits").into_iter().map(|n| n as u32).collect();
            (k, shape, bits)
        })
        .collect()
}

fn assert_matches_expected(map: &TensorMap, what: &str) {
    let want = expected();
    assert_eq!(map.len(), want.len(), "{what}: keys {:?}", map.keys().collect::<Vec<_>>());
    for (key, shape, bits) in want {
        let t = map.get(&key).unwrap_or_else(|| panic!("{what}: {key} missing"));
        assert_eq!(t.shape, shape, "{what}: shape of {key}");
        let got: Vec<u32> = t.data.iter().map(|v| v.to_bits()).collect();
        assert_eq!(got, bits, "{what}: values of {key}");
    }
}

#[test]
fn legacy_zip_and_safetensors_match_pytorch() {
    for (name, format) in [
        ("state_legacy.pth", WeightsFormat::LegacyPth),
        ("state_zip.pth", WeightsFormat::ZipPth),
        ("state.safetensors", WeightsFormat::Safetensors),
    ] {
        assert_eq!(detect_format(&read(name)), Some(format), "{name}");
        let map = load_tensors(&fixture(name)).unwrap_or_else(|e| panic!("{e}"));
        assert_matches_expected(&map, name);
    }
}

#[test]
fn zip_archive_folder_name_does_not_matter() {
    // The fixture's folder is `state_zip/`; the same bytes under another file name load.
    let dir = tempfile::tempdir().unwrap();
    let renamed = dir.path().join("renamed.bin");
    std::fs::copy(fixture("state_zip.pth"), &renamed).unwrap();
    let map = load_tensors(&renamed).unwrap();
    assert_matches_expected(&map, "renamed zip");
}

#[test]
fn nested_checkpoints_flatten_with_dotted_keys() {
    for name in ["nested_legacy.pth", "nested_zip.pth"] {
        let map = load_tensors(&fixture(name)).unwrap_or_else(|e| panic!("{e}"));
        let keys: Vec<&str> = map.keys().map(String::as_str).collect();
        assert_eq!(keys, ["param", "state_dict.inner.b", "state_dict.w"], "{name}");
        assert_eq!(map["state_dict.w"].shape, [2, 3]);
        assert_eq!(map["state_dict.w"].data, [0., 1., 2., 3., 4., 5.]);
        assert_eq!(map["state_dict.inner.b"].data, [1., 1.]);
        assert_eq!(map["param"].data, [0.5, -0.5]);
    }
}

#[test]
fn integer_tensors_are_refused_with_their_type() {
    let err = load_tensors(&fixture("int64_zip.pth")).unwrap_err();
    let msg = err.to_string();
    assert!(msg.contains("int64_zip.pth") && msg.contains("LongStorage") && msg.contains("steps"), "{msg}");
}

#[test]
fn unknown_content_is_refused_whatever_the_extension() {
    let err = parse_tensors(b"hello, not weights", Path::new("x.pth")).unwrap_err();
    assert!(matches!(err, WeightsError::Malformed { .. }));
    assert!(err.to_string().starts_with("x.pth: unrecognised weights format"), "{err}");
    let err = load_tensors(Path::new("/nonexistent/w.pth")).unwrap_err();
    assert!(matches!(err, WeightsError::Io { .. }) && err.to_string().contains("/nonexistent/w.pth"), "{err}");
}

/// A small deterministic generator (xorshift64*), so failures reproduce.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
}

/// Parses corrupt bytes: any outcome but a panic is fine, and an error is one line
/// that names the file.
fn parse_corrupt(bytes: &[u8], what: &str) {
    let path = Path::new("corrupt.pth");
    let results = [
        parse_tensors(bytes, path),
        parse_as(WeightsFormat::LegacyPth, bytes, path),
        parse_as(WeightsFormat::ZipPth, bytes, path),
        parse_as(WeightsFormat::Safetensors, bytes, path),
    ];
    for r in results {
        if let Err(e) = r {
            let msg = e.to_string();
            assert!(msg.starts_with("corrupt.pth: ") && !msg.contains('\n'), "{what}: {msg}");
        }
    }
}

#[test]
fn every_truncation_is_an_error_not_a_panic() {
    for name in ["state_legacy.pth", "state_zip.pth", "state.safetensors", "nested_legacy.pth", "nested_zip.pth"] {
        let bytes = read(name);
        for len in 0..bytes.len() {
            let cut = &bytes[..len];
            parse_corrupt(cut, name);
            // The legacy format's last storage is the file's end, so a cut always shows;
            // zip and safetensors lose their directory/data.
            assert!(parse_tensors(cut, Path::new(name)).is_err(), "{name} cut to {len} bytes parsed");
        }
    }
}

#[test]
fn corrupted_bytes_never_panic() {
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    for name in ["state_legacy.pth", "state_zip.pth", "state.safetensors", "nested_legacy.pth", "nested_zip.pth"] {
        let clean = read(name);
        for round in 0..3000 {
            let mut bytes = clean.clone();
            for _ in 0..1 + rng.below(4) {
                let at = rng.below(bytes.len());
                bytes[at] = match rng.below(4) {
                    0 => bytes[at] ^ (1 << rng.below(8)),
                    1 => 0xff,
                    2 => 0,
                    _ => rng.next() as u8,
                };
            }
            parse_corrupt(&bytes, &format!("{name} round {round}"));
        }
    }
}

#[test]
fn random_bytes_behind_valid_magic_never_panic() {
    let mut rng = Rng(12345);
    // Pickle opcodes torch uses, so random soup reaches deep into the VM.
    let opcodes = b"\x80cqrhj(}])t\x85\x86\x87sueaJKM\x8aXQRb\x88\x89NG.\x8c\x93\x94\x95";
    let prefixes: [&[u8]; 4] = [
        &[0x80, 0x02, 0x8a, 0x0a, 0x6c, 0xfc, 0x9c, 0x46, 0xf9, 0x20, 0x6a, 0xa8, 0x50, 0x19, 0x2e],
        b"PK\x03\x04",
        &[16, 0, 0, 0, 0, 0, 0, 0, b'{'],
        b"",
    ];
    for round in 0..20_000 {
        let mut bytes = prefixes[round % prefixes.len()].to_vec();
        let n = rng.below(200);
        for _ in 0..n {
            let b = if rng.below(3) == 0 { rng.next() as u8 } else { opcodes[rng.below(opcodes.len())] };
            bytes.push(b);
        }
        parse_corrupt(&bytes, &format!("random round {round}"));
    }
}

#[test]
fn legacy_pickle_soup_after_the_header_never_panics() {
    // Keep the legacy file's first three pickles intact and randomise the rest, which
    // puts the VM to work on the state-dict pickle itself.
    let clean = read("state_legacy.pth");
    let header_end = {
        let mut n = 0;
        let mut stops = 0;
        while stops < 3 {
            if clean[n] == b'.' {
                stops += 1;
            }
            n += 1;
        }
        n
    };
    let mut rng = Rng(777);
    for round in 0..5000 {
        let mut bytes = clean[..header_end].to_vec();
        // Splice: a random slice of the real object pickle, repeated and shuffled.
        for _ in 0..1 + rng.below(6) {
            let a = header_end + rng.below(clean.len() - header_end);
            let b = (a + rng.below(64)).min(clean.len());
            bytes.extend_from_slice(&clean[a..b]);
        }
        parse_corrupt(&bytes, &format!("soup round {round}"));
    }
}

#[test]
fn hostile_sizes_are_refused_without_allocating() {
    // A safetensors header claiming an enormous tensor inside a tiny file.
    let header = br#"{"w":{"dtype":"F32","shape":[4294967296,4294967296],"data_offsets":[0,16]}}"#;
    let mut bytes = (header.len() as u64).to_le_bytes().to_vec();
    bytes.extend_from_slice(header);
    bytes.extend_from_slice(&[0u8; 16]);
    let err = parse_tensors(&bytes, Path::new("huge.safetensors")).unwrap_err().to_string();
    assert!(err.contains("huge.safetensors") && err.contains("overflow"), "{err}");

    // A header length pointing past the end.
    let mut bytes = u64::MAX.to_le_bytes().to_vec();
    bytes.push(b'{');
    assert!(parse_as(WeightsFormat::Safetensors, &bytes, Path::new("h")).is_err());
}
