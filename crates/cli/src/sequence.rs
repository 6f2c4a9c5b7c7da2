//! `nst3d volume --frames ...`: a whole simulation with the EMA temporal
//! coherence of Algorithm 1 (`nst3d_sequence::ema`).
//!
//! All frames are densified into one common box (the union of their active
//! boxes plus the velocity margin) so fields can be carried from frame to
//! frame. Frames are read from disk when needed and every frame's field and
//! Adam moments live in a work folder ([`DiskStore`]), always, whatever the
//! sequence length: memory holds a few frames, and a killed run resumes from
//! its last completed sweep. Farm chunks optimise their frames plus a
//! warm-up overlap but derive the box, velocity scale and absorption from
//! the whole --frames range, so every chunk solves the same problem.
//!
//! Frames whose grid is empty (a simulation's first frames often are) are
//! copied to the output unchanged and cut the EMA chain; frames without a
//! velocity grid are carried to their neighbour unmoved (identity advection),
//! so the EMA still couples them, only without following the flow.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use nst3d_core::Grid3;
use nst3d_io::vdb::{read_vdb, write_vdb, GridValues, Transform, VdbGrid};
use nst3d_sequence::ema::{stylize_sequence_with, SequenceError, SequenceParams, Simulation, StateStore};
use nst3d_sequence::{expand_pattern, DiskStore, FrameSpec};
use nst3d_stylize::{Mode, StyleSpec, ViewLoss, ViewSpec};

use crate::progress::Progress;
use crate::volume::{
    absorption_for, check_args, frame_params, load_style_and_vgg, mean_loss, views_of, Cameras, VolumeArgs,
};

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
    /// `linked[t]`: frame `t` directly follows frame `t − 1` (no empty frame
    /// was taken out between them), so the EMA carries fields across.
    linked: Vec<bool>,
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

/// A farm chunk: `START-END` (frame numbers, inclusive).
fn parse_chunk(s: &str) -> Result<(i64, i64)> {
    let spec = FrameSpec::parse(s).with_context(|| format!("--chunk '{s}'"))?;
    let f = spec.frames();
    if f.len() != (f[f.len() - 1] - f[0] + 1) as usize {
        bail!("--chunk '{s}' must be one range START-END");
    }
    Ok((f[0], f[f.len() - 1]))
}

