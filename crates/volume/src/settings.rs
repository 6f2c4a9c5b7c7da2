//! The settings of a volume job, typed once: a front end (the command
//! line, a Python binding) fills a [`VolumeSettings`] and the library checks
//! and runs it. Defaults are the command line's.

use std::path::PathBuf;

use anyhow::{bail, Result};
use nst3d_features::VggLayer;
use nst3d_render::Projection;
use nst3d_stylize::{FrameParams, Limits, Mode, StyleSpec, ViewSpec};

use crate::upsample::Upsample;

pub use nst3d_core::UpAxis;

/// Everything `nst3d volume` can be asked, for one frame or a sequence.
#[derive(Clone, Debug)]
pub struct VolumeSettings {
    /// Input OpenVDB file; with [`VolumeSettings::sequence`] a pattern with `####` or `%04d`.
    pub input: PathBuf,
    /// Style painting (PNG or JPEG).
    pub style: PathBuf,
    /// Further paintings after `style`, for a style map: with
    /// [`VolumeSettings::style_map`] each owns the region the map gives it.
    pub more_styles: Vec<PathBuf>,
    /// Where each painting goes ([`crate::style_map::MapSource`]): a grid of
    /// the input (`NAME`), of another file (`FILE.vdb:NAME`), or `@height`
    /// / `@height-split`. A float map blends two paintings (0: `style`, 1:
    /// the first of `more_styles`).
    pub style_map: Option<String>,
    /// The map's values are labels: `k` picks painting `k` (0 is `style`).
    pub style_map_labels: bool,
    /// A map held in memory instead of `style_map` (the Python package's
    /// numpy map), over the input grid's active bounding box; one frame only.
    pub style_map_array: Option<crate::style_map::MapArray>,
    /// Output OpenVDB file (a pattern for a sequence), written atomically.
    pub out: PathBuf,
    /// Before | after | painting preview PNG (single frames).
    pub preview: Option<PathBuf>,
    /// Name of the float grid to stylize.
    pub grid: String,
    /// Transport by an optimised velocity (eq. 2) or a density scale field (eq. 5).
    pub mode: Mode,
    /// Coarse-to-fine levels; `None`: [`VolumeSettings::octaves`]'s default
    /// for the mode.
    pub octaves: Option<usize>,
    /// Adam iterations per octave (sweeps per octave for a sequence).
    pub iters: usize,
    /// Adam learning rate; `None`: 0.5 voxels per step in velocity mode, 0.2 in density mode.
    pub lr: Option<f32>,
    /// Largest stylization velocity in voxels; `None`: 4 % of the grid's
    /// largest side, at least 1 voxel, so small grids keep their shape.
    pub vmax: Option<f32>,
    /// Smallest density scale (density mode).
    pub smin: f32,
    /// Largest density scale (density mode).
    pub smax: f32,
    /// Style image scale factor (smaller = larger patterns).
    pub style_scale: f32,
    /// The art-directable strength (1 = the defaults): below 1 it shrinks
    /// how far the stylization may move the smoke (`vmax`) and how far it may
    /// scale it from 1 (`[smin, smax]`) by this factor, keeping the shape;
    /// above 1 it runs this many times the iterations (docs/design/volumes.md). A trained
    /// model reads it from [`ModelSettings::strength`].
    pub strength: f32,
    /// Match the painting's colour Grams too, not only its luminance's.
    pub style_color: bool,
    /// Stylize an RGB colour per voxel with the density: the
    /// smoke is rendered in colour (emission–absorption), the painting's
    /// colour Grams are matched, and the output gains a vec3 colour grid
    /// over the smoke's voxels. A single frame colours in a stage after the
    /// density ([`nst3d_stylize::color_stage`]), from
    /// [`nst3d_stylize::COLOR_VIEWS`] omniview cameras for as many sweeps as
    /// [`VolumeSettings::iterations`], scaling the density with the colour
    /// within the density limits; a sequence colours in its sweeps.
    /// Optimisation only for now.
    pub color: bool,
    /// Name of the written colour grid; `None`: by the input's grid names,
    /// else the up axis ([`crate::output::color_grid_name`]).
    pub color_grid: Option<String>,
    /// VGG-19 layers whose Gram matrices are matched.
    pub layers: Vec<VggLayer>,
    /// Absorption γ per unit density and voxel; `None`: the densest ray gets optical depth 3.
    pub absorption: Option<f32>,
    /// The differentiable histogram equalization of eq. 7.
    pub equalize: bool,
    /// Camera projection.
    pub projection: Projection,
    /// Vertical field of view of the perspective camera, degrees.
    pub fov: f32,
    /// The file's up axis.
    pub up: UpAxis,
    /// VGG-19 weights file; `None`: `$NST3D_VGG19`, else the user cache.
    pub weights: Option<PathBuf>,
    /// Camera set Θ: `front`, `omniview:N` or `ring:N[:ELEV]` (see [`crate::CameraSet`]).
    pub cameras: String,
    /// A shot camera or camera path (JSON, world space) instead of [`VolumeSettings::cameras`].
    pub camera_file: Option<PathBuf>,
    /// Seed of the omniview camera placement.
    pub camera_seed: u64,
    /// A camera set whose style loss is also reported before and after:
    /// views the optimiser never saw (single frames).
    pub eval_cameras: Option<String>,
    /// How much finer than the file the grid is stylized and written
    /// (small grids have no room for strokes; see [`crate::upsample`]).
    pub upsample: Upsample,
    /// Frames and temporal coherence when the input is a simulation.
    pub sequence: Option<SequenceSettings>,
    /// Stylize with a trained feed-forward network instead of optimising
    /// (frames independently; the style and optimiser settings are unused).
    pub model: Option<ModelSettings>,
}

