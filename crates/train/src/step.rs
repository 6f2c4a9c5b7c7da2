//! One training step of the feed-forward network (Sec. 5.1): network
//! forward on a patch, the output applied as a density scale or a velocity,
//! render + VGG-19 Gram loss, backward to the weights, gradient clipping,
//! Adam under OneCycle.

use crate::axes::{turn_to_z, turn_to_z_backward, Sight};
use nst3d_core::{math::lane_sum, Grid3};
use nst3d_network::{FeedForward, SolidTexture, Volume};
// The inference half lives with the network (the volume job applies a
// trained model without the training crate); re-exported for the trainer.
use nst3d_network::apply::CHUNK;
pub use nst3d_network::apply::{apply, apply_with_strength, mass_ratio, velocity_field, Stylization, MASS_PINNED};
use nst3d_optim::{clip_grad_norm, Adam, OneCycle};
use nst3d_stylize::frame::view_at;
use nst3d_stylize::{ViewError, ViewLoss, ViewSpec};
use nst3d_transport::{advect_linear_backward, downsample2, downsample2_backward};
use rayon::prelude::*;

/// Backward of [`apply`]: `∂L/∂o` from `∂L/∂d*`.
pub fn apply_backward(d: &Grid3, o: &Volume, s: Stylization, grad: &[f32]) -> Volume {
    match s {
        Stylization::Density => {
            let g =
                d.data.par_iter().zip(o.data.par_iter()).zip(grad.par_iter()).with_min_len(CHUNK).map(|((d, o), g)| {
                    let t = o.tanh();
                    g * d * (1.0 - t * t)
                });
            Volume::from_vec(1, o.dims, g.collect())
        }
        Stylization::Velocity { vmax } => {
            let n = o.voxels();
            let v = velocity_field(o, vmax);
            let mut gv = nst3d_core::fill::filled(n, [0.0f32; 3]);
            advect_linear_backward(d, &v, grad, &mut gv);
            // d(vmax tanh o)/do = vmax (1 - tanh²) = vmax - v² / vmax: from the field
            // already made, not a second tanh per value.
            let g = (0..3 * n).into_par_iter().with_min_len(CHUNK).map(|j| {
                let (a, i) = (j / n, j % n);
                gv[i][a] * (vmax - v[i][a] * v[i][a] / vmax)
            });
            Volume::from_vec(3, o.dims, g.collect())
        }
    }
}

/// `d*` scaled so the stylization redistributes the smoke without adding or
/// removing any: `k d*` with `k = Σ d / Σ d*`. Returns the scaled grid and `k`.
///
/// Why: the Gram loss of a render can be lowered by simply having less
/// smoke (an empty render is closer to a dark painting than bright smoke
/// is), and a network finds that route: density mode learned `s → 0`
/// everywhere, velocity mode thinned the smoke by reading from the empty
/// space around it (docs/design/feedforward.md). Fixing the
/// total takes that route away and leaves the look to the pattern.
pub fn conserve_mass(d: &Grid3, dstar: &Grid3) -> (Grid3, f32) {
    let k = mass_ratio(lane_sum(&d.data, None), lane_sum(&dstar.data, None));
    (Grid3::from_vec(dstar.dims, dstar.data.par_iter().with_min_len(CHUNK).map(|v| v * k).collect()), k)
}

/// Backward of [`conserve_mass`] w.r.t. the unscaled `dstar`, given
/// `grad = ∂L/∂(k d*)`: `k g_m − (k / Σ d*) Σ_i g_i d*_i` (`k` depends on
/// every voxel through `Σ d*`).
pub fn conserve_mass_backward(dstar: &Grid3, k: f32, grad: &[f32]) -> Vec<f32> {
    let total = lane_sum(&dstar.data, None);
    if total <= 0.0 {
        return grad.iter().map(|g| g * k).collect();
    }
    let dot = lane_sum(grad, Some(&dstar.data));
    let shift = (k as f64 * dot / total) as f32;
    grad.par_iter().with_min_len(CHUNK).map(|g| k * g - shift).collect()
}

/// Weight `λ` of the density-mode scale pin ([`scale_pin`]).
pub const SCALE_PIN: f32 = 100.0;

