//! VGG-19 up to relu5_1, forward to a set of taps and backward to the image.

use std::fmt;
use std::str::FromStr;
use std::sync::OnceLock;

use nst3d_core::{FeatureView, Image, Layout};
use nst3d_weights::TensorMap;

use crate::conv::{Conv1x1, Conv3x3, ConvAlgorithm};
use crate::ops::{MaxPool2x2, PoolArgmax};
use crate::tensor::{FeatureMap, Padding};
use crate::FeaturesError;

/// Output channels of the 13 convolutions conv1_1 .. conv5_1.
const CHANNELS: [usize; 13] = [64, 64, 128, 128, 256, 256, 256, 256, 512, 512, 512, 512, 512];
/// A max-pool follows these convolutions (conv1_2, conv2_2, conv3_4, conv4_4).
const POOL_AFTER: [usize; 4] = [1, 3, 7, 11];
/// State-dict indices of the 3x3 convolutions in the Gatys normalised VGG.
const GATYS_KEYS: [usize; 13] = [2, 5, 9, 12, 16, 19, 22, 25, 29, 32, 35, 38, 42];
/// State-dict indices (under `features.`) in torchvision's VGG-19.
const TORCHVISION_KEYS: [usize; 13] = [0, 2, 5, 7, 10, 12, 14, 16, 19, 21, 23, 25, 28];
const IMAGENET_MEAN: [f32; 3] = [0.485, 0.456, 0.406];
const IMAGENET_STD: [f32; 3] = [0.229, 0.224, 0.225];
/// Caffe VGG input: BGR in [0, 255] minus the BGR channel means.
const CAFFE_BGR_MEAN: [f32; 3] = [103.939, 116.779, 123.68];

/// A ReLU output of VGG-19 that features can be tapped at.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum VggLayer {
    /// After conv1_1 (64 channels, full resolution).
    Relu1_1,
    /// After conv1_2.
    Relu1_2,
    /// After conv2_1 (128 channels, 1/2 resolution).
    Relu2_1,
    /// After conv2_2.
    Relu2_2,
    /// After conv3_1 (256 channels, 1/4 resolution).
    Relu3_1,
    /// After conv3_2.
    Relu3_2,
    /// After conv3_3.
    Relu3_3,
    /// After conv3_4.
    Relu3_4,
    /// After conv4_1 (512 channels, 1/8 resolution).
    Relu4_1,
    /// After conv4_2.
    Relu4_2,
    /// After conv4_3.
    Relu4_3,
    /// After conv4_4.
    Relu4_4,
    /// After conv5_1 (512 channels, 1/16 resolution).
    Relu5_1,
}

const NAMES: [&str; 13] = [
    "relu1_1", "relu1_2", "relu2_1", "relu2_2", "relu3_1", "relu3_2", "relu3_3", "relu3_4", "relu4_1", "relu4_2",
    "relu4_3", "relu4_4", "relu5_1",
];

impl VggLayer {
    /// All layers, shallowest first.
    pub const ALL: [VggLayer; 13] = [
        VggLayer::Relu1_1,
        VggLayer::Relu1_2,
        VggLayer::Relu2_1,
        VggLayer::Relu2_2,
        VggLayer::Relu3_1,
        VggLayer::Relu3_2,
        VggLayer::Relu3_3,
        VggLayer::Relu3_4,
        VggLayer::Relu4_1,
        VggLayer::Relu4_2,
        VggLayer::Relu4_3,
        VggLayer::Relu4_4,
        VggLayer::Relu5_1,
    ];

    /// Index of the convolution this ReLU follows (0 = conv1_1).
    pub fn conv_index(self) -> usize {
        self as usize
    }

    /// Channels of the feature map at this layer.
    pub fn channels(self) -> usize {
        CHANNELS[self.conv_index()]
    }
}

impl FromStr for VggLayer {
    type Err = FeaturesError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        NAMES
            .iter()
            .position(|n| n.eq_ignore_ascii_case(s.trim()))
            .map(|i| VggLayer::ALL[i])
            .ok_or_else(|| FeaturesError::UnknownLayer(s.to_string()))
    }
}

impl fmt::Display for VggLayer {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(NAMES[self.conv_index()])
    }
}

/// Which published VGG-19 the weights come from; decides input
/// preprocessing, border padding and pooling.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VggFlavor {
    /// Gatys et al.'s normalised VGG (`vgg_normalised.pth`): a 1x1 conv maps RGB
    /// in [0, 1] to Caffe BGR, reflection padding, ceil-mode pooling.
    Gatys,
    /// torchvision `vgg19().features`: ImageNet mean/std normalisation, zero
    /// padding, floor pooling.
    Torchvision,
}