/// The sequence half of a volume job (paper Sec. 3.2, Algorithm 1), and
/// what a render farm needs: chunks, warm-up, resume.
#[derive(Clone, Debug)]
pub struct SequenceSettings {
    /// Frames, e.g. `1-120` or `1-3,5,7-20:2`.
    pub frames: String,
    /// EMA weight α of eq. 4 (0.8: at 0.7 the shared plume kept 0.51x of
    /// per-frame flicker, at 0.8 every plume measured is under 0.5x;
    /// docs/design/volumes.md).
    pub ema: f32,
    /// Each octave's first sweep runs without EMA blending (docs/guide/farm.md);
    /// `false` runs Algorithm 1 exactly as printed.
    pub ema_settle: bool,
    /// Simulation velocity grid; `None`: the first of velocity, vel, v.
    pub velocity_grid: Option<String>,
    /// Voxels per frame per velocity unit; `None`: fitted to the data.
    pub velocity_scale: Option<f32>,
    /// Farm chunk `START-END`: only these frames are written.
    pub chunk: Option<String>,
    /// Frames of overlap a chunk also optimises on each side (not written).
    pub warmup: i64,
    /// Redo frames whose output exists, and drop any saved state.
    pub force: bool,
    /// Folder of the per-frame states and checkpoint; `None`:
    /// `<out dir>/.nst3d-work/<hash of the job>`.
    pub work_dir: Option<PathBuf>,
}

impl Default for SequenceSettings {
    fn default() -> Self {
        Self {
            frames: String::new(),
            ema: 0.8,
            ema_settle: true,
            velocity_grid: None,
            velocity_scale: None,
            chunk: None,
            warmup: 0,
            force: false,
            work_dir: None,
        }
    }
}