/// The scale pin of density mode, `λ (ln k)²` with `k = Σ d / Σ d*` the
/// [`conserve_mass`] ratio, and its gradient w.r.t. every voxel of the
/// unscaled `dstar` (the same for all: `−2λ ln k / Σ d*`).
///
/// Why: conserving the mass makes the style loss blind to the level of
/// `s = 1 + tanh o` — `s` and `c s` give the same `k d*` — so nothing held
/// the networks' level, and the loss, which likes contrast, drove it into
/// `tanh`'s floor: the two-hour density models came out with `k ≈ 10⁵`,
/// `s ≈ 2e^{2o}` an unbounded exponential, and a frame unlike their
/// training data had its faint haze lifted 10⁴-fold into a box-shaped
/// cloud (docs/design/feedforward.md). With the pin `k` stays
/// near 1, so `k s` keeps the optimiser's `[0, 2]` and no voxel can grow
/// more than about twofold; the conservation still closes the "less smoke"
/// route.
pub fn scale_pin(dstar: &Grid3, k: f32, weight: f32) -> (f32, f32) {
    let total = lane_sum(&dstar.data, None);
    if total <= 0.0 || k <= 0.0 {
        return (0.0, 0.0);
    }
    let ln_k = (k as f64).ln();
    ((weight as f64 * ln_k * ln_k) as f32, (-2.0 * weight as f64 * ln_k / total) as f32)
}

/// The style loss of `d` summed over `octaves` scales and its gradient:
/// octave `k` renders `d` box-filtered down `2^k` times through
/// [`view_at`], the optimisation's own rule: absorption and exposure scaled
/// up `2^k` times, so each ray keeps its optical depth and the picture its
/// brightness. (Scaling the absorption alone drew every coarse octave half
/// as bright per level, the octave exposure bug the optimisation had
/// first.)
pub fn octave_loss(d: &Grid3, loss: &ViewLoss, view: &ViewSpec, octaves: usize) -> Result<(f32, Grid3), ViewError> {
    let (total, grad) = loss.loss_and_grad(d, view)?;
    if octaves <= 1 || d.dims.iter().any(|&n| n < 4) {
        return Ok((total, grad));
    }
    let coarse = downsample2(d);
    let view2 = view_at(view, 2.0);
    let (l2, g2) = octave_loss(&coarse, loss, &view2, octaves - 1)?;
    let mut grad = grad;
    for (g, c) in grad.data.iter_mut().zip(&downsample2_backward(d.dims, &g2).data) {
        *g += c;
    }
    Ok((total + l2, grad))
}

/// [`octave_loss`] of `d` from one sight: turned so the axis is the
/// renderer's z, or through the sight's camera; the gradient is w.r.t. `d`.
fn sight_loss(
    d: &Grid3,
    loss: &ViewLoss,
    view: &ViewSpec,
    sight: Sight,
    octaves: usize,
) -> Result<(f32, Grid3), ViewError> {
    match sight {
        Sight::Along(axis) => {
            let (l, g) = octave_loss(&turn_to_z(d, axis), loss, view, octaves)?;
            Ok((l, turn_to_z_backward(&g, axis)))
        }
        Sight::From(_) => octave_loss(d, loss, &ViewSpec { camera: sight.camera(d.dims), ..view.clone() }, octaves),
    }
}

/// The network and its optimiser between steps.
pub struct TrainStep {
    /// The network being trained.
    pub net: FeedForward,
    /// How its output is applied.
    pub stylization: Stylization,
    /// Joint gradient norm the step clips to (Sec. 5.1; 1.0 as the peer).
    pub clip: f32,
    /// Learning rate and `beta1` per step.
    pub schedule: OneCycle,
    /// Octaves of the loss (Sec. 5.1: two "to produce features at
    /// different scales"): octave `k` scores the stylized patch box-filtered
    /// `2^k` times smaller, so the painting's strokes are matched at
    /// `2^k` times their size in voxels too.
    pub octaves: usize,
    adam: Adam,
    steps: u64,
    /// Where the OneCycle schedule stands, in its steps: `steps` unless a
    /// time budget paces it ([`TrainStep::pace`]).
    position: f64,
    /// Schedule steps advanced per training step (1 unless paced).
    pub pace: f64,
    /// The last step's [`conserve_mass`] ratio `k`.
    last_mass_ratio: f32,
    /// The solid texture trained beside the network, if any
    /// ([`TrainStep::with_texture`]).
    texture: Option<SolidTexture>,
}