/// VGG-19 convolutions conv1_1 .. conv5_1 with frozen weights.
pub struct Vgg19 {
    flavor: VggFlavor,
    /// Input map from RGB in [0, 1] to what conv1_1 expects. Kept as its own
    /// pointwise layer (not folded into conv1_1): for torchvision the
    /// normalisation does not commute with zero padding.
    pre: Conv1x1,
    convs: Vec<Conv3x3>,
    pool: MaxPool2x2,
}

/// What [`Vgg19::backward`] needs from a forward pass (kept when `keep`).
struct Record {
    /// Post-ReLU output of every convolution run: the ReLU masks.
    acts: Vec<FeatureMap>,
    /// Winners of every pool run.
    pools: Vec<PoolArgmax>,
}

/// Result of [`Vgg19::forward`]: features at the requested taps.
pub struct VggForward {
    layers: Vec<VggLayer>,
    /// The taps' activations when there is no [`Record`] to read them from.
    maps: Vec<FeatureMap>,
    /// Planar copies of the taps, made on first request.
    planar: OnceLock<Vec<Image>>,
    input_size: (usize, usize),
    record: Option<Record>,
}

impl VggForward {
    /// Feature maps (planar `C x H x W`), in the order the taps were
    /// requested. Copied from the network's channels-last activations on
    /// first use; a loss that can read [`VggForward::features`] avoids that.
    pub fn taps(&self) -> &[Image] {
        self.planar.get_or_init(|| (0..self.layers.len()).map(|k| self.map(k).to_image()).collect())
    }

    /// The taps as `C x P` feature matrices where the network keeps them
    /// (channels-last), same order as [`VggForward::taps`]; no copy.
    pub fn features(&self) -> Vec<FeatureView<'_>> {
        (0..self.layers.len()).map(|k| self.map(k).view()).collect()
    }

    /// Activation of tap `k`.
    fn map(&self, k: usize) -> &FeatureMap {
        match &self.record {
            Some(rec) => &rec.acts[self.layers[k].conv_index()],
            None => &self.maps[k],
        }
    }

    /// The requested taps, same order as [`VggForward::taps`].
    pub fn layers(&self) -> &[VggLayer] {
        &self.layers
    }
}

/// Deterministic uniform value in `[-1, 1)` for element `i` of stream
/// `stream` (SplitMix64 of a linear key); mirrored in
/// `tools/fixtures/features_vgg.py` so both sides build identical weights.
fn hash_uniform(seed: u64, stream: u64, i: u64) -> f64 {
    let key = seed
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add(stream.wrapping_mul(0xD1B5_4A32_D192_ED03))
        .wrapping_add(i);
    let mut z = key.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    2.0 * ((z >> 40) as f64 / (1u64 << 24) as f64) - 1.0
}

fn conv_keys(flavor: VggFlavor, i: usize) -> (String, String) {
    match flavor {
        VggFlavor::Gatys => (format!("{}.weight", GATYS_KEYS[i]), format!("{}.bias", GATYS_KEYS[i])),
        VggFlavor::Torchvision => {
            (format!("features.{}.weight", TORCHVISION_KEYS[i]), format!("features.{}.bias", TORCHVISION_KEYS[i]))
        }
    }
}

fn tensor<'a>(t: &'a TensorMap, key: &str, shape: &[usize]) -> Result<&'a [f32], FeaturesError> {
    let d = t.get(key).ok_or_else(|| FeaturesError::MissingKey(key.to_string()))?;
    if d.shape != shape || d.data.len() != shape.iter().product::<usize>() {
        return Err(FeaturesError::BadShape { key: key.to_string(), found: d.shape.clone(), expected: shape.to_vec() });
    }
    Ok(&d.data)
}

fn in_channels(i: usize) -> usize {
    if i == 0 {
        3
    } else {
        CHANNELS[i - 1]
    }
}

fn padding_of(flavor: VggFlavor) -> Padding {
    match flavor {
        VggFlavor::Gatys => Padding::Reflect,
        VggFlavor::Torchvision => Padding::Zero,
    }
}

