//! Does the groom judge follow the look, or can it be fooled?
//!
//! `nst3d preview --style` scores a picture of a groom two ways: the
//! VGG-19 Gram loss of the whole picture to the painting, and the same
//! loss over the cells that hold hair only (`GramJudge::scores`). This
//! example scores pictures that are *not* stylizations, with the judge's
//! own code, as ratios to the input's picture:
//! - the input's picture times a gain (the groom unchanged, only darker or
//!   brighter, clamped to 1): a judge of the look should not call these
//!   nearer the painting;
//! - the painting itself pasted into the input's hair pixels (tiled from
//!   the top-left, the background kept black): the nearest a picture with
//!   the input's silhouette can look like the painting, so a judge should
//!   rank it above any groom;
//! - the input at the result's tone (one gain that gives its hair the
//!   result's mean luminance): what the result's change of brightness
//!   alone would score;
//! - the input with grain (each hair pixel times `1 + 0.5 u`, `u` uniform
//!   in [−1, 1] from a fixed hash) and the input blurred (a 5 × 5 box):
//!   texture changed in ways no painting asked for, which a judge of the
//!   look should not credit as much as a stylization;
//! - the result (the sheet's right half), for comparison.
//!
//! In grey each line also gives the product's tone-matched hair-only score
//! (`GramJudge::toned_hair_loss`).
//!
//!     cargo run --release -p nst3d-groom --example judge_sanity -- STYLE.jpg SHEET.png [--color]
//!
//! `SHEET.png` is an `input | result` sheet as `nst3d preview --input GROOM
//! --compare RESULT --turntable 8 --height 512` writes it (with `--color`,
//! in colour: then the colour judge scores it against the painting in
//! colour).

use std::path::Path;

use anyhow::Result;
use nst3d_core::Image;
use nst3d_groom::judge::GramJudge;
use nst3d_io::image::{load_style, resize_to_height};

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let color = args.iter().any(|a| a == "--color");
    let files: Vec<&String> = args.iter().filter(|a| !a.starts_with("--")).collect();
    if files.len() != 2 {
        anyhow::bail!("usage: judge_sanity STYLE.jpg SHEET.png [--color]");
    }
    let sheet = load_style(Path::new(files[1]), 1.0)?;
    let (h, w) = (sheet.height, sheet.width / 2);
    let p = h * sheet.width;
    // One half of the sheet, three channels.
    let half = |x0: usize| -> Image {
        let mut out = Image::zeros(3, h, w);
        for c in 0..3 {
            for y in 0..h {
                for x in 0..w {
                    out.data[c * h * w + y * w + x] = sheet.data[c * p + y * sheet.width + x0 + x];
                }
            }
        }
        out
    };
    let input = half(0);
    let result = half(sheet.width - w);
    let judge = GramJudge::with_color(Path::new(files[0]), h, None, color)?;
    let painting = resize_to_height(&load_style(Path::new(files[0]), 1.0)?, h);
    let luma = |img: &Image, i: usize| -> f32 {
        let n = img.height * img.width;
        (0..3).map(|c| nst3d_core::image::LUMA[c] * img.data[c * n + i]).sum()
    };
    let (whole0, hair0) = judge.scores(&input)?;
    let hair0 = hair0.ok_or_else(|| anyhow::anyhow!("the input's picture shows no hair"))?;
    // The product's tone-matched score (grey only: in colour tone is part of the palette).
    let toned0 = if color { None } else { judge.toned_hair_loss(&input)? };
    let score = |name: &str, img: &Image| -> Result<()> {
        let (whole, hair) = judge.scores(img)?;
        let mut line =
            format!("{name:<36} whole {:.3}   hair only {:.3}", whole / whole0, hair.map_or(f32::NAN, |v| v / hair0));
        if let Some(t0) = toned0 {
            let t = judge.toned_hair_loss(img)?.map_or(f32::NAN, |v| v / t0);
            line += &format!("   hair only, tone matched {t:.3}");
        }
        println!("{line}");
        Ok(())
    };

    score("the result", &result)?;
    // The painting (grey for the grey judge), tiled into the hair pixels.
    let n = h * w;
    let is_hair = |i: usize| (0..3).any(|c| input.data[c * n + i] > 0.02);
    let mut pasted = Image::zeros(3, h, w);
    for i in (0..n).filter(|&i| is_hair(i)) {
        let (y, x) = (i / w, i % w);
        let j = (y % painting.height) * painting.width + x % painting.width;
        let pn = painting.height * painting.width;
        let rgb: [f32; 3] = std::array::from_fn(|c| painting.data[c * pn + j]);
        let grey = luma(&painting, j);
        for (c, &v) in rgb.iter().enumerate() {
            pasted.data[c * n + i] = if color { v } else { grey };
        }
    }
    score("the painting pasted on the hair", &pasted)?;
    // The input at the result's tone: what brightness alone would score.
    let hair_mean = |img: &Image| {
        let n = img.height * img.width;
        let v: Vec<f32> = (0..n).map(|i| luma(img, i)).filter(|&v| v > 0.02).collect();
        v.iter().sum::<f32>() / v.len().max(1) as f32
    };
    let gain = hair_mean(&result) / hair_mean(&input);
    let mut at_tone = input.clone();
    at_tone.data.iter_mut().for_each(|v| *v = (*v * gain).min(1.0));
    score(&format!("the input at the result's tone (x {gain:.3})"), &at_tone)?;
    // Grain on the hair: a fixed hash, so the line is the same every run.
    let mut grain = input.clone();
    for i in (0..n).filter(|&i| is_hair(i)) {
        let hsh = (i as u64 ^ 0x9e37_79b9_7f4a_7c15).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        let u = ((hsh >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0;
        for c in 0..3 {
            grain.data[c * n + i] = (grain.data[c * n + i] * (1.0 + 0.5 * u)).clamp(0.0, 1.0);
        }
    }
    score("the input with grain", &grain)?;
    let mut blurred = input.clone();
    for c in 0..3 {
        for y in 0..h {
            for x in 0..w {
                let (mut sum, mut k) = (0.0f32, 0);
                for yy in y.saturating_sub(2)..(y + 3).min(h) {
                    for xx in x.saturating_sub(2)..(x + 3).min(w) {
                        sum += input.data[c * n + yy * w + xx];
                        k += 1;
                    }
                }
                blurred.data[c * n + y * w + x] = sum / k as f32;
            }
        }
    }
    score("the input blurred (5 x 5 box)", &blurred)?;
    for gain in [0.5f32, 0.75, 1.5, 2.0] {
        let mut lit = input.clone();
        lit.data.iter_mut().for_each(|v| *v = (*v * gain).min(1.0));
        score(&format!("the input x {gain}"), &lit)?;
    }
    Ok(())
}
