//! The `strands-iter` benchmark's work: one iteration of strand
//! stylization on a groom, timed stage by stage, and the dump of its inputs
//! the PyTorch peer (tools/bench/strands_iter_torch.py) replays.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use nst3d_core::stats::median;
use nst3d_core::Reporter;
use nst3d_features::{Vgg19, VggLayer};
use nst3d_io::groom::read_groom;
use nst3d_io::mesh::read_mesh;
use nst3d_loss::nnst::{LayerWeight, NnstParams};
use nst3d_strands::pipeline::{
    iteration, loss_and_gradient, match_view, poisson_view_angles, scale_learning_rate, style_target, Adam, NnstMatch,
    NnstTarget, SplatCamera, StrandScene, StylizeParams, CONSTRAINT_PASSES, HARD_TAU_FRACTION, SEGMENT_TOLERANCE,
};
use nst3d_strands::Preset;

/// What to time.
#[derive(Clone, Debug)]
pub struct StrandsIterSettings {
    /// The groom.
    pub groom: PathBuf,
    /// Its head mesh.
    pub mesh: PathBuf,
    /// The painting (its luminance is matched).
    pub style: PathBuf,
    /// VGG-19 weights; `None`: `$NST3D_VGG19`, else the user cache.
    pub weights: Option<PathBuf>,
    /// Square render size.
    pub size: usize,
    /// Timed iterations after one warm-up.
    pub iters: usize,
    /// Folder for the scene, camera, targets and style columns of the peer.
    pub dump: Option<PathBuf>,
}

/// The timings of a `strands-iter` run.
#[derive(Clone, Debug)]
pub struct StrandsIterReport {
    /// Milliseconds of the view's NNST match (once per view, not in the iteration).
    pub match_ms: f64,
    /// Loss of the warm-up iteration (iteration 0).
    pub loss_iter0: f32,
    /// Loss at match time.
    pub loss_match: f32,
    /// Loss of the last timed iteration.
    pub loss_last: f32,
    /// Median milliseconds per stage, in pipeline order.
    pub stages: Vec<(&'static str, f64)>,
    /// Wall milliseconds of each timed iteration.
    pub iteration_ms: Vec<f64>,
    /// CPU milliseconds per iteration (user + system, all threads).
    pub cpu_ms_per_iter: f64,
    /// Median wall milliseconds per iteration.
    pub ms_per_iter: f64,
}

/// `strands-iter`: one iteration of strand stylization on the Bangs groom
/// (short-hair preset, its proxy ratio, finest scale) through
/// [`iteration`], the function `nst3d strands` loops over. The
/// view's NNST match is made once, outside the timed iterations, as the
/// stylization caches it per view; it is timed on its own.
pub fn strands_iter(a: &StrandsIterSettings, reporter: &mut dyn Reporter) -> Result<StrandsIterReport> {
    if !(32..=4096).contains(&a.size) {
        bail!("--size must be between 32 and 4096, got {}", a.size);
    }
    let iters = a.iters.max(1);
    let t_setup = Instant::now();
    let groom = read_groom(&a.groom)?;
    let head = read_mesh(&a.mesh)?;
    let painting = nst3d_io::image::load_style(&a.style, 1.0)?;
    let vgg = Vgg19::load(a.weights.as_deref())?;
    let mut params = StylizeParams::from_preset(Preset::ShortHair.params(), groom.strand_count());
    params.render_size = a.size;
    let scene = StrandScene::build(&groom, Some(&head), &params, &mut |m| reporter.status(m))?;
    let finest = 2;
    let (psi, delta) =
        poisson_view_angles(&scene.frame, params.preset.polar_deg, params.preset.azimuth_deg, 1, params.seed)[0];
    let cam = scene.camera(psi, delta)?;
    vgg.prepare(VggLayer::Relu4_1);
    let target = style_target(&vgg, &painting, params.style_height(finest))?;
    let setup_s = t_setup.elapsed().as_secs_f64();

    let t_match = Instant::now();
    let (matched, loss0) = match_view(&scene, &vgg, &target, &cam)?;
    let match_ms = ms(t_match.elapsed());

    let samples = scene.field.sample_count();
    let threads = rayon::current_num_threads();
    reporter.status(&format!(
        "strands-iter: {} guides + {} proxies = {} strands, {} control points, {} velocity samples, \
         render {}x{}, style {} rows, threads={threads} iters={iters} (setup {setup_s:.1} s)",
        scene.guide_count,
        scene.rest.strand_count() - scene.guide_count,
        scene.rest.strand_count(),
        scene.rest.points.len(),
        samples,
        a.size,
        a.size,
        params.style_height(finest),
    ));
    let mut v = vec![0.0f32; 3 * samples];
    let mut adam = Adam::adamw(3 * samples, scale_learning_rate(&scene, &params, finest), params.weight_decay);
    if let Some(dir) = &a.dump {
        dump_scene(dir, &scene, &vgg, &cam, &matched, &target, &adam, loss0)
            .with_context(|| format!("--dump {}", dir.display()))?;
    }
    // One warm-up iteration (its loss is iteration 0's), then the timed ones.
    let warm = iteration(&scene, &vgg, &cam, &matched, &mut v, &mut adam)?;
    let cpu0 = cpu_seconds();
    let mut reports = Vec::with_capacity(iters);
    let mut wall = Vec::with_capacity(iters);
    for _ in 0..iters {
        let t = Instant::now();
        reports.push(iteration(&scene, &vgg, &cam, &matched, &mut v, &mut adam)?);
        wall.push(ms(t.elapsed()));
    }
    let cpu_ms = (cpu_seconds() - cpu0) * 1e3 / iters as f64;

    let names = reports[0].times.stages().map(|s| s.0);
    let stages = names
        .iter()
        .enumerate()
        .map(|(k, &name)| {
            let t: Vec<f64> = reports.iter().map(|r| ms(r.times.stages()[k].1)).collect();
            (name, median(&t))
        })
        .collect();
    Ok(StrandsIterReport {
        match_ms,
        loss_iter0: warm.loss,
        loss_match: loss0,
        loss_last: reports.last().map_or(warm.loss, |r| r.loss),
        stages,
        ms_per_iter: median(&wall),
        iteration_ms: wall,
        cpu_ms_per_iter: cpu_ms,
    })
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// User + system CPU time of this process (Linux `/proc/self/stat`, 100 Hz
/// ticks), the figure neighbours on a shared machine disturb least; 0
/// where the kernel does not say.
fn cpu_seconds() -> f64 {
    std::fs::read_to_string("/proc/self/stat")
        .ok()
        .and_then(|s| {
            // Fields after the parenthesised command name; utime, stime are 14, 15.
            let rest = &s[s.rfind(')')? + 2..];
            let f: Vec<&str> = rest.split_whitespace().collect();
            Some((f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?) / 100.0)
        })
        .unwrap_or(0.0)
}

/// Writes a little-endian `.npy` (format 1.0) of `shape` from raw values.
fn write_npy(path: &Path, descr: &str, shape: &[usize], bytes: &[u8]) -> std::io::Result<()> {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape = if dims.len() == 1 { format!("({},)", dims[0]) } else { format!("({})", dims.join(", ")) };
    let mut header = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}");
    // Magic (6) + version (2) + length (2) + header + newline, padded to 64.
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + bytes.len());
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    out.extend_from_slice(bytes);
    nst3d_io::atomic::write_atomic(path, |w| w.write_all(&out))
}

