//! `nst3d volume --frames ...`: a whole simulation with the EMA temporal
//! coherence of Algorithm 1 (`nst3d_sequence::ema`).
//!
//! All frames are densified into one common box (the union of their active
//! boxes plus the velocity margin) so fields can be carried from frame to
//! frame; frames are read from disk when needed, so memory holds the fields
//! and a couple of frames, not the whole simulation.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use nst3d_core::Grid3;
use nst3d_io::vdb::{read_vdb, write_vdb, GridValues, Transform, VdbGrid};
use nst3d_sequence::ema::{stylize_sequence, stylized_density, MemoryStore, SequenceError, SequenceParams, Simulation};
use nst3d_sequence::{expand_pattern, FrameSpec};
use nst3d_stylize::{Mode, StyleSpec, ViewLoss, ViewSpec};

use crate::progress::Progress;
use crate::volume::{auto_absorption, check_args, frame_params, front_camera, load_style_and_vgg, VolumeArgs};

/// Velocity grid names solvers write: Blender `velocity`, Houdini `vel` or `v`.
const VELOCITY_NAMES: [&str; 3] = ["velocity", "vel", "v"];

/// A simulation on disk: one VDB per frame.
struct VdbSimulation {
    paths: Vec<PathBuf>,
    grid: String,
    velocity_grid: Option<String>,
    /// Voxels per frame per stored velocity unit.
    velocity_scale: f32,
    origin: [i32; 3],
    dims: [usize; 3],
}

impl VdbSimulation {
    fn err(&self, t: usize, e: impl std::fmt::Display) -> SequenceError {
        SequenceError::Frame { frame: t, message: format!("{}: {e}", self.paths[t].display()) }
    }

