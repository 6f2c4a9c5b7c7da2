//! Colour with a style map: each region of the smoke takes the colour of
//! the painting the map gives it. Two paintings of opposite colours (warm
//! red-orange stripes, cool blue-cyan stripes) split at mid-height
//! (`@height-split`): the density-weighted mean colour of each half is
//! nearer its own painting's mean colour than the other's, in both
//! assignments, for a single frame and for a sequence.

use std::path::{Path, PathBuf};

use nst3d_core::{Grid3, Image};
use nst3d_stylize::Mode;
use nst3d_volume::{stylize_grid, stylize_sequence_files, SequenceSettings, Silent, Upsample, VolumeSettings};

fn shared(rel: &str) -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data").join(rel);
    assert!(p.exists(), "shared test data missing: {} (the repo expects ../shared beside it)", p.display());
    p
}

/// Diagonal stripes between two colours.
fn painting(path: &Path, a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    let n = 128;
    let mut img = Image::zeros(3, n, n);
    for y in 0..n {
        for x in 0..n {
            let c = if ((x + y) / 10) % 2 == 0 { a } else { b };
            (0..3).for_each(|ch| img.data[(ch * n + y) * n + x] = c[ch]);
        }
    }
    nst3d_io::image::write_png(path, &img).unwrap();
    std::array::from_fn(|ch| 0.5 * (a[ch] + b[ch]))
}

/// Chromaticity: the colour over the sum of its channels.
fn chroma(c: [f32; 3]) -> [f32; 3] {
    let s: f32 = c.iter().sum::<f32>().max(1e-6);
    c.map(|v| v / s)
}

fn dist(a: [f32; 3], b: [f32; 3]) -> f32 {
    a.iter().zip(&b).map(|(x, y)| (x - y) * (x - y)).sum::<f32>().sqrt()
}

/// The density-weighted mean colour of the voxels below and above the
/// middle of the box `(lo, size)` along z (where `@height-split` cuts), `lo`
/// in the grid's own voxels.
fn halves(density: &Grid3, color: &[Grid3], (lo, size): (f32, f32)) -> [[f32; 3]; 2] {
    let [nx, ny, _] = density.dims;
    let mut sum = [[0f64; 3]; 2];
    let mut weight = [0f64; 2];
    for (i, &d) in density.data.iter().enumerate() {
        let z = i / (nx * ny);
        let h = (z as f32 - lo) / (size - 1.0);
        let half = (h >= 0.5) as usize;
        weight[half] += d as f64;
        (0..3).for_each(|c| sum[half][c] += d as f64 * color[c].data[i] as f64);
    }
    std::array::from_fn(|r| std::array::from_fn(|c| (sum[r][c] / weight[r]) as f32))
}

fn settings(paintings: [&Path; 2], out: PathBuf) -> VolumeSettings {
    let mut s = VolumeSettings::new(shared("volumes/plume48/fluid_data_0040.vdb"), paintings[0], out);
    s.more_styles = vec![paintings[1].to_path_buf()];
    s.style_map = Some("@height-split".into());
    s.color = true;
    s.mode = Mode::Density;
    s.iters = 2;
    s.octaves = Some(1);
    s.upsample = Upsample::Factor(1);
    s
}

/// Each half's colour against both paintings' (chromaticity distances,
/// `[half][painting]`), printed for the record.
fn distances(halves: [[f32; 3]; 2], means: [[f32; 3]; 2], what: &str) -> [[f32; 2]; 2] {
    let d = halves.map(|h| means.map(|m| dist(chroma(h), chroma(m))));
    eprintln!("{what}: half colours {halves:?}, chromaticity distance [half][painting] {d:?}");
    d
}

#[test]
fn each_region_takes_its_own_paintings_colour() {
    let dir = tempfile::tempdir().unwrap();
    let (warm, cool) = (dir.path().join("warm.png"), dir.path().join("cool.png"));
    let warm_mean = painting(&warm, [0.95, 0.35, 0.1], [0.75, 0.15, 0.1]);
    let cool_mean = painting(&cool, [0.1, 0.35, 0.95], [0.15, 0.75, 0.85]);
    let file = nst3d_io::vdb::read_vdb(&shared("volumes/plume48/fluid_data_0040.vdb")).unwrap();
    let grid = file.grid("density").unwrap();
    let (bx, dense) = grid.to_dense().unwrap();
    for (paintings, means, what) in [
        ([warm.as_path(), &cool], [warm_mean, cool_mean], "warm below, cool above"),
        ([cool.as_path(), &warm], [cool_mean, warm_mean], "cool below, warm above"),
    ] {
        let s = settings(paintings, dir.path().join("unused.vdb"));
        let r = stylize_grid(&s, dense.clone(), &grid.transform, bx.origin, "density", &mut Silent).unwrap();
        let color = r.color.as_ref().expect("--color gives a colour");
        let d = distances(halves(&r.density, color, (r.margin as f32, r.dims[2] as f32)), means, what);
        for half in 0..2 {
            assert!(d[half][half] < d[half][1 - half], "{what}: half {half} is nearer the other painting: {d:?}");
        }
    }
}

/// A sequence with colour and a map: every frame's colour grid, each half
/// nearer its own painting's colour.
#[test]
fn a_sequence_colours_each_region_with_its_painting() {
    let dir = tempfile::tempdir().unwrap();
    let (warm, cool) = (dir.path().join("warm.png"), dir.path().join("cool.png"));
    let means =
        [painting(&warm, [0.95, 0.35, 0.1], [0.75, 0.15, 0.1]), painting(&cool, [0.1, 0.35, 0.95], [0.15, 0.75, 0.85])];
    let mut s = settings([&warm, &cool], dir.path().join("o_####.vdb"));
    s.input = shared("volumes/plume48").join("fluid_data_####.vdb");
    s.sequence = Some(SequenceSettings { frames: "39-40".into(), ..SequenceSettings::default() });
    // A sequence's colour moves one step per sweep (a frame's colour stage
    // takes 16 per iteration).
    s.iters = 12;
    stylize_sequence_files(&s, &mut Silent).unwrap();
    // @height spans the box the frames share; each frame is judged over its
    // own grid's voxels in that box.
    let boxes: Vec<_> = [39, 40]
        .iter()
        .map(|f| {
            let file = nst3d_io::vdb::read_vdb(&shared(&format!("volumes/plume48/fluid_data_{f:04}.vdb"))).unwrap();
            file.grid("density").unwrap().active_bbox().unwrap()
        })
        .collect();
    let (lo, hi) = (boxes.iter().map(|b| b.0[2]).min().unwrap(), boxes.iter().map(|b| b.1[2]).max().unwrap());
    for f in [39, 40] {
        let file = nst3d_io::vdb::read_vdb(&dir.path().join(format!("o_{f:04}.vdb"))).unwrap();
        let (bx, density) = file.grid("density").unwrap().to_dense().unwrap();
        let (cbx, color) = file.grid("color").expect("a colour grid").to_dense_vec3().unwrap();
        assert_eq!(
            (bx.origin, density.dims),
            (cbx.origin, color[0].dims),
            "frame {f}: the colour lies over the density"
        );
        let at = ((lo - bx.origin[2]) as f32, (hi - lo + 1) as f32);
        let d = distances(halves(&density, &color, at), means, &format!("frame {f}"));
        for half in 0..2 {
            assert!(d[half][half] < d[half][1 - half], "frame {f}: half {half} is nearer the other painting: {d:?}");
        }
    }
}
