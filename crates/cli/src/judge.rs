//! `nst3d judge`: arguments → [`nst3d_volume::JudgeSettings`] → one library
//! call → one line per judged file.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use nst3d_volume::{JudgeSettings, Ratios, UpAxis};

use crate::console::Console;

/// Arguments of `nst3d judge`.
#[derive(Args)]
pub struct JudgeArgs {
    /// The painting; with --style-map, once per painting in the map's order.
    #[arg(long, required = true)]
    style: Vec<PathBuf>,
    /// Judge region by region ([`nst3d_volume::judge_map`]): the map the
    /// results were made with, as `nst3d volume --style-map` takes it.
    #[arg(long)]
    style_map: Option<String>,
    /// The map's values are labels, as `nst3d volume --style-map-labels`.
    #[arg(long)]
    style_map_labels: bool,
    /// The file every result is compared with (the input, or the grey result).
    #[arg(long)]
    baseline: PathBuf,
    /// The stylized files to judge.
    #[arg(required = true)]
    results: Vec<PathBuf>,
    /// Held-out cameras: ring:N[:ELEV], omniview:N or front [default: ring:8:30].
    #[arg(long)]
    cameras: Option<String>,
    /// Name of the density grid [default: density].
    #[arg(long)]
    grid: Option<String>,
    /// The files' up axis: the ring goes around it [default: z].
    #[arg(long, value_parser = crate::named::<UpAxis>(UpAxis::NAMES.iter().copied()))]
    up: Option<UpAxis>,
    /// Also judge in colour: each file's `Cd` or `color` grid (white where
    /// it has none) against the colour painting.
    #[arg(long)]
    color: bool,
    /// VGG-19 weights file (default: $NST3D_VGG19, else the user cache).
    #[arg(long)]
    weights: Option<PathBuf>,
    /// VGG-19 layers whose Gram matrices are compared, equally weighted
    /// [default: relu1_1,relu2_1,relu3_1,relu4_1].
    #[arg(long, value_delimiter = ',')]
    layers: Vec<nst3d_features::VggLayer>,
    /// The painting's scale, as `nst3d volume --style-scale` [default: the
    /// volume job's, 0.5]: judge at the scale the results were made at.
    #[arg(long)]
    style_scale: Option<f32>,
    /// Absorption γ of every picture [default: the smallest automatic one
    /// over the baseline's views].
    #[arg(long)]
    absorption: Option<f32>,
}

fn line(r: &Ratios) -> String {
    let views: Vec<String> = r.0.iter().map(|v| format!("{v:.3}")).collect();
    format!("worst {:.3} median {:.3} mean {:.3} views {}", r.worst(), r.median(), r.mean(), views.join(" "))
}

/// Runs `nst3d judge`.
pub fn run(args: JudgeArgs) -> Result<()> {
    let mut styles = args.style.into_iter();
    let mut s = JudgeSettings::new(styles.next().expect("--style is required"), args.baseline, args.results);
    s.more_styles = styles.collect();
    s.cameras = args.cameras.unwrap_or(s.cameras);
    s.grid = args.grid.unwrap_or(s.grid);
    s.up = args.up.unwrap_or(s.up);
    s.color = args.color;
    s.weights = args.weights;
    s.style_scale = args.style_scale.unwrap_or(s.style_scale);
    s.absorption = args.absorption;
    if !args.layers.is_empty() {
        s.spec = nst3d_stylize::StyleSpec { layer_weights: vec![1.0; args.layers.len()], layers: args.layers };
    }
    if let Some(map) = &args.style_map {
        return judge_map(&s, map, args.style_map_labels);
    } else if !s.more_styles.is_empty() {
        anyhow::bail!("--style is given {} times: several paintings are judged with --style-map", s.styles().len());
    }
    let verdicts = nst3d_volume::judge(&s, &mut Console::default())?;
    println!("loss / baseline's loss per held-out view ({}), below 1 = closer to the painting", s.cameras);
    for v in verdicts {
        println!("{} grey {}", v.file.display(), line(&v.grey));
        if let Some(c) = &v.color {
            println!("{} colour {}", v.file.display(), line(c));
        }
        if let Some(c) = &v.color_smoke {
            println!("{} colour-on-smoke {}", v.file.display(), line(c));
        }
    }
    Ok(())
}

/// `nst3d judge --style-map`: a line per result and region, its ratio toward each painting.
fn judge_map(s: &JudgeSettings, map: &str, labels: bool) -> Result<()> {
    let verdicts = nst3d_volume::judge_map(s, map, labels, &mut Console::default())?;
    println!("region by region, guided loss / baseline's per held-out view ({}), lower = nearer", s.cameras);
    for v in verdicts {
        for (r, row) in v.regions.iter().enumerate() {
            let cells: Vec<String> = (row.iter().zip(s.styles()))
                .map(|(c, p)| format!("{}: {}", p.display(), c.as_ref().map_or("not seen".into(), line)))
                .collect();
            println!("{} region {r} | {}", v.file.display(), cells.join(" | "));
        }
        if let Some(seam) = nst3d_volume::SeamSummary::of(&v.seams) {
            println!("{} seam | {seam}", v.file.display());
        }
    }
    Ok(())
}
