//! The network's output applied to a density (Sec. 4): a density scale
//! (eq. 3) or a velocity that transports the smoke (eq. 1), at the trained
//! strength or raised for inference. Training (`nst3d-train`) and the
//! volume job's inference share it.

use nst3d_core::Grid3;
use nst3d_transport::advect_linear;
use rayon::prelude::*;

use crate::Volume;

/// How the network's output changes the density.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Stylization {
    /// `d* = d · s`, `s = 1 + tanh(o) ∈ [0, 2]` (eq. 3, one output channel).
    Density,
    /// `d* = I(d, g + v)`, `v = vmax · tanh(o)` voxels (eq. 1, three channels).
    Velocity {
        /// Largest displacement per axis, in voxels.
        vmax: f32,
    },
}

impl Stylization {
    /// Output channels the network needs.
    pub fn channels(self) -> usize {
        match self {
            Stylization::Density => 1,
            Stylization::Velocity { .. } => 3,
        }
    }
}

/// `d*` from the density `d` and the network's raw output `o`.
pub fn apply(d: &Grid3, o: &Volume, s: Stylization) -> Grid3 {
    apply_with_strength(d, o, s, 1.0)
}

/// [`apply`] with the stylization raised to `strength` (inference only; 1 is
/// the trained network): density mode scales by `s^strength` (the log-scale
/// field times `strength`), velocity mode moves by `strength · v`.
pub fn apply_with_strength(d: &Grid3, o: &Volume, s: Stylization, strength: f32) -> Grid3 {
    match s {
        Stylization::Density => {
            // `powf` is most of a voxel's cost; at strength 1 (training) it is the identity.
            let scale = |o: f32| if strength == 1.0 { 1.0 + o.tanh() } else { (1.0 + o.tanh()).powf(strength) };
            let data = d.data.par_iter().zip(o.data.par_iter()).with_min_len(CHUNK).map(|(d, &o)| d * scale(o));
            Grid3::from_vec(d.dims, data.collect())
        }
        Stylization::Velocity { vmax } => advect_linear(d, &velocity_field(o, strength * vmax)),
    }
}

/// Voxels an elementwise task over a patch or frame takes at least (a 64³
/// patch is 262,144): the training step's elementwise backward uses it too.
pub const CHUNK: usize = 1 << 14;

/// `vmax · tanh(o)` as one `[x, y, z]` vector per voxel.
pub fn velocity_field(o: &Volume, vmax: f32) -> Vec<[f32; 3]> {
    let n = o.voxels();
    (0..n)
        .into_par_iter()
        .with_min_len(CHUNK)
        .map(|i| std::array::from_fn(|a| vmax * o.data[a * n + i].tanh()))
        .collect()
}

/// `Σ before / Σ after`, or 1 when either is not positive (nothing to keep).
pub fn mass_ratio(before: f64, after: f64) -> f32 {
    if before > 0.0 && after > 0.0 {
        (before / after) as f32
    } else {
        1.0
    }
}

/// The `mass` a density model trained with the training's scale pin declares in its
/// metadata (velocity models and older density models say `conserved`).
pub const MASS_PINNED: &str = "conserved, scale pinned";
