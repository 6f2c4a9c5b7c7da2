//! `nst3d._nst3d`: the native half of the `nst3d` Python package
//! (`python/nst3d/__init__.py` is the half users import). Each function
//! fills the same typed settings the command line fills, starting from the
//! same defaults (`VolumeSettings::new`, `StrandSettings::new`,
//! `TrainSettings::new`), and makes the same library call, with the GIL
//! released. Arrays cross as `bytes` plus a shape (the Python half does the
//! numpy conversion): one copy each way, next to minutes of stylization, and
//! no dependency on numpy's C API, so one abi3 wheel serves every CPython
//! from 3.9.

#![warn(missing_docs)]

mod options;
mod reporter;

use std::path::PathBuf;

use nst3d_core::{Grid3, Groom, Strand, TriMesh};
use nst3d_groom::StrandSettings;
use nst3d_volume::{LoadedModel, ModelSettings, VolumeReport, VolumeSettings};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};

use crate::options::{apply_model, apply_strands, apply_train, apply_volume, Options};
use crate::reporter::run_job;

/// Same allocator as the `nst3d` binary: the same work costs the same.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// Keeps freed pages as the binary does (`nst3d_core::memory::ALLOCATOR_PURGE_DELAY_MS`).
fn keep_freed_pages() {
    use nst3d_core::memory::{ALLOCATOR_PURGE_DELAY_MS, MIMALLOC_OPTION_PURGE_DELAY};
    // SAFETY: sets one integer option; mimalloc allows it at any time.
    unsafe { libmimalloc_sys::mi_option_set(MIMALLOC_OPTION_PURGE_DELAY, ALLOCATOR_PURGE_DELAY_MS as _) }
}

pyo3::create_exception!(
    _nst3d,
    Nst3dError,
    PyRuntimeError,
    "A job failed; the message is the command line's one-line error."
);

type Dict<'py> = Bound<'py, PyDict>;

/// Little-endian f32 bytes → values (numpy's native order on every platform nst3d runs on).
fn f32s(bytes: &[u8], what: &str) -> PyResult<Vec<f32>> {
    if !bytes.len().is_multiple_of(4) {
        return Err(PyValueError::new_err(format!("{what}: {} bytes is not a whole number of float32", bytes.len())));
    }
    Ok(bytes.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect())
}

fn f32_bytes<'py>(py: Python<'py>, values: impl Iterator<Item = f32>) -> Bound<'py, PyBytes> {
    let v: Vec<u8> = values.flat_map(f32::to_le_bytes).collect();
    PyBytes::new(py, &v)
}

/// A dense grid from `bytes` of `dims` (x fastest); `what` names it in errors.
fn grid_of(bytes: &[u8], dims: [usize; 3], what: &str) -> PyResult<Grid3> {
    let values = f32s(bytes, what)?;
    let n = dims.iter().try_fold(1usize, |a, &d| a.checked_mul(d));
    if n != Some(values.len()) || values.is_empty() {
        return Err(PyValueError::new_err(format!("{what}: shape {dims:?} does not match {} values", values.len())));
    }
    Ok(Grid3::from_vec(dims, values))
}

/// Stylizes a dense density grid in memory (one frame, `nst3d volume`'s
/// settings); returns the stylized values over the same box and a report.
#[pyfunction]
#[pyo3(signature = (density, dims, style, options, progress=None, log=None))]
fn stylize_volume<'py>(
    py: Python<'py>,
    density: &[u8],
    dims: [usize; 3],
    style: PathBuf,
    options: &Dict<'py>,
    progress: Option<Py<PyAny>>,
    log: Option<Py<PyAny>>,
) -> PyResult<(Bound<'py, PyBytes>, Bound<'py, PyDict>)> {
    let grid = grid_of(density, dims, "density")?;
    let mut s = VolumeSettings::new("", style, "");
    apply_volume(&mut s, Options::new(options)?)?;
    let r = run_job(py, progress, log, move |rep| {
        nst3d_volume::stylize_grid(&s, grid, &nst3d_io::vdb::Transform::uniform(1.0), [0; 3], "density", rep)
    })?;
    let d = PyDict::new(py);
    d.set_item("upsample", r.upsample)?;
    d.set_item("dims", r.dims)?;
    d.set_item("cameras", r.cameras)?;
    d.set_item("loss_before", r.loss_before)?;
    d.set_item("loss_after", r.loss_after)?;
    d.set_item("held_out", r.held_out.as_ref().map(|h| h.means()))?;
    let out = r.cropped();
    Ok((f32_bytes(py, out.data.into_iter()), d))
}

