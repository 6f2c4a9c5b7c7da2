//! The settings of a groom job, typed once: a front end fills a
//! [`StrandSettings`] and the library checks and runs it.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use nst3d_core::UpAxis;
use nst3d_job::expand_pattern;
use nst3d_strands::pipeline::StylizeParams;
use nst3d_strands::{EmaClock, Preset, TemporalParams, ORIENTATION_EMA_NU};

/// Which temporal coherence an animated groom gets (Sec. 3.3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Temporal {
    /// The paper: EMA on the velocities and the 1€ filter on the points.
    EmaOneEuro,
    /// The EMA only.
    Ema,
    /// The 1€ filter only.
    OneEuro,
    /// Every frame stylized on its own.
    Off,
}

nst3d_core::named_enum!(Temporal, "a temporal filter", {
    EmaOneEuro => "ema-one-euro",
    Ema => "ema",
    OneEuro => "one-euro",
    Off => "off",
});

/// Everything `nst3d strands` can be asked, for one groom or an animation.
#[derive(Clone, Debug)]
pub struct StrandSettings {
    /// Input groom (.hair, .data, .ply, .usda, .usdc, .usd, .usdz, .abc); with `frames` a pattern.
    pub groom: PathBuf,
    /// Head or body mesh the strands grow from (.ply or .obj); with
    /// `frames` it may be a pattern too (a moving head). `None`: the groom
    /// has no mesh (no collision handling, no visibility culling).
    pub mesh: Option<PathBuf>,
    /// Style painting (PNG or JPEG); its luminance is matched.
    pub style: PathBuf,
    /// Further paintings of a style map (`--style` given again): strands
    /// take `style` and these by their `style_map` value.
    pub more_styles: Vec<PathBuf>,
    /// Where each strand's style-map value comes from
    /// ([`crate::style_map`]): `@height` (the roots' height, 0 lowest to 1
    /// highest), a `.txt` file (one number per strand, in file order), or
    /// the name of a strand or vertex property of a `.ply` groom or of a
    /// primvar of a USD groom (a vertex's at each strand's root).
    pub style_map: Option<String>,
    /// The map's values are labels (0 the first `--style`, 1 the second, …)
    /// rather than a blend of two paintings (0 the first, 1 the second).
    pub style_map_labels: bool,
    /// The map's values in memory, one per strand (the Python package's
    /// array); they take the place of `style_map`.
    pub style_map_values: Option<Vec<f32>>,
    /// Output groom, .usda, .usdc (or .usd, binary), .usdz or .ply (written atomically); with `frames` a pattern.
    pub out: PathBuf,
    /// Before | after | painting preview PNG; with `frames` a pattern.
    pub preview: Option<PathBuf>,
    /// Table 1 preset.
    pub preset: Preset,
    /// Frames of an animated groom (e.g. `1-24`), stylized in order.
    pub frames: Option<String>,
    /// Start over, ignoring the state a killed run of the same job left.
    pub force: bool,
    /// Folder of the state saved after every frame; `None`:
    /// `<out dir>/.nst3d-work/<hash of the job>`.
    pub work_dir: Option<PathBuf>,
    /// Temporal coherence of a sequence.
    pub temporal: Temporal,
    /// EMA coefficient σ (default: the preset's).
    pub ema_sigma: Option<f32>,
    /// EMA decaying period ν, as a fraction of the iterations (default: the preset's).
    pub ema_nu: Option<f32>,
    /// What the EMA's iteration count m runs over.
    pub ema_clock: EmaClock,
    /// 1€ blending parameter α (default: the preset's).
    pub one_euro_alpha: Option<f32>,
    /// 1€ scaling coefficient β (default: the preset's).
    pub one_euro_beta: Option<f32>,
    /// 1€ minimum cutoff frequency f_min in Hz (default: the preset's).
    pub one_euro_fmin: Option<f32>,
    /// Frame rate of the animation (default: the preset's).
    pub fps: Option<f32>,
    /// Style flow s*: a world-space velocity in groom units per frame that
    /// carries the stylization instead of the groom's own motion.
    pub style_flow: Option<[f32; 3]>,
    /// Total iterations over the three scales (default: the preset's).
    pub iters: Option<u32>,
    /// Square render size (default: the preset's).
    pub render_size: Option<usize>,
    /// Proxy strands to grow (default: the preset's proxy/guide ratio).
    pub proxies: Option<usize>,
    /// Which axis of the groom and mesh points up (`--up`); `None`: a
    /// USD layer's `upAxis`, else y ([`crate::axis::resolve`]). The
    /// cameras circle it, the previews stand on it, the output keeps it.
    pub up: Option<UpAxis>,
    /// Seed of densification and camera sampling.
    pub seed: u64,
    /// Multiplier on the preset's learning rates (scaled by the groom's radius).
    pub lr_scale: f32,
    /// The painting's scale on the hair: multiplies the preset's style sizes
    /// and the size the orientation term lays the painting at; `None`: the
    /// preset's ([`PresetParams::style_scale`](nst3d_strands::PresetParams::style_scale)).
    pub style_scale: Option<f32>,
    /// Cameras per scale whose matches are cached (0: a new camera every iteration).
    pub views_per_scale: usize,
    /// Evaluation views: the first this many of the finest scale's cameras
    /// (with `views_per_scale` 0, as many drawn afresh).
    pub eval_views: usize,
    /// Iterations of the three scales (overrides `iters`).
    pub scale_iters: Option<[u32; 3]>,
    /// Strand cross-section sigma in pixels (default: the pipeline's).
    pub strand_width: Option<f32>,
    /// Match each scale's targets on the groom the coarser scales left
    /// (`StylizeParams::rematch`); `None`: no, every scale matches on the
    /// rest groom (see [`StrandSettings::stylize_params`]).
    pub rematch: Option<bool>,
    /// Velocity samples blended per control point (eq. 5's neighbourhood);
    /// `None`: the preset's.
    pub field_neighbors: Option<usize>,
    /// Weight of the orientation term (`StylizeParams::orientation`); 0 runs
    /// the paper's NNST loss alone; `None`: the preset's. With it a
    /// sequence's EMA period is at least [`ORIENTATION_EMA_NU`].
    pub orientation: Option<f32>,
    /// VGG-19 weights file; `None`: `$NST3D_VGG19`, else the user cache.
    pub weights: Option<PathBuf>,
    /// Stylize the strands' colour too: after the shape (the
    /// same as without colour), a colour stage starting from the input's
    /// colours (white without) matches the painting's colours from cameras
    /// all around the groom; written as the output's colours
    /// (`primvars:displayColor`, `red/green/blue`).
    pub color: bool,
}

