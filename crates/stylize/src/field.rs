//! The quantity the optimiser changes: a stylisation velocity `v` (velocity
//! mode, `d* = I(d, g + v)`, paper eq. 2) or a density scale `s` (density
//! mode, `d* = d · s`, eq. 5). Both live on the grid of the density they act
//! on and expose their values as one flat slice so a single Adam runs both.

use nst3d_core::Grid3;
use nst3d_transport as transport;

/// Which field is optimised.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Optimise a velocity; density is transported by the linear mapping.
    Velocity,
    /// Optimise a per-voxel scale of the density.
    Density,
}

impl std::str::FromStr for Mode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "velocity" => Ok(Mode::Velocity),
            "density" => Ok(Mode::Density),
            _ => Err(format!("unknown mode '{s}' (expected velocity or density)")),
        }
    }
}

/// The optimised field on a grid of `dims` voxels.
#[derive(Clone, Debug)]
pub enum Field {
    /// Velocity parameters `w`, one vector per voxel in voxel units of its
    /// grid. The density moves by their smooth version `v = S w`
    /// ([`Field::velocity`]; docs/design/volumes.md says why).
    Velocity(Vec<[f32; 3]>),
    /// Per-voxel density scales `s`: the density is multiplied by `s`
    /// itself, and the optimiser steps along the tent-smoothed gradient
    /// ([`Field::descent`]; docs/design/volumes.md).
    Scale(Vec<f32>),
}

/// What [`Field::backward`] needs from [`Field::forward`]: the smoothed
/// velocity `S w` the density was moved by (velocity mode).
#[derive(Clone, Debug)]
pub struct Tape {
    velocity: Option<Vec<[f32; 3]>>,
}

/// The hard limits of Sec. 3.3: `‖v‖ ≤ vmax` or `s ∈ [smin, smax]`.
#[derive(Clone, Copy, Debug)]
pub struct Limits {
    /// Largest velocity norm, in voxels of the finest octave.
    pub vmax: f32,
    /// Smallest density scale.
    pub smin: f32,
    /// Largest density scale.
    pub smax: f32,
}

impl Field {
    /// The identity transport: zero velocity or unit scale.
    pub fn identity(mode: Mode, voxels: usize) -> Self {
        match mode {
            Mode::Velocity => Field::Velocity(vec![[0.0; 3]; voxels]),
            Mode::Density => Field::Scale(vec![1.0; voxels]),
        }
    }

    /// The identity plus a tiny fixed pseudo-random perturbation (1/100 of a
    /// voxel, or of the scale), the start of every optimisation.
    ///
    /// Why not exactly the identity: started at exactly zero, velocity mode
    /// drew a line down the middle of mirror-symmetric smoke (a centred
    /// source seen by the centred front camera: smoke_000002's cap and stem,
    /// plume48's stem, where it also showed as box-like bars), and this
    /// perturbation removes it (docs/design/volumes.md).
    /// Two things a symmetric start keeps: the two mirrored halves of the
    /// pattern meeting on the axis, and every sample sitting exactly on a
    /// voxel centre, where trilinear sampling has a kink and the first
    /// gradient is one-sided. The perturbation is seeded, so results stay
    /// reproducible, and far below anything visible.
    pub fn initial(mode: Mode, voxels: usize) -> Self {
        let mut f = Self::identity(mode, voxels);
        let mut rng = nst3d_core::math::SplitMix64::new(0x5eed);
        f.params_mut().iter_mut().for_each(|p| *p += 0.01 * (2.0 * rng.uniform_f32() - 1.0));
        f
    }

    /// Number of scalar parameters.
    pub fn len(&self) -> usize {
        self.params().len()
    }

    /// True when there are no parameters.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The parameters as one flat slice (for the optimiser).
    pub fn params(&self) -> &[f32] {
        match self {
            Field::Velocity(v) => v.as_flattened(),
            Field::Scale(s) => s,
        }
    }

    /// Mutable flat parameters.
    pub fn params_mut(&mut self) -> &mut [f32] {
        match self {
            Field::Velocity(v) => v.as_flattened_mut(),
            Field::Scale(s) => s,
        }
    }