/// Stylizes an OpenVDB file or sequence into files (`nst3d volume`);
/// `style_map_array` is a style map as float32 bytes and dims (x fastest)
/// over the input grid's active bounding box.
#[pyfunction]
#[pyo3(signature = (input, out, styles, options, progress=None, log=None, style_map_array=None))]
#[allow(clippy::too_many_arguments)]
fn stylize_vdb<'py>(
    py: Python<'py>,
    input: PathBuf,
    out: PathBuf,
    styles: Vec<PathBuf>,
    options: &Dict<'py>,
    progress: Option<Py<PyAny>>,
    log: Option<Py<PyAny>>,
    style_map_array: Option<(Vec<u8>, [usize; 3])>,
) -> PyResult<Bound<'py, PyDict>> {
    // Several paintings go where a style map puts them, in its order.
    let mut styles = styles.into_iter();
    let mut s = VolumeSettings::new(input, styles.next().unwrap_or_default(), out);
    s.more_styles = styles.collect();
    apply_volume(&mut s, Options::new(options)?)?;
    if let Some((bytes, dims)) = style_map_array {
        let values = grid_of(&bytes, dims, "style_map")?;
        s.style_map_array = Some(nst3d_volume::style_map::MapArray { values: std::sync::Arc::new(values) });
    }
    let r = run_job(py, progress, log, move |rep| nst3d_volume::stylize(&s, rep))?;
    let d = PyDict::new(py);
    match r {
        VolumeReport::Frame(f) => {
            d.set_item("kind", "frame")?;
            d.set_item("out", f.out)?;
            d.set_item("grid", f.grid)?;
            d.set_item("dims", f.dims)?;
            d.set_item("upsample", f.upsample)?;
            d.set_item("cameras", f.cameras)?;
            d.set_item("loss_before", f.loss_before)?;
            d.set_item("loss_after", f.loss_after)?;
            d.set_item("held_out", f.held_out.as_ref().map(|h| h.means()))?;
        }
        VolumeReport::Sequence(nst3d_volume::SequenceReport::NothingToDo { frames, start, end }) => {
            d.set_item("kind", "sequence")?;
            d.set_item("stylized", 0)?;
            d.set_item("kept", frames)?;
            d.set_item("chunk", (start, end))?;
        }
        VolumeReport::Sequence(nst3d_volume::SequenceReport::Done(q)) => {
            d.set_item("kind", "sequence")?;
            d.set_item("stylized", q.stylized)?;
            d.set_item("unchanged", q.unchanged)?;
            d.set_item("cameras", q.cameras)?;
            d.set_item("mean_loss", q.mean_loss)?;
            d.set_item("flicker", q.flicker)?;
        }
        VolumeReport::Model(m) => {
            d.set_item("kind", "model")?;
            d.set_item("stylized", m.frames)?;
            d.set_item("skipped", m.skipped)?;
            d.set_item("seconds", m.seconds)?;
        }
    }
    Ok(d)
}

/// The groom of `points` (x, y, z float32 bytes) cut into strands of `counts` points.
fn groom_of(points: &[u8], counts: Vec<usize>) -> PyResult<Groom> {
    let p = f32s(points, "points")?;
    if p.len() % 3 != 0 {
        return Err(PyValueError::new_err("points: expected an (N, 3) array"));
    }
    let total: usize = counts.iter().sum();
    if total * 3 != p.len() {
        return Err(PyValueError::new_err(format!("counts add up to {total} points, points holds {}", p.len() / 3)));
    }
    let mut strands = Vec::with_capacity(counts.len());
    let mut at = 0;
    for n in counts {
        strands.push(Strand::new(p[at..at + 3 * n].chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()));
        at += 3 * n;
    }
    let g = Groom { strands };
    g.validate().map_err(|e| Nst3dError::new_err(format!("groom: {e}")))?;
    Ok(g)
}

