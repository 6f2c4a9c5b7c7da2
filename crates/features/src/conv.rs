//! 3x3 (stride 1, pad 1) and 1x1 convolutions with their input gradients.
//!
//! Weights are frozen, so backward only ever computes the gradient with
//! respect to the input: for a 3x3 convolution that is again a 3x3
//! convolution, of the output gradient with the spatially flipped,
//! channel-transposed kernel. Both directions therefore share one kernel,
//! Winograd F(4x4, 3x3) where channel counts allow, direct otherwise (the
//! RGB layer), each prepared on first use.

use std::sync::OnceLock;

use rayon::prelude::*;

use nst3d_core::{bf16, precision};

use crate::conv_bf16::{self, Bf16Conv};
use crate::simd::dispatch;
use crate::tensor::{pad, take_buffer, FeatureMap, Padded, Padding, Source};
use crate::winograd::{self, WinogradWeights};
use crate::FeaturesError;

/// A prepared "valid" 3x3 convolution kernel.
enum Kernel {
    Winograd(WinogradWeights),
    /// Direct loops for few channels: `wt` is `[tap][cin][cout]` when the
    /// output is wide (vectorised over outputs), else `[cout][tap][cin]`.
    Direct {
        cin: usize,
        cout: usize,
        wt: Vec<f32>,
    },
}

impl Kernel {
    fn new(w: &[f32], cin: usize, cout: usize, algorithm: ConvAlgorithm) -> Self {
        if algorithm == ConvAlgorithm::Auto && winograd::supports(cin, cout) {
            return Kernel::Winograd(WinogradWeights::new(w, cin, cout));
        }
        let mut wt = vec![0.0; w.len()];
        for co in 0..cout {
            for ci in 0..cin {
                for tap in 0..9 {
                    let v = w[(co * cin + ci) * 9 + tap];
                    if wide_output(cout) {
                        wt[(tap * cin + ci) * cout + co] = v;
                    } else {
                        wt[(co * 9 + tap) * cin + ci] = v;
                    }
                }
            }
        }
        Kernel::Direct { cin, cout, wt }
    }

    /// Convolves `src` to `out_h x out_w`; the direct path works on a padded
    /// copy, Winograd reads `src` in place.
    fn run(&self, src: Source<'_>, out_h: usize, out_w: usize, bias: Option<&[f32]>, relu: bool) -> FeatureMap {
        match self {
            Kernel::Winograd(ww) => winograd::conv(src, out_h, out_w, ww, bias, relu),
            Kernel::Direct { cin, cout, wt } => {
                let padded = pad(src, out_h + 2, out_w + 2);
                direct(&padded, out_h, out_w, *cin, *cout, wt, bias, relu)
            }
        }
    }
}

fn wide_output(cout: usize) -> bool {
    cout >= 16
}

/// Direct "valid" 3x3 convolution (see [`Kernel::Direct`] for the layouts).
#[allow(clippy::too_many_arguments)]
fn direct(
    inp: &Padded,
    out_h: usize,
    out_w: usize,
    cin: usize,
    cout: usize,
    wt: &[f32],
    bias: Option<&[f32]>,
    relu: bool,
) -> FeatureMap {
    // Every value is set below (bias first), so a pooled buffer's old
    // contents never show.
    let mut data = take_buffer(out_h * out_w * cout);
    data.resize(out_h * out_w * cout, 0.0);
    let mut out = FeatureMap::from_vec(out_h, out_w, cout, data);
    let zero = vec![0.0; cout];
    let bias = bias.unwrap_or(&zero);
    out.data.par_chunks_mut(out_w * cout).enumerate().for_each(|(y, row)| {
        dispatch(
            #[inline(always)]
            || {
                for x in 0..out_w {
                    let acc = &mut row[x * cout..(x + 1) * cout];
                    acc.copy_from_slice(bias);
                    for tap in 0..9 {
                        let s = ((y + tap / 3) * inp.w + x + tap % 3) * cin;
                        let px = &inp.data[s..s + cin];
                        if wide_output(cout) {
                            for (ci, a) in px.iter().enumerate() {
                                let wrow = &wt[(tap * cin + ci) * cout..(tap * cin + ci + 1) * cout];
                                for (o, wv) in acc.iter_mut().zip(wrow) {
                                    *o += a * wv;
                                }
                            }
                        } else {
                            for (co, o) in acc.iter_mut().enumerate() {
                                *o += dot(px, &wt[(co * 9 + tap) * cin..(co * 9 + tap + 1) * cin]);
                            }
                        }
                    }
                    if relu {
                        acc.iter_mut().for_each(|v| *v = v.max(0.0));
                    }
                }
            },
        )
    });
    out
}