impl StrandSettings {
    /// The command line's defaults for stylizing `groom` on `mesh` with `style` into `out`.
    pub fn new(
        groom: impl Into<PathBuf>,
        mesh: impl Into<PathBuf>,
        style: impl Into<PathBuf>,
        out: impl Into<PathBuf>,
    ) -> Self {
        Self {
            groom: groom.into(),
            mesh: Some(mesh.into()),
            style: style.into(),
            more_styles: Vec::new(),
            style_map: None,
            style_map_labels: false,
            style_map_values: None,
            out: out.into(),
            preview: None,
            preset: Preset::ShortHair,
            frames: None,
            force: false,
            work_dir: None,
            temporal: Temporal::EmaOneEuro,
            ema_sigma: None,
            ema_nu: None,
            ema_clock: EmaClock::Scale,
            one_euro_alpha: None,
            one_euro_beta: None,
            one_euro_fmin: None,
            fps: None,
            style_flow: None,
            iters: None,
            render_size: None,
            proxies: None,
            up: None,
            seed: 0,
            lr_scale: 1.0,
            style_scale: None,
            views_per_scale: 8,
            eval_views: 4,
            scale_iters: None,
            strand_width: None,
            rematch: None,
            field_neighbors: None,
            orientation: None,
            weights: None,
            color: false,
        }
    }

    /// Checks the numbers before any slow work.
    pub fn check(&self) -> Result<()> {
        if self.iters == Some(0) {
            bail!("--iters must be at least 1");
        }
        if let Some(n) = self.render_size {
            if !(16..=16384).contains(&n) {
                bail!("--render-size must be 16 to 16384 pixels, got {n}");
            }
        }
        if !(self.lr_scale.is_finite() && self.lr_scale > 0.0) {
            bail!("--lr-scale must be a positive number, got {}", self.lr_scale);
        }
        if let Some(s) = self.style_scale.filter(|s| !(s.is_finite() && *s > 0.0)) {
            bail!("--style-scale must be a positive number, got {s}");
        }
        if self.scale_iters.is_some_and(|n| n.iter().all(|&k| k == 0)) {
            bail!("--scale-iters must run at least one iteration");
        }
        if let Some(w) = self.strand_width {
            if !(w.is_finite() && w > 0.0) {
                bail!("--strand-width must be a positive number of pixels, got {w}");
            }
        }
        if let Some(w) = self.orientation.filter(|w| !(w.is_finite() && *w >= 0.0)) {
            bail!("--orientation must be 0 or a positive number, got {w}");
        }
        if let Some(k) = self.field_neighbors {
            if !(1..=256).contains(&k) {
                bail!("--field-neighbors must be 1 to 256, got {k}");
            }
        }
        self.check_style_map()?;
        if self.color && self.frames.is_some() {
            bail!("--color stylizes one groom; it is not carried through --frames yet");
        }
        if let Some(v) = self.style_flow {
            if !v.iter().all(|c| c.is_finite()) {
                bail!("--style-flow needs three finite numbers X,Y,Z, got {v:?}");
            }
        }
        Ok(())
    }

