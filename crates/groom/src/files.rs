//! What the groom jobs share: writing a groom and its preview, frame
//! patterns, and the checks an artist would make on the result.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use nst3d_core::Image;
use nst3d_io::groom::{write_ply_strands, write_usda_curves_with, Groom, GroomFile, UsdPrimvars};
use nst3d_io::image::{luminance_rgb, resize_to_height, side_by_side, write_png};
use nst3d_io::mesh::TriMesh;
use nst3d_strands::pipeline::{max_length_change, polyline_length, GroomView, StrandScene};
use nst3d_strands::{FlatStrands, MeshBvh};

use crate::settings::{frame_path, OutFormat};

pub use nst3d_io::image::PREVIEW_HEIGHT;

/// Writes `strands` to `path` in `format`, atomically. With `input` (the
/// groom file the strands were made from, in its topology: same strands,
/// same points each) the output keeps the input's attributes unchanged:
/// per-point widths and colours, and in `.usda` the input layer's other
/// primvars ([`attribute_notes`] says what a format cannot hold). Fails,
/// writing nothing, when the topologies differ. Without `input` (generated
/// grooms) only points are written.
pub fn write_groom(path: &Path, format: OutFormat, strands: &FlatStrands, input: Option<&GroomFile>) -> Result<()> {
    let mut g = strands.to_groom();
    let no_primvars = UsdPrimvars::default();
    let mut primvars = &no_primvars;
    if let Some(input) = input {
        g.copy_attributes_from(&input.groom)
            .map_err(|e| anyhow::anyhow!("{}: {}", path.display(), nst3d_io::ErrorKind::from(e)))
            .context("cannot give the output the input's attributes")?;
        primvars = &input.usd_primvars;
    }
    match format {
        OutFormat::Usda => write_usda_curves_with(path, &g, primvars)?,
        OutFormat::Ply => write_ply_strands(path, &g)?,
    }
    Ok(())
}

/// What of `input`'s attributes an output in `format` will not hold, one
/// line each (for the job to say once, before the slow part): primvars the
/// reader could not keep, any primvar at all in `.ply`, a z-up layer's axis
/// in `.ply`, and colours finer than the 8 bits per channel of `.ply`.
pub fn attribute_notes(input: &GroomFile, format: OutFormat) -> Vec<String> {
    let mut notes = input.usd_primvars.dropped.clone();
    if format == OutFormat::Ply {
        let names: Vec<&str> = input.usd_primvars.primvars.iter().map(|p| p.name.as_str()).collect();
        if !names.is_empty() {
            notes.push(format!("a .ply output cannot hold {}: write .usda to keep them", names.join(", ")));
        }
        // Y is what a reader of the .ply will assume anyway.
        if let Some(axis) = input.usd_primvars.up_axis.as_deref().filter(|&a| a != "Y") {
            notes.push(format!(
                "a .ply output has no up axis (the input layer is {axis}-up; its points are written as they are): \
                 write .usda to keep it"
            ));
        }
        let fine = |c: f32| {
            let k = (c.clamp(0.0, 1.0) * 255.0).round();
            ((k as f64 / 255.0) as f32) != c
        };
        if input.groom.strands.iter().flat_map(|s| s.colors.iter().flatten()).flatten().any(|&c| fine(c)) {
            notes.push(
                "colours are rounded to 8 bits per channel in a .ply output: write .usda to keep them exactly".into(),
            );
        }
    }
    notes
}

/// Before | after | painting from the front camera.
pub fn write_preview(path: &Path, scene: &StrandScene, after: &FlatStrands, painting: &Image) -> Result<()> {
    let h = PREVIEW_HEIGHT;
    let cam = scene.front_camera(h)?;
    let before = scene.render(&scene.undeformed, &cam)?;
    let after = scene.render(after, &cam)?;
    let paint = resize_to_height(&luminance_rgb(painting), h);
    write_png(path, &side_by_side(&[&before, &after, &paint]))?;
    Ok(())
}

/// Whether `path` names a groom (by its magic number or extension) rather
/// than an OpenVDB file.
pub fn is_groom_file(path: &Path) -> bool {
    if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("vdb")) {
        return false;
    }
    let mut head = [0u8; 64];
    let n = std::fs::File::open(path).and_then(|mut f| std::io::Read::read(&mut f, &mut head)).unwrap_or(0);
    nst3d_io::groom::detect_groom_format(path, &head[..n]).is_some()
}

/// What `nst3d preview` draws of a groom.
#[derive(Clone, Debug)]
pub struct GroomPreviewSettings {
    /// The groom (.hair, .data, .ply, .usda, .abc).
    pub input: PathBuf,
    /// A second groom with the same strands (e.g. the stylized result),
    /// drawn to the right of `input` from the same cameras.
    pub compare: Option<PathBuf>,
    /// The mesh the strands grow from (front direction and culling).
    pub mesh: Option<PathBuf>,
    /// Output PNG; with `turntable` a pattern (`####` or `%04d`, from 1).
    pub out: PathBuf,
    /// Pictures at evenly spaced azimuths from the front.
    pub turntable: Option<usize>,
    /// Camera elevation in degrees.
    pub elevation: f32,
    /// Picture height in pixels.
    pub height: usize,
}