/// Dot product with 16 independent partial sums (vectorisable without
/// reassociation).
#[inline(always)]
fn dot(a: &[f32], b: &[f32]) -> f32 {
    let mut acc = [0.0f32; 16];
    let (ca, cb) = (a.chunks_exact(16), b.chunks_exact(16));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for l in 0..16 {
            acc[l] += x[l] * y[l];
        }
    }
    let tail: f32 = ra.iter().zip(rb).map(|(x, y)| x * y).sum();
    acc.iter().sum::<f32>() + tail
}

/// How a [`Conv3x3`] computes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ConvAlgorithm {
    /// Winograd F(4x4, 3x3) where channel counts allow (multiples of 16 in,
    /// 32 out), direct otherwise. About 1e-5 relative to the largest output.
    #[default]
    Auto,
    /// Direct summation everywhere: a slow reference that rounds like a
    /// plain fp32 convolution (for comparisons with PyTorch).
    Direct,
}

/// 3x3 convolution, stride 1, padding 1 (zero or reflection), with bias.
pub struct Conv3x3 {
    algorithm: ConvAlgorithm,
    cin: usize,
    cout: usize,
    padding: Padding,
    weight: Vec<f32>,
    bias: Vec<f32>,
    fwd: OnceLock<Kernel>,
    bwd: OnceLock<Kernel>,
    fwd16: OnceLock<Bf16Conv>,
    bwd16: OnceLock<Bf16Conv>,
}

impl Conv3x3 {
    /// `weight` in PyTorch layout `[cout][cin][3][3]`, `bias` of `cout`.
    pub fn new(
        cin: usize,
        cout: usize,
        weight: Vec<f32>,
        bias: Vec<f32>,
        padding: Padding,
    ) -> Result<Self, FeaturesError> {
        if cin == 0 || cout == 0 || weight.len() != cout * cin * 9 || bias.len() != cout {
            return Err(FeaturesError::BadConv { cin, cout, weight: weight.len(), bias: bias.len() });
        }
        Ok(Self {
            algorithm: ConvAlgorithm::Auto,
            cin,
            cout,
            padding,
            weight,
            bias,
            fwd: OnceLock::new(),
            bwd: OnceLock::new(),
            fwd16: OnceLock::new(),
            bwd16: OnceLock::new(),
        })
    }

    /// The same convolution computed with `algorithm`.
    pub fn with_algorithm(self, algorithm: ConvAlgorithm) -> Self {
        Self {
            algorithm,
            fwd: OnceLock::new(),
            bwd: OnceLock::new(),
            fwd16: OnceLock::new(),
            bwd16: OnceLock::new(),
            ..self
        }
    }

    /// Input channels.
    pub fn in_channels(&self) -> usize {
        self.cin
    }

    /// Output channels.
    pub fn out_channels(&self) -> usize {
        self.cout
    }

    /// Border handling.
    pub fn padding(&self) -> Padding {
        self.padding
    }

    fn fwd_kernel(&self) -> &Kernel {
        self.fwd.get_or_init(|| Kernel::new(&self.weight, self.cin, self.cout, self.algorithm))
    }

    fn bwd_kernel(&self) -> &Kernel {
        self.bwd.get_or_init(|| Kernel::new(&self.backward_weight(), self.cout, self.cin, self.algorithm))
    }

    /// The weights of the input gradient's convolution: flipped taps,
    /// swapped channel roles, `w'[ci][co][ky][kx] = w[co][ci][2-ky][2-kx]`.
    fn backward_weight(&self) -> Vec<f32> {
        let (cin, cout) = (self.cin, self.cout);
        let mut wb = vec![0.0; self.weight.len()];
        for co in 0..cout {
            for ci in 0..cin {
                for tap in 0..9 {
                    wb[(ci * cout + co) * 9 + 8 - tap] = self.weight[(co * cin + ci) * 9 + tap];
                }
            }
        }
        wb
    }