/// How much faster the solid texture learns than the network: Adam moves
/// every parameter by about the learning rate a step, and a texel must
/// move by about 1 (`tanh`'s range) in a few thousand steps where a
/// weight moves by hundredths. The optimiser holds `T / TEXTURE_RATE`.
/// Measured: at 10× and 30× the texture was still near its start after
/// 5,500 steps (scales within 0.72–1.29 and 0.40–1.61); at 300× it was
/// carving (a third of the texels below 0.2) by 3,700.
pub const TEXTURE_RATE: f32 = 300.0;

impl TrainStep {
    /// A trainer for `net` (whose output channels must fit `stylization`).
    ///
    /// # Panics
    /// If the network's output channels do not match the stylization.
    pub fn new(net: FeedForward, stylization: Stylization, schedule: OneCycle) -> Self {
        assert_eq!(net.out_channels(), stylization.channels(), "network output channels vs stylization");
        let n = net.flat().len();
        Self {
            net,
            stylization,
            clip: 1.0,
            schedule,
            octaves: 2,
            adam: Adam::new(n, 0.0),
            steps: 0,
            position: 0.0,
            pace: 1.0,
            last_mass_ratio: 1.0,
            texture: None,
        }
    }

    /// The trainer with a solid texture learned beside the network
    /// ([`SolidTexture`]); its values follow the network's in the
    /// optimiser's parameters.
    pub fn with_texture(mut self, texture: SolidTexture) -> Self {
        self.adam = Adam::new(self.net.flat().len() + texture.values.len(), 0.0);
        self.texture = Some(texture);
        self
    }

    /// The solid texture being trained, if any.
    pub fn texture(&self) -> Option<&SolidTexture> {
        self.texture.as_ref()
    }

    /// Replaces the texture's values (a checkpoint's).
    pub fn set_texture(&mut self, texture: SolidTexture) {
        self.texture = Some(texture);
    }

    /// Every trained parameter in the optimiser's order: the network's
    /// ([`FeedForward::flat`]), then the texture's over [`TEXTURE_RATE`].
    pub fn params(&self) -> Vec<f32> {
        let mut p = self.net.flat();
        if let Some(t) = &self.texture {
            p.extend(t.values.iter().map(|v| v / TEXTURE_RATE));
        }
        p
    }

    /// Sets every trained parameter from [`TrainStep::params`]' order.
    pub fn set_params(&mut self, p: &[f32]) {
        let n = p.len() - self.texture.as_ref().map_or(0, |t| t.values.len());
        self.net.set_flat(&p[..n]);
        if let Some(t) = &mut self.texture {
            t.values.iter_mut().zip(&p[n..]).for_each(|(v, q)| *v = q * TEXTURE_RATE);
        }
    }

    /// Steps taken.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// The last step's mass ratio `k = Σ d / Σ d*` (near 1 while
    /// [`scale_pin`] holds the network's level).
    pub fn last_mass_ratio(&self) -> f32 {
        self.last_mass_ratio
    }

    /// The learning rate of the last step.
    pub fn last_lr(&self) -> f32 {
        self.adam.lr
    }

    /// Where the schedule stands (schedule steps done).
    pub fn position(&self) -> f64 {
        self.position
    }

    /// Whether the schedule has reached its last step.
    pub fn schedule_done(&self) -> bool {
        self.position >= self.schedule.total_steps as f64 - 1e-9
    }

    /// Adam's moments and step count (for a checkpoint).
    pub fn adam_state(&self) -> (&[f32], &[f32], u64) {
        self.adam.state()
    }

    /// Restores a checkpoint's optimiser state; the trainer continues at
    /// step `step`.
    pub fn set_adam_state(&mut self, m: &[f32], v: &[f32], step: u64) -> Result<(), nst3d_optim::OptimError> {
        self.adam.set_state(m, v, step)?;
        self.steps = step;
        self.position = step as f64;
        Ok(())
    }

