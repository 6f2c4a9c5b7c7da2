//! What the groom jobs share: writing a groom and its preview, frame
//! patterns, and the checks an artist would make on the result.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use nst3d_core::Image;
use nst3d_io::groom::{write_ply_strands, write_usda_curves, Groom};
use nst3d_io::image::{luminance_rgb, resize_to_height, side_by_side, write_png};
use nst3d_io::mesh::TriMesh;
use nst3d_sequence::expand_pattern;
use nst3d_strands::pipeline::{max_length_change, polyline_length, StrandScene};
use nst3d_strands::{FlatStrands, MeshBvh};

use crate::settings::OutFormat;

pub use nst3d_io::image::PREVIEW_HEIGHT;

/// Writes `strands` to `path` in `format`, atomically.
pub fn write_groom(path: &Path, format: OutFormat, strands: &FlatStrands) -> Result<()> {
    let g = strands.to_groom();
    match format {
        OutFormat::Usda => write_usda_curves(path, &g)?,
        OutFormat::Ply => write_ply_strands(path, &g)?,
    }
    Ok(())
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
        let vs_input = (0..written.strand_count())
            .map(|s| ((polyline_length(written.strand(s)) - input_lengths[s]) / input_lengths[s].max(1e-30)).abs())
            .fold(0.0f64, f64::max);
        let rest_guides =
            FlatStrands { points: scene.rest.points[..guides.points.len()].to_vec(), offsets: guides.offsets.clone() };
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

/// Path `pattern` at `frame` (clear error without a placeholder).
pub fn frame_path(pattern: &Path, frame: i64, what: &str) -> Result<PathBuf> {
    let text = pattern.to_str().with_context(|| format!("{what} {} is not valid UTF-8", pattern.display()))?;
    Ok(PathBuf::from(expand_pattern(text, frame).with_context(|| format!("{what} with --frames"))?))
}

/// Whether `path` names a frame pattern rather than one file.
pub fn is_pattern(path: &Path) -> bool {
    path.to_str().is_some_and(|p| expand_pattern(p, 0).is_ok())
}
