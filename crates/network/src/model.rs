//! The model file: a trained network's weights plus what it is, as one
//! `.safetensors` file (the ecosystem's format for weights). The tensors are
//! named after Fig. 9's layers (`e1.weight`, `m3.bias`, ...) in PyTorch's
//! shapes, so `safetensors.torch.load_file` reads them into
//! `torch_ff_ref.py`'s `FeedForward` too; the metadata says the format, the
//! architecture and its widths, and carries the trainer's own keys
//! (painting hash, rotation ranges, steps, version).

use std::collections::BTreeMap;
use std::path::Path;

use crate::feedforward::{FeedForward, LAYERS};
use crate::texture::SolidTexture;

/// The `format` metadata value of nst3d model files.
pub const FORMAT: &str = "nst3d-feedforward-v1";

/// Layer names in [`FeedForward::layers`]' order.
pub const LAYER_NAMES: [&str; LAYERS] = ["e1", "e2", "m1", "m2", "m3", "m4", "d1", "d2", "last"];

/// A trained network and its description.
#[derive(Clone, Debug, PartialEq)]
pub struct Model {
    /// The weights.
    pub net: FeedForward,
    /// The learned solid texture multiplied into the result, if the model
    /// was trained with one (tensor `texture`, `P × P × P`; metadata
    /// `texture_period`).
    pub texture: Option<SolidTexture>,
    /// String metadata beyond the architecture (the trainer's keys).
    pub info: BTreeMap<String, String>,
}

/// Why a model file could not be used; the message names the file.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// Not readable as a safetensors file at all.
    #[error(transparent)]
    Weights(#[from] nst3d_weights::WeightsError),
    /// A safetensors file, but not a usable nst3d model.
    #[error("{path}: {problem}")]
    Invalid {
        /// The file.
        path: String,
        /// What is wrong with it.
        problem: String,
    },
}

impl Model {
    /// The file's bytes: tensors in layer order, then metadata (`format`,
    /// `architecture`, `channels`, `out_channels` and [`Model::info`]).
    pub fn to_bytes(&self) -> Vec<u8> {
        let tensors = self.tensors();
        let tensors: Vec<(&str, &[usize], &[f32])> =
            tensors.iter().map(|(n, shape, data)| (n.as_str(), shape.as_slice(), *data)).collect();
        nst3d_weights::safetensors_bytes(&tensors, &self.metadata())
    }

    /// The weights by name (`e1.weight`, `e1.bias`, ...), in layer order,
    /// with their PyTorch shapes.
    pub fn tensors(&self) -> Vec<(String, Vec<usize>, &[f32])> {
        let mut out = Vec::with_capacity(2 * LAYER_NAMES.len());
        for (l, name) in self.net.layers.iter().zip(LAYER_NAMES) {
            out.push((format!("{name}.weight"), vec![l.cout, l.cin, l.k, l.k, l.k], &l.weight[..]));
            out.push((format!("{name}.bias"), vec![l.cout], &l.bias[..]));
        }
        if let Some(t) = &self.texture {
            out.push((TEXTURE.to_string(), vec![t.period; 3], &t.values[..]));
        }
        out
    }

    /// The file's metadata: `format`, `architecture`, `channels`,
    /// `out_channels` and [`Model::info`].
    pub fn metadata(&self) -> BTreeMap<String, String> {
        let mut meta = self.info.clone();
        meta.insert("format".into(), FORMAT.into());
        meta.insert("architecture".into(), "volumetric-style-transfer fig9".into());
        meta.insert("channels".into(), self.net.layers[0].cout.to_string());
        meta.insert("out_channels".into(), self.net.out_channels().to_string());
        if let Some(t) = &self.texture {
            meta.insert(TEXTURE_PERIOD.into(), t.period.to_string());
        }
        meta
    }

    /// Reads a model file's bytes; `source` names it in errors. Refuses
    /// files of another format, a network of other shapes than its metadata
    /// says, and non-finite weights.
    pub fn from_bytes(bytes: &[u8], source: &Path) -> Result<Model, ModelError> {
        let (tensors, info) = nst3d_weights::parse_safetensors(bytes, source)?;
        Self::from_parts(&tensors, info, source)
    }

