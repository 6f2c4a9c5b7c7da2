//! `nst3d volume`: stylize one OpenVDB density grid (paper Sec. 3).
//!
//! The grid is read, densified over its active box plus a margin (a velocity
//! may carry smoke a little outside its original shape, Sec. 3.3), stylized
//! by [`nst3d_stylize::stylize_frame`], and written back sparse into the same
//! index space with the same transform. A before/after preview is rendered
//! from the first camera of the set.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use nst3d_core::{Grid3, Image};
use nst3d_features::{Vgg19, VggLayer};
use nst3d_io::vdb::{read_vdb, write_vdb, GridValues, Transform, VdbGrid};
use nst3d_render::{Camera, CameraRig, Projection};
use nst3d_stylize::{stylize_frame_views, FrameParams, Limits, Mode, StyleSpec, ViewLoss, ViewSpec};

use crate::progress::Progress;
use nst3d_io::image::resize_to_height;

/// Arguments of `nst3d volume`.
#[derive(Args)]
pub struct VolumeArgs {
    /// Input OpenVDB file.
    #[arg(long)]
    pub(crate) input: PathBuf,
    /// Style painting (PNG or JPEG).
    #[arg(long)]
    pub(crate) style: PathBuf,
    /// Output OpenVDB file (written atomically).
    #[arg(long)]
    pub(crate) out: PathBuf,
    /// Before/after preview PNG.
    #[arg(long)]
    pub(crate) preview: Option<PathBuf>,
    /// Frames to stylize as a sequence (e.g. `1-120` or `1-3,5,7-20:2`);
    /// then --input and --out are patterns with `####` or `%04d`.
    #[arg(long)]
    pub(crate) frames: Option<String>,
    /// EMA weight α of the temporal coherence (eq. 4), sequences only.
    #[arg(long, default_value_t = 0.7)]
    pub(crate) ema: f32,
    /// Let each octave's first sweep run without EMA blending (on by
    /// default: it makes farm chunks meet at their seams and cuts flicker
    /// further at the same style loss; docs/FARM.md, docs/SEQUENCES.md).
    /// `--ema-settle false` runs Algorithm 1 exactly as printed.
    #[arg(long, value_name = "BOOL", num_args = 0..=1, default_value_t = true, default_missing_value = "true",
          action = clap::ArgAction::Set)]
    pub(crate) ema_settle: bool,
    /// Simulation velocity grid for the EMA (default: the first of velocity, vel, v).
    #[arg(long)]
    pub(crate) velocity_grid: Option<String>,
    /// Voxels per frame per unit of the velocity grid (default: fitted to the data).
    #[arg(long)]
    pub(crate) velocity_scale: Option<f32>,
    /// Name of the float grid to stylize.
    #[arg(long, default_value = "density")]
    pub(crate) grid: String,
    /// velocity (transport by an optimised velocity, eq. 2) or density (scale field, eq. 5).
    #[arg(long, default_value = "velocity")]
    pub(crate) mode: Mode,
    /// Octaves (coarse-to-fine levels).
    #[arg(long, default_value_t = 2)]
    pub(crate) octaves: usize,
    /// Adam iterations per octave.
    #[arg(long, default_value_t = 20)]
    pub(crate) iters: usize,
    /// Adam learning rate (default: 0.5 voxels per step in velocity mode, 0.1 in density mode).
    #[arg(long)]
    pub(crate) lr: Option<f32>,
    /// Largest stylization velocity, in voxels (velocity mode; default 4% of
    /// the grid's largest side, at least 1 voxel, so small grids keep their shape).
    #[arg(long)]
    pub(crate) vmax: Option<f32>,
    /// Smallest density scale (density mode).
    #[arg(long, default_value_t = 0.0)]
    pub(crate) smin: f32,
    /// Largest density scale (density mode).
    #[arg(long, default_value_t = 2.0)]
    pub(crate) smax: f32,
    /// Style image scale factor (smaller = larger patterns).
    #[arg(long, default_value_t = 0.5)]
    pub(crate) style_scale: f32,
    /// Match the painting's colour statistics too (by default only its
    /// luminance: the renderer draws grey smoke, which cannot reach colour Grams).
    #[arg(long)]
    pub(crate) style_color: bool,
    /// VGG-19 layers whose Gram matrices are matched.
    #[arg(long, value_delimiter = ',', default_value = "relu1_1,relu2_1,relu3_1,relu4_1")]
    pub(crate) layers: Vec<VggLayer>,
    /// Absorption γ per unit density and voxel (default: chosen so the densest ray has optical depth 3).
    #[arg(long)]
    pub(crate) absorption: Option<f32>,
    /// Apply the differentiable histogram equalization of eq. 7 (helps dense, flat-white smoke).
    #[arg(long)]
    pub(crate) equalize: bool,
    /// Camera projection.
    #[arg(long, value_enum, default_value = "perspective")]
    pub(crate) camera: CameraKind,
    /// Vertical field of view of the perspective camera, degrees.
    #[arg(long, default_value_t = 30.0)]
    pub(crate) fov: f32,
    /// Which index axis points up in the file (Blender caches are z-up, Houdini y-up).
    #[arg(long, value_enum, default_value = "z")]
    pub(crate) up: UpAxis,
    /// VGG-19 weights file (default: $NST3D_VGG19, else the user cache; see tools/fetch_weights.sh).
    #[arg(long)]
    pub(crate) weights: Option<PathBuf>,
    /// Camera set Θ whose style losses are summed each iteration: `front`,
    /// `omniview:N` (N Poisson-disk cameras on a sphere, Sec. 4) or
    /// `ring:N[:ELEV]` (a turntable of N cameras at ELEV degrees).
    #[arg(long, default_value = "front", conflicts_with = "camera_file")]
    pub(crate) cameras: String,
    /// Shot camera or camera path (JSON, world space; see docs/CAMERAS.md).
    #[arg(long)]
    pub(crate) camera_file: Option<PathBuf>,
    /// Seed of the omniview camera placement.
    #[arg(long, default_value_t = 0)]
    pub(crate) camera_seed: u64,
    /// Also report the style loss seen from this camera set (same syntax as
    /// --cameras), before and after: views the optimiser never saw.
    #[arg(long)]
    pub(crate) eval_cameras: Option<String>,
    /// Farm chunk: stylize and write only frames START-END of --frames.
    #[arg(long, requires = "frames")]
    pub(crate) chunk: Option<String>,
    /// Frames of overlap a chunk also optimises on each side (not written),
    /// so its EMA sees the same neighbours as one whole run (docs/FARM.md).
    #[arg(long, default_value_t = 0)]
    pub(crate) warmup: i64,
    /// Redo frames whose output file already exists.
    #[arg(long)]
    pub(crate) force: bool,
    /// Folder for per-frame optimisation state and the checkpoint (default:
    /// `<out dir>/.nst3d-work/<hash of the job's inputs and settings>`).
    #[arg(long)]
    pub(crate) work_dir: Option<PathBuf>,
}