    /// Copies a dense block at index `origin` into the common box.
    fn place(&self, src_origin: [i32; 3], src: &Grid3, out: &mut Grid3) {
        let [nx, ny, nz] = src.dims;
        for z in 0..nz {
            for y in 0..ny {
                let (oy, oz) = (src_origin[1] + y as i32 - self.origin[1], src_origin[2] + z as i32 - self.origin[2]);
                let ox = src_origin[0] - self.origin[0];
                if oy < 0 || oz < 0 || oy as usize >= self.dims[1] || oz as usize >= self.dims[2] || ox < 0 {
                    continue;
                }
                let dst = out.index(ox as usize, oy as usize, oz as usize);
                let n = nx.min(self.dims[0] - ox as usize);
                out.data[dst..dst + n].copy_from_slice(&src.data[src.index(0, y, z)..][..n]);
            }
        }
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
            self.place(bx.origin, &dense, &mut out);
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
                self.place(bx.origin, d, c);
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
                    let upper = [(x + 1 < nx).then(|| i + 1), (y + 1 < ny).then(|| i + nx), (z + 1 < nz).then(|| i + nx * ny)];
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
}

/// Runs a sequence stylization.
pub fn run(args: VolumeArgs) -> Result<()> {
    check_args(&args)?;
    let spec = FrameSpec::parse(args.frames.as_deref().unwrap_or_default())?;
    let input = args.input.to_string_lossy().to_string();
    let output = args.out.to_string_lossy().to_string();
    let frames = spec.frames().to_vec();
    let paths: Vec<PathBuf> = frames.iter().map(|&f| expand_pattern(&input, f).map(PathBuf::from)).collect::<Result<_, _>>()?;
    let outs: Vec<PathBuf> = frames
        .iter()
        .map(|&f| expand_pattern(&output, f).map(PathBuf::from))
        .collect::<Result<_, _>>()
        .context("--out must be a pattern too when --frames is given")?;

    // One pass over the headers: every frame must read, have the grid, and
    // share one transform; the common box is the union of active boxes.
    let mut transform: Option<Transform> = None;
    let mut lo = [i32::MAX; 3];
    let mut hi = [i32::MIN; 3];
    let mut velocity_grid = args.velocity_grid.clone();
    for p in &paths {
        let file = read_vdb(p)?;
        let grid = file
            .grid(&args.grid)
            .with_context(|| format!("{}: no grid named '{}'", p.display(), args.grid))?;
        if matches!(grid.values, GridValues::Unsupported { .. } | GridValues::Vec3(_)) {
            bail!("{}: grid '{}' is not a float grid", p.display(), args.grid);
        }
        if grid.has_non_finite() {
            bail!("{}: grid '{}' has non-finite values", p.display(), args.grid);
        }
        match &transform {
            None => transform = Some(grid.transform.clone()),
            Some(t) if t.voxel_size != grid.transform.voxel_size => {
                bail!("{}: voxel size {:?} differs from the first frame's {:?}", p.display(), grid.transform.voxel_size, t.voxel_size)
            }
            _ => {}
        }
        if let Some((a, b)) = grid.active_bbox() {
            for k in 0..3 {
                lo[k] = lo[k].min(a[k]);
                hi[k] = hi[k].max(b[k]);
            }
        }
        if velocity_grid.is_none() {
            velocity_grid = VELOCITY_NAMES.iter().find(|n| file.grid(n).is_some()).map(|n| n.to_string());
        }
    }
    if lo[0] > hi[0] {
        bail!("every frame's grid '{}' is empty: nothing to stylize", args.grid);
    }
    let extent = (0..3).map(|k| (hi[k] - lo[k] + 1) as usize).max().unwrap_or(1);
    let vmax = args.vmax.unwrap_or((0.04 * extent as f32).max(1.0));
    let margin = match args.mode {
        Mode::Velocity => vmax.ceil() as i32 + 1,
        Mode::Density => 0,
    };
    let origin = lo.map(|v| v - margin);
    let dims: [usize; 3] = std::array::from_fn(|k| (hi[k] - lo[k] + 1 + 2 * margin) as usize);
    if dims.iter().product::<usize>() > (1 << 28) {
        bail!("the frames' common box {dims:?} is too large to stylize densely");
    }
    let mut sim = VdbSimulation { paths, grid: args.grid.clone(), velocity_grid, velocity_scale: 1.0, origin, dims };
    if sim.velocity_grid.is_some() {
        sim.velocity_scale = match args.velocity_scale {
            Some(s) if s.is_finite() && s >= 0.0 => s,
            Some(s) => bail!("--velocity-scale must be a non-negative number, got {s}"),
            None => calibrate(&sim)?,
        };
    }
    eprintln!(
        "{} frames, common box {}x{}x{} at {:?}, velocity grid {} (x{:.4} voxels/frame)",
        sim.len(),
        dims[0],
        dims[1],
        dims[2],
        origin,
        sim.velocity_grid.as_deref().unwrap_or("none"),
        sim.velocity_scale
    );

    let (style, vgg) = load_style_and_vgg(&args)?;
    let camera = front_camera(dims, args.up, args.camera, args.fov);
    let gamma = match args.absorption {
        Some(g) if g.is_finite() && g > 0.0 => g,
        Some(g) => bail!("--absorption must be a positive number, got {g}"),
        // The densest frame sets the absorption for all, so brightness does not pump.
        None => {
            let mut best = f32::INFINITY;
            for t in 0..sim.len() {
                if let Ok(g) = auto_absorption(&sim.density(t)?, &camera) {
                    best = best.min(g);
                }
            }
            best
        }
    };
    let view = ViewSpec { camera: Some(camera), gamma, exposure: gamma, equalize: args.equalize };
    let style_spec = StyleSpec { layers: args.layers.clone(), layer_weights: vec![1.0; args.layers.len()] };
    let loss = ViewLoss::new(&vgg, &style, &style_spec)?;
    let params = SequenceParams { frame: frame_params(&args, vmax, &view), alpha: args.ema };

    let n = sim.len();
    let mut store = MemoryStore::default();
    let mut progress = Progress::new((args.octaves * args.iters * n) as u64);
    stylize_sequence(&sim, &loss, std::slice::from_ref(&view), &params, &mut store, &mut |p| {
        progress.step(format!(
            "octave {} sweep {}/{} frame {} loss {:.4e}",
            p.octave + 1,
            p.iteration,
            args.iters,
            frames[p.frame],
            p.loss
        ))
    })?;
    progress.finish();

    let transform = transform.expect("at least one frame");
    let mut stylized = Vec::with_capacity(n);
    let mut losses = 0.0;
    for t in 0..n {
        let d = stylized_density(&sim, &mut store, t)?;
        if d.data.iter().any(|v| !v.is_finite()) {
            bail!("frame {}: stylization produced non-finite densities (try a smaller --lr)", frames[t]);
        }
        losses += loss.loss(&d, &view)?;
        let file = read_vdb(&sim.paths[t])?;
        let src = file.grid(&args.grid).expect("checked above");
        let mut out = VdbGrid::from_dense(&src.name, transform.clone(), origin, &d, 0.0);
        out.metadata = src.metadata.clone();
        out.class = src.class.clone();
        let grids: Vec<VdbGrid> = file
            .grids
            .iter()
            .filter(|g| !matches!(g.values, GridValues::Unsupported { .. }))
            .map(|g| if g.name == src.name { out.clone() } else { g.clone() })
            .collect();
        write_vdb(&outs[t], &grids)?;
        stylized.push(d);
    }
    let velocities: Vec<_> = (0..n).map(|t| sim.velocity(t)).collect::<Result<_, _>>()?;
    let render = |d: &Grid3| loss.image(d, &view).expect("the view rendered during optimisation");
    let flicker = nst3d_sequence::flicker::flicker(&stylized, &velocities, render);
    println!(
        "{} frames stylized ({:?} mode, EMA {}); mean style loss {:.4e}; flicker {:.5}; wrote {}",
        n,
        args.mode,
        args.ema,
        losses / n as f32,
        flicker,
        output
    );
    Ok(())
}

/// Fits the velocity scale on the middle pair of frames that both have smoke.
fn calibrate(sim: &VdbSimulation) -> Result<f32> {
    let n = sim.len();
    for t in (n / 2..n.saturating_sub(1)).chain(0..n / 2) {
        let (d0, d1) = (sim.density(t)?, sim.density(t + 1)?);
        if d0.max() <= 0.0 || d1.max() <= 0.0 {
            continue;
        }
        let saved = sim.velocity_scale;
        let unit = VdbSimulation { velocity_scale: 1.0, paths: sim.paths.clone(), grid: sim.grid.clone(), velocity_grid: sim.velocity_grid.clone(), ..*sim };
        let _ = saved;
        if let Some(u) = unit.velocity(t)? {
            if let Some(s) = nst3d_sequence::calibrate::velocity_scale(&d0, &d1, &u) {
                return Ok(s);
            }
        }
    }
    Ok(0.0)
}