    /// The bf16 kernel this call runs on, when the precision in force is
    /// bf16 and the layer takes it (the `Direct` reference never does).
    fn bf16_kernel(&self) -> Option<bf16::Kernel> {
        if self.algorithm != ConvAlgorithm::Auto || !conv_bf16::supports(self.cin, self.cout) {
            return None;
        }
        precision::path().kernel()
    }

    fn fwd16(&self) -> &Bf16Conv {
        self.fwd16.get_or_init(|| Bf16Conv::new(&self.weight, self.cin, self.cout))
    }

    fn bwd16(&self) -> &Bf16Conv {
        self.bwd16.get_or_init(|| Bf16Conv::new(&self.backward_weight(), self.cout, self.cin))
    }

    /// Builds the prepared kernels of the precision in force now rather
    /// than on first use.
    pub fn prepare(&self) {
        if self.bf16_kernel().is_some() {
            self.fwd16();
            self.bwd16();
        } else {
            self.fwd_kernel();
            self.bwd_kernel();
        }
    }

    /// Bytes of prepared weights held (both precisions, as built so far).
    pub fn prepared_bytes(&self) -> usize {
        self.fwd16.get().map_or(0, Bf16Conv::bytes) + self.bwd16.get().map_or(0, Bf16Conv::bytes)
    }

    /// `conv(x) + bias`.
    pub fn forward(&self, x: &FeatureMap) -> FeatureMap {
        self.forward_fused(x, false)
    }

    /// `relu(conv(x) + bias)` in one pass.
    pub fn forward_relu(&self, x: &FeatureMap) -> FeatureMap {
        self.forward_fused(x, true)
    }

    fn forward_fused(&self, x: &FeatureMap, relu: bool) -> FeatureMap {
        assert_eq!(x.channels, self.cin, "conv input channels");
        let src = Source { map: x, pad: 1, mode: self.padding, mask: None };
        match self.bf16_kernel() {
            Some(k) => self.fwd16().run(k, src, x.height, x.width, Some(&self.bias), relu),
            None => self.fwd_kernel().run(src, x.height, x.width, Some(&self.bias), relu),
        }
    }

    /// Gradient w.r.t. the input of [`Conv3x3::forward`] from `grad_out`.
    pub fn backward(&self, grad_out: &FeatureMap) -> FeatureMap {
        self.backward_masked(grad_out, None)
    }

    /// Gradient w.r.t. the input of [`Conv3x3::forward_relu`], given that
    /// call's output (the ReLU mask is applied while reading `grad_out`).
    pub fn backward_relu(&self, grad_out: &FeatureMap, relu_out: &FeatureMap) -> FeatureMap {
        self.backward_masked(grad_out, Some(relu_out))
    }

    fn backward_masked(&self, g: &FeatureMap, mask: Option<&FeatureMap>) -> FeatureMap {
        assert_eq!(g.channels, self.cout, "conv gradient channels");
        let k16 = self.bf16_kernel();
        let run = |src: Source<'_>, oh: usize, ow: usize| match k16 {
            Some(k) => self.bwd16().run(k, src, oh, ow, None, false),
            None => self.bwd_kernel().run(src, oh, ow, None, false),
        };
        let (h, w) = (g.height, g.width);
        match self.padding {
            Padding::Zero => run(Source { map: g, pad: 1, mode: Padding::Zero, mask }, h, w),
            Padding::Reflect => {
                // Gradient w.r.t. the reflection-padded input ((h+2) x (w+2)),
                // then the mirrored border rows/columns fold back onto their sources.
                let gp = run(Source { map: g, pad: 2, mode: Padding::Zero, mask }, h + 2, w + 2);
                let out = fold_reflection(&gp, h, w);
                gp.recycle();
                out
            }
        }
    }
}

/// Adjoint of 1-pixel reflection padding: `(h+2) x (w+2)` -> `h x w`.
fn fold_reflection(gp: &FeatureMap, h: usize, w: usize) -> FeatureMap {
    let c = gp.channels;
    let (pw, at) = (w + 2, |y: usize, x: usize| (y * (w + 2) + x) * c);
    let mut out = FeatureMap::zeros(h, w, c);
    out.data.par_chunks_mut(w * c).enumerate().for_each(|(y, row)| {
        // Padded rows feeding source row y: y+1 always, 0 when y == 1, h+1 when y == h-2.
        let mut srcs = vec![y + 1];
        if y == 1 {
            srcs.push(0);
        }
        if y + 2 == h {
            srcs.push(h + 1);
        }
        for sy in srcs {
            for x in 0..w {
                let dst = &mut row[x * c..(x + 1) * c];
                let mut add = |sx: usize| {
                    for (d, v) in dst.iter_mut().zip(&gp.data[at(sy, sx)..at(sy, sx) + c]) {
                        *d += v;
                    }
                };
                add(x + 1);
                if x == 1 {
                    add(0);
                }
                if x + 2 == w {
                    add(pw - 1);
                }
            }
        }
    });
    out
}