/// A camera set as named on the command line.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum CameraSet {
    /// The default front camera.
    Front,
    /// `omniview:N`.
    Omniview(usize),
    /// `ring:N[:ELEV]`.
    Ring(usize, f32),
}

impl CameraSet {
    /// Parses `front`, `omniview:N` or `ring:N[:ELEV]`.
    pub(crate) fn parse(s: &str) -> Result<Self> {
        let parts: Vec<&str> = s.split(':').collect();
        let count = |p: &str| -> Result<usize> {
            match p.parse::<usize>() {
                Ok(n) if (1..=1024).contains(&n) => Ok(n),
                _ => bail!("camera set '{s}': count must be a whole number from 1 to 1024"),
            }
        };
        match parts.as_slice() {
            ["front"] => Ok(Self::Front),
            ["omniview", n] => Ok(Self::Omniview(count(n)?)),
            ["ring", n] => Ok(Self::Ring(count(n)?, 0.0)),
            ["ring", n, e] => match e.parse::<f32>() {
                Ok(el) if (-89.0..=89.0).contains(&el) => Ok(Self::Ring(count(n)?, el)),
                _ => bail!("camera set '{s}': elevation must be degrees in [-89, 89]"),
            },
            _ => bail!("unknown camera set '{s}' (expected front, omniview:N or ring:N[:ELEV])"),
        }
    }

