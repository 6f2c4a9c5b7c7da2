//! `nst3d volume --color` end to end on a real Blender frame: the
//! written file keeps every input grid and gains a vec3 colour grid that
//! python3-openvdb reads, over the smoke's voxels only, in [0, 1] (an
//! albedo), named as the DCC expects; combinations colour cannot do yet fail with one line.

mod common;
use common::{nst3d, s, shared};

use std::path::Path;
use std::process::Command;

/// `name type active_voxels` for every grid, then for `color`: the channel
/// minima and maxima and how many colour voxels hold no density.
fn openvdb_colour_summary(path: &Path, color: &str) -> String {
    let script = format!(
        "import sys\ntry:\n import pyopenvdb as vdb\nexcept ImportError:\n sys.exit('python3-openvdb missing: apt-get install python3-openvdb')\n\
grids = vdb.readAll('{p}')[0]\nprint(' '.join('%s:%s:%d' % (g.name, g.valueTypeName, g.activeVoxelCount()) for g in grids))\n\
c = [g for g in grids if g.name == '{c}'][0]; d = [g for g in grids if g.name == 'density'][0].getConstAccessor()\n\
vals = [(it.min, it.value) for it in c.iterOnValues()]\n\
print(*['%.3f' % min(v[i] for _, v in vals) for i in range(3)], *['%.3f' % max(v[i] for _, v in vals) for i in range(3)],\
 sum(1 for ijk, _ in vals if d.getValue(ijk) == 0.0))\n",
        p = path.display(),
        c = color
    );
    let o = Command::new("/usr/bin/python3").arg("-c").arg(script).output().expect(
        "/usr/bin/python3 not found: the colour test needs Debian's python3-openvdb (apt-get install python3-openvdb)",
    );
    assert!(o.status.success(), "python3-openvdb failed: {}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8(o.stdout).unwrap()
}

#[test]
fn color_adds_a_vec3_grid_python_openvdb_reads() {
    let dir = tempfile::tempdir().unwrap();
    let input = shared("volumes/plume48/fluid_data_0040.vdb");
    let style = shared("styles/woman_with_hat.jpg");
    let out = dir.path().join("c.vdb");
    let preview = dir.path().join("c.png");
    let o = nst3d(&[
        "volume",
        "--input",
        s(&input),
        "--style",
        s(&style),
        "--mode",
        "density",
        "--iters",
        "6",
        "--color",
        "--preview",
        s(&preview),
        "--out",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let summary = openvdb_colour_summary(&out, "color");
    let mut lines = summary.lines();
    let grids: Vec<&str> = lines.next().unwrap().split(' ').collect();
    // Blender's grid names (velocity, flame) give Principled Volume's `color`,
    // beside every grid the input had.
    let mut names: Vec<&str> = grids.iter().map(|g| g.split(':').next().unwrap()).collect();
    names.sort();
    assert_eq!(names, ["color", "density", "flame", "shadow", "temperature", "velocity"], "{summary}");
    let grid = |name: &str| *grids.iter().find(|g| g.starts_with(&format!("{name}:"))).unwrap();
    assert!(grid("color").starts_with("color:vec3s:"), "{summary}");
    let active = |g: &str| g.rsplit(':').next().unwrap().parse::<u64>().unwrap();
    assert!(active(grid("color")) > 1000 && active(grid("color")) <= active(grid("density")), "{summary}");
    let stats: Vec<f32> = lines.next().unwrap().split(' ').map(|v| v.parse().unwrap()).collect();
    // The colour stage's channels reach above white; the file holds them as
    // an albedo, every channel in [0, 1], the brightness in the density.
    assert!(nst3d_stylize::color_stage::COLOR_RANGE.1 > 1.0);
    assert!(stats[..3].iter().all(|v| *v >= 0.0) && stats[3..6].iter().all(|v| *v <= 1.0), "{summary}");
    assert!(stats[..3].iter().zip(&stats[3..6]).any(|(lo, hi)| hi - lo > 0.2), "the colour stayed flat: {summary}");
    assert_eq!(stats[6], 0.0, "colour where there is no smoke: {summary}");
    let png = image::open(&preview).unwrap().to_rgb8();
    let coloured = png.pixels().filter(|p| p[0].abs_diff(p[1]) > 40 || p[1].abs_diff(p[2]) > 40).count();
    assert!(coloured > 1000, "the preview is grey");

    // The judge: a file against itself scores 1 from every view, grey,
    // colour and colour on the smoke; an input 2x coarser than the result is refined to the result's
    // voxels and judged beside it; a grid the files lack is one line.
    let o =
        nst3d(&["judge", "--style", s(&style), "--baseline", s(&out), "--color", "--cameras", "ring:3:30", s(&out)]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for kind in ["grey", "colour", "colour-on-smoke"] {
        let line = text.lines().find(|l| l.contains(&format!(" {kind} worst"))).unwrap_or_else(|| panic!("{text}"));
        assert!(line.ends_with("views 1.000 1.000 1.000"), "{line}");
    }
    let fine = dir.path().join("fine.vdb");
    let o = nst3d(&[
        "volume",
        "--input",
        s(&input),
        "--style",
        s(&style),
        "--mode",
        "density",
        "--iters",
        "1",
        "--octaves",
        "1",
        "--upsample",
        "2",
        "--out",
        s(&fine),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = nst3d(&["judge", "--style", s(&style), "--baseline", s(&input), "--cameras", "ring:3:30", s(&fine)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let at_job_scale = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(at_job_scale.contains(" grey worst "));
    // The painting is read at the volume job's --style-scale unless told
    // otherwise: at another scale the same files score otherwise.
    let o = nst3d(&[
        "judge",
        "--style",
        s(&style),
        "--baseline",
        s(&input),
        "--cameras",
        "ring:3:30",
        "--style-scale",
        "1",
        s(&fine),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let grey_line = |t: &str| t.lines().find(|l| l.contains(" grey worst ")).map(|l| l.to_string());
    assert_ne!(
        grey_line(&at_job_scale),
        grey_line(&String::from_utf8_lossy(&o.stdout)),
        "--style-scale changed nothing"
    );
    let o = nst3d(&["judge", "--style", s(&style), "--baseline", s(&input), "--absorption", "0", s(&fine)]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("--absorption must be a positive number") && err.lines().count() == 1, "{err}");
    // Voxels need not be cubes: smoke_000003's are 0.1326 x 0.1329 x 0.1317.
    let boxy = shared("volumes/smoke_000003.vdb");
    let o = nst3d(&["judge", "--style", s(&style), "--baseline", s(&boxy), "--cameras", "ring:2:30", s(&boxy)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stdout).contains("views 1.000 1.000"), "{}", String::from_utf8_lossy(&o.stdout));
    let o = nst3d(&["judge", "--style", s(&style), "--baseline", s(&input), "--grid", "smoke", s(&out)]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("no grid named 'smoke'") && err.lines().count() == 1, "{err}");

    // `nst3d preview --color`: the input (no colour grid) drawn grey beside
    // the result drawn in its colour, with one camera and absorption.
    let sheet = dir.path().join("sheet.png");
    let o = nst3d(&[
        "preview",
        "--input",
        s(&input),
        "--compare",
        s(&out),
        "--color",
        "--height",
        "256",
        "--out",
        s(&sheet),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let png = image::open(&sheet).unwrap().to_rgb8();
    let half = png.width() / 2;
    let tinted = |left: bool| {
        png.enumerate_pixels()
            .filter(|(x, _, p)| (*x < half) == left && (p[0].abs_diff(p[1]) > 40 || p[1].abs_diff(p[2]) > 40))
            .count()
    };
    assert_eq!(tinted(true), 0, "the input has no colour grid: drawn grey");
    assert!(tinted(false) > 1000, "the coloured result is drawn in colour ({} pixels)", tinted(false));

    // The name follows --color-grid, and --color-grid alone is refused.
    let o = nst3d(&[
        "volume",
        "--input",
        s(&input),
        "--style",
        s(&style),
        "--mode",
        "density",
        "--iters",
        "1",
        "--octaves",
        "1",
        "--color",
        "--color-grid",
        "Cd",
        "--out",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(openvdb_colour_summary(&out, "Cd").contains("Cd:vec3s:"));
}

/// A sequence with colour: every frame gets its colour grid (the colour is
/// carried by the EMA with the field), and the report's flicker is measured.
/// What colour cannot do yet fails with one line.
#[test]
fn color_sequences_write_colour_per_frame_and_refuse_what_they_cannot_do() {
    let dir = tempfile::tempdir().unwrap();
    let pattern = shared("volumes/plume48").join("fluid_data_####.vdb");
    let style = shared("styles/woman_with_hat.jpg");
    let out = dir.path().join("o_####.vdb");
    let o = nst3d(&[
        "volume",
        "--input",
        s(&pattern),
        "--frames",
        "39-40",
        "--style",
        s(&style),
        "--mode",
        "density",
        "--color",
        "--iters",
        "2",
        "--octaves",
        "1",
        "--out",
        s(&out),
    ]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(text.contains("2 frames stylized") && text.contains("flicker"), "{text}");
    for f in ["o_0039.vdb", "o_0040.vdb"] {
        let summary = openvdb_colour_summary(&dir.path().join(f), "color");
        assert!(summary.contains("color:vec3s:"), "{f}: {summary}");
    }
    let frame = shared("volumes/plume48/fluid_data_0040.vdb");
    let out = dir.path().join("o.vdb");
    let o = nst3d(&["volume", "--input", s(&frame), "--style", s(&style), "--color", "--equalize", "--out", s(&out)]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--equalize"));
}