/// Stylizes a groom in memory (`nst3d strands`, one groom): `points` and
/// `counts` are the strands, `mesh` a head mesh file or `(vertices,
/// triangles)` bytes and counts; `styles` one painting or several, shared
/// by `style_map_values` (float32 bytes, one per strand) or the
/// `style_map` option; returns the new points in the same order.
#[pyfunction]
#[pyo3(signature = (points, counts, styles, options, mesh_file=None, mesh=None, progress=None, log=None, colors=None, style_map_values=None))]
#[allow(clippy::too_many_arguments)]
fn stylize_groom<'py>(
    py: Python<'py>,
    points: &[u8],
    counts: Vec<usize>,
    styles: Vec<PathBuf>,
    options: &Dict<'py>,
    mesh_file: Option<PathBuf>,
    mesh: Option<(Vec<u8>, Vec<u32>)>,
    progress: Option<Py<PyAny>>,
    log: Option<Py<PyAny>>,
    colors: Option<&[u8]>,
    style_map_values: Option<&[u8]>,
) -> PyResult<(Bound<'py, PyBytes>, Bound<'py, PyDict>)> {
    let mut groom = groom_of(points, counts)?;
    if let Some(c) = colors {
        let c = f32s(c, "colors")?;
        if c.len() != 3 * groom.point_count() {
            return Err(PyValueError::new_err(format!(
                "colors: {} values for {} points, expected an (N, 3) array",
                c.len(),
                groom.point_count()
            )));
        }
        let mut at = 0;
        for st in &mut groom.strands {
            let n = st.points.len();
            st.colors = Some(c[3 * at..3 * (at + n)].chunks_exact(3).map(|v| [v[0], v[1], v[2]]).collect());
            at += n;
        }
    }
    let mut s = strand_settings("", styles, "", style_map_values)?;
    s.mesh = None;
    apply_strands(&mut s, Options::new(options)?)?;
    let head = match (mesh_file, mesh) {
        (Some(path), _) => Some(nst3d_io::mesh::read_mesh(&path).map_err(|e| Nst3dError::new_err(e.to_string()))?),
        (None, Some((v, t))) => {
            let v = f32s(&v, "mesh vertices")?;
            if v.len() % 3 != 0 || t.len() % 3 != 0 {
                return Err(PyValueError::new_err("mesh: expected (V, 3) vertices and (T, 3) triangles"));
            }
            let n = (v.len() / 3) as u32;
            if let Some(bad) = t.iter().find(|&&i| i >= n) {
                return Err(PyValueError::new_err(format!("mesh: triangle index {bad} but {n} vertices")));
            }
            Some(TriMesh {
                vertices: v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
                triangles: t.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
                normals: None,
            })
        }
        (None, None) => None,
    };
    let r = run_job(py, progress, log, move |rep| nst3d_groom::stylize_groom(&s, &groom, head.as_ref(), rep))?;
    let d = groom_report(py, &r.report)?;
    if let Some(c) = &r.colors {
        d.set_item("colors", f32_bytes(py, c.iter().flatten().flatten().copied()))?;
    }
    Ok((f32_bytes(py, r.strands.points.iter().flatten().copied()), d))
}

fn groom_report<'py>(py: Python<'py>, r: &nst3d_groom::GroomReport) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("kind", "groom")?;
    d.set_item("strands", r.strands)?;
    d.set_item("points", r.points)?;
    d.set_item("preset", r.preset)?;
    d.set_item("proxies", r.proxies)?;
    d.set_item("iterations", r.iterations)?;
    d.set_item("render_size", r.render_size)?;
    d.set_item("loss_before", r.eval_before)?;
    d.set_item("loss_after", r.eval_after)?;
    d.set_item("held_out", (r.held_out.before, r.held_out.after_rematched))?;
    d.set_item("length_change", r.checks.vs_input)?;
    d.set_item("inside", r.checks.inside)?;
    Ok(d)
}

/// The settings of a groom job with `styles` (the first, then a style
/// map's others) and the map's values as float32 bytes, if given.
fn strand_settings(
    groom: impl Into<PathBuf>,
    styles: Vec<PathBuf>,
    out: impl Into<PathBuf>,
    map_values: Option<&[u8]>,
) -> PyResult<StrandSettings> {
    let mut styles = styles.into_iter();
    let mut s = StrandSettings::new(groom, "", styles.next().unwrap_or_default(), out);
    s.more_styles = styles.collect();
    s.style_map_values = map_values.map(|b| f32s(b, "style_map")).transpose()?;
    Ok(s)
}