/// Pointwise (1x1) convolution: a per-pixel affine map of channels. The Gatys
/// VGG starts with one (RGB in [0, 1] -> Caffe BGR), and the torchvision
/// ImageNet normalisation is the diagonal case.
#[derive(Clone, Debug)]
pub struct Conv1x1 {
    cin: usize,
    cout: usize,
    weight: Vec<f32>,
    bias: Vec<f32>,
}

impl Conv1x1 {
    /// `weight` is `[cout][cin]` (PyTorch `[cout][cin][1][1]`), `bias` of `cout`.
    pub fn new(cin: usize, cout: usize, weight: Vec<f32>, bias: Vec<f32>) -> Result<Self, FeaturesError> {
        if cin == 0 || cout == 0 || weight.len() != cout * cin || bias.len() != cout {
            return Err(FeaturesError::BadConv { cin, cout, weight: weight.len(), bias: bias.len() });
        }
        Ok(Self { cin, cout, weight, bias })
    }

    /// `y[o] = bias[o] + sum_i weight[o][i] x[i]` at every pixel.
    pub fn forward(&self, x: &FeatureMap) -> FeatureMap {
        assert_eq!(x.channels, self.cin, "1x1 conv input channels");
        let mut out = FeatureMap::zeros(x.height, x.width, self.cout);
        out.data.par_chunks_mut(self.cout * 1024).zip(x.data.par_chunks(self.cin * 1024)).for_each(|(o, i)| {
            for (op, ip) in o.chunks_exact_mut(self.cout).zip(i.chunks_exact(self.cin)) {
                for (co, v) in op.iter_mut().enumerate() {
                    *v = self.bias[co] + dot(ip, &self.weight[co * self.cin..(co + 1) * self.cin]);
                }
            }
        });
        out
    }

