//! Feed-forward stylization (paper Sec. 4 and 5.2): a trained network
//! (`nst3d train`) stylizes each frame on its own, from every viewpoint at
//! once, with no optimisation and no temporal machinery, so frames can run
//! in any order on any blade. Grids run in tiles read from and written to
//! the sparse VDB leaves ([`nst3d_network::tiled::infer_tiles`]), so memory
//! follows the tile size and the smoke, never the dense box.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use nst3d_core::{Grid3, Reporter};
use nst3d_io::vdb::{read_vdb, GridValues, SparseGrid, VdbGrid, LEAF_DIM};
use nst3d_job::{expand_pattern, FrameSpec};
use nst3d_network::apply::{apply_with_strength, mass_ratio, Stylization, MASS_PINNED};
use nst3d_network::tiled::infer_tiles;
use nst3d_network::{Model, Volume};
use nst3d_stylize::Mode;

use crate::output::write_stylized_grid;
use crate::settings::{ModelSettings, VolumeSettings};
use crate::style_map::{weights, VoxelMap};

/// What a feed-forward job did.
#[derive(Clone, Debug)]
pub struct ModelReport {
    /// Frames stylized.
    pub frames: usize,
    /// Frames skipped because their output exists, or copied because empty.
    pub skipped: usize,
    /// The model's mode.
    pub mode: Mode,
    /// Models run on every frame (one per painting of a style map).
    pub models: usize,
    /// Voxels of the frames' boxes (active box plus room for the velocity).
    pub voxels: u64,
    /// Seconds spent in the network and transport (not reading or writing).
    pub seconds: f64,
    /// For a sequence, the flicker of the written frames by the metric the
    /// optimised sequences report ([`crate::flicker_of_outputs`]).
    pub flicker: Option<f64>,
    /// The output (pattern).
    pub out: String,
}

/// The model file, checked against what the user asked for.
fn load_model(m: &ModelSettings) -> Result<(Model, Mode, f32)> {
    let bytes = std::fs::read(&m.path).with_context(|| format!("cannot read the model {}", m.path.display()))?;
    let model = Model::from_bytes(&bytes, &m.path)?;
    let mode = match model.info.get("mode").map(String::as_str) {
        Some("density") => Mode::Density,
        Some("velocity") => Mode::Velocity,
        _ => bail!("{}: the model does not say its mode (density or velocity)", m.path.display()),
    };
    if let Some(asked) = m.mode.filter(|&a| a != mode) {
        bail!("{}: a {mode:?}-mode model, but --mode {asked:?} was asked for", m.path.display());
    }
    let want = if mode == Mode::Density { 1 } else { 3 };
    if model.net.out_channels() != want {
        bail!(
            "{}: a {mode:?}-mode model needs {want} output channels, it has {}",
            m.path.display(),
            model.net.out_channels()
        );
    }
    // Velocity models move smoke by up to vmax voxels, as in training.
    let vmax = match mode {
        Mode::Velocity => {
            let f: f32 = model.info.get("vmax_fraction").and_then(|v| v.parse().ok()).unwrap_or(0.04);
            let p: f32 = model.info.get("patch").and_then(|v| v.parse().ok()).unwrap_or(32.0);
            f * p
        }
        Mode::Density => 0.0,
    };
    if m.tile < m.margin || m.tile == 0 {
        bail!("--tile ({}) must be at least --tile-margin ({})", m.tile, m.margin);
    }
    Ok((model, mode, vmax))
}

/// A trained network loaded once, to stylize grids in memory (a front end
/// such as the Python binding keeps it between calls).
#[derive(Clone, Debug)]
pub struct LoadedModel {
    model: Model,
    mode: Mode,
    vmax: f32,
    settings: ModelSettings,
}

impl LoadedModel {
    /// Reads and checks the model file `m.path`.
    pub fn load(m: &ModelSettings) -> Result<Self> {
        let (model, mode, vmax) = load_model(m)?;
        Ok(Self { model, mode, vmax, settings: m.clone() })
    }