    /// The cameras for a grid of `dims` voxels. Omniview and ring cameras
    /// are built around +y and turned so their axis is the file's up axis.
    pub(crate) fn cameras(&self, args: &VolumeArgs, dims: [usize; 3]) -> Vec<Camera> {
        let projection = projection(args.camera);
        let (yup_dims, turn): ([usize; 3], fn([f32; 3]) -> [f32; 3]) = match args.up {
            UpAxis::Y => (dims, |v| v),
            // Frame y is index z, frame z is index −y: the ring's first
            // camera then sits on the −y side, as the z-up front camera.
            UpAxis::Z => ([dims[0], dims[2], dims[1]], |v| [v[0], -v[2], v[1]]),
        };
        let cams = match *self {
            Self::Front => return vec![front_camera(dims, args.up, args.camera, args.fov)],
            Self::Omniview(n) => nst3d_render::omniview(n, args.camera_seed, yup_dims, projection),
            Self::Ring(n, el) => nst3d_render::ring(n, el, yup_dims, projection),
        };
        let (c_frame, c_index) = (yup_dims.map(|n| (n as f32 - 1.0) * 0.5), dims.map(|n| (n as f32 - 1.0) * 0.5));
        let point = |p: [f32; 3]| {
            let r = turn(std::array::from_fn(|a| p[a] - c_frame[a]));
            std::array::from_fn(|a| c_index[a] + r[a])
        };
        cams.into_iter().map(|c| Camera { eye: point(c.eye), target: point(c.target), up: turn(c.up), ..c }).collect()
    }
}

fn projection(kind: CameraKind) -> Projection {
    match kind {
        CameraKind::Orthographic => Projection::Orthographic,
        CameraKind::Perspective => Projection::Perspective,
    }
}

/// Where the cameras come from: a named set or a camera file.
pub(crate) enum Cameras {
    /// The same set for every frame, in the dense box's index space.
    Set(CameraSet),
    /// A shot camera or path, mapped per frame.
    Rig(CameraRig),
}

impl Cameras {
    /// Reads --cameras / --camera-file.
    pub(crate) fn from_args(args: &VolumeArgs) -> Result<Self> {
        Ok(match &args.camera_file {
            Some(p) => Self::Rig(CameraRig::from_json_file(p)?),
            None => Self::Set(CameraSet::parse(&args.cameras)?),
        })
    }

    /// Θ at `frame` for a dense box of `dims` whose voxel (0,0,0) is index
    /// `origin` of a grid with `transform`.
    pub(crate) fn at(
        &self,
        args: &VolumeArgs,
        frame: f64,
        dims: [usize; 3],
        transform: &Transform,
        origin: [i32; 3],
    ) -> Vec<Camera> {
        match self {
            Self::Set(set) => set.cameras(args, dims),
            Self::Rig(rig) => vec![rig.at_frame(frame, &dense_index_to_world(transform, origin))],
        }
    }
}

/// Index-to-world matrix of a dense box starting at index `origin`: the
/// grid's transform after a translation by the origin.
pub(crate) fn dense_index_to_world(transform: &Transform, origin: [i32; 3]) -> [[f64; 4]; 4] {
    let mut m = transform.index_to_world;
    for r in 0..3 {
        m[r][3] += (0..3).map(|c| transform.index_to_world[r][c] * origin[c] as f64).sum::<f64>();
    }
    m
}