impl VolumeSettings {
    /// The command line's defaults for stylizing `input` with `style` into `out`.
    pub fn new(input: impl Into<PathBuf>, style: impl Into<PathBuf>, out: impl Into<PathBuf>) -> Self {
        Self {
            input: input.into(),
            style: style.into(),
            more_styles: Vec::new(),
            style_map: None,
            style_map_array: None,
            style_map_labels: false,
            out: out.into(),
            preview: None,
            grid: "density".into(),
            mode: Mode::Velocity,
            octaves: None,
            iters: 20,
            lr: None,
            vmax: None,
            smin: 0.0,
            smax: 2.0,
            style_scale: 0.5,
            strength: 1.0,
            style_color: false,
            color: false,
            color_grid: None,
            layers: vec![VggLayer::Relu1_1, VggLayer::Relu2_1, VggLayer::Relu3_1, VggLayer::Relu4_1],
            absorption: None,
            equalize: false,
            projection: Projection::Perspective,
            fov: 30.0,
            up: UpAxis::Z,
            weights: None,
            cameras: "front".into(),
            camera_file: None,
            camera_seed: 0,
            eval_cameras: None,
            upsample: Upsample::Auto,
            sequence: None,
            model: None,
        }
    }

    /// Estimated peak memory (bytes) of stylizing a grid of `dims` voxels
    /// (after refinement) by optimisation: 400 MB (weights, the painting's
    /// features, buffers) plus 240 bytes per voxel (the field, its Adam
    /// moments, the transport and renderer tapes), and 200 MB more for a
    /// sequence (neighbouring frames and their velocities). Fitted to the
    /// peak RSS of plume48 refined 1-8x (13 K-6.7 M voxels), up to 10 % above it
    /// (docs/guide/farm.md); cameras barely change it (they are rendered in turn).
    pub fn memory_estimate(dims: [usize; 3], sequence: bool) -> u64 {
        let voxels = dims.iter().map(|&d| d as u64).product::<u64>();
        let fixed = if sequence { 600_000_000 } else { 400_000_000 };
        voxels.saturating_mul(240).saturating_add(fixed)
    }

    /// Refuses, before the grid is refined or anything is optimised, a
    /// stylization whose [`VolumeSettings::memory_estimate`] exceeds what
    /// this machine has available.
    pub fn check_memory(dims: [usize; 3], sequence: bool) -> Result<()> {
        let need = Self::memory_estimate(dims, sequence);
        let what = format!("stylizing a {}x{}x{} grid", dims[0], dims[1], dims[2]);
        let lower = "lower --upsample, or stylize with a trained --model (tiled, bounded memory)";
        nst3d_core::memory::check_fits(need, &what, lower).map_err(anyhow::Error::msg)
    }

    /// Checks the numbers before any slow work, so a typo fails in a second.
    pub fn check(&self) -> Result<()> {
        if self.octaves == Some(0) || self.iters == 0 {
            bail!("--octaves and --iters must be at least 1");
        }
        for (name, v) in [
            ("--vmax", self.vmax.unwrap_or(1.0)),
            ("--fov", self.fov),
            ("--style-scale", self.style_scale),
            ("--strength", self.strength),
        ] {
            if !(v.is_finite() && v > 0.0) {
                bail!("{name} must be a positive number, got {v}");
            }
        }
        if !(self.smin.is_finite() && self.smax.is_finite() && self.smin < self.smax && self.smin >= 0.0) {
            bail!("need 0 <= --smin < --smax, got {} and {}", self.smin, self.smax);
        }
        if self.color && self.model.is_some() {
            bail!("--color works with the optimisation, not with a trained --model (yet)");
        }
        if self.color && self.equalize {
            bail!("--color cannot be combined with --equalize (eq. 7 equalizes grey pictures)");
        }
        self.check_style_map()?;
        let ema = self.sequence.as_ref().map_or(SequenceSettings::default().ema, |s| s.ema);
        if !(0.0..1.0).contains(&ema) {
            bail!("--ema must be in [0, 1), got {ema}");
        }
        Ok(())
    }

