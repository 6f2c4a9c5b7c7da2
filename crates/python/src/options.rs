//! Keyword arguments onto typed settings. The Python half passes only the
//! options the caller gave (as `str`, `int`, `float`, `bool` or sequences);
//! everything else keeps the command line's default. The names are the
//! command line's flags with `_` for `-`; an unknown name is an error, not
//! silently ignored.

use std::path::PathBuf;

use nst3d_features::VggLayer;
use nst3d_groom::StrandSettings;
use nst3d_volume::{ModelSettings, SequenceSettings, VolumeSettings};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// The options of one call, taken one by one; what is left at the end is unknown.
pub struct Options<'py> {
    items: Vec<(String, Bound<'py, PyAny>)>,
}

impl<'py> Options<'py> {
    /// Reads the option dict (keys must be strings; `None` values are skipped).
    pub fn new(d: &Bound<'py, PyDict>) -> PyResult<Self> {
        let mut items = Vec::new();
        for (k, v) in d.iter() {
            let k: String = k.extract().map_err(|_| PyTypeError::new_err("option names must be strings"))?;
            if !v.is_none() {
                items.push((k, v));
            }
        }
        Ok(Self { items })
    }

    fn take(&mut self, name: &str) -> Option<Bound<'py, PyAny>> {
        let i = self.items.iter().position(|(k, _)| k == name)?;
        Some(self.items.remove(i).1)
    }

    fn typed<T>(
        &mut self,
        name: &str,
        what: &str,
        f: impl FnOnce(&Bound<'py, PyAny>) -> PyResult<T>,
    ) -> PyResult<Option<T>> {
        match self.take(name) {
            None => Ok(None),
            Some(v) => f(&v).map(Some).map_err(|_| {
                let got = v.get_type().name().map(|n| n.to_string()).unwrap_or_else(|_| "?".into());
                PyTypeError::new_err(format!("option '{name}': expected {what}, got {got}"))
            }),
        }
    }

    fn f32(&mut self, name: &str) -> PyResult<Option<f32>> {
        self.typed(name, "a number", |v| v.extract::<f32>())
    }

    /// A strength as `--strength` reads it: subtle, default, strong or a number.
    fn strength(&mut self, name: &str) -> PyResult<Option<f32>> {
        let Some(v) = self.typed(name, "subtle, default, strong or a number", |v| {
            v.extract::<String>().or_else(|_| v.extract::<f32>().map(|x| x.to_string()))
        })?
        else {
            return Ok(None);
        };
        nst3d_volume::settings::parse_strength(&v)
            .map(Some)
            .map_err(|e| PyValueError::new_err(format!("option '{name}': {e}")))
    }

    fn usize(&mut self, name: &str) -> PyResult<Option<usize>> {
        self.typed(name, "a whole number >= 0", |v| v.extract::<usize>())
    }

    fn u64(&mut self, name: &str) -> PyResult<Option<u64>> {
        self.typed(name, "a whole number >= 0", |v| v.extract::<u64>())
    }

    fn bool(&mut self, name: &str) -> PyResult<Option<bool>> {
        self.typed(name, "True or False", |v| v.extract::<bool>())
    }

    fn string(&mut self, name: &str) -> PyResult<Option<String>> {
        self.typed(name, "a string", |v| v.extract::<String>())
    }

    fn path(&mut self, name: &str) -> PyResult<Option<PathBuf>> {
        self.typed(name, "a path", |v| v.extract::<PathBuf>())
    }

    /// A string parsed by `parse`; its error is the message.
    fn parsed<T>(&mut self, name: &str, parse: impl FnOnce(&str) -> Result<T, String>) -> PyResult<Option<T>> {
        match self.string(name)? {
            None => Ok(None),
            Some(s) => parse(&s).map(Some).map_err(|e| PyValueError::new_err(format!("option '{name}': {e}"))),
        }
    }

    /// Fails on any option no setting took.
    fn finish(self, what: &str) -> PyResult<()> {
        match self.items.first() {
            None => Ok(()),
            Some((k, _)) => Err(PyTypeError::new_err(format!("{what}: unknown option '{k}'"))),
        }
    }
}

