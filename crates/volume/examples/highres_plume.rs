//! Makes a paper-sized test volume (Sec. 5.2 stylizes 645 x 609 x 1553) from
//! a small simulation frame: its density box trilinearly resampled to the
//! given size, written leaf by leaf so the volume is never dense in memory.
//! The high-resolution figures of docs/guide/feedforward.md were made with it.
//!
//!     cargo run --release -p nst3d-volume --example highres_plume -- IN.vdb OUT.vdb [NX NY NZ]

use std::path::PathBuf;

use nst3d_core::Grid3;
use nst3d_io::vdb::{read_vdb, write_vdb, GridValues, SparseGrid, Transform, VdbGrid, LEAF_DIM};
use rayon::prelude::*;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    anyhow::ensure!(args.len() == 2 || args.len() == 5, "usage: highres_plume IN.vdb OUT.vdb [NX NY NZ]");
    let (input, output) = (PathBuf::from(&args[0]), PathBuf::from(&args[1]));
    let dims: [usize; 3] = if args.len() == 5 {
        std::array::from_fn(|a| args[2 + a].parse().expect("sizes are numbers"))
    } else {
        [645, 609, 1553]
    };
    let file = read_vdb(&input)?;
    let grid = file.grid("density").ok_or_else(|| anyhow::anyhow!("{}: no density grid", input.display()))?;
    let (_, d) = grid.to_dense()?;
    let scale: [f32; 3] = std::array::from_fn(|a| d.dims[a] as f32 / dims[a] as f32);
    let sample = |g: &Grid3, p: [f32; 3]| -> f32 {
        // Trilinear, clamped at the border (the box edge is empty smoke anyway).
        let mut v = 0.0;
        let c: [(usize, usize, f32); 3] = std::array::from_fn(|a| {
            let x = (p[a].max(0.0)).min((g.dims[a] - 1) as f32);
            let i = (x as usize).min(g.dims[a].saturating_sub(2));
            (i, (i + 1).min(g.dims[a] - 1), x - i as f32)
        });
        for (dz, wz) in [(c[2].0, 1.0 - c[2].2), (c[2].1, c[2].2)] {
            for (dy, wy) in [(c[1].0, 1.0 - c[1].2), (c[1].1, c[1].2)] {
                for (dx, wx) in [(c[0].0, 1.0 - c[0].2), (c[0].1, c[0].2)] {
                    v += wx * wy * wz * g.data[g.index(dx, dy, dz)];
                }
            }
        }
        v
    };
    let leaf = LEAF_DIM as usize;
    // One slab of leaves (8 z-planes) per task, merged at the end.
    let slabs: Vec<SparseGrid<f32>> = (0..dims[2].div_ceil(leaf))
        .into_par_iter()
        .map(|lz| {
            let mut out = SparseGrid::new(0.0f32);
            let z0 = lz * leaf;
            let nz = leaf.min(dims[2] - z0);
            for y0 in (0..dims[1]).step_by(leaf) {
                for x0 in (0..dims[0]).step_by(leaf) {
                    let size = [leaf.min(dims[0] - x0), leaf.min(dims[1] - y0), nz];
                    let mut values = Vec::with_capacity(size.iter().product());
                    for z in z0..z0 + size[2] {
                        for y in y0..y0 + size[1] {
                            for x in x0..x0 + size[0] {
                                let p = [x, y, z].map(|i| i as f32 + 0.5);
                                values.push(sample(&d, std::array::from_fn(|a| p[a] * scale[a] - 0.5)));
                            }
                        }
                    }
                    out.insert_region([x0 as i32, y0 as i32, z0 as i32], size, &values, |v| v > 1e-3);
                }
            }
            out
        })
        .collect();
    let mut all = SparseGrid::new(0.0f32);
    for slab in slabs {
        for l in slab.leaves() {
            all.insert_leaf(l.clone());
        }
    }
    let voxel = grid.transform.voxel_size.map(|v| v * scale[0] as f64);
    let out = VdbGrid::new("density", "fog volume", Transform::uniform(voxel[0]), GridValues::Float(all));
    println!("{}x{}x{} voxels, {} active", dims[0], dims[1], dims[2], out.active_voxel_count());
    write_vdb(&output, &[out])?;
    println!("wrote {}", output.display());
    Ok(())
}