    /// The model's mode.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// The model's metadata (the trainer's keys: style, patch, steps...).
    pub fn info(&self) -> &std::collections::BTreeMap<String, String> {
        &self.model.info
    }

    /// Stylizes the dense grid `density` tile by tile, exactly as a frame
    /// file is (the same tiles, normalisation and mass conservation), and
    /// returns the result over the same box: smoke a velocity carries
    /// outside the box is not kept. An empty grid comes back unchanged.
    /// `origin` is the index of the grid's voxel (0,0,0): the network's
    /// stride lattice and the tiles are fixed in index space, so the same
    /// voxels give the file's result only at the file's index.
    pub fn stylize(
        &self,
        density: &Grid3,
        origin: [i32; 3],
        progress: Option<&mut (dyn Reporter + '_)>,
    ) -> Result<Grid3> {
        if let Some(v) = density.data.iter().find(|v| !v.is_finite()) {
            bail!("the density holds a non-finite value ({v})");
        }
        let grid = VdbGrid::from_dense("density", nst3d_io::vdb::Transform::uniform(1.0), origin, density, 0.0);
        let GridValues::Float(sparse) = &grid.values else { unreachable!("from_dense makes a float grid") };
        let Some(bbox) = grid.active_bbox() else { return Ok(density.clone()) };
        let (styled, _, k) = stylize_sparse(&self.model, self.mode, self.vmax, sparse, bbox, &self.settings, progress);
        nst3d_core::stop::check()?;
        if let Some(why) = erased(k) {
            bail!("{why}");
        }
        let out = styled.region(origin, density.dims);
        if out.iter().any(|v| !v.is_finite()) {
            bail!("the network produced non-finite densities");
        }
        Ok(Grid3::from_vec(density.dims, out))
    }
}

/// Stylizes one frame's density grid with the network, tile by tile,
/// straight from the sparse grid into a sparse result: densities are
/// normalised to `[0, 1]` by the frame's largest active value (as in
/// training), each tile and its margin are read from the leaves, run,
/// applied as a scale or a velocity, scaled back, and only the tile's own
/// voxels that hold smoke are kept; tiles with no smoke in reach are not
/// run. Nothing of the frame's size is ever dense, so memory follows the
/// tile. Returns the result, the voxels of the frame's box and the factor
/// that restored the frame's mass (infinite when nothing was left to scale).
fn stylize_sparse(
    model: &Model,
    mode: Mode,
    vmax: f32,
    grid: &SparseGrid<f32>,
    (lo, hi): ([i32; 3], [i32; 3]),
    m: &ModelSettings,
    mut progress: Option<&mut (dyn Reporter + '_)>,
) -> (SparseGrid<f32>, u64, f32) {
    let max = grid.iter_active().map(|(_, v)| v).fold(0.0f32, f32::max);
    let mut out = SparseGrid::new(0.0f32);
    if !(max > 0.0) {
        return (out, 0, 1.0);
    }
    // The active box plus room for the velocity to move smoke outwards,
    // starting on a leaf corner: tiles (multiples of 8) then cover whole
    // leaves, and the network's stride lattice is fixed in index space, so a
    // frame's result does not depend on the tile size.
    let room = if mode == Mode::Velocity { (vmax * m.strength.max(1.0)).ceil() as i32 + 1 } else { 0 };
    let origin: [i32; 3] = std::array::from_fn(|a| (lo[a] - room).div_euclid(LEAF_DIM) * LEAF_DIM);
    let dims: [usize; 3] = std::array::from_fn(|a| (hi[a] + room - origin[a] + 1) as usize);
    let at = |p: [usize; 3]| -> [i32; 3] { std::array::from_fn(|a| origin[a] + p[a] as i32) };
    let how = match mode {
        Mode::Density => Stylization::Density,
        Mode::Velocity => Stylization::Velocity { vmax },
    };
    // A region without smoke stays without smoke in either mode (a scale of
    // zero, or zero moved about): its tile is skipped.
    let mut written = 0.0f64;
    let tile = m.tile.next_multiple_of(LEAF_DIM as usize);
    let tiles: usize = dims.iter().map(|n| n.div_ceil(tile)).product();
    if let Some(r) = progress.as_deref_mut() {
        r.begin(tiles as u64);
    }
    let mut seen = 0;
    let read = |from: [usize; 3], size: [usize; 3]| {
        seen += 1;
        if let Some(r) = progress.as_deref_mut() {
            r.step(&format!("tile {seen}/{tiles}"));
        }
        // Asked to stop: the remaining tiles are skipped and the frame is
        // not written (one_frame checks before it writes).
        if nst3d_core::stop::requested() {
            return None;
        }
        let mut v = grid.region(at(from), size);
        if v.iter().all(|x| *x == 0.0) {
            return None;
        }
        v.iter_mut().for_each(|x| *x /= max);
        Some(Volume::from_vec(1, size, v))
    };
    infer_tiles(&model.net, dims, tile, m.margin, read, |t, input, o| {
        // Applied on the whole region: a velocity reads density up to vmax
        // away, which the margin holds.
        let styled = apply_with_strength(&Grid3::from_vec(t.size, input.data.clone()), o, how, m.strength);
        let core: [usize; 3] = std::array::from_fn(|a| t.hi[a] - t.lo[a]);
        let mut values = Vec::with_capacity(core.iter().product());
        for z in t.lo[2]..t.hi[2] {
            for y in t.lo[1]..t.hi[1] {
                let row = ((z - t.from[2]) * t.size[1] + (y - t.from[1])) * t.size[0];
                let (a, b) = (t.lo[0] - t.from[0], t.hi[0] - t.from[0]);
                let row = styled.data[row + a..row + b].iter().map(|v| v * max);
                match &model.texture {
                    // The texture is fixed in index space: tiles and frames agree.
                    Some(tex) => values.extend(row.zip(t.lo[0]..t.hi[0]).map(|(v, x)| {
                        let [gx, gy, gz] = at([x, y, z]);
                        v * tex.scale([gx as i64, gy as i64, gz as i64], m.strength)
                    })),
                    None => values.extend(row),
                }
            }
        }
        written += values.iter().filter(|v| **v > 0.0).map(|v| *v as f64).sum::<f64>();
        out.insert_region(at(t.lo), core, &values, |v| v > 0.0 || !v.is_finite());
    });
    // The frame keeps its total density, as every training patch did
    // (train::step::conserve_mass): the network redistributes smoke.
    let k = mass_ratio(grid.iter_active().map(|(_, v)| v as f64).sum(), written);
    for leaf in out.leaves_mut() {
        leaf.values.iter_mut().for_each(|v| *v *= k);
    }
    if let Some(r) = progress {
        r.end();
    }
    (out, dims.iter().product::<usize>() as u64, if written > 0.0 { k } else { f32::INFINITY })
}

/// The models of a job (one, or one per painting of a style map), all of
/// one mode, each with the distance its velocity may move smoke.
struct Models {
    list: Vec<(Model, f32)>,
    mode: Mode,
}

impl Models {
    /// `m.path` and `m.more`, checked to share a mode.
    fn load(m: &ModelSettings) -> Result<Self> {
        let (model, mode, vmax) = load_model(m)?;
        let mut list = vec![(model, vmax)];
        for path in &m.more {
            let (model, other, vmax) = load_model(&ModelSettings { path: path.clone(), ..m.clone() })?;
            if other != mode {
                bail!(
                    "{}: a {other:?}-mode model, but {} is {mode:?}-mode: a style map blends models of one mode",
                    path.display(),
                    m.path.display()
                );
            }
            list.push((model, vmax));
        }
        Ok(Self { list, mode })
    }
}

/// One frame file in, one out; `frame`: its number in a sequence (a style
/// map file given as a pattern is that frame's).
fn one_frame(
    s: &VolumeSettings,
    models: &Models,
    m: &ModelSettings,
    (input, out, frame): (&Path, &Path, Option<i64>),
    mut progress: Option<&mut (dyn Reporter + '_)>,
) -> Result<Option<(u64, f64)>> {
    let file = read_vdb(input)?;
    let grid = file.grid(&s.grid).with_context(|| format!("{}: no grid named '{}'", input.display(), s.grid))?;
    let GridValues::Float(sparse) = &grid.values else {
        bail!("{}: grid '{}' is not a float grid", input.display(), s.grid);
    };
    let Some(bbox) = grid.active_bbox() else { return Ok(None) };
    if let Some(ijk) = grid.first_non_finite() {
        bail!("{}: grid '{}' has a non-finite value at {ijk:?}", input.display(), s.grid);
    }
    // Every map is read before the slow part.
    let map = match s.map_source()? {
        None => None,
        Some(source) => {
            let source = frame.map_or(Ok(source.clone()), |f| source.at_frame(f))?;
            let labels = source.labels(s.style_map_labels);
            let smoke = (bbox.0, std::array::from_fn(|a| (bbox.1[a] - bbox.0[a] + 1) as usize));
            Some((VoxelMap::new(&source, Some((&file, input)), &grid.transform, smoke, s.up, labels)?, labels))
        }
    };
    let t0 = Instant::now();
    let mut results = Vec::new();
    let mut voxels = 0;
    for (model, vmax) in &models.list {
        let (styled, n, k) = stylize_sparse(model, models.mode, *vmax, sparse, bbox, m, progress.as_deref_mut());
        nst3d_core::stop::check()?;
        if let Some(why) = erased(k) {
            bail!("{}: {why}", input.display());
        }
        results.push(styled);
        voxels = voxels.max(n);
    }
    let styled = match &map {
        None => results.remove(0),
        Some((map, labels)) => blend(&results, map, sparse, *labels)?,
    };
    let secs = t0.elapsed().as_secs_f64();
    if styled.iter_active().any(|(_, v)| !v.is_finite()) {
        bail!("{}: the network produced non-finite densities", input.display());
    }
    let mut result = VdbGrid::new(&grid.name, &grid.class, grid.transform.clone(), GridValues::Float(styled));
    result.metadata = grid.metadata.clone();
    write_stylized_grid(out, &file, result)?;
    Ok(Some((voxels, secs)))
}

/// The most a frame's result is scaled up to keep its input's mass. A model
/// that kept under a thousandth of the smoke has erased it (a collapsed
/// training run makes one): scaling what is left up would draw the
/// network's rounding residue as hot blocks, and where nothing is left the
/// frame would be written empty. A trained model's factor stays near 1
/// (the training's scale pin holds it there).
const MOST_MASS_RESTORED: f32 = 1000.0;

/// Why a result must not be written, from its mass factor `k`
/// ([`stylize_sparse`]; infinite when nothing was left).
fn erased(k: f32) -> Option<String> {
    (!(k <= MOST_MASS_RESTORED)).then(|| {
        format!(
            "the model erased the smoke: it kept {} of the frame's density (a collapsed training run makes such a \
             model; retrain it)",
            if k.is_finite() { format!("1/{k:.0}") } else { "none".into() }
        )
    })
}

/// The models' results blended voxel by voxel by the style map's weights
/// (`map` read at each voxel, as [`crate::style_map::regions`] weighs a
/// dense box; `input`: the frame's density, where a label must name a
/// model). Each result keeps the frame's mass, and the weights sum to 1,
/// so the blend keeps it too where the results overlap.
fn blend(
    results: &[SparseGrid<f32>],
    map: &VoxelMap,
    input: &SparseGrid<f32>,
    labels: bool,
) -> Result<SparseGrid<f32>> {
    let mut out = SparseGrid::new(0.0f32);
    let mut w = vec![0.0; results.len()];
    for (k, r) in results.iter().enumerate() {
        for (ijk, v) in r.iter_active() {
            weights(map.at(ijk), input.get(ijk) > 0.0, labels, &mut w)?;
            if w[k] > 0.0 {
                out.set_active(ijk, out.get(ijk) + w[k] * v);
            }
        }
    }
    Ok(out)
}

/// What a user should know about a model file before trusting its result:
/// trained before the density pin, or along one axis only.
fn notes_on(model: &Model, mode: Mode, path: &Path, reporter: &mut dyn Reporter) {
    if mode == Mode::Density && model.info.get("mass").map(String::as_str) != Some(MASS_PINNED) {
        reporter.note(&format!(
            "{} was trained before the density scale pin: on smoke unlike its training data it can lift faint \
             haze many times over (docs/design/feedforward.md); retrain it to fix that",
            path.display()
        ));
    }
    if !model.info.contains_key("view_axes") {
        reporter.note(&format!(
            "{} was trained on pictures along its patches' z axis only: its strokes are stretched into \
             columns along the grid's z, streaks from the side (docs/design/feedforward.md); \
             retrain it to fix that",
            path.display()
        ));
    }
}

/// Stylizes `s.input` (one frame, or the frames of `s.sequence`) with the
/// model `m`, each frame on its own.
pub fn stylize_with_model(s: &VolumeSettings, m: &ModelSettings, reporter: &mut dyn Reporter) -> Result<ModelReport> {
    s.check()?;
    let models = Models::load(m)?;
    let mode = models.mode;
    for ((model, _), path) in models.list.iter().zip(std::iter::once(&m.path).chain(&m.more)) {
        notes_on(model, mode, path, reporter);
    }
    let input = s.input.to_string_lossy().to_string();
    let output = s.out.to_string_lossy().to_string();
    let jobs: Vec<(PathBuf, PathBuf, bool, Option<i64>)> = match &s.sequence {
        None => vec![(s.input.clone(), s.out.clone(), true, None)],
        Some(seq) => {
            let spec = FrameSpec::parse(&seq.frames)?;
            let frames: Vec<i64> = match &seq.chunk {
                Some(c) => {
                    // The same chunk syntax and checks as optimised sequences.
                    let (a, b) = crate::sequence::parse_chunk(c)?;
                    spec.within(a, b)
                }
                None => spec.frames().to_vec(),
            };
            let mut v = Vec::new();
            for f in frames {
                let o = PathBuf::from(expand_pattern(&output, f)?);
                let todo = seq.force || !o.exists();
                v.push((PathBuf::from(expand_pattern(&input, f)?), o, todo, Some(f)));
            }
            v
        }
    };
    let (mut frames, mut skipped, mut voxels, mut seconds) = (0, 0, 0u64, 0.0);
    // A sequence shows frames; a single frame (which may be paper-sized and
    // take minutes) shows its tiles.
    let per_tile = s.sequence.is_none();
    if !per_tile {
        reporter.begin(jobs.len() as u64);
    }
    for (inp, out, todo, frame) in &jobs {
        if !todo {
            skipped += 1;
            reporter.step(&format!("{} exists, kept", out.display()));
            continue;
        }
        let progress = if per_tile { Some(&mut *reporter) } else { None };
        match one_frame(s, &models, m, (inp, out, *frame), progress)? {
            Some((n, t)) => {
                frames += 1;
                voxels += n;
                seconds += t;
            }
            None if s.sequence.is_none() => bail!("{}: grid '{}' is empty: nothing to stylize", inp.display(), s.grid),
            None => {
                // An empty frame of a sequence: the input, byte for byte.
                let bytes = std::fs::read(inp).with_context(|| format!("cannot read {}", inp.display()))?;
                nst3d_io::atomic::write_atomic(out, |w| w.write_all(&bytes))
                    .with_context(|| format!("cannot write {}", out.display()))?;
                skipped += 1;
            }
        }
        if !per_tile {
            reporter.step(&format!("{}", out.display()));
        }
    }
    if !per_tile {
        reporter.end();
    }
    let flicker = match s.sequence {
        // Scored as an optimised sequence of the model's mode would be.
        Some(_) => crate::flicker_of_outputs(&VolumeSettings { mode, ..s.clone() }, reporter)?,
        None => None,
    };
    let models = models.list.len();
    Ok(ModelReport { frames, skipped, mode, models, voxels, seconds, flicker, out: output })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_network::FeedForward;
    use std::collections::BTreeMap;

    /// A blob of smoke away from the origin, sparse.
    fn blob() -> (SparseGrid<f32>, ([i32; 3], [i32; 3])) {
        let mut g = SparseGrid::new(0.0f32);
        let (c, r) = ([-5.0f32, 30.0, 17.0], 11.0f32);
        for z in 5..30 {
            for y in 18..43 {
                for x in -17..8 {
                    let d2 = (x as f32 - c[0]).powi(2) + (y as f32 - c[1]).powi(2) + (z as f32 - c[2]).powi(2);
                    if d2 < r * r {
                        g.set_active([x, y, z], 1.0 - d2 / (r * r) + 0.01 * ((x + 2 * y + 3 * z) % 5) as f32);
                    }
                }
            }
        }
        let bbox = g.active_bbox().unwrap();
        (g, bbox)
    }

    /// A density model that scales the smoke to (almost) nothing is refused
    /// with a reason, neither written empty nor scaled up from its residue.
    #[test]
    fn a_model_that_erases_the_smoke_is_refused() {
        let (g, bbox) = blob();
        let m = ModelSettings::new(PathBuf::new());
        let k_with_bias = |bias: f32| {
            let mut net = FeedForward::new(2, 1, 4);
            net.layers.last_mut().unwrap().bias.iter_mut().for_each(|b| *b = bias);
            stylize_sparse(&Model { net, texture: None, info: BTreeMap::new() }, Mode::Density, 0.0, &g, bbox, &m, None)
                .2
        };
        // 1 + tanh(-100) is exactly 0 in f32; 1 + tanh(-8) about 2e-7.
        let (none, residue, fresh) = (k_with_bias(-100.0), k_with_bias(-8.0), k_with_bias(0.0));
        assert!(erased(none).unwrap().contains("kept none of"), "{none}");
        assert!(residue.is_finite() && erased(residue).unwrap().contains("kept 1/"), "{residue}");
        assert_eq!(erased(fresh), None, "{fresh}");
    }

    /// Small tiles give the one-tile result (the margin covers the
    /// network's reach), in both modes, and nothing is written where no
    /// smoke can reach.
    #[test]
    fn tile_size_does_not_change_the_frame() {
        let (g, bbox) = blob();
        for (mode, out_c, vmax) in [(Mode::Density, 1, 0.0), (Mode::Velocity, 3, 2.0)] {
            let model = Model { net: FeedForward::new(2, out_c, 4), texture: None, info: BTreeMap::new() };
            let run = |tile: usize| {
                let m = ModelSettings { tile, ..ModelSettings::new(PathBuf::new()) };
                stylize_sparse(&model, mode, vmax, &g, bbox, &m, None).0
            };
            let (whole, tiled) = (run(256), run(8));
            assert!(whole.active_voxel_count() > 1000);
            assert_eq!(whole.active_voxel_count(), tiled.active_voxel_count(), "{mode:?}");
            for (ijk, v) in whole.iter_active() {
                assert!((v - tiled.get(ijk)).abs() <= 1e-5 * v.abs().max(1.0), "{mode:?} at {ijk:?}");
            }
            // Density mode only scales: no voxel outside the input's smoke.
            if mode == Mode::Density {
                assert!(whole.iter_active().all(|(ijk, _)| g.is_active(ijk)));
            }
        }
    }
}