macro_rules! set {
    ($o:ident . $get:ident ( $($arg:expr),+ ) => $dst:expr) => {
        if let Some(v) = $o.$get($($arg),+)? {
            $dst = v;
        }
    };
    ($o:ident . $get:ident ( $($arg:expr),+ ) => Some $dst:expr) => {
        if let Some(v) = $o.$get($($arg),+)? {
            $dst = Some(v);
        }
    };
}

/// `nst3d volume`'s flags onto [`VolumeSettings`].
pub fn apply_volume(s: &mut VolumeSettings, mut o: Options<'_>) -> PyResult<()> {
    set!(o.path("preview") => Some s.preview);
    set!(o.string("grid") => s.grid);
    // Kept for --model too: the CLI checks a given mode against the model's.
    let mode = o.parsed("mode", |m| m.parse())?;
    if let Some(m) = mode {
        s.mode = m;
    }
    set!(o.usize("octaves") => Some s.octaves);
    set!(o.usize("iters") => s.iters);
    set!(o.f32("lr") => Some s.lr);
    set!(o.f32("vmax") => Some s.vmax);
    set!(o.f32("smin") => s.smin);
    set!(o.f32("smax") => s.smax);
    set!(o.f32("style_scale") => s.style_scale);
    set!(o.strength("strength") => s.strength);
    set!(o.bool("style_color") => s.style_color);
    set!(o.bool("color") => s.color);
    set!(o.string("color_grid") => Some s.color_grid);
    if let Some(v) = o.typed("layers", "a list of layer names", |v| v.extract::<Vec<String>>())? {
        s.layers = v
            .iter()
            .map(|l| l.parse::<VggLayer>().map_err(|e| PyValueError::new_err(format!("option 'layers': {e}"))))
            .collect::<PyResult<_>>()?;
    }
    set!(o.f32("absorption") => Some s.absorption);
    set!(o.bool("equalize") => s.equalize);
    set!(o.parsed("camera", |v| v.parse()) => s.projection);
    set!(o.f32("fov") => s.fov);
    set!(o.parsed("up", |v| v.parse()) => s.up);
    set!(o.path("weights") => Some s.weights);
    set!(o.string("cameras") => s.cameras);
    set!(o.path("camera_file") => Some s.camera_file);
    set!(o.u64("camera_seed") => s.camera_seed);
    set!(o.string("eval_cameras") => Some s.eval_cameras);
    set!(o.string("style_map") => Some s.style_map);
    set!(o.bool("style_map_labels") => s.style_map_labels);
    if let Some(u) = o.typed("upsample", "'auto' or a factor", |v| {
        v.extract::<String>().or_else(|_| v.extract::<usize>().map(|k| k.to_string()))
    })? {
        s.upsample = u.parse().map_err(|e| PyValueError::new_err(format!("option 'upsample': {e}")))?;
    }
    // The sequence half: present when frames are given.
    if let Some(frames) = o.string("frames")? {
        let mut q = SequenceSettings { frames, ..SequenceSettings::default() };
        set!(o.f32("ema") => q.ema);
        set!(o.bool("ema_settle") => q.ema_settle);
        set!(o.string("velocity_grid") => Some q.velocity_grid);
        set!(o.f32("velocity_scale") => Some q.velocity_scale);
        set!(o.string("chunk") => Some q.chunk);
        if let Some(w) = o.typed("warmup", "a whole number", |v| v.extract::<i64>())? {
            q.warmup = w;
        }
        set!(o.bool("force") => q.force);
        set!(o.path("work_dir") => Some q.work_dir);
        s.sequence = Some(q);
    }
    if let Some(path) = o.path("model")? {
        let mut m = ModelSettings::new(path);
        set!(o.usize("tile") => m.tile);
        set!(o.usize("tile_margin") => m.margin);
        m.mode = mode;
        m.strength = s.strength;
        s.model = Some(m);
    }
    o.finish("stylize_vdb")
}

/// `nst3d volume --model`'s tile flags and `--strength` onto [`ModelSettings`].
pub fn apply_model(m: &mut ModelSettings, mut o: Options<'_>) -> PyResult<()> {
    set!(o.usize("tile") => m.tile);
    set!(o.usize("tile_margin") => m.margin);
    set!(o.parsed("mode", |s| s.parse()) => Some m.mode);
    set!(o.strength("strength") => m.strength);
    o.finish("Model.load")
}