fn torchvision_pre() -> Conv1x1 {
    let mut w = vec![0.0; 9];
    let mut b = vec![0.0; 3];
    for c in 0..3 {
        w[c * 4] = 1.0 / IMAGENET_STD[c];
        b[c] = -IMAGENET_MEAN[c] / IMAGENET_STD[c];
    }
    Conv1x1::new(3, 3, w, b).expect("3x3 normalisation")
}

impl Vgg19 {
    fn assemble(flavor: VggFlavor, pre: Conv1x1, convs: Vec<Conv3x3>) -> Self {
        Self { flavor, pre, convs, pool: MaxPool2x2 { ceil_mode: flavor == VggFlavor::Gatys } }
    }

    /// Loads the network from `explicit`, else from `$NST3D_VGG19`, else
    /// from the user cache `tools/fetch_weights.sh` fills: the one place
    /// every job (volume, groom, benchmark) finds its weights.
    pub fn load(explicit: Option<&std::path::Path>) -> Result<Self, FeaturesError> {
        let path = match explicit {
            Some(p) => p.to_path_buf(),
            None => nst3d_weights::locate_vgg19()?,
        };
        let tensors = nst3d_weights::load_vgg19_weights(&path)?;
        Self::from_tensors(&tensors).map_err(|e| FeaturesError::File { path, source: Box::new(e) })
    }