/// Draws a groom (and its comparison) as the stylization's cameras see it,
/// without stylizing; returns the number of pictures written.
pub fn preview_groom(s: &GroomPreviewSettings) -> Result<usize> {
    let n = s.turntable.unwrap_or(1);
    if n == 0 || n > 3600 {
        anyhow::bail!("--turntable {n}: give 1 to 3600 pictures");
    }
    if !(16..=8192).contains(&s.height) {
        anyhow::bail!("--height {}: give 16 to 8192 pixels", s.height);
    }
    nst3d_io::atomic::check_output("--out", &s.out, &["png"], &[]).map_err(anyhow::Error::msg)?;
    let outs: Vec<PathBuf> = match s.turntable {
        Some(_) => (1..=n as i64).map(|i| frame_path(&s.out, i, "--out")).collect::<Result<_>>()?,
        None => vec![s.out.clone()],
    };
    let groom = FlatStrands::from_groom(&nst3d_io::groom::read_groom(&s.input)?)?;
    let compare = match &s.compare {
        Some(p) => {
            let c = FlatStrands::from_groom(&nst3d_io::groom::read_groom(p)?)?;
            if c.strand_count() != groom.strand_count() {
                anyhow::bail!(
                    "{}: {} strands, {} has {}: not the same groom",
                    p.display(),
                    c.strand_count(),
                    s.input.display(),
                    groom.strand_count()
                );
            }
            Some(c)
        }
        None => None,
    };
    let head = s.mesh.as_deref().map(nst3d_io::mesh::read_mesh).transpose()?;
    let params = nst3d_strands::pipeline::StylizeParams::from_preset(
        nst3d_strands::Preset::ShortHair.params(),
        groom.strand_count(),
    );
    let view = GroomView::new(&groom, head.as_ref(), &params)?;
    for (i, out) in outs.iter().enumerate() {
        let azimuth = 360.0 * i as f32 / n as f32;
        let mut pictures = vec![view.render(&groom, s.elevation, azimuth, s.height)?];
        if let Some(c) = &compare {
            pictures.push(view.render(c, s.elevation, azimuth, s.height)?);
        }
        write_png(out, &side_by_side(&pictures.iter().collect::<Vec<_>>()))?;
    }
    Ok(outs.len())
}

/// Lengths and collisions of a stylized groom.
#[derive(Clone, Copy, Debug, Default)]
pub struct Checks {
    /// Largest relative length change of the written strands against the
    /// input groom's own polylines (what an artist measures).
    pub vs_input: f64,
    /// Against the resampled rest guides (what the constraint holds).
    pub vs_rest: f32,
    /// Written control points inside the mesh (0 without one).
    pub inside: usize,
}

/// Largest relative change of each written strand's length against the
/// input's `input_lengths`; the two must hold the same strands.
fn largest_length_change(input_lengths: &[f64], written: &FlatStrands) -> Result<f64> {
    if written.strand_count() != input_lengths.len() {
        bail!("{} strands written for an input of {}", written.strand_count(), input_lengths.len());
    }
    Ok(input_lengths
        .iter()
        .enumerate()
        .map(|(s, len)| ((polyline_length(written.strand(s)) - len) / len.max(1e-30)).abs())
        .fold(0.0f64, f64::max))
}

impl Checks {
    /// `guides`: the optimized (re-sampled) guides; `written`: what goes to
    /// the file, in the input's topology.
    pub fn new(
        groom: &Groom,
        scene: &StrandScene,
        guides: &FlatStrands,
        written: &FlatStrands,
        head: Option<&TriMesh>,
    ) -> Result<Self> {
        let input_lengths: Vec<f64> = groom.strands.iter().map(|s| polyline_length(&s.points)).collect();
        let vs_input = largest_length_change(&input_lengths, written)?;
        let Some(rest) = scene.rest.points.get(..guides.points.len()) else {
            bail!(
                "the optimised guides have {} points, the scene's rest pose {}",
                guides.points.len(),
                scene.rest.points.len()
            );
        };
        let rest_guides = FlatStrands { points: rest.to_vec(), offsets: guides.offsets.clone() };
        let vs_rest = max_length_change(&rest_guides, guides);
        // The scene's collider is this mesh's BVH already.
        let built;
        let bvh = match (&scene.constraints.collider, head) {
            (Some(b), _) => Some(b),
            (None, Some(head)) => {
                built = MeshBvh::new(head)?;
                Some(&built)
            }
            (None, None) => None,
        };
        let inside = bvh.map_or(0, |bvh| written.points.iter().filter(|&&p| bvh.is_inside(p)).count());
        Ok(Checks { vs_input, vs_rest, inside })
    }

    /// The worst of both.
    pub fn worst(self, other: Checks) -> Checks {
        Checks {
            vs_input: self.vs_input.max(other.vs_input),
            vs_rest: self.vs_rest.max(other.vs_rest),
            inside: self.inside.max(other.inside),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A written groom with other strands than the input's is an error, not
    /// an index out of bounds; the same strands give their largest change.
    #[test]
    fn length_checks_refuse_a_mismatched_groom() {
        let written = FlatStrands { points: vec![[0.0; 3], [0.0, 2.0, 0.0], [0.0; 3], [0.0, 1.0, 0.0]], offsets: vec![0, 2, 4] };
        let e = largest_length_change(&[1.0], &written).unwrap_err().to_string();
        assert!(e.contains("2 strands written for an input of 1"), "{e}");
        assert!((largest_length_change(&[1.0, 1.0], &written).unwrap() - 1.0).abs() < 1e-12);
    }
}