    /// The paintings in the map's order (`style`, then `more_styles`).
    pub fn styles(&self) -> Vec<PathBuf> {
        std::iter::once(self.style.clone()).chain(self.more_styles.iter().cloned()).collect()
    }

    /// The paintings a style map places: the `--style` paintings, or with
    /// a trained model its models (one per painting).
    pub fn regions(&self) -> usize {
        match &self.model {
            Some(m) => 1 + m.more.len(),
            None => 1 + self.more_styles.len(),
        }
    }

    /// Where the style map comes from: `style_map` parsed, or the array
    /// over the input grid; `None` without a map.
    pub fn map_source(&self) -> Result<Option<crate::style_map::MapSource>> {
        use crate::style_map::MapSource;
        match (&self.style_map, &self.style_map_array) {
            (Some(_), Some(_)) => bail!("give --style-map or a style map array, not both"),
            (Some(spec), None) => Ok(Some(MapSource::parse(spec)?)),
            (None, Some(a)) => Ok(Some(MapSource::Array { array: a.clone(), grid: self.grid.clone() })),
            (None, None) => Ok(None),
        }
    }

    /// A style map's settings fit together, before any file is read.
    fn check_style_map(&self) -> Result<()> {
        let n = self.regions();
        let what = if self.model.is_some() { "--model files" } else { "--style paintings" };
        let Some(source) = self.map_source()? else {
            if n > 1 {
                bail!("{n} {what} need a --style-map saying where each goes");
            }
            if self.style_map_labels {
                bail!("--style-map-labels needs a --style-map");
            }
            return Ok(());
        };
        if self.style_map_array.is_some() && self.sequence.is_some() {
            bail!("a style map array covers one frame's box; for a sequence give a grid name or a FILE.vdb pattern");
        }
        if n < 2 {
            bail!("--style-map needs at least two {what} (got one)");
        }
        if n > 2 && !source.labels(self.style_map_labels) {
            bail!("a float --style-map blends two paintings, got {n}; pass --style-map-labels for a label map");
        }
        Ok(())
    }

    /// The Gram layers, equally weighted.
    pub(crate) fn style_spec(&self) -> StyleSpec {
        StyleSpec { layers: self.layers.clone(), layer_weights: vec![1.0; self.layers.len()] }
    }

    /// Octaves: `octaves`, else 2 in velocity mode and 3 in density mode
    /// (the paper's Table 1 rows for each).
    pub fn octaves(&self) -> usize {
        self.octaves.unwrap_or(match self.mode {
            Mode::Velocity => 2,
            Mode::Density => 3,
        })
    }

    /// The optimiser settings shared by single frames and sequences.
    pub(crate) fn frame_params(&self, vmax: f32, view: &ViewSpec) -> FrameParams {
        // Density mode: the paper's Table 1 row for it (Fig. 4: 3 octaves, 20
        // iterations, learning rate 0.2), measured stronger from unseen views
        // than 2 octaves at 0.1 on all three shared paintings
        // (docs/design/volumes.md).
        let lr = self.lr.unwrap_or(match self.mode {
            Mode::Velocity => 0.5,
            Mode::Density => 0.2,
        });
        FrameParams {
            mode: self.mode,
            octaves: self.octaves(),
            iterations: self.iterations(),
            learning_rate: lr,
            limits: Limits {
                vmax,
                smin: 1.0 - self.reach() * (1.0 - self.smin),
                smax: 1.0 + self.reach() * (self.smax - 1.0),
            },
            view: view.clone(),
        }
    }

    /// Iterations (sweeps for a sequence) per octave: `iters`, times the
    /// strength above 1.
    pub fn iterations(&self) -> usize {
        ((self.iters as f32 * self.strength.max(1.0)).round() as usize).max(1)
    }

    /// The strength's share of the limits: the strength up to 1.
    fn reach(&self) -> f32 {
        self.strength.min(1.0)
    }