    /// Restores a checkpoint's schedule position (after [`TrainStep::set_adam_state`]).
    pub fn set_position(&mut self, position: f64) {
        self.position = position;
    }

    /// One step on `patch` (densities in `[0, 1]`, sides a multiple of 4)
    /// seen with `view`'s absorption from each of `sights`
    /// ([`crate::axes`]); returns the style loss (summed over the octaves,
    /// the mean over the sights) before the update. `at` is where the
    /// patch's corner lies in the solid texture's space (unused without one).
    pub fn step(
        &mut self,
        patch: &Grid3,
        at: [i64; 3],
        loss: &ViewLoss,
        view: &ViewSpec,
        sights: &[Sight],
    ) -> Result<f32, ViewError> {
        let g = self.gradient(patch, at, loss, view, sights)?;
        self.update(g.grads, g.mass_ratio);
        Ok(g.loss)
    }

    /// The loss of `patch` and its gradient with respect to the network's
    /// parameters ([`FeedForward::flat`] order), the network unchanged: the
    /// half of [`TrainStep::step`] each patch of a batch runs on its own.
    pub fn gradient(
        &self,
        patch: &Grid3,
        at: [i64; 3],
        loss: &ViewLoss,
        view: &ViewSpec,
        sights: &[Sight],
    ) -> Result<PatchGradient, ViewError> {
        assert!(!sights.is_empty(), "a step renders its patch at least once");
        let x = Volume::from_grid(patch);
        let (o, tape) = self.net.forward(&x);
        let styled = apply(patch, &o, self.stylization);
        let textured = self.texture.as_ref().map(|t| t.apply(&styled, at));
        let raw = textured.as_ref().unwrap_or(&styled);
        let (dstar, k) = conserve_mass(patch, raw);
        let (mut l, mut grad_dstar) = (0.0f32, vec![0.0f32; dstar.len()]);
        let share = 1.0 / sights.len() as f32;
        for &sight in sights {
            let (ls, gs) = sight_loss(&dstar, loss, view, sight, self.octaves)?;
            l += share * ls;
            for (g, a) in grad_dstar.iter_mut().zip(&gs.data) {
                *g += share * a;
            }
        }
        let mut grad_raw = conserve_mass_backward(raw, k, &grad_dstar);
        if self.stylization == Stylization::Density {
            let (_, g) = scale_pin(raw, k, SCALE_PIN);
            grad_raw.iter_mut().for_each(|x| *x += g);
        }
        let (grad_styled, grad_texture) = match &self.texture {
            Some(t) => t.apply_backward(&styled, at, &grad_raw),
            None => (grad_raw, Vec::new()),
        };
        let grad_o = apply_backward(patch, &o, self.stylization, &grad_styled);
        let mut grads = FeedForward::flat_grads(&self.net.backward(&tape, &grad_o));
        grads.extend(grad_texture.iter().map(|g| g * TEXTURE_RATE));
        Ok(PatchGradient { loss: l, grads, mass_ratio: k })
    }

    /// The other half of [`TrainStep::step`]: `grads` (one patch's, or a
    /// batch's mean) clipped, one Adam step under the schedule, the
    /// schedule advanced. `mass_ratio` is what [`TrainStep::last_mass_ratio`]
    /// reports.
    pub fn update(&mut self, mut grads: Vec<f32>, mass_ratio: f32) {
        self.last_mass_ratio = mass_ratio;
        // The network's and the texture's gradients are clipped apart: the
        // texture's, TEXTURE_RATE times larger, would otherwise take the
        // whole norm and scale the network's steps down with it.
        let n = grads.len() - self.texture.as_ref().map_or(0, |t| t.values.len());
        let (net, texture) = grads.split_at_mut(n);
        clip_grad_norm(&mut [net], self.clip);
        clip_grad_norm(&mut [texture], self.clip);
        let (lr, beta1) = self.schedule.at(self.position.floor() as u64);
        self.adam.lr = lr as f32;
        self.adam.beta1 = beta1 as f32;
        let mut params = self.params();
        self.adam.step(&mut params, &grads);
        self.set_params(&params);
        self.steps += 1;
        self.position += self.pace;
    }
}

