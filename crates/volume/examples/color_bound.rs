//! How far could colour lower the held-out colour loss at all?
//!
//! The judge scores a colour result against the grey result from 8 held-out
//! views (`nst3d judge --color`). The chroma layer keeps each voxel's
//! luminance, so every colour render has the grey render's luminance `L`
//! and some per-pixel chroma. This example drops the 3D constraint: per
//! held-out view it optimises a free chroma *picture* `c = r / (w · r)`
//! (w the Rec. 601 luma weights, `r` in the layer's raw range) on the grey
//! render, `L · c`, against the colour painting. No 3D colour field of this
//! kind can do better from that view, so the ratio it reaches bounds what
//! `--color` can reach. A second run frees the brightness too (`L · r`,
//! `r` in [0, 3]: any colour over the grey picture's footprint, which
//! changes the grey loss) for comparison. Pictures: `OUT_view_k.png`
//! (grey | best chroma | best free colour).
//!
//!     cargo run --release -p nst3d-volume --example color_bound -- STYLE.jpg GREY.vdb OUT [ITERS] [VIEWS]
//!
//! `VIEWS` is a comma-separated list of held-out view indices (default all 8).
//!
//!     cargo run --release -p nst3d-volume --example color_bound -- --field CAMERAS STYLE GREY.vdb OUT SWEEPS
//!
//! runs the colour stage itself (`nst3d_stylize::stylize_color`, on the
//! fixed grey density) from the `CAMERAS` set for `SWEEPS` passes (`LR=`
//! sets its rate, `GUARD=` its grey guard's weight) and prints the 8 held-out ratios: with `ring:8:30` (the
//! judge's own views) it is the layer's bound when every judged view is
//! trained on.

use std::path::{Path, PathBuf};

use anyhow::{anyhow, Result};
use nst3d_core::image::LUMA;
use nst3d_core::{Grid3, Image};
use nst3d_features::Vgg19;
use nst3d_io::vdb::read_vdb;
use nst3d_optim::Adam;
use nst3d_stylize::color_view_image;
use nst3d_stylize::{stylize_color, ColorStageParams, StyleSpec, ViewLoss};
use nst3d_volume::cameras::{CameraSet, Lens};
use nst3d_volume::dense::{density_grid, pad};
use nst3d_volume::look::{absorption_for, views_of};
use nst3d_volume::{UpAxis, VolumeSettings};

/// The raw range of the smoke's chroma layer (`nst3d_stylize::color::RAW_RANGE`).
const CHROMA_RANGE: (f32, f32) = nst3d_stylize::color::RAW_RANGE;
/// Free colour: any channel between black and three times the grey picture.
const FREE_RANGE: (f32, f32) = (0.0, 3.0);

#[derive(Clone, Copy)]
enum Kind {
    /// `L · r / (w · r)`: luminance kept.
    Chroma,
    /// `L · r`: luminance free.
    Free,
}

fn picture(l: &[f32], r: &[f32], kind: Kind, h: usize, w: usize) -> Image {
    let p = l.len();
    let mut data = vec![0.0; 3 * p];
    for i in 0..p {
        let m = match kind {
            Kind::Chroma => (0..3).map(|c| LUMA[c] * r[c * p + i]).sum::<f32>(),
            Kind::Free => 1.0,
        };
        for c in 0..3 {
            data[c * p + i] = l[i] * r[c * p + i] / m;
        }
    }
    Image::from_vec(3, h, w, data)
}

/// d loss / d r from d loss / d picture.
fn raw_grad(l: &[f32], r: &[f32], g: &Image, kind: Kind) -> Vec<f32> {
    let p = l.len();
    let mut out = vec![0.0; 3 * p];
    for i in 0..p {
        // gc: d loss / d c with the picture L · c.
        let gc: [f32; 3] = std::array::from_fn(|c| g.data[c * p + i] * l[i]);
        match kind {
            Kind::Free => (0..3).for_each(|c| out[c * p + i] = gc[c]),
            Kind::Chroma => {
                let rr: [f32; 3] = std::array::from_fn(|c| r[c * p + i]);
                let m: f32 = (0..3).map(|c| LUMA[c] * rr[c]).sum();
                let gr: f32 = (0..3).map(|c| gc[c] * rr[c]).sum();
                for j in 0..3 {
                    out[j * p + i] = gc[j] / m - LUMA[j] * gr / (m * m);
                }
            }
        }
    }
    out
}