/// Absorption from --absorption, or the smallest [`auto_absorption`] over
/// every density and camera given, so no view of any frame saturates.
pub(crate) fn absorption_for<'a>(
    args: &VolumeArgs,
    pairs: impl Iterator<Item = (&'a Grid3, &'a Camera)>,
) -> Result<f32> {
    match args.absorption {
        Some(g) if g.is_finite() && g > 0.0 => Ok(g),
        Some(g) => bail!("--absorption must be a positive number, got {g}"),
        None => {
            let mut best = f32::INFINITY;
            for (d, c) in pairs {
                if let Ok(g) = auto_absorption(d, c) {
                    best = best.min(g);
                }
            }
            if !best.is_finite() {
                bail!("the density is zero everywhere in view: nothing to stylize");
            }
            Ok(best)
        }
    }
}

/// Views for `cameras` with absorption `gamma`.
pub(crate) fn views_of(cameras: &[Camera], gamma: f32, equalize: bool) -> Vec<ViewSpec> {
    cameras.iter().map(|c| ViewSpec { camera: Some(*c), gamma, exposure: gamma, equalize }).collect()
}

#[derive(Clone, Copy, ValueEnum)]
pub(crate) enum CameraKind {
    Orthographic,
    Perspective,
}

#[derive(Clone, Copy, ValueEnum)]
pub(crate) enum UpAxis {
    Y,
    Z,
}

/// Loads VGG-19 from `--weights`, `$NST3D_VGG19` or the cache.
pub fn load_vgg(explicit: Option<&Path>) -> Result<Vgg19> {
    let path = match explicit {
        Some(p) => p.to_path_buf(),
        None => nst3d_weights::locate_vgg19()?,
    };
    let tensors = nst3d_weights::load_vgg19_weights(&path)?;
    Ok(Vgg19::from_tensors(&tensors).with_context(|| format!("{}", path.display()))?)
}

/// The painting (luminance unless --style-color) and the network.
pub(crate) fn load_style_and_vgg(args: &VolumeArgs) -> Result<(Image, Vgg19)> {
    let style = nst3d_io::image::load_style(&args.style, args.style_scale)?;
    let style = if args.style_color { style } else { nst3d_io::image::luminance_rgb(&style) };
    Ok((style, load_vgg(args.weights.as_deref())?))
}

/// Checks the numeric arguments before any slow work.
pub(crate) fn check_args(args: &VolumeArgs) -> Result<()> {
    if args.octaves == 0 || args.iters == 0 {
        bail!("--octaves and --iters must be at least 1");
    }
    for (name, v) in [("--vmax", args.vmax.unwrap_or(1.0)), ("--fov", args.fov), ("--style-scale", args.style_scale)] {
        if !(v.is_finite() && v > 0.0) {
            bail!("{name} must be a positive number, got {v}");
        }
    }
    if !(args.smin.is_finite() && args.smax.is_finite() && args.smin < args.smax && args.smin >= 0.0) {
        bail!("need 0 <= --smin < --smax, got {} and {}", args.smin, args.smax);
    }
    if !(0.0..1.0).contains(&args.ema) {
        bail!("--ema must be in [0, 1), got {}", args.ema);
    }
    Ok(())
}

/// The optimiser settings shared by single frames and sequences.
pub(crate) fn frame_params(args: &VolumeArgs, vmax: f32, view: &ViewSpec) -> FrameParams {
    let lr = args.lr.unwrap_or(match args.mode {
        Mode::Velocity => 0.5,
        Mode::Density => 0.1,
    });
    FrameParams {
        mode: args.mode,
        octaves: args.octaves,
        iterations: args.iters,
        learning_rate: lr,
        limits: Limits { vmax, smin: args.smin, smax: args.smax },
        view: view.clone(),
    }
}