    /// `vmax` for a box whose largest side is `extent` voxels: `--vmax`, or 4 %
    /// of the side (at least 1 voxel), scaled by the strength up to 1.
    pub(crate) fn vmax_for(&self, extent: usize) -> f32 {
        match self.vmax {
            Some(v) => v * self.reach(),
            None => (0.04 * extent as f32 * self.reach()).max(1.0),
        }
    }

    /// Empty voxels around the box, so the velocity can move smoke outwards.
    pub(crate) fn margin(&self, vmax: f32) -> usize {
        match self.mode {
            Mode::Velocity => vmax.ceil() as usize + 1,
            Mode::Density => 0,
        }
    }
}

/// `--strength`: a named look or a positive number.
pub fn parse_strength(s: &str) -> Result<f32, String> {
    match s {
        "subtle" => Ok(0.5),
        "default" => Ok(1.0),
        "strong" => Ok(1.5),
        _ => match s.parse::<f32>() {
            Ok(v) if v.is_finite() && v > 0.0 && v <= 10.0 => Ok(v),
            _ => Err(format!("'{s}' is not subtle, default, strong or a number in (0, 10]")),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `--strength` below 1 narrows the limits around "no change", above 1 adds
    /// iterations, and explicit limits are scaled the same way.
    #[test]
    fn strength_scales_the_limits_or_the_iterations() {
        let mut s = VolumeSettings::new("in.vdb", "p.jpg", "out.vdb");
        let view = ViewSpec { camera: None, gamma: 1.0, exposure: 1.0, equalize: false };
        assert_eq!((s.vmax_for(100), s.iterations()), (4.0, 20));
        s.strength = 0.5;
        let p = s.frame_params(s.vmax_for(100), &view);
        assert_eq!((p.limits.vmax, p.limits.smin, p.limits.smax, p.iterations), (2.0, 0.5, 1.5, 20));
        assert_eq!(s.vmax_for(10), 1.0, "at least one voxel by default");
        s.vmax = Some(3.0);
        assert_eq!(s.vmax_for(100), 1.5);
        s.strength = 1.5;
        let p = s.frame_params(s.vmax_for(100), &view);
        assert_eq!((p.limits.vmax, p.limits.smin, p.limits.smax, p.iterations), (3.0, 0.0, 2.0, 30));
        s.strength = 0.0;
        assert!(s.check().is_err());
    }
}

/// A trained model and how to run it.
#[derive(Clone, Debug)]
pub struct ModelSettings {
    /// The model file written by `nst3d train`.
    pub path: PathBuf,
    /// Further models, one per painting of a style map after `path`, in
    /// the map's order: every model stylizes the frame and the results are
    /// blended voxel by voxel by the map's weights.
    pub more: Vec<PathBuf>,
    /// Tile side in voxels (rounded up to a multiple of 4).
    pub tile: usize,
    /// Context around each tile, in voxels (rounded up to a multiple of 4).
    pub margin: usize,
    /// The mode the user asked for, if any: a model of the other mode is refused.
    pub mode: Option<Mode>,
    /// How far the network's stylization is taken (`--strength`; 1 as
    /// trained): the density scale `s` becomes `s^strength`, a velocity
    /// `strength · v`, before the frame's total is restored.
    pub strength: f32,
}

impl ModelSettings {
    /// `--tile`'s default: a 128³ tile keeps memory near 1 GB at width 16.
    pub const DEFAULT_TILE: usize = 128;
    /// `--tile-margin`'s default: 32 voxels cover the network's reach.
    pub const DEFAULT_MARGIN: usize = 32;

    /// The command line's defaults for the model file `path`.
    pub fn new(path: impl Into<PathBuf>) -> Self {
        Self {
            path: path.into(),
            more: Vec::new(),
            tile: Self::DEFAULT_TILE,
            margin: Self::DEFAULT_MARGIN,
            mode: None,
            strength: 1.0,
        }
    }
}