/// Stylizes a groom file or an animated groom into files (`nst3d strands`).
#[pyfunction]
#[pyo3(signature = (groom, out, styles, options, mesh=None, progress=None, log=None, style_map_values=None))]
#[allow(clippy::too_many_arguments)]
fn stylize_groom_file<'py>(
    py: Python<'py>,
    groom: PathBuf,
    out: PathBuf,
    styles: Vec<PathBuf>,
    options: &Dict<'py>,
    mesh: Option<PathBuf>,
    progress: Option<Py<PyAny>>,
    log: Option<Py<PyAny>>,
    style_map_values: Option<&[u8]>,
) -> PyResult<Bound<'py, PyDict>> {
    let mut s = strand_settings(groom, styles, out.clone(), style_map_values)?;
    s.mesh = mesh;
    apply_strands(&mut s, Options::new(options)?)?;
    if s.frames.is_none() {
        let r = run_job(py, progress, log, move |rep| nst3d_groom::stylize_groom_file(&s, rep))?;
        let d = groom_report(py, &r)?;
        d.set_item("out", r.out)?;
        return Ok(d);
    }
    let r = run_job(py, progress, log, move |rep| nst3d_groom::stylize_groom_sequence(&s, rep))?;
    let d = PyDict::new(py);
    d.set_item("kind", "groom sequence")?;
    d.set_item("frames", r.sequence.frames)?;
    d.set_item("temporal", format!("{:?}", r.mode))?;
    d.set_item("loss_before", r.sequence.eval_before)?;
    d.set_item("loss_after", r.sequence.eval_output)?;
    d.set_item("flicker", r.sequence.flicker)?;
    d.set_item("length_change", r.worst.vs_input)?;
    d.set_item("inside", r.worst.inside)?;
    d.set_item("out", out)?;
    Ok(d)
}

/// Trains the feed-forward network (`nst3d train`) on `inputs`: files, or
/// with `frame_lists` (one per input) `####` patterns, expanded by the
/// library's frame-list parser as the command line does.
#[pyfunction]
#[pyo3(signature = (inputs, frame_lists, style, out, options, progress=None, log=None))]
#[allow(clippy::too_many_arguments)]
fn train<'py>(
    py: Python<'py>,
    inputs: Vec<String>,
    frame_lists: Vec<String>,
    style: PathBuf,
    out: PathBuf,
    options: &Dict<'py>,
    progress: Option<Py<PyAny>>,
    log: Option<Py<PyAny>>,
) -> PyResult<Bound<'py, PyDict>> {
    let frames = nst3d_train::job::training_frames(&inputs, &frame_lists)
        .map_err(|e| Nst3dError::new_err(nst3d_core::report::one_line(e.as_ref())))?;
    let mut s = nst3d_train::TrainSettings::new(frames, style, out);
    apply_train(&mut s, Options::new(options)?)?;
    let r = run_job(py, progress, log, move |rep| nst3d_train::train(&s, rep))?;
    let d = PyDict::new(py);
    d.set_item("steps", r.steps)?;
    d.set_item("resumed_at", r.resumed_at)?;
    d.set_item("loss_first", r.loss_first)?;
    d.set_item("loss_last", r.loss_last)?;
    d.set_item("out", r.out)?;
    Ok(d)
}

/// A trained feed-forward network, loaded once.
#[pyclass(module = "nst3d._nst3d", frozen)]
struct Model {
    inner: LoadedModel,
}

#[pymethods]
impl Model {
    /// Reads and checks a model file written by `train`.
    #[staticmethod]
    #[pyo3(signature = (path, options))]
    fn load(path: PathBuf, options: &Dict<'_>) -> PyResult<Self> {
        let mut m = ModelSettings::new(path);
        apply_model(&mut m, Options::new(options)?)?;
        let inner = LoadedModel::load(&m).map_err(|e| Nst3dError::new_err(nst3d_core::report::one_line(e.as_ref())))?;
        Ok(Self { inner })
    }

    /// `"density"` or `"velocity"`.
    #[getter]
    fn mode(&self) -> &'static str {
        match self.inner.mode() {
            nst3d_stylize::Mode::Density => "density",
            nst3d_stylize::Mode::Velocity => "velocity",
        }
    }

    /// The model's metadata.
    #[getter]
    fn info(&self) -> std::collections::BTreeMap<String, String> {
        self.inner.info().clone()
    }

    /// Stylizes a dense grid (bytes of `dims`, x fastest, voxel (0,0,0) at
    /// index `origin`) in one pass.
    #[pyo3(signature = (density, dims, origin=[0, 0, 0], progress=None, log=None))]
    #[allow(clippy::too_many_arguments)]
    fn stylize<'py>(
        &self,
        py: Python<'py>,
        density: &[u8],
        dims: [usize; 3],
        origin: [i32; 3],
        progress: Option<Py<PyAny>>,
        log: Option<Py<PyAny>>,
    ) -> PyResult<Bound<'py, PyBytes>> {
        let grid = grid_of(density, dims, "density")?;
        let model = &self.inner;
        let out = run_job(py, progress, log, move |rep| model.stylize(&grid, origin, Some(rep)))?;
        Ok(f32_bytes(py, out.data.into_iter()))
    }
}