fn npy_f32(dir: &Path, name: &str, shape: &[usize], v: &[f32]) -> std::io::Result<()> {
    let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
    write_npy(&dir.join(name), "<f4", shape, &bytes)
}

fn npy_i64(dir: &Path, name: &str, v: &[i64]) -> std::io::Result<()> {
    let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
    write_npy(&dir.join(name), "<i8", &[v.len()], &bytes)
}

fn json_v3(v: [f32; 3]) -> String {
    format!("[{:e}, {:e}, {:e}]", v[0], v[1], v[2])
}

/// `meta.json` of the dump: the camera, the strand look, the collision
/// constraint and AdamW's settings the peer replays.
fn peer_meta(scene: &StrandScene, cam: &SplatCamera, adam: &Adam, loss0: f32) -> String {
    let st = &scene.style;
    let col = &scene.constraints.collision;
    // The hyper-columns the strand pipeline builds (its views use the defaults).
    let nnst = NnstParams::default();
    format!(
        r#"{{
  "samples": {samples},
  "camera": {{"eye": {eye}, "right": {right}, "down": {down}, "forward": {fwd},
             "fx": {fx:e}, "fy": {fy:e}, "cx": {cx:e}, "cy": {cy:e}, "width": {cw}, "height": {ch}, "near": {near:e}}},
  "style": {{"width": {sw:e}, "length_sigma": {ls:e}, "root_shade": {rs:e}, "tip_shade": {ts:e},
            "root_opacity": {ro:e}, "tip_opacity": {to:e}, "background": {bg}, "visibility_threshold": {vt:e},
            "dilation": {dil:e}}},
  "collision": {{"tau": {tau:e}, "kappa": {kappa:e}, "skip_roots": {skip}, "hard_tau_fraction": {htf:e},
                "passes": {passes}, "segment_tolerance": {stol:e}}},
  "adamw": {{"lr": {lr:e}, "beta1": {b1:e}, "beta2": {b2:e}, "eps": {eps:e}, "weight_decay": {wd:e}}},
  "nnst_grid_divisor": {divisor},
  "nnst_layer_weight": "{layer_weight}",
  "nst3d_loss_iter0": {loss0:e}
}}
"#,
        samples = scene.field.sample_count(),
        divisor = nnst.grid_divisor,
        layer_weight = match nnst.layer_weight {
            LayerWeight::InverseChannels => "inverse_channels",
            LayerWeight::InverseSqrtChannels => "inverse_sqrt_channels",
        },
        eye = json_v3(cam.eye),
        right = json_v3(cam.right),
        down = json_v3(cam.down),
        fwd = json_v3(cam.forward),
        fx = cam.fx,
        fy = cam.fy,
        cx = cam.cx,
        cy = cam.cy,
        cw = cam.width,
        ch = cam.height,
        near = cam.near,
        sw = st.width,
        ls = st.length_sigma,
        rs = st.root_shade,
        ts = st.tip_shade,
        ro = st.root_opacity,
        to = st.tip_opacity,
        bg = json_v3(st.background),
        vt = st.visibility_threshold,
        dil = st.dilation,
        tau = col.tau,
        kappa = col.kappa,
        skip = col.skip_roots,
        htf = HARD_TAU_FRACTION,
        passes = CONSTRAINT_PASSES,
        stol = SEGMENT_TOLERANCE,
        lr = adam.lr,
        b1 = adam.beta1,
        b2 = adam.beta2,
        eps = adam.eps,
        wd = adam.weight_decay,
    )
}