/// A front camera for a grid of `dims` voxels: looking at the centre from
/// the side where the up axis stays vertical in the picture.
pub(crate) fn front_camera(dims: [usize; 3], up: UpAxis, kind: CameraKind, fov: f32) -> Camera {
    let c = dims.map(|n| (n as f32 - 1.0) * 0.5);
    let extent = dims.iter().copied().max().unwrap_or(1) as f32;
    let (dir, upv) = match up {
        // z up: look along +y from the -y side (x to the right).
        UpAxis::Z => ([0.0, 1.0, 0.0], [0.0, 0.0, 1.0]),
        // y up: look along -z from the +z side, as Houdini's default camera.
        UpAxis::Y => ([0.0, 0.0, -1.0], [0.0, 1.0, 0.0]),
    };
    let projection = projection(kind);
    // Horizontal extent over vertical extent of the grid as seen from this side.
    let aspect = match up {
        UpAxis::Z => dims[0] as f32 / dims[2].max(1) as f32,
        UpAxis::Y => dims[0] as f32 / dims[1].max(1) as f32,
    };
    // Far enough that the grid's bounding sphere fits the field of view.
    let half = (fov.to_radians() * 0.5).tan().min(1e3);
    let radius = 0.5 * 3f32.sqrt() * extent;
    let dist = radius / (half * aspect.min(1.0)).max(1e-3) + radius;
    let eye = [0, 1, 2].map(|a| c[a] - dir[a] * dist);
    Camera { projection, eye, target: c, up: upv, fov_y_deg: fov, aspect }
}

/// Runs `nst3d volume`.
pub fn run(args: VolumeArgs) -> Result<()> {
    check_args(&args)?;
    if args.frames.is_some() {
        return crate::sequence::run(args);
    }
    // Read and check everything before the slow part, so a bad input fails in a second.
    let file = read_vdb(&args.input)?;
    let grid = file.grid(&args.grid).with_context(|| {
        let names: Vec<&str> = file.grids.iter().map(|g| g.name.as_str()).collect();
        format!("{}: no grid named '{}' (grids: {})", args.input.display(), args.grid, names.join(", "))
    })?;
    let (bx, dense) = grid.to_dense()?;
    let (style, vgg) = load_style_and_vgg(&args)?;

    let vmax = args.vmax.unwrap_or_else(|| (0.04 * *bx.dims.iter().max().unwrap_or(&1) as f32).max(1.0));
    // Room for the velocity to move smoke outwards.
    let margin = match args.mode {
        Mode::Velocity => vmax.ceil() as usize + 1,
        Mode::Density => 0,
    };
    let padded = pad(&dense, margin);
    let origin = bx.origin.map(|o| o - margin as i32);
    let cameras = Cameras::from_args(&args)?.at(&args, 0.0, padded.dims, &grid.transform, origin);
    let gamma = absorption_for(&args, cameras.iter().map(|c| (&padded, c)))?;
    let views = views_of(&cameras, gamma, args.equalize);
    let view = views[0].clone();
    let spec = StyleSpec { layers: args.layers.clone(), layer_weights: vec![1.0; args.layers.len()] };
    let loss = ViewLoss::new(&vgg, &style, &spec)?;
    let params = frame_params(&args, vmax, &view);
    let held_out = match &args.eval_cameras {
        Some(e) => {
            let cams = CameraSet::parse(e)?.cameras(&args, padded.dims);
            let g = absorption_for(&args, cams.iter().map(|c| (&padded, c)))?;
            views_of(&cams, g, args.equalize)
        }
        None => Vec::new(),
    };
    let held_out_before = mean_loss(&loss, &padded, &held_out)?;

    let mut progress = Progress::new((args.octaves * args.iters) as u64);
    let result = stylize_frame_views(&padded, &loss, &params, &views, &mut |p| {
        progress.step(format!(
            "octave {}/{} iteration {}/{} loss {:.4e}",
            p.octave + 1,
            p.octaves,
            p.iteration,
            p.iterations,
            p.loss
        ))
    })?;
    progress.finish();
    if result.density.data.iter().any(|v| !v.is_finite()) {
        bail!("stylization produced non-finite densities (try a smaller --lr)");
    }

    let mut out_grid = VdbGrid::from_dense(&grid.name, grid.transform.clone(), origin, &result.density, 0.0);
    out_grid.metadata = grid.metadata.clone();
    out_grid.class = grid.class.clone();
    // Keep every other grid of the input so the file drops in for the
    // original; grids of value types we cannot carry (e.g. int32 obstacles)
    // are dropped, and said so.
    let mut grids = Vec::with_capacity(file.grids.len());
    for g in &file.grids {
        if g.name == grid.name {
            grids.push(out_grid.clone());
        } else if matches!(g.values, GridValues::Unsupported { .. }) {
            eprintln!("nst3d: note: grid '{}' ({}) is not copied to the output", g.name, g.values.type_name());
        } else {
            grids.push(g.clone());
        }
    }
    write_vdb(&args.out, &grids)?;

    if let Some(preview) = &args.preview {
        // Before | after | the painting, all scaled to one readable height.
        let h = PREVIEW_HEIGHT;
        let before = resize_to_height(&display(&loss, &padded, &view)?, h);
        let after = resize_to_height(&display(&loss, &result.density, &view)?, h);
        let painting = resize_to_height(&style, h);
        let sheet = nst3d_io::image::side_by_side(&[&before, &after, &painting]);
        nst3d_io::image::write_png(preview, &sheet)?;
    }
    if !held_out.is_empty() {
        let after = mean_loss(&loss, &result.density, &held_out)?;
        println!(
            "held-out cameras {}: mean style loss {:.4e} -> {:.4e}",
            args.eval_cameras.as_deref().unwrap_or(""),
            held_out_before,
            after
        );
    }
    println!(
        "{}: grid '{}' {}x{}x{} stylized ({:?} mode, {} camera{}); style loss {:.4e} -> {:.4e} ({:.0}% lower); wrote {}",
        args.input.display(),
        grid.name,
        bx.dims[0],
        bx.dims[1],
        bx.dims[2],
        args.mode,
        views.len(),
        if views.len() == 1 { "" } else { "s" },
        result.loss_before,
        result.loss_after,
        100.0 * result.loss_drop(),
        args.out.display()
    );
    Ok(())
}