/// One patch's part of a step ([`TrainStep::gradient`]).
#[derive(Clone, Debug)]
pub struct PatchGradient {
    /// The style loss before the update.
    pub loss: f32,
    /// The loss's gradient, in [`FeedForward::flat`] order.
    pub grads: Vec<f32>,
    /// The patch's mass ratio `k` ([`conserve_mass`]).
    pub mass_ratio: f32,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::axes::Axis;
    use nst3d_core::gradcheck::{check_gradient, directional, dot, pseudo_random};

    #[test]
    fn apply_gradients_match_finite_differences() {
        let dims = [5, 4, 6];
        let d = Grid3::from_vec(dims, pseudo_random(120, 1).iter().map(|v| v.abs()).collect());
        let w = pseudo_random(120, 2);
        for s in [Stylization::Density, Stylization::Velocity { vmax: 1.3 }] {
            let c = s.channels();
            let o = Volume::from_vec(c, dims, pseudo_random(120 * c, 3));
            let g = apply_backward(&d, &o, s, &w);
            let r = check_gradient(
                &o.data,
                &g.data,
                |q| dot(&w, &apply(&d, &Volume::from_vec(c, dims, q.to_vec()), s).data),
                1e-3,
                200,
                1e-3,
            );
            // Trilinear sampling has kinks at integer offsets: a few probes may cross one.
            assert!(r.max_rel_err < 2e-2, "{s:?}: {r:?}");
        }
    }

    /// `--strength` at inference: 1 is the trained network, 0 leaves the
    /// smoke as it was, 2 applies the density scale twice over (its log
    /// doubled) and moves a velocity model's smoke twice as far.
    #[test]
    fn strength_raises_the_stylization_to_a_power() {
        let dims = [5, 4, 6];
        let d = Grid3::from_vec(dims, pseudo_random(120, 1).iter().map(|v| v.abs()).collect());
        let o = Volume::from_vec(1, dims, pseudo_random(120, 3));
        let once = apply(&d, &o, Stylization::Density);
        assert_eq!(apply_with_strength(&d, &o, Stylization::Density, 1.0).data, once.data);
        assert_eq!(apply_with_strength(&d, &o, Stylization::Density, 0.0).data, d.data);
        let twice = apply_with_strength(&d, &o, Stylization::Density, 2.0);
        for ((t, s), d) in twice.data.iter().zip(&once.data).zip(&d.data) {
            assert!((t * d - s * s).abs() <= 1e-5 * (1.0 + s * s), "{t} · {d} against {s}²");
        }
        let ov = Volume::from_vec(3, dims, pseudo_random(360, 4));
        let far = apply_with_strength(&d, &ov, Stylization::Velocity { vmax: 0.6 }, 2.0);
        assert_eq!(far.data, apply(&d, &ov, Stylization::Velocity { vmax: 1.2 }).data);
        assert_eq!(apply_with_strength(&d, &ov, Stylization::Velocity { vmax: 0.6 }, 0.0).data, d.data);
    }

    /// The two-octave loss is the fine loss plus the coarse loss of the
    /// box-filtered patch at twice the absorption, and its gradient is the
    /// fine gradient plus the coarse one taken back through the box filter
    /// (both pieces have their own finite-difference checks: the view loss
    /// in `stylize`, the filter in `transport`).
    #[test]
    fn octave_loss_adds_the_coarse_octave_and_its_gradient() {
        nst3d_core::precision::fp32(octave_loss_check)
    }