    /// Builds the network from a checkpoint's tensors, telling the flavor
    /// from its keys (`features.0.weight` = torchvision, `0.weight` of shape
    /// `[3, 3, 1, 1]` = Gatys). Only conv1_1 .. conv5_1 are read.
    pub fn from_tensors(t: &TensorMap) -> Result<Self, FeaturesError> {
        let (flavor, pre) = if t.contains_key("features.0.weight") {
            (VggFlavor::Torchvision, torchvision_pre())
        } else if t.get("0.weight").is_some_and(|d| d.shape == [3, 3, 1, 1]) {
            let w = tensor(t, "0.weight", &[3, 3, 1, 1])?;
            let b = tensor(t, "0.bias", &[3])?;
            (VggFlavor::Gatys, Conv1x1::new(3, 3, w.to_vec(), b.to_vec())?)
        } else {
            return Err(FeaturesError::UnknownFlavor);
        };
        let convs = (0..CHANNELS.len())
            .map(|i| {
                let (wk, bk) = conv_keys(flavor, i);
                let (cin, cout) = (in_channels(i), CHANNELS[i]);
                let w = tensor(t, &wk, &[cout, cin, 3, 3])?;
                let b = tensor(t, &bk, &[cout])?;
                Conv3x3::new(cin, cout, w.to_vec(), b.to_vec(), padding_of(flavor))
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Self::assemble(flavor, pre, convs))
    }

    /// Same architecture with deterministic He-scaled uniform weights
    /// (`w = u * sqrt(6 / (9 cin))`, bias `0.1 u`, `u` from SplitMix64 of
    /// `(seed, layer, index)`): for benchmarks and tests without a checkpoint.
    /// The Gatys flavor gets the exact Caffe input map.
    pub fn random(flavor: VggFlavor, seed: u64) -> Self {
        let pre = match flavor {
            VggFlavor::Torchvision => torchvision_pre(),
            VggFlavor::Gatys => {
                // out[o] = 255 * rgb[2 - o] - mean_bgr[o]
                let mut w = vec![0.0; 9];
                for o in 0..3 {
                    w[o * 3 + 2 - o] = 255.0;
                }
                Conv1x1::new(3, 3, w, CAFFE_BGR_MEAN.iter().map(|m| -m).collect()).expect("Caffe input map")
            }
        };
        let convs = (0..CHANNELS.len())
            .map(|i| {
                let (cin, cout) = (in_channels(i), CHANNELS[i]);
                let a = (6.0 / (9.0 * cin as f64)).sqrt();
                let w = (0..cout * cin * 9).map(|k| (hash_uniform(seed, i as u64, k as u64) * a) as f32).collect();
                let b = (0..cout).map(|k| (hash_uniform(seed, i as u64, (1 << 40) + k as u64) * 0.1) as f32).collect();
                Conv3x3::new(cin, cout, w, b, padding_of(flavor)).expect("VGG layer shapes")
            })
            .collect();
        Self::assemble(flavor, pre, convs)
    }

    /// The same network with every 3x3 convolution computed by `algorithm`
    /// ([`ConvAlgorithm::Direct`]: slow fp32 reference).
    pub fn with_algorithm(self, algorithm: ConvAlgorithm) -> Self {
        Self { convs: self.convs.into_iter().map(|c| c.with_algorithm(algorithm)).collect(), ..self }
    }

    /// Which published network this is.
    pub fn flavor(&self) -> VggFlavor {
        self.flavor
    }

    /// Prepares the (Winograd) kernels of every convolution up to `deepest`
    /// now, so the first forward/backward is not slower than the rest.
    pub fn prepare(&self, deepest: VggLayer) {
        use rayon::prelude::*;
        self.convs[..=deepest.conv_index()].par_iter().for_each(|c| c.prepare());
    }

    /// The fewest pixels a side of the input may have for every convolution
    /// up to the deepest of `taps` to get a valid map: two pixels a side
    /// under reflection padding (reflecting a single pixel is undefined, as
    /// in PyTorch), one under zero padding, after this flavour's pooling.
    pub fn min_input(&self, taps: &[VggLayer]) -> usize {
        let deepest = taps.iter().map(|t| t.conv_index()).max().unwrap_or(0);
        let need = match padding_of(self.flavor) {
            Padding::Reflect => 2,
            Padding::Zero => 1,
        };
        let reaches = |mut side: usize| {
            for i in 0..=deepest {
                if side < need {
                    return false;
                }
                if POOL_AFTER.contains(&i) && i < deepest {
                    side = if self.pool.ceil_mode { side.div_ceil(2) } else { side / 2 };
                }
            }
            true
        };
        (2..).find(|&s| reaches(s)).expect("some side reaches every layer")
    }

    /// Runs up to the deepest requested tap on `rgb` (3 x H x W, RGB in
    /// [0, 1], H and W at least [`Vgg19::min_input`] of `taps`). With `keep`,
    /// stores what [`Vgg19::backward`] needs.
    pub fn forward(&self, rgb: &Image, taps: &[VggLayer], keep: bool) -> VggForward {
        assert_eq!(rgb.channels, 3, "VGG-19 input must have 3 channels");
        assert!(rgb.height >= 2 && rgb.width >= 2, "VGG-19 input must be at least 2x2");
        let mut out = VggForward {
            layers: taps.to_vec(),
            maps: Vec::new(),
            planar: OnceLock::new(),
            input_size: (rgb.height, rgb.width),
            record: None,
        };
        let mut maps: Vec<Option<FeatureMap>> = vec![None; taps.len()];
        let Some(deepest) = taps.iter().map(|l| l.conv_index()).max() else { return out };
        let mut acts: Vec<FeatureMap> = Vec::with_capacity(deepest + 1);
        let mut pools = Vec::new();
        let rgb_map = FeatureMap::from_image(rgb);
        let pre = self.pre.forward(&rgb_map);
        rgb_map.recycle();
        // The next convolution's input when it is not the previous ReLU
        // output itself (which is read in place from `acts`, never cloned).
        let mut x = Some(pre);
        for i in 0..=deepest {
            let y = match &x {
                Some(x) => self.convs[i].forward_relu(x),
                None => self.convs[i].forward_relu(acts.last().expect("previous activation")),
            };
            if let Some(x) = x.take() {
                x.recycle();
            }
            if !keep {
                // With a record the taps are read from it; without, keep a copy.
                for (slot, l) in maps.iter_mut().zip(taps) {
                    if l.conv_index() == i {
                        *slot = Some(y.clone());
                    }
                }
            }
            if POOL_AFTER.contains(&i) && i < deepest {
                let (p, arg) = self.pool.forward(&y);
                pools.push(arg);
                x = Some(p);
            }
            if keep {
                acts.push(y);
            } else if x.is_some() || i == deepest {
                y.recycle();
            } else {
                // Without a record the activation still feeds the next layer.
                acts.clear();
                acts.push(y);
            }
        }
        if keep {
            out.record = Some(Record { acts, pools });
        } else {
            acts.into_iter().for_each(FeatureMap::recycle);
            out.maps = maps.into_iter().map(|m| m.expect("every tap is at or above the deepest layer")).collect();
        }
        out
    }

    /// Gradient w.r.t. the input RGB image from gradients at the taps (same
    /// order and shapes as `fwd.taps()`, in either layout; channels-last is
    /// used as it is). `fwd` must come from [`Vgg19::forward`] with `keep = true`.
    pub fn backward(&self, fwd: &VggForward, tap_grads: &[FeatureView<'_>]) -> Image {
        let rec = fwd.record.as_ref().expect("Vgg19::backward needs a forward pass run with keep = true");
        assert_eq!(tap_grads.len(), fwd.layers.len(), "one gradient per tap");
        let (h, w) = fwd.input_size;
        let Some(deepest) = fwd.layers.iter().map(|l| l.conv_index()).max() else { return Image::zeros(3, h, w) };
        let mut pools = rec.pools.iter().rev();
        let mut g: Option<FeatureMap> = None;
        for i in (0..=deepest).rev() {
            for (l, tg) in fwd.layers.iter().zip(tap_grads) {
                if l.conv_index() == i {
                    let a = &rec.acts[i];
                    assert_eq!(
                        (tg.channels, tg.height, tg.width),
                        (a.channels, a.height, a.width),
                        "gradient shape at {l}"
                    );
                    match (g.as_mut(), tg.layout) {
                        (Some(g), Layout::ChannelsLast) => g.add_assign_slice(tg.data),
                        (Some(g), Layout::Planar) => {
                            let tg = FeatureMap::from_view(*tg);
                            g.add_assign_slice(&tg.data);
                            tg.recycle();
                        }
                        (None, _) => g = Some(FeatureMap::from_view(*tg)),
                    }
                }
            }
            let gi = g.take().expect("gradient reaches every layer below the deepest tap");
            let mut gx = self.convs[i].backward_relu(&gi, &rec.acts[i]);
            gi.recycle();
            if i > 0 && POOL_AFTER.contains(&(i - 1)) {
                let pooled = self.pool.backward(&gx, pools.next().expect("pool record"));
                gx.recycle();
                gx = pooled;
            }
            g = Some(gx);
        }
        let g = g.expect("input gradient");
        let out = self.pre.backward(&g).to_image();
        g.recycle();
        out
    }
}

/// Activations go back to the buffer pool for the next pass.
impl Drop for VggForward {
    fn drop(&mut self) {
        if let Some(rec) = self.record.take() {
            rec.acts.into_iter().for_each(FeatureMap::recycle);
        }
        std::mem::take(&mut self.maps).into_iter().for_each(FeatureMap::recycle);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::{check_gradient, dot, pseudo_random};
    use nst3d_weights::TensorData;

    /// Reflection needs two pixels a side at every convolution (ceil
    /// pooling), zero padding one (floor pooling): 9 and 8 pixels reach
    /// relu4_1, and a network fed exactly that many runs to its deepest tap.
    #[test]
    fn min_input_reaches_the_deepest_tap() {
        let taps = [VggLayer::Relu1_1, VggLayer::Relu4_1];
        for (flavor, least) in [(VggFlavor::Gatys, 9), (VggFlavor::Torchvision, 8)] {
            let vgg = Vgg19::random(flavor, 1);
            assert_eq!(vgg.min_input(&taps), least, "{flavor:?}");
            assert_eq!(vgg.min_input(&[VggLayer::Relu1_1]), 2);
            let rgb = Image::from_vec(3, least, least + 3, pseudo_random(3 * least * (least + 3), 2));
            let fwd = vgg.forward(&rgb, &taps, false);
            assert!(fwd.taps()[1].data.iter().all(|v| v.is_finite()));
        }
    }

    #[test]
    fn layer_names_round_trip() {
        for l in VggLayer::ALL {
            assert_eq!(l.to_string().parse::<VggLayer>().unwrap(), l);
        }
        assert!("relu6_1".parse::<VggLayer>().is_err());
    }

    /// Finite differences through thousands of ReLU kinks (and fp32 loss
    /// rounding at small steps) are noisy entry by entry, so most checked
    /// entries must agree; the exact comparison is the PyTorch fixture test.
    #[test]
    fn whole_net_gradient() {
        nst3d_core::precision::fp32(|| {
            for flavor in [VggFlavor::Torchvision, VggFlavor::Gatys] {
                let net = Vgg19::random(flavor, 3);
                let (h, w) = (18, 17);
                let x = Image::from_vec(3, h, w, pseudo_random(3 * h * w, 4).iter().map(|v| 0.5 + 0.4 * v).collect());
                let taps = [VggLayer::Relu1_1, VggLayer::Relu2_1, VggLayer::Relu3_1, VggLayer::Relu4_1];
                let f = net.forward(&x, &taps, true);
                // Probes on the channels-last features, the layout the style loss passes back.
                let probes: Vec<Vec<f32>> =
                    f.features().iter().enumerate().map(|(k, t)| pseudo_random(t.data.len(), 10 + k as u64)).collect();
                let grads: Vec<FeatureView> =
                    f.features().iter().zip(&probes).map(|(t, p)| FeatureView { data: p, ..*t }).collect();
                let g = net.backward(&f, &grads);
                let scale = g.data.iter().fold(0.0f32, |m, v| m.max(v.abs())) as f64;
                let entries: Vec<usize> = (0..24).map(|k| (k * 131 + 7) % x.data.len()).collect();
                let good = entries
                    .iter()
                    .filter(|&&i| {
                        let loss = |p: &[f32]| {
                            let mut xi = x.clone();
                            xi.data[i] = p[0];
                            let f = net.forward(&xi, &taps, false);
                            f.features().iter().zip(&probes).map(|(t, pr)| dot(pr, t.data)).sum::<f64>()
                        };
                        check_gradient(&[x.data[i]], &[g.data[i]], loss, 1e-3, 1, scale * 0.1).max_rel_err < 5e-2
                    })
                    .count();
                assert!(good >= 16, "{flavor:?}: only {good} of 24 entries match (16 needed) finite differences");
            }
        })
    }

    /// The whole network in bf16 against fp32 on a 64² image of smoke-like
    /// greys: each tap (relu1_1 .. relu4_1) of a bf16 forward, and the
    /// input gradient of a bf16 backward through the fp32 forward's record
    /// (a bf16 forward flips ReLUs of outputs near zero, which changes which
    /// gradients pass, not the kernels' error). Tolerance, stated once: RMS
    /// error within 3 % of the fp32 RMS (each layer adds bf16's operand
    /// rounding, up to 10 convolutions deep; measured 0.3-0.5 % forward,
    /// 0.2 % backward).
    #[test]
    fn bf16_network_matches_fp32() {
        use nst3d_core::precision::{fp32, scoped, Precision};
        let rms_rel = |a: &[f32], b: &[f32]| {
            let e: f64 = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum();
            let r: f64 = b.iter().map(|y| (*y as f64).powi(2)).sum();
            (e / r).sqrt()
        };
        for flavor in [VggFlavor::Torchvision, VggFlavor::Gatys] {
            let net = Vgg19::random(flavor, 5);
            let n = 64;
            let x = Image::from_vec(3, n, n, pseudo_random(3 * n * n, 6).iter().map(|v| 0.5 + 0.4 * v).collect());
            let taps = [VggLayer::Relu1_1, VggLayer::Relu2_1, VggLayer::Relu3_1, VggLayer::Relu4_1];
            let f32s = fp32(|| net.forward(&x, &taps, true));
            let f16s = scoped(Precision::Bf16, || net.forward(&x, &taps, false));
            for (k, (a, b)) in f16s.features().iter().zip(f32s.features()).enumerate() {
                let e = rms_rel(a.data, b.data);
                assert!(e < 3e-2, "{flavor:?} tap {k}: RMS error {e}");
            }
            let probes: Vec<Vec<f32>> = f32s.features().iter().map(|t| t.data.to_vec()).collect();
            let grads: Vec<FeatureView> =
                f32s.features().iter().zip(&probes).map(|(t, d)| FeatureView { data: d, ..*t }).collect();
            let g32 = fp32(|| net.backward(&f32s, &grads));
            let g16 = scoped(Precision::Bf16, || net.backward(&f32s, &grads));
            let e = rms_rel(&g16.data, &g32.data);
            assert!(e < 3e-2, "{flavor:?} input gradient: RMS error {e}");
            assert_ne!(g16.data, g32.data, "the bf16 run did not take the bf16 path");
        }
    }

    #[test]
    fn from_tensors_names_missing_and_misshaped_keys() {
        let mut t = TensorMap::new();
        assert!(matches!(Vgg19::from_tensors(&t), Err(FeaturesError::UnknownFlavor)));
        t.insert("features.0.weight".into(), TensorData { shape: vec![64, 3, 3, 3], data: vec![0.0; 64 * 27] });
        let e = Vgg19::from_tensors(&t).err().unwrap();
        assert!(e.to_string().contains("features.0.bias"), "{e}");
        t.insert("features.0.bias".into(), TensorData { shape: vec![64], data: vec![0.0; 64] });
        t.insert("features.2.weight".into(), TensorData { shape: vec![64, 64, 3], data: vec![0.0; 64 * 64 * 3] });
        let e = Vgg19::from_tensors(&t).err().unwrap();
        assert!(e.to_string().contains("features.2.weight"), "{e}");
    }
}