/// Mean style loss of `d` over `views` (0 for none).
pub(crate) fn mean_loss(loss: &ViewLoss, d: &Grid3, views: &[ViewSpec]) -> Result<f32> {
    let mut total = 0.0;
    for v in views {
        total += loss.loss(d, v)?;
    }
    Ok(total / views.len().max(1) as f32)
}

/// Height of the preview sheet in pixels.
pub(crate) const PREVIEW_HEIGHT: usize = 384;

/// Absorption giving the densest ray an optical depth of 3: dense enough to
/// show shape, thin enough that the image does not flatten to white.
pub(crate) fn auto_absorption(d: &Grid3, camera: &Camera) -> Result<f32> {
    // With γ = 0 the render is the plain column sum of density along each ray.
    let (sums, _) = nst3d_render::render(d, camera, 0.0)?;
    let max = sums.data.iter().copied().fold(0.0f32, f32::max);
    if !(max > 0.0) {
        bail!("the density is zero everywhere in view: nothing to stylize");
    }
    Ok(3.0 / max)
}

/// The picture an artist sees of a density: the network's grey image, 2x.
pub(crate) fn display(loss: &ViewLoss, d: &Grid3, view: &ViewSpec) -> Result<Image> {
    Ok(nst3d_render::upsample2x(&loss.image(d, view)?))
}

/// Surrounds a grid with `m` voxels of empty space on every side.
pub(crate) fn pad(g: &Grid3, m: usize) -> Grid3 {
    if m == 0 {
        return g.clone();
    }
    let [nx, ny, nz] = g.dims;
    let mut out = Grid3::zeros([nx + 2 * m, ny + 2 * m, nz + 2 * m]);
    for z in 0..nz {
        for y in 0..ny {
            let dst = out.index(m, y + m, z + m);
            out.data[dst..dst + nx].copy_from_slice(&g.data[g.index(0, y, z)..g.index(0, y, z) + nx]);
        }
    }
    out
}