    fn octave_loss_check() {
        use nst3d_features::{Vgg19, VggFlavor};
        use nst3d_stylize::StyleSpec;
        let vgg = Vgg19::random(VggFlavor::Torchvision, 3);
        let style = nst3d_core::Image::from_vec(
            3,
            32,
            32,
            pseudo_random(3 * 32 * 32, 4).iter().map(|v| 0.5 + 0.4 * v).collect(),
        );
        let loss = ViewLoss::new(&vgg, &style, &StyleSpec::default()).unwrap();
        let view = ViewSpec { camera: None, gamma: 0.5, exposure: 0.5, equalize: false };
        // A density of constant 2x2x2 blocks: its coarse octave is the
        // block values themselves, built here without the code under test,
        // seen with twice the absorption per (twice as long) voxel and
        // twice the exposure (half as many voxels light each ray).
        let blocks = Grid3::from_vec([8; 3], pseudo_random(512, 5).iter().map(|v| 0.5 + 0.5 * v).collect());
        let mut d = Grid3::zeros([16; 3]);
        for z in 0..16 {
            for y in 0..16 {
                for x in 0..16 {
                    let i = d.index(x, y, z);
                    d.data[i] = blocks.data[blocks.index(x / 2, y / 2, z / 2)];
                }
            }
        }
        let fine = loss.loss(&d, &view).unwrap();
        let coarse = loss.loss(&blocks, &ViewSpec { gamma: 1.0, exposure: 1.0, ..view.clone() }).unwrap();
        let l = octave_loss(&d, &loss, &view, 2).unwrap().0;
        assert!((l - (fine + coarse)).abs() <= 1e-5 * l.abs(), "{l} vs {fine} + {coarse}");
        // One octave is the plain view loss.
        assert_eq!(octave_loss(&d, &loss, &view, 1).unwrap().0, fine);
        // The coarse octave's part of the gradient (the whole minus the
        // plain view's): each fine voxel gets an eighth of its block's
        // gradient in the coarse view (the view loss's own gradient is
        // checked against finite differences in nst3d-stylize).
        let g = octave_loss(&d, &loss, &view, 2).unwrap().1;
        let g_fine = loss.loss_and_grad(&d, &view).unwrap().1;
        let g_blocks = loss.loss_and_grad(&blocks, &ViewSpec { gamma: 1.0, exposure: 1.0, ..view.clone() }).unwrap().1;
        let big = g_blocks.data.iter().fold(0f32, |m, v| m.max(v.abs())) / 8.0;
        assert!(big > 0.0);
        for z in 0..16 {
            for y in 0..16 {
                for x in 0..16 {
                    let i = d.index(x, y, z);
                    let want = g_blocks.data[blocks.index(x / 2, y / 2, z / 2)] / 8.0;
                    let got = g.data[i] - g_fine.data[i];
                    assert!((got - want).abs() <= 1e-4 * big, "voxel {x},{y},{z}: coarse gradient {got} vs {want}");
                }
            }
        }
    }

    /// The whole chain a training step descends, from the network's weights
    /// through the density scale, the kept total, the scale pin, a turned
    /// patch (or one seen through an oblique perspective camera) and the
    /// two-octave render and Gram loss, against finite differences: near the
    /// input's level and with the last bias thinning the patch (so the pin
    /// pulls hard). Every layer is checked, each along one direction (a
    /// per-weight check with a floor of 3 % of the largest gradient, as this
    /// was first, left the first layers' gradients, 10⁻⁴ of the last's at
    /// PyTorch's initialisation, under the floor).
    #[test]
    fn a_training_step_gradient_matches_finite_differences() {
        nst3d_core::precision::fp32(training_step_check)
    }

    fn training_step_check() {
        use nst3d_features::{Vgg19, VggFlavor};
        use nst3d_stylize::StyleSpec;
        let vgg = Vgg19::random(VggFlavor::Torchvision, 3);
        let style = nst3d_core::Image::from_vec(
            3,
            24,
            24,
            pseudo_random(3 * 24 * 24, 4).iter().map(|v| 0.5 + 0.4 * v).collect(),
        );
        let loss = ViewLoss::new(&vgg, &style, &StyleSpec::default()).unwrap();
        let view = ViewSpec { camera: None, gamma: 0.5, exposure: 0.5, equalize: false };
        let patch = Grid3::from_vec([12; 3], pseudo_random(1728, 11).iter().map(|v| 0.5 + 0.5 * v).collect());
        // What the step descends: the style loss it reports plus the pin.
        let oblique = Sight::From([0.48, 0.6, -0.64]);
        for (sight, bias) in
            [(Sight::Along(Axis::Y), 0.0f32), (Sight::Along(Axis::Y), -1.2), (oblique, 0.0), (oblique, -1.2)]
        {
            training_step_check_from(&patch, &loss, &view, sight, bias);
        }
    }

    /// The step of [`training_step_check_from`], a share of each layer's
    /// weights' mean size: at 1e-2 kinks crossed reached 4e-2.
    const STEP: f32 = 3e-3;