    /// Gradient w.r.t. the input: `g_x[i] = sum_o weight[o][i] g[o]`.
    pub fn backward(&self, grad_out: &FeatureMap) -> FeatureMap {
        assert_eq!(grad_out.channels, self.cout, "1x1 conv gradient channels");
        let mut out = FeatureMap::zeros(grad_out.height, grad_out.width, self.cin);
        out.data.par_chunks_mut(self.cin * 1024).zip(grad_out.data.par_chunks(self.cout * 1024)).for_each(|(o, g)| {
            for (op, gp) in o.chunks_exact_mut(self.cin).zip(g.chunks_exact(self.cout)) {
                for (co, gv) in gp.iter().enumerate() {
                    for (ci, v) in op.iter_mut().enumerate() {
                        *v += self.weight[co * self.cin + ci] * gv;
                    }
                }
            }
        });
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::{check_gradient, dot as gdot, pseudo_random};
    use nst3d_core::precision::{fp32, scoped, Precision};

    fn fm(h: usize, w: usize, c: usize, seed: u64) -> FeatureMap {
        FeatureMap::from_vec(h, w, c, pseudo_random(h * w * c, seed))
    }

    /// Plain f64 reference: zero/reflect padded correlation, PyTorch semantics.
    fn reference(x: &FeatureMap, wt: &[f32], b: &[f32], cout: usize, mode: Padding) -> Vec<f64> {
        let (h, w, cin) = (x.height as isize, x.width as isize, x.channels);
        let mut out = vec![0.0f64; (h * w) as usize * cout];
        let src = |v: isize, n: isize| -> Option<isize> {
            if (0..n).contains(&v) {
                Some(v)
            } else if mode == Padding::Reflect {
                Some(if v < 0 { -v } else { 2 * n - 2 - v })
            } else {
                None
            }
        };
        for y in 0..h {
            for xx in 0..w {
                for co in 0..cout {
                    let mut s = b[co] as f64;
                    for ky in 0..3 {
                        for kx in 0..3 {
                            let (Some(sy), Some(sx)) = (src(y + ky - 1, h), src(xx + kx - 1, w)) else { continue };
                            for ci in 0..cin {
                                s += x.data[((sy * w + sx) as usize) * cin + ci] as f64
                                    * wt[((co * cin + ci) * 3 + ky as usize) * 3 + kx as usize] as f64;
                            }
                        }
                    }
                    out[((y * w + xx) as usize) * cout + co] = s;
                }
            }
        }
        out
    }

    fn check_forward(cin: usize, cout: usize, h: usize, w: usize, mode: Padding) {
        // Realistic activations: non-negative (post-ReLU) inputs, He-scaled weights.
        let x =
            FeatureMap::from_vec(h, w, cin, pseudo_random(h * w * cin, 5).iter().map(|v| v.max(0.0) * 3.0).collect());
        let scale = (6.0 / (9.0 * cin as f32)).sqrt();
        let wt: Vec<f32> = pseudo_random(cout * cin * 9, 6).iter().map(|v| v * scale).collect();
        let b = pseudo_random(cout, 7);
        let conv = Conv3x3::new(cin, cout, wt.clone(), b.clone(), mode).unwrap();
        let y = conv.forward(&x);
        let r = reference(&x, &wt, &b, cout, mode);
        let max = r.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let err = y.data.iter().zip(&r).fold(0.0f64, |m, (a, b)| m.max((*a as f64 - b).abs()));
        assert!(err / max < 2e-5, "cin {cin} cout {cout} {h}x{w} {mode:?}: rel err {}", err / max);
    }

    #[test]
    fn winograd_matches_direct_reference() {
        fp32(|| {
            check_forward(64, 64, 13, 10, Padding::Zero);
            check_forward(256, 512, 9, 8, Padding::Zero);
            check_forward(32, 32, 17, 5, Padding::Reflect);
        })
    }

    #[test]
    fn direct_matches_reference() {
        fp32(|| {
            check_forward(3, 64, 7, 9, Padding::Zero);
            check_forward(3, 64, 6, 5, Padding::Reflect);
            check_forward(64, 3, 5, 6, Padding::Zero);
        })
    }

    fn gradcheck_conv(cin: usize, cout: usize, mode: Padding, relu: bool) {
        let (h, w) = (7, 6);
        let x = fm(h, w, cin, 11);
        let scale = (1.0 / (9.0 * cin as f32)).sqrt();
        let wt: Vec<f32> = pseudo_random(cout * cin * 9, 12).iter().map(|v| v * scale).collect();
        let conv = Conv3x3::new(cin, cout, wt, pseudo_random(cout, 13), mode).unwrap();
        let probe = pseudo_random(h * w * cout, 14);
        let y = if relu { conv.forward_relu(&x) } else { conv.forward(&x) };
        let g = FeatureMap::from_vec(h, w, cout, probe.clone());
        let gx = if relu { conv.backward_relu(&g, &y) } else { conv.backward(&g) };
        let loss = |p: &[f32]| {
            let xi = FeatureMap::from_vec(h, w, cin, p.to_vec());
            let y = if relu { conv.forward_relu(&xi) } else { conv.forward(&xi) };
            gdot(&probe, &y.data)
        };
        let floor = gx.data.iter().fold(0.0f32, |m, v| m.max(v.abs())) as f64 * 0.02;
        let r = check_gradient(&x.data, &gx.data, loss, 1e-2, 200, floor);
        assert!(r.max_rel_err < 1e-2, "cin {cin} cout {cout} {mode:?} relu {relu}: {r:?}");
    }

    #[test]
    fn conv3x3_gradients() {
        fp32(|| {
            for mode in [Padding::Zero, Padding::Reflect] {
                gradcheck_conv(16, 32, mode, false); // Winograd both ways
                gradcheck_conv(3, 16, mode, false); // direct forward, direct backward
                gradcheck_conv(32, 16, mode, false); // direct forward, Winograd backward
            }
        })
    }

    /// `<backward(g), x> = <g, forward(x) - bias>`: exact adjointness over
    /// many shapes (tile remainders, tiny maps) without finite differences.
    #[test]
    fn backward_is_adjoint_of_forward() {
        fp32(|| {
            for mode in [Padding::Zero, Padding::Reflect] {
                for (cin, cout, h, w) in
                    [(256, 512, 5, 5), (16, 32, 2, 3), (32, 64, 10, 9), (64, 3, 6, 7), (3, 64, 5, 4), (32, 32, 3, 2)]
                {
                    let conv =
                        Conv3x3::new(cin, cout, pseudo_random(cout * cin * 9, 41), vec![0.0; cout], mode).unwrap();
                    let x = fm(h, w, cin, 42);
                    let g = fm(h, w, cout, 43);
                    let lhs = gdot(&conv.backward(&g).data, &x.data);
                    let rhs = gdot(&g.data, &conv.forward(&x).data);
                    let scale = (cin as f64 * 9.0 * (h * w * cout) as f64).sqrt();
                    assert!((lhs - rhs).abs() < 1e-4 * scale, "{mode:?} {cin}->{cout} {h}x{w}: {lhs} vs {rhs}");
                }
            }
        })
    }

    #[test]
    fn fused_relu_backward_is_mask_then_conv_backward() {
        fp32(|| {
            for mode in [Padding::Zero, Padding::Reflect] {
                let conv = Conv3x3::new(16, 32, pseudo_random(32 * 16 * 9, 31), pseudo_random(32, 32), mode).unwrap();
                let x = fm(9, 11, 16, 33);
                let y = conv.forward_relu(&x);
                assert_eq!(y, crate::ops::relu(&conv.forward(&x)));
                let g = fm(9, 11, 32, 34);
                let fused = conv.backward_relu(&g, &y);
                let split = conv.backward(&crate::ops::relu_backward(&g, &y));
                assert_eq!(fused, split);
            }
        })
    }

    #[test]
    fn conv1x1_gradient() {
        fp32(|| {
            let x = fm(4, 5, 3, 21);
            let conv = Conv1x1::new(3, 4, pseudo_random(12, 22), pseudo_random(4, 23)).unwrap();
            let probe = pseudo_random(4 * 5 * 4, 24);
            let gx = conv.backward(&FeatureMap::from_vec(4, 5, 4, probe.clone()));
            let loss = |p: &[f32]| gdot(&probe, &conv.forward(&FeatureMap::from_vec(4, 5, 3, p.to_vec())).data);
            assert!(check_gradient(&x.data, &gx.data, loss, 1e-2, 60, 1e-3).max_rel_err < 1e-3);
        })
    }

    #[test]
    fn bad_shapes_are_errors() {
        fp32(|| {
            assert!(Conv3x3::new(2, 3, vec![0.0; 10], vec![0.0; 3], Padding::Zero).is_err());
            assert!(Conv1x1::new(3, 3, vec![0.0; 9], vec![0.0; 2]).is_err());
        })
    }

    /// Every bf16 kernel this machine has (the portable one always).
    fn bf16_kernels() -> Vec<bf16::Kernel> {
        bf16::Kernel::all_here()
    }

    /// Max error over max |reference| and RMS error over RMS reference.
    fn errors(got: &[f32], want: &[f64]) -> (f64, f64) {
        let max = want.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let err = got.iter().zip(want).fold(0.0f64, |m, (a, b)| m.max((*a as f64 - b).abs()));
        let e2: f64 = got.iter().zip(want).map(|(a, b)| (*a as f64 - b).powi(2)).sum();
        let r2: f64 = want.iter().map(|b| b * b).sum();
        (err / max, (e2 / r2).sqrt())
    }

    /// The bf16 tolerance, stated once: bf16 keeps 8 mantissa bits (a
    /// rounding of at most 2^-9 = 0.2 % per operand); sums of many such
    /// products stay within 1 % of the largest output and 0.5 % in RMS.
    const BF16_MAX_REL: f64 = 1e-2;
    const BF16_RMS_REL: f64 = 5e-3;

    /// bf16 forward against the f64 reference, every kernel, shapes with
    /// block remainders (widths not a multiple of 32, tiny maps), channel
    /// counts not a multiple of 32, both paddings, and the kernels agree
    /// with each other to summation order.
    #[test]
    fn bf16_forward_matches_reference_within_tolerance() {
        for (cin, cout, h, w, mode) in [
            (64, 64, 13, 37, Padding::Zero),
            (256, 512, 9, 8, Padding::Reflect),
            (16, 48, 5, 2, Padding::Reflect),
            (128, 128, 34, 33, Padding::Zero),
        ] {
            let x = FeatureMap::from_vec(
                h,
                w,
                cin,
                pseudo_random(h * w * cin, 5).iter().map(|v| v.max(0.0) * 3.0).collect(),
            );
            let scale = (6.0 / (9.0 * cin as f32)).sqrt();
            let wt: Vec<f32> = pseudo_random(cout * cin * 9, 6).iter().map(|v| v * scale).collect();
            let b = pseudo_random(cout, 7);
            let r = reference(&x, &wt, &b, cout, mode);
            let packed = conv_bf16::Bf16Conv::new(&wt, cin, cout);
            let src = Source { map: &x, pad: 1, mode, mask: None };
            let outs: Vec<FeatureMap> =
                bf16_kernels().into_iter().map(|k| packed.run(k, src, h, w, Some(&b), false)).collect();
            for (k, y) in bf16_kernels().iter().zip(&outs) {
                let (max, rms) = errors(&y.data, &r);
                assert!(max < BF16_MAX_REL && rms < BF16_RMS_REL, "{k:?} {cin}->{cout} {h}x{w} {mode:?}: {max} {rms}");
                let (same, _) = errors(&y.data, &outs[0].data.iter().map(|v| *v as f64).collect::<Vec<_>>());
                assert!(same < 1e-5, "{k:?} differs from the portable kernel by {same}");
            }
        }
    }

    /// A ReLU mask applied while copying (the backward's input) gives the
    /// convolution of the masked map, channel padding and both paddings too.
    #[test]
    fn bf16_masked_source_is_the_masked_map() {
        for (cin, cout, h, w, mode) in [(16, 32, 7, 9, Padding::Reflect), (64, 32, 6, 40, Padding::Zero)] {
            let x = FeatureMap::from_vec(h, w, cin, pseudo_random(h * w * cin, 61));
            let m = FeatureMap::from_vec(h, w, cin, pseudo_random(h * w * cin, 62));
            let masked = FeatureMap::from_vec(
                h,
                w,
                cin,
                x.data.iter().zip(&m.data).map(|(v, k)| if *k > 0.0 { *v } else { 0.0 }).collect(),
            );
            let wt = pseudo_random(cout * cin * 9, 63);
            let packed = conv_bf16::Bf16Conv::new(&wt, cin, cout);
            for k in bf16_kernels() {
                let a = packed.run(k, Source { map: &x, pad: 1, mode, mask: Some(&m) }, h, w, None, false);
                let b = packed.run(k, Source { map: &masked, pad: 1, mode, mask: None }, h, w, None, false);
                assert_eq!(a.data, b.data, "{k:?} {cin}->{cout} {mode:?}");
            }
        }
    }

    /// The public calls take the bf16 path under `bf16` (fused ReLU, masked
    /// backward, reflection folding) and stay within the tolerance of fp32.
    #[test]
    fn bf16_forward_and_backward_match_fp32() {
        for mode in [Padding::Zero, Padding::Reflect] {
            let (cin, cout, h, w) = (64, 128, 19, 35);
            let conv =
                Conv3x3::new(cin, cout, pseudo_random(cout * cin * 9, 51), pseudo_random(cout, 52), mode).unwrap();
            let x =
                FeatureMap::from_vec(h, w, cin, pseudo_random(h * w * cin, 53).iter().map(|v| v.max(0.0)).collect());
            let g = fm(h, w, cout, 54);
            let (y32, gx32) = fp32(|| {
                let y = conv.forward_relu(&x);
                let gx = conv.backward_relu(&g, &y);
                (y, gx)
            });
            // The same ReLU mask (fp32's) for both backwards: a bf16 forward
            // flips the sign of outputs near zero, which changes the mask, not
            // the kernel's error.
            let (y16, gx16) = scoped(Precision::Bf16, || (conv.forward_relu(&x), conv.backward_relu(&g, &y32)));
            assert_ne!(y16, y32, "the bf16 call did not take the bf16 path");
            for (name, a, b) in [("forward", &y16, &y32), ("backward", &gx16, &gx32)] {
                let (max, rms) = errors(&a.data, &b.data.iter().map(|v| *v as f64).collect::<Vec<_>>());
                assert!(max < BF16_MAX_REL && rms < BF16_RMS_REL, "{mode:?} {name}: {max} {rms}");
            }
        }
    }
}
