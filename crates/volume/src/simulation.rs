//! A simulation on disk, one OpenVDB file per frame, as the EMA sweeps of
//! Algorithm 1 read it ([`nst3d_sequence::ema::Simulation`]): every frame's
//! density and velocity in one common dense box, so fields can be carried
//! from frame to frame.

use std::path::PathBuf;

use anyhow::Result;
use nst3d_core::Grid3;
use nst3d_io::vdb::read_vdb;
use nst3d_sequence::ema::{SequenceError, Simulation};

use crate::dense::paste;

/// Velocity grid names solvers write: Blender `velocity`, Houdini `vel` or `v`.
pub const VELOCITY_NAMES: [&str; 3] = ["velocity", "vel", "v"];

/// The frames of a simulation in one common box.
#[derive(Clone)]
pub struct VdbSimulation {
    /// One file per frame, in order.
    pub paths: Vec<PathBuf>,
    /// The density grid's name.
    pub grid: String,
    /// The velocity grid's name, if the simulation has one.
    pub velocity_grid: Option<String>,
    /// Voxels per frame per stored velocity unit.
    pub velocity_scale: f32,
    /// Index of the common box's voxel (0,0,0).
    pub origin: [i32; 3],
    /// The common box's size.
    pub dims: [usize; 3],
    /// `linked[t]`: frame `t` directly follows frame `t − 1` (no empty frame
    /// was taken out between them), so the EMA carries fields across.
    pub linked: Vec<bool>,
}

impl VdbSimulation {
    fn err(&self, t: usize, e: impl std::fmt::Display) -> SequenceError {
        SequenceError::Frame { frame: t, message: format!("{}: {e}", self.paths[t].display()) }
    }

    /// Fits the velocity scale (voxels per frame per stored unit) on the
    /// middle pair of frames that both have smoke: solvers store velocity in
    /// different units, and the EMA needs it in voxels per frame.
    pub fn calibrate(&self) -> Result<f32> {
        let n = self.len();
        let unit = VdbSimulation { velocity_scale: 1.0, ..self.clone() };
        for t in (n / 2..n.saturating_sub(1)).chain(0..n / 2) {
            let (d0, d1) = (self.density(t)?, self.density(t + 1)?);
            if d0.max() <= 0.0 || d1.max() <= 0.0 {
                continue;
            }
            if let Some(u) = unit.velocity(t)? {
                if let Some(s) = nst3d_sequence::calibrate::velocity_scale(&d0, &d1, &u) {
                    return Ok(s);
                }
            }
        }
        Ok(0.0)
    }
}

impl Simulation for VdbSimulation {
    fn len(&self) -> usize {
        self.paths.len()
    }
    fn dims(&self) -> [usize; 3] {
        self.dims
    }
    fn density(&self, t: usize) -> Result<Grid3, SequenceError> {
        let file = read_vdb(&self.paths[t]).map_err(|e| self.err(t, e))?;
        let grid = file.grid(&self.grid).ok_or_else(|| self.err(t, format!("no grid named '{}'", self.grid)))?;
        let mut out = Grid3::zeros(self.dims);
        if grid.active_voxel_count() > 0 {
            let (bx, dense) = grid.to_dense().map_err(|e| self.err(t, e))?;
            paste(&dense, bx.origin, &mut out, self.origin);
        }
        Ok(out)
    }
    fn velocity(&self, t: usize) -> Result<Option<Vec<[f32; 3]>>, SequenceError> {
        let Some(name) = &self.velocity_grid else { return Ok(None) };
        let file = read_vdb(&self.paths[t]).map_err(|e| self.err(t, e))?;
        let Some(grid) = file.grid(name) else { return Ok(None) };
        let mut comps = [Grid3::zeros(self.dims), Grid3::zeros(self.dims), Grid3::zeros(self.dims)];
        if grid.active_voxel_count() > 0 {
            let (bx, dense) = grid.to_dense_vec3().map_err(|e| self.err(t, e))?;
            for (c, d) in comps.iter_mut().zip(&dense) {
                paste(d, bx.origin, c, self.origin);
            }
        }
        // A staggered (MAC) grid stores component a on the lower face along a:
        // the centre value is the mean of the two faces.
        let staggered = grid.class == "staggered";
        let g = &comps[0];
        let mut u = vec![[0.0f32; 3]; g.len()];
        let [nx, ny, nz] = self.dims;
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    let i = g.index(x, y, z);
                    let upper =
                        [(x + 1 < nx).then(|| i + 1), (y + 1 < ny).then(|| i + nx), (z + 1 < nz).then(|| i + nx * ny)];
                    for a in 0..3 {
                        let c = &comps[a].data;
                        let v = match (staggered, upper[a]) {
                            (true, Some(j)) => 0.5 * (c[i] + c[j]),
                            _ => c[i],
                        };
                        u[i][a] = v * self.velocity_scale;
                    }
                }
            }
        }
        Ok(Some(u))
    }
    fn linked(&self, t: usize) -> bool {
        self.linked.get(t).copied().unwrap_or(true)
    }
}