    /// A model from the tensors and metadata of [`Model::tensors`] and
    /// [`Model::metadata`], checked as [`Model::from_bytes`] checks a file;
    /// `source` names them in errors.
    pub fn from_parts(
        tensors: &nst3d_weights::TensorMap,
        mut info: BTreeMap<String, String>,
        source: &Path,
    ) -> Result<Model, ModelError> {
        let invalid = |problem: String| ModelError::Invalid { path: source.display().to_string(), problem };
        match info.get("format").map(String::as_str) {
            Some(FORMAT) => {}
            Some(other) => return Err(invalid(format!("model format '{other}', this nst3d reads '{FORMAT}'"))),
            None => return Err(invalid("a .safetensors file, but not an nst3d model (no 'format' metadata)".into())),
        }
        let number = |key: &str| -> Result<usize, ModelError> {
            info.get(key)
                .and_then(|v| v.parse().ok())
                .filter(|&v| (1..=1024).contains(&v))
                .ok_or_else(|| invalid(format!("metadata '{key}' is missing or not a width from 1 to 1024")))
        };
        let (c, out) = (number("channels")?, number("out_channels")?);
        // Every tensor is checked against the widths before a network of
        // those widths is made: a small file claiming 1024 channels must not
        // cost a gigabyte.
        let mut found = Vec::with_capacity(2 * LAYER_NAMES.len());
        for (&(cin, cout, k, _, _), name) in FeedForward::layer_shapes(c, out).iter().zip(LAYER_NAMES) {
            for (suffix, shape) in [("weight", vec![cout, cin, k, k, k]), ("bias", vec![cout])] {
                let key = format!("{name}.{suffix}");
                let t = tensors.get(&key).ok_or_else(|| invalid(format!("tensor {key} is missing")))?;
                if t.shape != shape {
                    return Err(invalid(format!(
                        "tensor {key} has shape {:?}, the metadata's widths (channels {c}) need {shape:?}",
                        t.shape
                    )));
                }
                if let Some(i) = t.data.iter().position(|v| !v.is_finite()) {
                    return Err(invalid(format!("tensor {key} holds a non-finite weight at {i}")));
                }
                found.push(&t.data);
            }
        }
        let mut net = FeedForward::new(c, out, 0);
        let slots = net.layers.iter_mut().flat_map(|l| [&mut l.weight, &mut l.bias]);
        for (dst, src) in slots.zip(found) {
            dst.copy_from_slice(src);
        }
        let texture = texture_from(tensors, &info).map_err(invalid)?;
        for key in ["format", "architecture", "channels", "out_channels", TEXTURE_PERIOD] {
            info.remove(key);
        }
        Ok(Model { net, texture, info })
    }
}

/// Name of the solid texture's tensor.
pub const TEXTURE: &str = "texture";
/// Metadata key of the solid texture's period.
pub const TEXTURE_PERIOD: &str = "texture_period";