/// FNV-1a, 64 bits: a stable name for a job's work folder (the same on
/// every machine and build, unlike the standard library's hasher).
fn fnv1a(bytes: &[u8], mut h: u64) -> u64 {
    for b in bytes {
        h ^= *b as u64;
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

/// Everything the optimised states depend on, so a work folder is only
/// reused by the same job: settings, the style image and camera file
/// contents, and each input frame's size and modification time.
fn job_hash(args: &VolumeArgs, run_paths: &[PathBuf]) -> Result<u64> {
    let settings = format!(
        "{:?}|{:?}|{:?}|{}|{:?}|{}|{}|{:?}|{:?}|{}|{}|{:?}|{:?}|{}|{}|{}|{}|{:?}|{:?}|{}|{}|{}|{}|{:?}|{}|{:?}|{}|{:?}",
        args.input,
        args.frames,
        args.chunk,
        args.warmup,
        args.out,
        args.ema,
        args.ema_settle,
        args.velocity_grid,
        args.velocity_scale,
        args.grid,
        matches!(args.mode, Mode::Velocity),
        args.lr,
        args.vmax,
        args.octaves,
        args.iters,
        args.smin,
        args.smax,
        args.absorption,
        args.layers.iter().map(|l| format!("{l:?}")).collect::<Vec<_>>(),
        args.style_scale,
        args.style_color,
        args.equalize,
        matches!(args.camera, crate::volume::CameraKind::Perspective),
        args.fov,
        matches!(args.up, crate::volume::UpAxis::Z),
        args.cameras,
        args.camera_seed,
        args.weights,
    );
    let mut read = vec![args.style.clone()];
    read.extend(args.camera_file.clone());
    job_fingerprint(&settings, &read, run_paths)
}

/// A stable hash of a job: its `settings` text, the contents of the files
/// in `read` (small: a painting, a camera file) and the path, size and
/// modification time of the files in `stamped` (the input frames).
pub(crate) fn job_fingerprint(settings: &str, read: &[PathBuf], stamped: &[PathBuf]) -> Result<u64> {
    let mut h = fnv1a(settings.as_bytes(), 0xcbf2_9ce4_8422_2325);
    for p in read {
        h = fnv1a(&std::fs::read(p).with_context(|| format!("{}", p.display()))?, h);
    }
    for p in stamped {
        let meta = std::fs::metadata(p).with_context(|| format!("{}", p.display()))?;
        let mtime =
            meta.modified().ok().and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok()).map_or(0, |d| d.as_nanos());
        h = fnv1a(format!("{}|{}|{mtime}", p.display(), meta.len()).as_bytes(), h);
    }
    Ok(h)
}

/// Runs a sequence stylization: the whole of --frames, or one --chunk of it
/// with --warmup frames of overlap (docs/FARM.md).
pub fn run(args: VolumeArgs) -> Result<()> {
    check_args(&args)?;
    let spec = FrameSpec::parse(args.frames.as_deref().unwrap_or_default())?;
    let input = args.input.to_string_lossy().to_string();
    let output = args.out.to_string_lossy().to_string();
    let all = spec.frames().to_vec();
    if args.warmup < 0 {
        bail!("--warmup must be 0 or more frames, got {}", args.warmup);
    }
    let (start, end) = match &args.chunk {
        Some(c) => parse_chunk(c)?,
        None => (all[0], all[all.len() - 1]),
    };
    let written: Vec<i64> = spec.within(start, end);
    if written.is_empty() {
        bail!("--chunk {start}-{end} holds none of the frames {}", args.frames.as_deref().unwrap_or_default());
    }
    // The chunk optimises its frames plus the warm-up on each side.
    let run_frames = spec.within(start.saturating_sub(args.warmup), end.saturating_add(args.warmup));
    let path_of = |f: i64| expand_pattern(&input, f).map(PathBuf::from);
    let out_of = |f: i64| {
        expand_pattern(&output, f).map(PathBuf::from).context("--out must be a pattern too when --frames is given")
    };
    let paths: Vec<PathBuf> = all.iter().map(|&f| path_of(f)).collect::<Result<_, _>>()?;
    let outs: Vec<PathBuf> = run_frames.iter().map(|&f| out_of(f)).collect::<Result<_, _>>()?;
    let is_written = |f: i64| (start..=end).contains(&f);
    let todo: Vec<usize> =
        (0..run_frames.len()).filter(|&i| is_written(run_frames[i]) && (args.force || !outs[i].exists())).collect();
    let existing = written.len() - todo.len();
    if todo.is_empty() {
        println!("all {} frames {start}-{end} already exist; nothing to do (--force redoes them)", written.len());
        return Ok(());
    }
    if existing > 0 {
        eprintln!("{existing} of {} frames already exist and are kept (--force redoes them)", written.len());
    }

    // One pass over ALL frames of --frames, not just the chunk: the common
    // box, the velocity scale and the absorption must be the same in every
    // chunk or the chunks would not blend at their seams.
    let mut transform: Option<Transform> = None;
    let mut lo = [i32::MAX; 3];
    let mut hi = [i32::MIN; 3];
    // Frames whose grid has no active voxel (a simulation's first frames
    // often do): nothing to stylize, so they are written unchanged and the
    // EMA chain is cut there rather than carried through emptiness.
    let mut empty = Vec::with_capacity(paths.len());
    let mut grid_names: Vec<Vec<String>> = Vec::with_capacity(paths.len());
    for p in &paths {
        let file = read_vdb(p)?;
        let grid = file.grid(&args.grid).with_context(|| format!("{}: no grid named '{}'", p.display(), args.grid))?;
        if matches!(grid.values, GridValues::Unsupported { .. } | GridValues::Vec3(_)) {
            bail!("{}: grid '{}' is not a float grid", p.display(), args.grid);
        }
        if grid.has_non_finite() {
            bail!("{}: grid '{}' has non-finite values", p.display(), args.grid);
        }
        grid_names.push(file.grids.iter().map(|g| g.name.clone()).collect());
        let Some((a, b)) = grid.active_bbox() else {
            empty.push(true);
            continue;
        };
        empty.push(false);
        // The transform of an empty frame does not matter: it is copied as it is.
        match &transform {
            None => transform = Some(grid.transform.clone()),
            Some(t) if t.voxel_size != grid.transform.voxel_size => {
                bail!(
                    "{}: voxel size {:?} differs from the first frame's {:?}",
                    p.display(),
                    grid.transform.voxel_size,
                    t.voxel_size
                )
            }
            _ => {}
        }
        for k in 0..3 {
            lo[k] = lo[k].min(a[k]);
            hi[k] = hi[k].max(b[k]);
        }
    }
    let Some(transform) = transform else {
        bail!("every frame's grid '{}' is empty: nothing to stylize", args.grid);
    };
    let has = |i: usize, name: &str| grid_names[i].iter().any(|g| g == name);
    let live_all: Vec<usize> = (0..paths.len()).filter(|&i| !empty[i]).collect();
    let velocity_grid = match &args.velocity_grid {
        Some(v) if !live_all.iter().any(|&i| has(i, v)) => {
            bail!("no frame with smoke has a velocity grid '{v}' (grids: {})", grid_names[live_all[0]].join(", "))
        }
        Some(v) => Some(v.clone()),
        None => VELOCITY_NAMES.iter().find(|n| live_all.iter().any(|&i| has(i, n))).map(|n| n.to_string()),
    };
    match &velocity_grid {
        None => eprintln!(
            "nst3d: note: no velocity grid (looked for {}): the EMA carries each frame's field to the next \
             unmoved (no advection)",
            VELOCITY_NAMES.join(", ")
        ),
        Some(v) => {
            let missing: Vec<i64> = live_all.iter().filter(|&&i| !has(i, v)).map(|&i| all[i]).collect();
            if !missing.is_empty() {
                eprintln!(
                    "nst3d: note: frames {missing:?} have no grid '{v}': the EMA carries their fields to the next \
                     frame unmoved"
                );
            }
        }
    }
    let is_empty = |f: i64| all.iter().position(|&a| a == f).is_some_and(|i| empty[i]);
    let passed: Vec<i64> = todo.iter().map(|&i| run_frames[i]).filter(|&f| is_empty(f)).collect();
    if !passed.is_empty() {
        eprintln!(
            "nst3d: note: frames {passed:?} have an empty grid '{}'; they are written unchanged (not stylized)",
            args.grid
        );
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
    let mut full = VdbSimulation {
        paths: paths.clone(),
        grid: args.grid.clone(),
        velocity_grid,
        velocity_scale: 1.0,
        origin,
        dims,
        linked: Vec::new(),
    };
    if full.velocity_grid.is_some() {
        full.velocity_scale = match args.velocity_scale {
            Some(s) if s.is_finite() && s >= 0.0 => s,
            Some(s) => bail!("--velocity-scale must be a non-negative number, got {s}"),
            None => calibrate(&full)?,
        };
    }
    // The frames optimised: the run's frames with smoke. `run_index[k]` is
    // frame k's place in `run_frames`; two are linked when adjacent there.
    let run_index: Vec<usize> = (0..run_frames.len()).filter(|&i| !is_empty(run_frames[i])).collect();
    let live: Vec<i64> = run_index.iter().map(|&i| run_frames[i]).collect();
    let sim_of = |i: usize| run_index.iter().position(|&r| r == i);
    let sim = VdbSimulation {
        paths: live.iter().map(|&f| path_of(f)).collect::<Result<_, _>>()?,
        grid: full.grid.clone(),
        velocity_grid: full.velocity_grid.clone(),
        linked: (0..run_index.len()).map(|k| k == 0 || run_index[k] == run_index[k - 1] + 1).collect(),
        ..full
    };
    eprintln!(
        "{} frames ({} to write, {} warm-up, {} empty), common box {}x{}x{} at {:?}, velocity grid {} (x{:.4} voxels/frame)",
        run_frames.len(),
        todo.len(),
        run_frames.iter().filter(|&&f| !is_written(f)).count(),
        run_frames.len() - sim.len(),
        dims[0],
        dims[1],
        dims[2],
        origin,
        sim.velocity_grid.as_deref().unwrap_or("none"),
        sim.velocity_scale
    );

    let (style, vgg) = load_style_and_vgg(&args)?;
    let cameras = Cameras::from_args(&args)?;
    let cams_at = |f: i64| cameras.at(&args, f as f64, dims, &transform, origin);
    // The densest frame and view of the whole sequence set the absorption
    // for all, so brightness does not pump and chunks agree.
    let gamma = match args.absorption {
        Some(_) => absorption_for(&args, std::iter::empty())?,
        None => {
            let mut best = f32::INFINITY;
            for &t in &live_all {
                let d = full.density(t)?;
                let cams = cams_at(all[t]);
                if let Ok(g) = absorption_for(&args, cams.iter().map(|c| (&d, c))) {
                    best = best.min(g);
                }
            }
            if !best.is_finite() {
                bail!("the density is zero everywhere in view: nothing to stylize");
            }
            best
        }
    };
    let views: Vec<Vec<ViewSpec>> = live.iter().map(|&f| views_of(&cams_at(f), gamma, args.equalize)).collect();
    let style_spec = StyleSpec { layers: args.layers.clone(), layer_weights: vec![1.0; args.layers.len()] };
    let loss = ViewLoss::new(&vgg, &style, &style_spec)?;
    // Unused by the sweeps (each frame has its views); any view of the run will do.
    let first_view = match views.first() {
        Some(v) => v[0].clone(),
        None => views_of(&cams_at(all[live_all[0]]), gamma, args.equalize).remove(0),
    };
    let params = SequenceParams {
        frame: frame_params(&args, vmax, &first_view),
        alpha: args.ema,
        settle_first_sweep: args.ema_settle,
    };

    let work = match &args.work_dir {
        Some(w) => w.clone(),
        None => {
            let out_dir = args.out.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(std::path::Path::new("."));
            out_dir.join(".nst3d-work").join(format!("{:016x}", job_hash(&args, &sim.paths)?))
        }
    };
    if args.force {
        DiskStore::remove(&work).with_context(|| format!("cannot clear the work folder {}", work.display()))?;
    }
    // A chunk of empty frames only has nothing to optimise.
    let mut store = if sim.is_empty() { None } else { Some(DiskStore::open(&work)?) };
    if let Some(store) = &mut store {
        let n = sim.len();
        let per_octave = args.iters * n;
        let mut done_steps = 0;
        if let Some(r) = store.resume_point() {
            done_steps = (r.octave * args.iters + r.sweeps_done) * n;
            if r.octave + 1 == r.octaves && r.sweeps_done == args.iters {
                eprintln!("optimisation already complete in {}; writing the missing frames", work.display());
            } else {
                eprintln!("resuming at octave {} sweep {} from {}", r.octave + 1, r.sweeps_done + 1, work.display());
            }
        }
        // A resumed run counts only the steps left.
        let mut progress = Progress::new((args.octaves * per_octave).saturating_sub(done_steps) as u64);
        stylize_sequence_with(&sim, &loss, &|t| views[t].clone(), &params, store, &mut |p| {
            progress.step(format!(
                "octave {} sweep {}/{} frame {} loss {:.4e}",
                p.octave + 1,
                p.iteration,
                args.iters,
                live[p.frame],
                p.loss
            ))
        })?;
        progress.finish();
    }

    // Write every frame we can; one that fails is reported and the others still land.
    let mut failures = Vec::new();
    let mut losses = 0.0;
    let (mut stylized, mut unchanged) = (0usize, 0usize);
    let (mut flicker_sum, mut pairs) = (0.0f64, 0usize);
    let mut prev: Option<(usize, Grid3)> = None;
    for &i in &todo {
        let Some(t) = sim_of(i) else {
            // An empty frame: the input file byte for byte, so every grid is as it was.
            let src = &paths[all.iter().position(|&a| a == run_frames[i]).expect("run frames are --frames")];
            let copied =
                std::fs::read(src).and_then(|bytes| nst3d_io::atomic::write_atomic(&outs[i], |w| w.write_all(&bytes)));
            match copied {
                Ok(()) => unchanged += 1,
                Err(e) => {
                    eprintln!("nst3d: frame {} failed: {}: {e}", run_frames[i], outs[i].display());
                    failures.push(run_frames[i]);
                }
            }
            continue;
        };
        let result = (|| -> Result<Grid3> {
            let d = sim.density(t)?;
            let store = store.as_mut().expect("frames with smoke were optimised");
            let st = store.load(t)?.context("the frame has no optimised field")?;
            let d = st.field.transport(&d);
            if d.data.iter().any(|v| !v.is_finite()) {
                bail!("stylization produced non-finite densities (try a smaller --lr)");
            }
            let file = read_vdb(&sim.paths[t])?;
            let src = file.grid(&args.grid).context("the grid vanished")?;
            let mut out = VdbGrid::from_dense(&src.name, transform.clone(), origin, &d, 0.0);
            out.metadata = src.metadata.clone();
            out.class = src.class.clone();
            let grids: Vec<VdbGrid> = file
                .grids
                .iter()
                .filter(|g| !matches!(g.values, GridValues::Unsupported { .. }))
                .map(|g| if g.name == src.name { out.clone() } else { g.clone() })
                .collect();
            write_vdb(&outs[i], &grids)?;
            Ok(d)
        })();
        match result {
            Ok(d) => {
                stylized += 1;
                losses += mean_loss(&loss, &d, &views[t])?;
                // Flicker of consecutive written frames, computed pairwise so
                // memory holds two frames.
                if let Some((tp, dp)) = &prev {
                    if *tp + 1 == t && sim.linked(t) {
                        let vel = sim.velocity(*tp)?;
                        let render =
                            |g: &Grid3| loss.image(g, &views[t][0]).expect("the view rendered during optimisation");
                        flicker_sum +=
                            nst3d_sequence::flicker::flicker(&[dp.clone(), d.clone()], &[vel, None], render) as f64;
                        pairs += 1;
                    }
                }
                prev = Some((t, d));
            }
            Err(e) => {
                eprintln!("nst3d: frame {} failed: {e:#}", run_frames[i]);
                failures.push(run_frames[i]);
            }
        }
    }
    if !failures.is_empty() {
        bail!(
            "{} of {} frames failed: {:?} (rerun to retry them; finished frames are kept)",
            failures.len(),
            todo.len(),
            failures
        );
    }
    // Every frame landed: the states are no longer needed (they are large).
    // Only the store's own files go: --work-dir may hold other things.
    let _ = DiskStore::remove(&work);
    println!(
        "{} frames stylized ({:?} mode, EMA {}, {} camera{}); mean style loss {:.4e}; flicker {:.5}; {}wrote {}",
        stylized,
        args.mode,
        args.ema,
        views.first().map_or(0, |v| v.len()),
        if views.first().is_some_and(|v| v.len() == 1) { "" } else { "s" },
        losses / stylized.max(1) as f32,
        if pairs > 0 { flicker_sum / pairs as f64 } else { 0.0 },
        if unchanged > 0 { format!("{unchanged} empty frames copied unchanged; ") } else { String::new() },
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
        let unit = VdbSimulation {
            velocity_scale: 1.0,
            paths: sim.paths.clone(),
            grid: sim.grid.clone(),
            velocity_grid: sim.velocity_grid.clone(),
            linked: sim.linked.clone(),
            ..*sim
        };
        if let Some(u) = unit.velocity(t)? {
            if let Some(s) = nst3d_sequence::calibrate::velocity_scale(&d0, &d1, &u) {
                return Ok(s);
            }
        }
    }
    Ok(0.0)
}