/// `nst3d strands`'s flags onto [`StrandSettings`].
pub fn apply_strands(s: &mut StrandSettings, mut o: Options<'_>) -> PyResult<()> {
    set!(o.path("preview") => Some s.preview);
    set!(o.string("style_map") => Some s.style_map);
    set!(o.bool("style_map_labels") => s.style_map_labels);
    set!(o.parsed("preset", |p| p.parse()) => s.preset);
    set!(o.string("frames") => Some s.frames);
    set!(o.bool("force") => s.force);
    set!(o.path("work_dir") => Some s.work_dir);
    set!(o.parsed("temporal", |v| v.parse()) => s.temporal);
    set!(o.f32("ema_sigma") => Some s.ema_sigma);
    set!(o.f32("ema_nu") => Some s.ema_nu);
    set!(o.parsed("ema_clock", |v| v.parse()) => s.ema_clock);
    set!(o.f32("one_euro_alpha") => Some s.one_euro_alpha);
    set!(o.f32("one_euro_beta") => Some s.one_euro_beta);
    set!(o.f32("one_euro_fmin") => Some s.one_euro_fmin);
    set!(o.f32("fps") => Some s.fps);
    set!(o.typed("style_flow", "three numbers", |v| v.extract::<[f32; 3]>()) => Some s.style_flow);
    if let Some(v) = o.typed("iters", "a whole number", |v| v.extract::<u32>())? {
        s.iters = Some(v);
    }
    set!(o.usize("render_size") => Some s.render_size);
    set!(o.usize("proxies") => Some s.proxies);
    set!(o.parsed("up", |v| v.parse()) => Some s.up);
    set!(o.u64("seed") => s.seed);
    set!(o.f32("lr_scale") => s.lr_scale);
    set!(o.f32("style_scale") => Some s.style_scale);
    set!(o.usize("views_per_scale") => s.views_per_scale);
    set!(o.usize("eval_views") => s.eval_views);
    if let Some(v) = o.typed("scale_iters", "three whole numbers", |v| v.extract::<[u32; 3]>())? {
        s.scale_iters = Some(v);
    }
    set!(o.f32("strand_width") => Some s.strand_width);
    set!(o.bool("rematch") => Some s.rematch);
    set!(o.usize("field_neighbors") => Some s.field_neighbors);
    set!(o.f32("orientation") => Some s.orientation);
    set!(o.bool("color") => s.color);
    set!(o.path("weights") => Some s.weights);
    o.finish("stylize_groom")
}

/// `nst3d train`'s flags onto [`nst3d_train::TrainSettings`].
pub fn apply_train(s: &mut nst3d_train::TrainSettings, mut o: Options<'_>) -> PyResult<()> {
    set!(o.string("grid") => s.grid);
    if let Some(m) = o.parsed("mode", |m| m.parse::<nst3d_stylize::Mode>())? {
        s.velocity = matches!(m, nst3d_stylize::Mode::Velocity);
    }
    set!(o.f32("style_scale") => s.style_scale);
    set!(o.path("weights") => Some s.weights);
    set!(o.usize("channels") => s.channels);
    set!(o.usize("patch") => s.patch);
    set!(o.usize("octaves") => s.octaves);
    set!(o.u64("steps") => Some s.steps);
    if let Some(m) = o.typed("minutes", "a number", |v| v.extract::<f64>())? {
        s.minutes = Some(m);
    }
    set!(o.f32("theta") => s.theta_deg);
    set!(o.f32("phi") => s.phi_deg);
    if let Some(v) = o.parsed("view_axes", |v| v.parse::<nst3d_train::ViewAxes>())? {
        s.view_axes = v;
    }
    if let Some(a) = o.parsed("absorption", |v| v.parse::<nst3d_train::Absorption>())? {
        s.absorption = a;
    }
    set!(o.usize("texture") => Some s.texture);
    set!(o.u64("seed") => s.seed);
    set!(o.u64("checkpoint_every") => s.checkpoint_every);
    set!(o.usize("batch") => s.batch);
    o.finish("train")
}