/// Reads a groom file (any format `nst3d strands` reads): its points
/// (float32 bytes, x y z) and the point count of each strand.
#[pyfunction]
fn read_groom<'py>(py: Python<'py>, path: PathBuf) -> PyResult<(Bound<'py, PyBytes>, Vec<usize>)> {
    let g =
        py.detach(|| nst3d_io::groom::read_groom_file(&path)).map_err(|e| Nst3dError::new_err(e.to_string()))?.groom;
    let counts = g.strands.iter().map(|s| s.points.len()).collect();
    Ok((f32_bytes(py, g.strands.iter().flat_map(|s| s.points.iter().flatten().copied())), counts))
}

/// Reads a triangle mesh (.ply or .obj): vertices (float32 bytes) and
/// triangle indices.
#[pyfunction]
fn read_mesh<'py>(py: Python<'py>, path: PathBuf) -> PyResult<(Bound<'py, PyBytes>, Vec<u32>)> {
    let m = py.detach(|| nst3d_io::mesh::read_mesh(&path)).map_err(|e| Nst3dError::new_err(e.to_string()))?;
    Ok((f32_bytes(py, m.vertices.iter().flatten().copied()), m.triangles.iter().flatten().copied().collect()))
}

/// `nst3d bench volume-iter`'s work (shared/bench/README.md): per-iteration
/// milliseconds and their median.
#[pyfunction]
#[pyo3(signature = (n=128, mode="velocity", iters=6))]
fn bench_volume_iter(py: Python<'_>, n: usize, mode: &str, iters: usize) -> PyResult<(Vec<f64>, f64)> {
    if !(16..=512).contains(&n) {
        return Err(PyValueError::new_err(format!("n must be between 16 and 512, got {n}")));
    }
    let mode: nst3d_stylize::Mode = mode.parse().map_err(PyValueError::new_err)?;
    let r = py.detach(|| nst3d_stylize::bench::volume_iter(n, mode, iters.max(1)));
    Ok((r.iteration_ms, r.median_ms))
}

/// Worker threads for every later job (default: all cores); only the first
/// call counts, as for the command line's `--threads`.
#[pyfunction]
fn set_threads(n: usize) -> PyResult<()> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(n.max(1))
        .build_global()
        .map_err(|e| Nst3dError::new_err(format!("cannot start {n} threads: {e}")))
}

/// Worker threads the jobs use.
#[pyfunction]
fn threads() -> usize {
    rayon::current_num_threads()
}

/// Arithmetic of the heavy products for every later job, as the command
/// line's `--precision`: "auto" (bf16 where the CPU has AMX tiles, fp32
/// otherwise; the 3D network's convolutions in bf16 on AVX512-BF16 too),
/// "bf16" or "fp32". Returns what it runs on this machine.
#[pyfunction]
fn set_precision(name: &str) -> PyResult<String> {
    let p: nst3d_core::precision::Precision = name.parse().map_err(pyo3::exceptions::PyValueError::new_err)?;
    nst3d_core::precision::set(p);
    Ok(nst3d_core::precision::path().describe().to_string())
}

/// What the heavy products run in now (e.g. "fp32" or "bf16 (AMX-BF16 tiles, fp32 accumulation)").
#[pyfunction]
fn precision() -> String {
    nst3d_core::precision::path().describe().to_string()
}

#[pymodule]
fn _nst3d(m: &Bound<'_, PyModule>) -> PyResult<()> {
    keep_freed_pages();
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("Nst3dError", m.py().get_type::<Nst3dError>())?;
    m.add_function(wrap_pyfunction!(stylize_volume, m)?)?;
    m.add_function(wrap_pyfunction!(stylize_vdb, m)?)?;
    m.add_function(wrap_pyfunction!(stylize_groom, m)?)?;
    m.add_function(wrap_pyfunction!(stylize_groom_file, m)?)?;
    m.add_function(wrap_pyfunction!(train, m)?)?;
    m.add_function(wrap_pyfunction!(read_groom, m)?)?;
    m.add_function(wrap_pyfunction!(read_mesh, m)?)?;
    m.add_function(wrap_pyfunction!(bench_volume_iter, m)?)?;
    m.add_function(wrap_pyfunction!(set_threads, m)?)?;
    m.add_function(wrap_pyfunction!(threads, m)?)?;
    m.add_function(wrap_pyfunction!(set_precision, m)?)?;
    m.add_function(wrap_pyfunction!(precision, m)?)?;
    m.add_class::<Model>()?;
    Ok(())
}
