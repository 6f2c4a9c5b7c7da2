//! The style-map judge: each region of a stylized frame scored against each
//! painting by the guided Gram loss, from the cameras of `omniview:N`.
//!
//! `map_judge INPUT.vdb MAP LABELS(0|1) VIEWS A.jpg B.jpg RESULT.vdb...`
//! prints, per result, the mean over the views that show a region of its
//! loss against each painting (lower is nearer). Every result is judged
//! over the same pixels: the regions rendered through the input's smoke.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use nst3d_core::Grid3;
use nst3d_io::vdb::read_vdb;
use nst3d_stylize::{MapLoss, StyleSpec, ViewLoss};
use nst3d_volume::look::{absorption_for, views_of};
use nst3d_volume::style_map::{regions, sample, MapBox, MapSource};
use nst3d_volume::{CameraSet, Lens, UpAxis, VolumeSettings};

/// The result's density over the input's box (`origin`, `dims`), so every
/// file is rendered on the same lattice.
fn dense(path: &Path, origin: [i32; 3], dims: [usize; 3]) -> Result<Grid3> {
    let f = read_vdb(path)?;
    let (bx, g) = f.grid("density").context("no density grid")?.to_dense()?;
    let mut out = Grid3::zeros(dims);
    for z in 0..g.dims[2] {
        for y in 0..g.dims[1] {
            for x in 0..g.dims[0] {
                let p = [x, y, z].map(|v| v as i64);
                let q: [i64; 3] = std::array::from_fn(|a| p[a] + (bx.origin[a] - origin[a]) as i64);
                if (0..3).all(|a| q[a] >= 0 && q[a] < dims[a] as i64) {
                    let i = out.index(q[0] as usize, q[1] as usize, q[2] as usize);
                    out.data[i] = g.data[g.index(x, y, z)];
                }
            }
        }
    }
    Ok(out)
}

fn main() -> Result<()> {
    let a: Vec<String> = std::env::args().collect();
    let (input, map, labels, n) = (PathBuf::from(&a[1]), &a[2], a[3] == "1", a[4].parse::<usize>()?);
    let paintings = [PathBuf::from(&a[5]), PathBuf::from(&a[6])];
    let file = read_vdb(&input)?;
    let grid = file.grid("density").context("no density grid")?;
    let (bx, d) = grid.to_dense()?;
    let source = MapSource::parse(map)?;
    let labels = source.labels(labels);
    let at =
        MapBox { dims: d.dims, origin: bx.origin, transform: &grid.transform, inner: ([0; 3], d.dims), up: UpAxis::Z };
    let regions = regions(&sample(&source, Some((&file, &input)), &at, labels)?, &d, 2, labels)?;
    let s = VolumeSettings::new(&input, &paintings[0], "unused.vdb");
    let cams = CameraSet::parse(&format!("omniview:{n}"))?.cameras(&Lens::of(&s), d.dims);
    let views = views_of(&cams, absorption_for(None, cams.iter().map(|c| (&d, c)))?, false);
    let vgg = nst3d_features::Vgg19::load(None)?;
    let spec = StyleSpec::default();
    let mut losses = Vec::new();
    for p in &paintings {
        let img = nst3d_io::image::luminance_rgb(&nst3d_io::image::load_style(p, s.style_scale)?);
        losses.push(ViewLoss::new(&vgg, &img, &spec)?);
    }
    let judge = MapLoss::new(losses);
    for result in &a[7..] {
        let r = dense(Path::new(result), bx.origin, d.dims)?;
        let mut sums = [[0.0f64; 2]; 2];
        let mut counts = [0usize; 2];
        for v in &views {
            for (k, row) in judge.region_table(&r, &d, &regions, v)?.into_iter().enumerate() {
                if let Some(row) = row {
                    counts[k] += 1;
                    sums[k][0] += row[0] as f64;
                    sums[k][1] += row[1] as f64;
                }
            }
        }
        let m = |k: usize, p: usize| sums[k][p] / counts[k].max(1) as f64;
        println!(
            "{result}: region0 vs A {:.4} vs B {:.4} ({} views) | region1 vs A {:.4} vs B {:.4} ({} views)",
            m(0, 0),
            m(0, 1),
            counts[0],
            m(1, 0),
            m(1, 1),
            counts[1]
        );
    }
    Ok(())
}