    /// The paintings and the style map agree: several paintings need a
    /// map and a map several paintings, a blend two.
    fn check_style_map(&self) -> Result<()> {
        let mapped = self.style_map.is_some() || self.style_map_values.is_some();
        let paintings = 1 + self.more_styles.len();
        match (mapped, paintings) {
            (false, 1) => {}
            (false, n) => bail!("{n} paintings (--style) need a --style-map saying which strands take which"),
            (true, 1) => bail!("--style-map needs two or more paintings (--style given again), got one"),
            (true, n) if !self.style_map_labels && n != 2 => {
                bail!("a blending --style-map takes two paintings, got {n} (add --style-map-labels to pick one of {n})")
            }
            (true, _) => {}
        }
        if self.style_map_labels && !mapped {
            bail!("--style-map-labels needs a --style-map");
        }
        Ok(())
    }

    /// The paintings in order: `style`, then `more_styles`.
    pub fn paintings(&self) -> Vec<&Path> {
        std::iter::once(self.style.as_path()).chain(self.more_styles.iter().map(PathBuf::as_path)).collect()
    }

    /// The outputs checked before any work (`io::atomic::check_output`): a
    /// groom file that is not the input groom and whose folder takes a
    /// file, and a `.png` preview; for a sequence those of `frame`.
    pub fn check_outputs(&self, frame: Option<i64>) -> Result<()> {
        use nst3d_io::atomic::check_output;
        let at = |p: &Path, flag: &str| -> Result<PathBuf> {
            match frame {
                Some(f) => frame_path(p, f, flag),
                None => Ok(p.to_path_buf()),
            }
        };
        let (groom, out) = (at(&self.groom, "--groom")?, at(&self.out, "--out")?);
        check_output("--out", &out, &["usda", "usdc", "usd", "usdz", "ply"], &[&groom]).map_err(anyhow::Error::msg)?;
        if let Some(p) = &self.preview {
            check_output("--preview", &at(p, "--preview")?, &["png"], &[]).map_err(anyhow::Error::msg)?;
        }
        Ok(())
    }

    /// Bytes a stylization with `params` needs at its peak, from the peak
    /// RSS measured at Table 1 sizes (docs/design/strands.md: 2.99M control points
    /// at 600² took 3.3 GB, 450K at 500² took 2.0 GB; this gives 3.7 and
    /// 2.4): 0.4 GB + 180 B per control point of guides and proxies + 7.7 KB
    /// per render pixel (the VGG features and splat buffers of one view).
    pub fn memory_estimate(params: &StylizeParams, guides: usize) -> u64 {
        let points = ((guides + params.proxies) * params.preset.points_per_strand.max(2)) as u64;
        let pixels = (params.render_size * params.render_size) as u64;
        400_000_000 + 180 * points + 7_700 * pixels
    }

    /// Refuses, before any work, a stylization whose estimated peak memory
    /// ([`StrandSettings::memory_estimate`]) exceeds what this machine has
    /// available.
    pub fn check_memory(params: &StylizeParams, guides: usize) -> Result<()> {
        let need = Self::memory_estimate(params, guides);
        let what = format!(
            "stylizing {guides} guides and {} proxies at {}x{}",
            params.proxies, params.render_size, params.render_size
        );
        nst3d_core::memory::check_fits(need, &what, "lower --render-size or --proxies").map_err(anyhow::Error::msg)
    }

    /// The stylization settings for a groom of `guides` strands (proxies
    /// default to the preset's proxy/guide ratio).
    pub fn stylize_params(&self, guides: usize) -> StylizeParams {
        let mut params = StylizeParams::from_preset(self.preset.params(), guides);
        if let Some(n) = self.iters {
            params = params.with_total_iterations(n);
        }
        if let Some(r) = self.render_size {
            params.render_size = r;
        }
        if let Some(m) = self.proxies {
            params.proxies = m;
        }
        params.seed = self.seed;
        params.lr_scale = self.lr_scale;
        params.style_scale = self.style_scale.unwrap_or(params.style_scale);
        params.views_per_scale = self.views_per_scale;
        params.eval_views = self.eval_views;
        if let Some(n) = self.scale_iters {
            params.iterations = n;
        }
        if let Some(w) = self.strand_width {
            params.strand_width_px = w;
        }
        if let Some(k) = self.field_neighbors {
            params.preset.neighbors = k;
        }
        params.orientation = self.orientation.unwrap_or(params.orientation);
        // Every scale matches on the rest groom by default, as eq. 2 is
        // written: targets re-matched on the stylization so far feed its
        // gaps back into the targets, which gave every style the same
        // clumps, and a sequence flickers more with them (the fur ball in
        // the wind: 0.56x of per-frame stylization against 0.46x).
        params.rematch = self.rematch.unwrap_or(false);
        params.color = self.color;
        params
    }