/// The inputs of one `strands-iter` iteration, for the PyTorch peer:
/// `.npy` arrays plus `meta.json` (see tools/bench/strands_iter_torch.py).
/// The collision constraint is handed over as each rest point's closest
/// surface point and outward direction (the peer has no BVH).
#[allow(clippy::too_many_arguments)]
fn dump_scene(
    dir: &Path,
    scene: &StrandScene,
    vgg: &Vgg19,
    cam: &SplatCamera,
    matched: &NnstMatch,
    target: &NnstTarget,
    adam: &Adam,
    loss0: f32,
) -> Result<()> {
    std::fs::create_dir_all(dir)?;
    let flat = |p: &[[f32; 3]]| -> Vec<f32> { p.iter().flatten().copied().collect() };
    let rest = scene.field.rest_points();
    let n = rest.len();
    npy_f32(dir, "rest.npy", &[n, 3], &flat(rest))?;
    npy_f32(dir, "undeformed.npy", &[n, 3], &flat(&scene.undeformed.points))?;
    npy_i64(dir, "offsets.npy", &scene.rest.offsets.iter().map(|&o| o as i64).collect::<Vec<_>>())?;
    let w = scene.field.weights();
    let (mut rows, mut cols, mut vals) = (Vec::new(), Vec::new(), Vec::new());
    for i in 0..w.targets() {
        for (j, x) in w.row(i) {
            rows.push(i as i64);
            cols.push(j as i64);
            vals.push(x);
        }
    }
    npy_i64(dir, "rbf_rows.npy", &rows)?;
    npy_i64(dir, "rbf_cols.npy", &cols)?;
    npy_f32(dir, "rbf_vals.npy", &[vals.len()], &vals)?;
    let normals = scene.root_normals.as_deref().context("the scene has no root normals (no mesh)")?;
    npy_f32(dir, "root_normals.npy", &[normals.len(), 3], &flat(normals))?;
    let bvh = scene.constraints.collider.as_ref().context("the scene has no collider")?;
    let (mut closest, mut outward) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for &p in rest {
        // The outward direction project_collisions pushes along at p.
        let hit = bvh.closest_point(p);
        let s = hit.signed_distance;
        let away: [f32; 3] = std::array::from_fn(|k| (p[k] - hit.point[k]) * s.signum());
        let len = away.iter().map(|c| c * c).sum::<f32>().sqrt();
        let pn = p.iter().map(|c| c * c).sum::<f32>().sqrt();
        let dir = if s.abs() > 1e-7 * (1.0 + pn) && len > 0.0 { away.map(|c| c / len) } else { hit.normal };
        closest.push(hit.point);
        outward.push(dir);
    }
    npy_f32(dir, "closest.npy", &[n, 3], &flat(&closest))?;
    npy_f32(dir, "outward.npy", &[n, 3], &flat(&outward))?;
    let t = matched.targets();
    npy_f32(dir, "targets.npy", &[t.channels, t.height, t.width], &t.data)?;
    let c = target.columns();
    npy_f32(dir, "style_columns.npy", &[c.channels, c.height, c.width], &c.data)?;
    // nst3d's gradient at v = 0, for the peer's autograd to check.
    let samples = scene.field.sample_count();
    let (_, grad0) = loss_and_gradient(scene, vgg, cam, matched, &vec![0.0; 3 * samples])?;
    npy_f32(dir, "grad0.npy", &[samples, 3], &grad0)?;
    let img = scene.render(&scene.undeformed, cam)?;
    npy_f32(dir, "render0.npy", &[img.channels, img.height, img.width], &img.data)?;
    let meta = peer_meta(scene, cam, adam, loss0);
    nst3d_io::atomic::write_atomic(&dir.join("meta.json"), |w| w.write_all(meta.as_bytes()))?;
    Ok(())
}