    fn training_step_check_from(patch: &Grid3, loss: &ViewLoss, view: &ViewSpec, sight: Sight, bias: f32) {
        let schedule = OneCycle::new(1e-4, 10, 20.0);
        let total = |net: &FeedForward| -> f64 {
            let t = TrainStep::new(net.clone(), Stylization::Density, schedule.clone());
            let l = t.gradient(patch, [0; 3], loss, view, &[sight]).unwrap().loss;
            let raw = apply(patch, &net.forward(&Volume::from_grid(patch)).0, Stylization::Density);
            let (_, k) = conserve_mass(patch, &raw);
            l as f64 + scale_pin(&raw, k, SCALE_PIN).0 as f64
        };
        let mut net = FeedForward::new(2, 1, 5);
        // A variance-keeping gain and small biases, so the first layers move
        // the loss by more than its f32 rounding (at PyTorch's initialisation
        // their gradients are 10⁻⁴ of the last layer's).
        for l in &mut net.layers {
            l.weight.iter_mut().for_each(|w| *w *= 2.45);
            l.bias.iter_mut().for_each(|b| *b *= 0.1);
        }
        *net.layers[nst3d_network::feedforward::LAYERS - 1].bias.last_mut().unwrap() = bias;
        let t = TrainStep::new(net.clone(), Stylization::Density, schedule.clone());
        let g = t.gradient(patch, [0; 3], loss, view, &[sight]).unwrap().grads;
        // Layer by layer along a direction with the gradient's signs, moved
        // by a share of the layer's weights' size: one difference quotient
        // checks every weight of the layer, far above the loss's rounding.
        let w = net.flat();
        let mut start = 0;
        for (l, layer) in net.layers.iter().enumerate() {
            let n = layer.weight.len();
            let range = start..start + n;
            start += n + layer.bias.len();
            let v: Vec<f32> = pseudo_random(n, 30 + l as u64)
                .iter()
                .zip(&g[range.clone()])
                .map(|(r, g)| r.abs() * g.signum())
                .collect();
            let step = STEP * w[range.clone()].iter().map(|x| x.abs()).sum::<f32>() / n as f32;
            let err = directional(&g[range.clone()], &v, step, |t| {
                let mut x = w.clone();
                x[range.clone()].iter_mut().zip(&v).for_each(|(x, v)| *x += t * v);
                let mut probe = net.clone();
                probe.set_flat(&x);
                total(&probe)
            });
            // Kinks crossed and f32 rounding: up to 1.1e-2 measured; a
            // gradient 20 % off scores 0.17.
            assert!(err < 3e-2, "{sight:?}, bias {bias}, layer {l}: relative error {err}");
        }
    }

    /// The chain through a solid texture: the loss (and pin) of a step with
    /// a texture of period 5 on a 12³ patch at a negative corner (texels
    /// under several voxels, wrapped on both sides), against finite
    /// differences along one direction of the texture's parameters (in the
    /// optimiser's scaling, `T / TEXTURE_RATE`) and of the last layer's
    /// weights (reached through the texture's scale).
    #[test]
    fn a_textured_training_step_gradient_matches_finite_differences() {
        nst3d_core::precision::fp32(textured_step_check)
    }