fn optimise(loss: &ViewLoss, l: &[f32], h: usize, w: usize, kind: Kind, iters: usize) -> Result<(f32, Image)> {
    let (lo, hi) = match kind {
        Kind::Chroma => CHROMA_RANGE,
        Kind::Free => FREE_RANGE,
    };
    let mut r = vec![1.0f32; 3 * l.len()];
    let mut adam = Adam::new(r.len(), 0.05);
    let mut best = (f32::INFINITY, picture(l, &r, kind, h, w));
    for _ in 0..iters {
        let img = picture(l, &r, kind, h, w);
        let (v, g) = loss.loss_and_grad_image(&img)?;
        if v < best.0 {
            best = (v, img);
        }
        let gr = raw_grad(l, &r, &g, kind);
        adam.step(&mut r, &gr);
        r.iter_mut().for_each(|x| *x = x.clamp(lo, hi));
    }
    Ok(best)
}

fn main() -> Result<()> {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let train_cams = match args.first().map(String::as_str) {
        Some("--field") => {
            args.remove(0);
            Some(args.remove(0))
        }
        _ => None,
    };
    anyhow::ensure!((3..=5).contains(&args.len()), "usage: color_bound STYLE GREY.vdb OUT [ITERS] [VIEWS]");
    let (style, grey, out) = (PathBuf::from(&args[0]), PathBuf::from(&args[1]), &args[2]);
    let iters: usize = args.get(3).map_or(Ok(150), |s| s.parse())?;
    let file = read_vdb(&grey).map_err(|e| anyhow!("{e}"))?;
    let (dbox, d) = density_grid(&file, &grey, "density")?.to_dense()?;
    // FILE_COLOR=X.vdb: judge X's colour grid on this density (a diagnosis:
    // the colour a job wrote, seen with these views).
    let file_color: Option<Vec<Grid3>> = match std::env::var("FILE_COLOR") {
        Ok(p) => {
            let f = read_vdb(Path::new(&p)).map_err(|e| anyhow!("{e}"))?;
            let g = f.grid("color").or_else(|| f.grid("Cd")).ok_or_else(|| anyhow!("{p}: no colour grid"))?;
            let (cbox, ch) = g.to_dense_vec3()?;
            Some(ch.into_iter().map(|c| pad(&nst3d_volume::dense::in_box(Some((cbox, c)), &dbox), 4)).collect())
        }
        Err(_) => None,
    };
    // The judge's margin, cameras, absorption and lens (crates/volume/src/judge.rs).
    let raw_d = d.clone();
    let d = pad(&d, 4);
    let lens = Lens { up: UpAxis::Z, ..Lens::of(&VolumeSettings::new("", "", "")) };
    let cams = CameraSet::parse("ring:8:30")?.cameras(&lens, d.dims);
    let gamma = absorption_for(None, cams.iter().map(|c| (&d, c)))?;
    let views = views_of(&cams, gamma, false);
    let chosen: Vec<usize> = match args.get(4) {
        Some(s) => s.split(',').map(|v| v.parse()).collect::<Result<_, _>>()?,
        None => (0..views.len()).collect(),
    };

    let vgg = Vgg19::load(None)?;
    let painting = nst3d_io::image::load_style(&style, 1.0)?;
    let loss = ViewLoss::new(&vgg, &painting, &StyleSpec::default())?;
    let white = vec![Grid3::from_vec(d.dims, vec![1.0; d.len()]); 3];
    if let Some(mut c) = file_color {
        for i in 0..d.len() {
            if c.iter().all(|g| g.data[i] == 0.0) {
                c.iter_mut().for_each(|g| g.data[i] = 1.0);
            }
        }
        let r: Vec<f32> = views
            .iter()
            .map(|v| Ok(loss.loss_color(&d, &c, v)? / loss.loss_color(&d, &white, v)?))
            .collect::<Result<_>>()?;
        println!("file colour: {}", r.iter().map(|r| format!("{r:.3}")).collect::<Vec<_>>().join(" "));
        return Ok(());
    }
    if let Some(train) = train_cams {
        // PAD=0 trains in the job's framing (density mode pads nothing); the
        // judge's views keep their 4-voxel margin.
        let pad_n: usize = std::env::var("PAD").ok().and_then(|v| v.parse().ok()).unwrap_or(4).min(4);
        let full = d.clone();
        let d = pad(&raw_d, pad_n);
        let tcams = CameraSet::parse(&train)?.cameras(&lens, d.dims);
        // The job's absorption (its front camera) and the smallest over the
        // colour cameras; GAMMA=judge|job|min|mix picks the training views'.
        let front = CameraSet::parse("front")?.cameras(&lens, d.dims).remove(0);
        let g_job = absorption_for(None, std::iter::once((&d, &front)))?;
        let g_min = absorption_for(None, tcams.iter().map(|c| (&d, c)))?.min(g_job);
        let mode = std::env::var("GAMMA").unwrap_or("judge".into());
        eprintln!("gamma judge {gamma} job {g_job} min {g_min}");
        let tviews = match mode.as_str() {
            "job" => views_of(&tcams, g_job, false),
            "min" => views_of(&tcams, g_min, false),
            "mix" => {
                let levels = [g_min, (g_min * g_job).sqrt(), g_job];
                (0..3 * tcams.len())
                    .map(|i| views_of(std::slice::from_ref(&tcams[i % tcams.len()]), levels[i % 3], false).remove(0))
                    .collect()
            }
            _ => views_of(&tcams, gamma, false),
        };
        let base: Vec<f32> = views.iter().map(|v| loss.loss_color(&full, &white, v)).collect::<Result<_, _>>()?;
        let env = |k: &str| std::env::var(k).ok().and_then(|v| v.parse::<f32>().ok());
        let params = ColorStageParams {
            iterations: iters * tcams.len(),
            learning_rate: env("LR").unwrap_or(nst3d_stylize::color::LEARNING_RATE),
            grey_guard: env("GUARD").unwrap_or(nst3d_stylize::color_stage::GREY_GUARD),
            smoke_term: env("SMOKE").unwrap_or(nst3d_stylize::color_stage::SMOKE_TERM),
            density: None,
        };
        let grey = ViewLoss::new(&vgg, &painting.luminance3(), &StyleSpec::default())?;
        let r = stylize_color(&d, &loss, &grey, &tviews, &params, &mut |p| {
            if p.iteration % 32 == 0 {
                eprintln!("iter {}: {:.4e}", p.iteration, p.loss)
            }
        })?;
        let color: Vec<Grid3> = r.color.iter().map(|c| pad(c, 4 - pad_n)).collect();
        let d = full;
        let r = nst3d_stylize::ColorResult { color, ..r };
        let got: Vec<f32> = views.iter().map(|v| loss.loss_color(&d, &r.color, v)).collect::<Result<_, _>>()?;
        for k in [0, 2] {
            let grey = color_view_image(&d, &white, &views[k])?;
            let col = color_view_image(&d, &r.color, &views[k])?;
            let sheet = nst3d_io::image::side_by_side(&[&grey, &col]);
            let sheet = nst3d_io::image::resize_to_height(&sheet, 384);
            nst3d_io::image::write_png(Path::new(&format!("{out}_field_view_{k}.png")), &sheet)?;
        }
        let mut ratios: Vec<f32> = got.iter().zip(&base).map(|(a, b)| a / b).collect();
        println!("held-out ratios: {}", ratios.iter().map(|r| format!("{r:.3}")).collect::<Vec<_>>().join(" "));
        ratios.sort_by(f32::total_cmp);
        println!("median {:.3} worst {:.3}", ratios[ratios.len() / 2], ratios[ratios.len() - 1]);
        return Ok(());
    }
    println!("view  white_loss  chroma_ratio  free_ratio");
    let (mut chroma_all, mut free_all) = (Vec::new(), Vec::new());
    for &k in &chosen {
        let rgb = color_view_image(&d, &white, &views[k])?;
        let (h, w) = (rgb.height, rgb.width);
        let l = rgb.data[..h * w].to_vec();
        let base = loss.loss_and_grad_image(&rgb)?.0;
        let (c, ci) = optimise(&loss, &l, h, w, Kind::Chroma, iters)?;
        let (f, fi) = optimise(&loss, &l, h, w, Kind::Free, iters)?;
        println!("{k:4}  {base:10.4e}  {:12.3}  {:10.3}", c / base, f / base);
        chroma_all.push(c / base);
        free_all.push(f / base);
        let sheet = nst3d_io::image::side_by_side(&[&rgb, &ci, &fi]);
        let sheet = nst3d_io::image::resize_to_height(&sheet, 256.max(h));
        nst3d_io::image::write_png(Path::new(&format!("{out}_view_{k}.png")), &sheet)?;
    }
    let median = |v: &mut Vec<f32>| {
        v.sort_by(f32::total_cmp);
        v[v.len() / 2]
    };
    println!("median  chroma {:.3}  free {:.3}", median(&mut chroma_all), median(&mut free_all));
    Ok(())
}