/// The solid texture the metadata declares, checked against its tensor
/// (none when the metadata names no period; a texture tensor without one is
/// refused rather than silently ignored).
fn texture_from(
    tensors: &nst3d_weights::TensorMap,
    info: &BTreeMap<String, String>,
) -> Result<Option<SolidTexture>, String> {
    let Some(period) = info.get(TEXTURE_PERIOD) else {
        return match tensors.contains_key(TEXTURE) {
            true => Err(format!("tensor {TEXTURE} without the metadata '{TEXTURE_PERIOD}'")),
            false => Ok(None),
        };
    };
    let period: usize = period
        .parse()
        .ok()
        .filter(|p| (1..=256).contains(p))
        .ok_or_else(|| format!("metadata '{TEXTURE_PERIOD}' is not a period from 1 to 256"))?;
    let t = tensors.get(TEXTURE).ok_or_else(|| format!("tensor {TEXTURE} is missing"))?;
    if t.shape != [period; 3] {
        return Err(format!("tensor {TEXTURE} has shape {:?}, the period {period} needs {:?}", t.shape, [period; 3]));
    }
    if let Some(i) = t.data.iter().position(|v| !v.is_finite()) {
        return Err(format!("tensor {TEXTURE} holds a non-finite value at {i}"));
    }
    Ok(Some(SolidTexture { period, values: t.data.clone() }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_refusals() {
        let mut info = BTreeMap::new();
        info.insert("mode".to_string(), "density".to_string());
        let m = Model { net: FeedForward::new(3, 1, 9), texture: None, info };
        let bytes = m.to_bytes();
        let p = Path::new("m.safetensors");
        assert_eq!(Model::from_bytes(&bytes, p).unwrap(), m);

        // Another format, truncation, a NaN and wrong widths each say what is wrong.
        let e = Model::from_bytes(&bytes[..bytes.len() / 2], p).unwrap_err().to_string();
        assert!(e.contains("m.safetensors"), "{e}");
        let mut nan = m.clone();
        nan.net.layers[4].weight[7] = f32::NAN;
        let e = Model::from_bytes(&nan.to_bytes(), p).unwrap_err().to_string();
        assert!(e.contains("m3.weight") && e.contains("non-finite"), "{e}");
        let foreign = nst3d_weights::safetensors_bytes(&[("x", &[1], &[1.0])], &BTreeMap::new());
        let e = Model::from_bytes(&foreign, p).unwrap_err().to_string();
        assert!(e.contains("not an nst3d model"), "{e}");
        let key = b"\"channels\":\"3\"";
        let at = bytes.windows(key.len()).position(|w| w == key).expect("channels in the header");
        let mut wider = bytes.clone();
        wider[at + key.len() - 2] = b'4';
        let e = Model::from_bytes(&wider, p).unwrap_err().to_string();
        assert!(e.contains("e1.weight") && e.contains("channels 4"), "{e}");
    }

    /// A model with a solid texture writes it as a tensor and reads it
    /// back; a texture of the wrong shape, or a period with no tensor, is
    /// refused by name.
    #[test]
    fn a_texture_round_trips_and_a_wrong_one_is_refused() {
        let m = Model { net: FeedForward::new(2, 1, 9), texture: Some(SolidTexture::new(4, 1)), info: BTreeMap::new() };
        let p = Path::new("m.safetensors");
        assert_eq!(Model::from_bytes(&m.to_bytes(), p).unwrap(), m);
        let mut tensors = nst3d_weights::TensorMap::new();
        for (name, shape, data) in m.tensors() {
            tensors.insert(name, nst3d_weights::TensorData { shape, data: data.to_vec() });
        }
        let mut wrong = m.metadata();
        wrong.insert(TEXTURE_PERIOD.into(), "5".into());
        let e = Model::from_parts(&tensors, wrong, p).unwrap_err().to_string();
        assert!(e.contains("tensor texture has shape [4, 4, 4]"), "{e}");
        tensors.remove(TEXTURE);
        let e = Model::from_parts(&tensors, m.metadata(), p).unwrap_err().to_string();
        assert!(e.contains("tensor texture is missing"), "{e}");
    }

    /// The example model shipped with nst3d reads and writes back to the
    /// same bytes: what the writer writes has not changed since it was made.
    #[test]
    fn the_example_model_writes_back_byte_for_byte() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/starry_density.safetensors");
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(Model::from_bytes(&bytes, &path).unwrap().to_bytes(), bytes);
    }

    #[test]
    fn a_small_file_claiming_1024_channels_is_refused_before_allocating() {
        // Found while writing the fuzz harness: the network of the claimed
        // width (1.8 GB at 1024 channels) used to be made and initialised
        // before the tensors were compared with it.
        let m = Model { net: FeedForward::new(1, 1, 9), texture: None, info: BTreeMap::new() };
        let bytes = m.to_bytes();
        let key = b"\"channels\":\"1\"";
        let at = bytes.windows(key.len()).position(|w| w == key).expect("channels in the header");
        let mut claim = bytes[..at].to_vec();
        claim.extend_from_slice(b"\"channels\":\"1024\"");
        claim.extend_from_slice(&bytes[at + key.len()..]);
        // The header grew by 3 bytes: fix its length prefix.
        let n = u64::from_le_bytes(claim[..8].try_into().unwrap()) + 3;
        claim[..8].copy_from_slice(&n.to_le_bytes());
        let e = Model::from_bytes(&claim, Path::new("m.safetensors")).unwrap_err().to_string();
        assert!(e.contains("e1.weight") && e.contains("channels 1024"), "{e}");
    }
}