    /// The velocity `v = S w` that moves the density (velocity mode), for a
    /// field on a grid of `dims` voxels; `None` for a scale field.
    ///
    /// Optimised voxel by voxel, a velocity turns into voxel-scale noise: its
    /// gradient is the image gradient times the slope of the piecewise-linear
    /// density at `g + v`, which flips sign from voxel to voxel, and Adam's
    /// steps are about `±lr` per component whatever the gradient's size. Such
    /// a field scrambles dense smoke into blocks and gives edges staircases
    /// along the grid axes. Moving the density by `S w`, one tent pass of the
    /// optimised parameters ([`transport::tent_smooth`]), keeps every velocity
    /// smooth over at least three voxels, and `‖w‖ ≤ vmax` still bounds `‖v‖`.
    ///
    /// # Panics
    /// If the field does not have one vector per voxel of `dims`.
    pub fn velocity(&self, dims: [usize; 3]) -> Option<Vec<[f32; 3]>> {
        match self {
            Field::Velocity(w) => Some(transport::tent_smooth(w, dims)),
            Field::Scale(_) => None,
        }
    }

    /// The scale `s` that multiplies the density (density mode); `None` for
    /// a velocity field.
    pub fn scale(&self) -> Option<&[f32]> {
        match self {
            Field::Scale(s) => Some(s),
            Field::Velocity(_) => None,
        }
    }

    /// `d* = T(d, field)`: `I(d, g + S w)` or `d · s`.
    pub fn transport(&self, d: &Grid3) -> Grid3 {
        self.forward(d).0
    }

    /// [`Field::transport`], keeping in a [`Tape`] what
    /// [`Field::backward`] needs, so that an iteration smooths `w` once.
    pub fn forward(&self, d: &Grid3) -> (Grid3, Tape) {
        match self {
            Field::Velocity(_) => {
                let v = self.velocity(d.dims).expect("velocity field");
                (transport::advect_linear(d, &v), Tape { velocity: Some(v) })
            }
            Field::Scale(s) => (transport::modulate(d, s), Tape { velocity: None }),
        }
    }

    /// Gradient w.r.t. the flat parameters from the gradient w.r.t. `d*`.
    pub fn transport_backward(&self, d: &Grid3, grad_out: &[f32]) -> Vec<f32> {
        let tape = Tape { velocity: self.velocity(d.dims) };
        self.backward(d, &tape, grad_out)
    }

    /// Backward of [`Field::forward`]: the gradient w.r.t. the flat
    /// parameters from the gradient w.r.t. `d*` and the forward's tape.
    ///
    /// # Panics
    /// If `tape` is not from this field's forward on a grid of `d`'s size.
    pub fn backward(&self, d: &Grid3, tape: &Tape, grad_out: &[f32]) -> Vec<f32> {
        match self {
            Field::Velocity(w) => {
                let v = tape.velocity.as_deref().expect("the tape of a velocity field");
                let mut g = vec![[0.0f32; 3]; w.len()];
                transport::advect_linear_backward(d, v, grad_out, &mut g);
                // `S` is symmetric, so it is its own adjoint: ∂L/∂w = S ∂L/∂v.
                transport::tent_smooth(&g, d.dims).into_flattened()
            }
            Field::Scale(s) => {
                let mut g = vec![0.0f32; s.len()];
                transport::modulate_backward(d, grad_out, &mut g);
                g
            }
        }
    }

    /// The direction the optimiser is given for a gradient `grad` of this
    /// field's parameters on a grid of `dims` voxels: the gradient itself in
    /// velocity mode (its smoothing is in the parameterisation, `v = S w`),
    /// the tent-smoothed gradient `S ∇` in density mode.
    ///
    /// Why density mode smooths the step and not the field: stepped along
    /// the raw gradient, per-voxel scales drew small grid-aligned marks in
    /// dense smoke — Adam moves every voxel by about `±lr` however small
    /// its gradient, so the patterns the renders cannot tell apart
    /// (neighbouring voxels pulling opposite ways) grow as fast as the ones
    /// they can. `S` removes them from every step (it has no response at
    /// the grid's Nyquist frequency). Smoothing the field instead,
    /// `d · (1 + S (s − 1))`, also removed them, but it smoothed twice
    /// (the field and, through its adjoint, the gradient), and the strokes
    /// lost about a third of their strength from views the optimiser never
    /// saw (docs/design/volumes.md). `S` is positive semi-definite (its
    /// frequency response is `cos²`), so `S ∇` is still a descent direction.
    pub fn descent(&self, grad: Vec<f32>, dims: [usize; 3]) -> Vec<f32> {
        match self {
            Field::Velocity(_) => grad,
            Field::Scale(_) => transport::tent_smooth_flat(&grad, 1, dims),
        }
    }