    fn textured_step_check() {
        use nst3d_features::{Vgg19, VggFlavor};
        use nst3d_stylize::StyleSpec;
        let vgg = Vgg19::random(VggFlavor::Torchvision, 3);
        let style =
            nst3d_core::Image::from_vec(3, 24, 24, pseudo_random(3 * 576, 4).iter().map(|v| 0.5 + 0.4 * v).collect());
        let loss = ViewLoss::new(&vgg, &style, &StyleSpec::default()).unwrap();
        let view = ViewSpec { camera: None, gamma: 0.5, exposure: 0.5, equalize: false };
        let patch = Grid3::from_vec([12; 3], pseudo_random(1728, 11).iter().map(|v| 0.5 + 0.5 * v).collect());
        let (at, sight) = ([-3, 4, -11], Sight::From([0.48, 0.6, -0.64]));
        let mut texture = SolidTexture::new(5, 2);
        texture.values.iter_mut().zip(pseudo_random(125, 6)).for_each(|(t, r)| *t = 1.2 * r);
        let fresh = || {
            TrainStep::new(FeedForward::new(2, 1, 5), Stylization::Density, OneCycle::new(1e-4, 10, 20.0))
                .with_texture(texture.clone())
        };
        let trainer = |p: &[f32]| {
            let mut t = fresh();
            t.set_params(p);
            t
        };
        let total = |p: &[f32]| -> f64 {
            let t = trainer(p);
            let l = t.gradient(&patch, at, &loss, &view, &[sight]).unwrap().loss;
            let styled = apply(&patch, &t.net.forward(&Volume::from_grid(&patch)).0, Stylization::Density);
            let raw = t.texture().unwrap().apply(&styled, at);
            let (_, k) = conserve_mass(&patch, &raw);
            l as f64 + scale_pin(&raw, k, SCALE_PIN).0 as f64
        };
        let p0 = fresh().params();
        let g = trainer(&p0).gradient(&patch, at, &loss, &view, &[sight]).unwrap().grads;
        let n_tex = texture.values.len();
        let last = nst3d_network::feedforward::LAYERS - 1;
        let net_n = p0.len() - n_tex;
        let last_layer = fresh().net.layers[last].clone();
        let last_w = net_n - last_layer.bias.len() - last_layer.weight.len();
        for (name, range) in [("texture", net_n..p0.len()), ("last layer", last_w..net_n)] {
            let n = range.len();
            let v: Vec<f32> =
                pseudo_random(n, 40).iter().zip(&g[range.clone()]).map(|(r, g)| r.abs() * g.signum()).collect();
            let step = 1e-2 * p0[range.clone()].iter().map(|x| x.abs()).sum::<f32>() / n as f32;
            let err = directional(&g[range.clone()], &v, step, |t| {
                let mut x = p0.clone();
                x[range.clone()].iter_mut().zip(&v).for_each(|(x, v)| *x += t * v);
                total(&x)
            });
            assert!(err < 3e-2, "{name}: relative error {err}");
        }
    }

    #[test]
    fn conserving_mass_keeps_the_total_and_its_gradient_matches_finite_differences() {
        let dims = [4, 5, 3];
        let d = Grid3::from_vec(dims, pseudo_random(60, 7).iter().map(|v| v.abs()).collect());
        let raw = Grid3::from_vec(dims, pseudo_random(60, 8).iter().map(|v| 0.2 + v.abs()).collect());
        let (scaled, k) = conserve_mass(&d, &raw);
        let sum = |g: &Grid3| g.data.iter().map(|v| *v as f64).sum::<f64>();
        assert!((sum(&scaled) - sum(&d)).abs() < 1e-4 * sum(&d));
        let w = pseudo_random(60, 9);
        let analytic = conserve_mass_backward(&raw, k, &w);
        let r = check_gradient(
            &raw.data,
            &analytic,
            |x| dot(&w, &conserve_mass(&d, &Grid3::from_vec(dims, x.to_vec())).0.data),
            // A smooth rational map: a large step keeps f32 rounding out.
            1e-2,
            60,
            1e-2,
        );
        assert!(r.max_rel_err < 1e-2, "{r:?}");
    }

    #[test]
    fn the_scale_pin_gradient_matches_finite_differences() {
        let dims = [4, 5, 3];
        let d = Grid3::from_vec(dims, pseudo_random(60, 7).iter().map(|v| v.abs()).collect());
        let pin = |x: &[f32]| {
            let raw = Grid3::from_vec(dims, x.to_vec());
            let (_, k) = conserve_mass(&d, &raw);
            scale_pin(&raw, k, 3.0)
        };
        // Below, at and above the input's level.
        for level in [0.1f32, 0.5, 2.0] {
            let raw: Vec<f32> = pseudo_random(60, 8).iter().map(|v| level * (0.2 + v.abs())).collect();
            let (p, g) = pin(&raw);
            assert!(p >= 0.0);
            let r = check_gradient(&raw, &vec![g; 60], |x| pin(x).0 as f64, 1e-2 * level, 60, 1e-2);
            assert!(r.max_rel_err < 1e-2, "level {level}: {r:?}");
        }
        // At the input's own total the pin is zero and flat.
        assert_eq!(pin(&d.data), (0.0, 0.0));
    }
}