    /// The temporal settings of a sequence: the preset's (Table 1) with any
    /// overrides, and whether the preset had none (static presets borrow
    /// Long Hair's, the animated hair example).
    pub fn temporal_params(&self) -> (TemporalParams, bool) {
        let preset = self.preset.params();
        let borrowed = preset.temporal.is_none();
        let mut t =
            preset.temporal.unwrap_or_else(|| Preset::LongHair.params().temporal.expect("Long Hair is animated"));
        let set = |dst: &mut f32, v: Option<f32>| {
            if let Some(v) = v {
                *dst = v;
            }
        };
        // With the orientation term the EMA holds on to the previous
        // frame's field longer ([`ORIENTATION_EMA_NU`]).
        if self.orientation.unwrap_or(preset.orientation) > 0.0 {
            t.ema_nu = t.ema_nu.max(ORIENTATION_EMA_NU);
        }
        set(&mut t.ema_sigma, self.ema_sigma);
        set(&mut t.ema_nu, self.ema_nu);
        set(&mut t.blend_alpha, self.one_euro_alpha);
        set(&mut t.beta, self.one_euro_beta);
        set(&mut t.min_cutoff_hz, self.one_euro_fmin);
        set(&mut t.fps, self.fps);
        (t, borrowed)
    }
}

/// The groom formats nst3d writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OutFormat {
    /// USD BasisCurves, text.
    Usda,
    /// USD BasisCurves, a binary crate file (`.usdc`, or `.usd`).
    Usdc,
    /// USD BasisCurves, a crate file in a `.usdz` package.
    Usdz,
    /// PLY strand points, the layout the readers take.
    Ply,
}

impl OutFormat {
    /// The format `path`'s extension names.
    pub fn of(path: &Path) -> Result<Self> {
        match path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
            Some("usda") => Ok(Self::Usda),
            // `.usd` is binary, as USD itself writes it by default.
            Some("usdc") | Some("usd") => Ok(Self::Usdc),
            Some("usdz") => Ok(Self::Usdz),
            Some("ply") => Ok(Self::Ply),
            _ => bail!("--out {}: the output groom must end in .usda, .usdc, .usd, .usdz or .ply", path.display()),
        }
    }
}

/// Path `pattern` at `frame` (clear error without a placeholder).
pub fn frame_path(pattern: &Path, frame: i64, what: &str) -> Result<PathBuf> {
    let text = pattern.to_str().with_context(|| format!("{what} {} is not valid UTF-8", pattern.display()))?;
    Ok(PathBuf::from(expand_pattern(text, frame).with_context(|| format!("{what} with --frames"))?))
}

/// Whether `path` names a frame pattern rather than one file.
pub fn is_pattern(path: &Path) -> bool {
    path.to_str().is_some_and(|p| expand_pattern(p, 0).is_ok())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The orientation term is the preset's, for one frame or a sequence,
    /// unless asked for; with it a sequence's EMA holds on longer, unless
    /// `--ema-nu` says otherwise.
    #[test]
    fn orientation_is_the_presets_and_holds_the_ema_in_a_sequence() {
        let mut s = StrandSettings::new("g.ply", "m.obj", "s.png", "o.ply");
        s.preset = Preset::FurBall;
        let fur = Preset::FurBall.params().orientation;
        assert!(fur > 0.0);
        assert_eq!(s.stylize_params(10).orientation, fur);
        s.frames = Some("1-3".into());
        assert_eq!(s.stylize_params(10).orientation, fur);
        assert_eq!(s.temporal_params().0.ema_nu, ORIENTATION_EMA_NU);
        s.orientation = Some(0.0);
        assert_eq!(s.stylize_params(10).orientation, 0.0);
        assert_eq!(s.temporal_params().0.ema_nu, Preset::FurBall.params().temporal.unwrap().ema_nu);
        s.orientation = Some(0.5);
        s.ema_nu = Some(0.8);
        assert_eq!(s.temporal_params().0.ema_nu, 0.8);
        s.preset = Preset::ShortHair;
        s.frames = None;
        s.orientation = None;
        assert_eq!(s.stylize_params(10).orientation, 0.0);
    }

    /// The painting's scale on the hair is the preset's unless given.
    #[test]
    fn style_scale_is_the_presets_unless_given() {
        let mut s = StrandSettings::new("g.ply", "m.obj", "s.png", "o.ply");
        for preset in Preset::ALL {
            s.preset = preset;
            assert_eq!(s.stylize_params(10).style_scale, preset.params().style_scale);
        }
        s.style_scale = Some(0.75);
        assert_eq!(s.stylize_params(10).style_scale, 0.75);
        s.style_scale = Some(0.0);
        assert!(s.check().is_err());
    }
}