    /// Projects onto the feasible set after an optimiser step. `vmax` is
    /// given in voxels of this field's grid.
    pub fn constrain(&mut self, limits: &Limits, vmax_here: f32) {
        match self {
            Field::Velocity(v) => transport::limit_velocity(v, vmax_here),
            Field::Scale(s) => transport::clamp_scale(s, limits.smin, limits.smax),
        }
    }

    /// The field carried along a displacement `u` (voxels, one vector per
    /// voxel of `dims`) by one semi-Lagrangian step: the value at `g` is read
    /// at `g - u(g)`. This is `T(v̂, u)` of eq. 4. Outside the grid a velocity
    /// reads as 0 and a scale as 1 (no change).
    pub fn carried(&self, dims: [usize; 3], u: &[[f32; 3]]) -> Field {
        let back: Vec<[f32; 3]> = u.iter().map(|w| [-w[0], -w[1], -w[2]]).collect();
        let carry = |values: Vec<f32>| transport::advect_linear(&Grid3::from_vec(dims, values), &back).data;
        match self {
            Field::Velocity(v) => {
                let comps: Vec<Vec<f32>> = (0..3).map(|a| carry(v.iter().map(|x| x[a]).collect())).collect();
                Field::Velocity((0..v.len()).map(|i| [comps[0][i], comps[1][i], comps[2][i]]).collect())
            }
            // Carry the deviation from 1 so that scale read from outside is 1.
            Field::Scale(s) => {
                Field::Scale(carry(s.iter().map(|x| x - 1.0).collect()).iter().map(|x| x + 1.0).collect())
            }
        }
    }

    /// The exponential moving average of eq. 4: `(1 - α)·self + α·other`.
    pub fn blend(&mut self, other: &Field, alpha: f32) {
        for (a, b) in self.params_mut().iter_mut().zip(other.params()) {
            *a = (1.0 - alpha) * *a + alpha * b;
        }
    }

    /// Carries the field to a grid of `to` voxels (the next, finer octave).
    /// Velocities are rescaled because they are measured in voxels.
    pub fn resize(&self, from: [usize; 3], to: [usize; 3]) -> Field {
        match self {
            Field::Velocity(v) => Field::Velocity(transport::resize_velocity(v, from, to)),
            Field::Scale(s) => {
                let g = Grid3::from_vec(from, s.clone());
                Field::Scale(transport::resize_grid(&g, to).data)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn carried_follows_the_displacement_and_blend_is_the_ema() {
        let dims = [6, 1, 1];
        let mut v = vec![[0.0f32; 3]; 6];
        v[2] = [1.0, 2.0, 3.0];
        let u = vec![[1.0, 0.0, 0.0]; 6];
        let Field::Velocity(c) = Field::Velocity(v).carried(dims, &u) else { unreachable!() };
        assert_eq!(c[3], [1.0, 2.0, 3.0], "moved one voxel along +x");
        assert_eq!(c[0], [0.0; 3], "read from outside: zero velocity");

        let Field::Scale(s) = Field::Scale(vec![2.0; 6]).carried(dims, &u) else { unreachable!() };
        assert_eq!(s[0], 1.0, "read from outside: unit scale");
        assert_eq!(s[5], 2.0);

        let mut a = Field::Scale(vec![1.0; 6]);
        a.blend(&Field::Scale(vec![3.0; 6]), 0.25);
        assert_eq!(a.params(), &[1.5; 6]);
    }
}
