//! How far could any hair lower the groom judge's whole-picture score?
//!
//! The judge (`nst3d preview --style`) scores a picture of the groom on a
//! black background: the VGG-19 Gram loss of the whole picture to the
//! painting's luminance, as a ratio to the input's picture. The background
//! is the same black in every groom's picture. This example drops the
//! groom: on one judged picture of the input it optimises a free grey
//! picture over the input's hair pixels (any grey in `[0, 1]` where the
//! input shows hair, the background kept black), 150 Adam steps, and
//! reports the ratio it reaches over the whole picture. No groom with the
//! input's silhouette can do better from that view, so it bounds what
//! `nst3d strands` can reach on the judge. A second bound frees every
//! pixel (the silhouette too) for comparison, and a third pastes the
//! painting itself into the hair pixels (no optimisation).
//! With `BOUND.png`, the free grey picture over the hair is written there.
//!
//!     cargo run --release -p nst3d-groom --example grey_bound -- STYLE.jpg SHEET.png [ITERS]
//!
//! `SHEET.png` is an input | result sheet as `nst3d preview --input GROOM
//! --compare RESULT --turntable 8 --elevation 15 --height 512` writes it;
//! its left half is the input's picture. The result's own ratio (the right
//! half) is printed beside the bounds.

use std::path::Path;

use anyhow::Result;
use nst3d_core::image::LUMA;
use nst3d_core::{FeatureView, Image};
use nst3d_features::{Vgg19, VggLayer};
use nst3d_io::image::{load_style, luminance_rgb, resize_to_height};
use nst3d_loss::{style_loss, StyleTarget};
use nst3d_optim::Adam;

const LAYERS: [VggLayer; 4] = [VggLayer::Relu1_1, VggLayer::Relu2_1, VggLayer::Relu3_1, VggLayer::Relu4_1];

/// The judge's loss of a grey picture (one value per pixel) and, with
/// `grad`, its gradient per pixel.
fn loss(vgg: &Vgg19, target: &StyleTarget, grey: &[f32], h: usize, w: usize, grad: bool) -> Result<(f32, Vec<f32>)> {
    let rgb = Image::from_vec(3, h, w, [grey; 3].concat());
    let fwd = vgg.forward(&rgb, &LAYERS, grad);
    let feats = fwd.features();
    let (l, taps) = style_loss(&feats, target)?;
    if !grad {
        return Ok((l, Vec::new()));
    }
    let views: Vec<FeatureView> = feats.iter().zip(&taps).map(|(f, g)| FeatureView { data: g, ..*f }).collect();
    let g = vgg.backward(&fwd, &views);
    let p = h * w;
    Ok((l, (0..p).map(|i| g.data[i] + g.data[p + i] + g.data[2 * p + i]).collect()))
}

/// 150 (or `iters`) Adam steps on the pixels where `free`, in `[0, 1]`;
/// the best loss seen.
fn optimise(
    vgg: &Vgg19,
    target: &StyleTarget,
    start: &[f32],
    free: &[bool],
    h: usize,
    w: usize,
    iters: usize,
    save: Option<&Path>,
) -> Result<f32> {
    let mut x = start.to_vec();
    let mut adam = Adam::new(x.len(), 0.02);
    let mut best = f32::INFINITY;
    for _ in 0..iters {
        let (l, mut g) = loss(vgg, target, &x, h, w, true)?;
        best = best.min(l);
        for (gi, &f) in g.iter_mut().zip(free) {
            if !f {
                *gi = 0.0;
            }
        }
        adam.step(&mut x, &g);
        for (xi, &f) in x.iter_mut().zip(free) {
            *xi = if f { xi.clamp(0.0, 1.0) } else { 0.0 };
        }
    }
    if let Some(path) = save {
        nst3d_io::image::write_png(path, &Image::from_vec(1, h, w, x.clone()))?;
    }
    Ok(best.min(loss(vgg, target, &x, h, w, false)?.0))
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 2 {
        anyhow::bail!("usage: grey_bound STYLE.jpg SHEET.png [ITERS [BOUND.png]]");
    }
    let iters: usize = args.get(2).map(|s| s.parse()).transpose()?.unwrap_or(150);
    let sheet = load_style(Path::new(&args[1]), 1.0)?;
    let (h, w) = (sheet.height, sheet.width / 2);
    let half = |x0: usize| -> Vec<f32> {
        let p = sheet.height * sheet.width;
        let mut v = vec![0.0; h * w];
        for y in 0..h {
            for x in 0..w {
                let i = y * sheet.width + x0 + x;
                v[y * w + x] = (0..3).map(|c| LUMA[c] * sheet.data[c * p + i]).sum();
            }
        }
        v
    };
    let input = half(0);
    let result = half(sheet.width - w);

    let vgg = Vgg19::load(None)?;
    let painting = luminance_rgb(&load_style(Path::new(&args[0]), 1.0)?);
    let grey = resize_to_height(&painting, h);
    let target = StyleTarget::from_features(&vgg.forward(&grey, &LAYERS, false).features(), &[1.0; 4])?;

    let base = loss(&vgg, &target, &input, h, w, false)?.0;
    let res = loss(&vgg, &target, &result, h, w, false)?.0;
    let hair: Vec<bool> = input.iter().map(|&v| v > 0.02).collect();
    // The painting pasted into the hair pixels, tiled from its top-left.
    let pasted: Vec<f32> = (0..h * w)
        .map(|i| {
            if !hair[i] {
                return 0.0;
            }
            let (y, x) = (i / w, i % w);
            grey.data[(y % grey.height) * grey.width + x % grey.width]
        })
        .collect();
    let paste = loss(&vgg, &target, &pasted, h, w, false)?.0;
    let masked = optimise(&vgg, &target, &input, &hair, h, w, iters, args.get(3).map(Path::new))?;
    let everywhere = optimise(&vgg, &target, &input, &vec![true; h * w], h, w, iters, None)?;
    println!(
        "{}: hair {:.3} of the picture; ratio to the input: result {:.3}, painting pasted on the hair {:.3}, \
         free grey on the hair {:.3}, free grey everywhere {:.3}",
        args[1],
        hair.iter().filter(|&&b| b).count() as f32 / (h * w) as f32,
        res / base,
        paste / base,
        masked / base,
        everywhere / base
    );
    Ok(())
}
