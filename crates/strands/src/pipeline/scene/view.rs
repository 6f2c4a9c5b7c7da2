//! How a groom file looks from the stylization's cameras without a
//! stylization: `nst3d preview` of a groom.

use nst3d_core::math::{add, scale, V3};
use nst3d_core::mesh::TriMesh;
use nst3d_core::Image;
use nst3d_splat::{render, SplatCamera, StrandStyle, Strands};

use super::{growth_directions, shell};
use crate::bvh::MeshBvh;
use crate::pipeline::views::{view_frame, ViewFrame};
use crate::pipeline::{PipelineError, StylizeParams};
use crate::strands::FlatStrands;

/// How a groom file looks from the stylization's cameras, without setting
/// up a stylization (no proxies, no fitting): `nst3d preview` of a groom.
#[derive(Clone, Debug)]
pub struct GroomView {
    /// The cameras' frame.
    pub frame: ViewFrame,
    /// Eye distance from the centre.
    pub distance: f32,
    /// Vertical field of view, degrees.
    pub fov_deg: f32,
    /// Look of the strands at `render_size`.
    pub style: StrandStyle,
    /// The size `style`'s strand width is given for.
    pub render_size: usize,
    /// Scalp normal at every root (culling), when there is a mesh.
    pub root_normals: Option<Vec<V3>>,
}

impl GroomView {
    /// The view of `strands` (growing from `head`, if given) with the
    /// shell and look `params` would stylize it with.
    pub fn new(strands: &FlatStrands, head: Option<&TriMesh>, params: &StylizeParams) -> Result<Self, PipelineError> {
        let root_normals = match head {
            Some(h) => {
                let bvh = MeshBvh::new(h)?;
                Some(strands.roots().iter().map(|&r| bvh.closest_point(r).normal).collect::<Vec<V3>>())
            }
            None => None,
        };
        let growth = growth_directions(strands, strands.strand_count());
        let frame = view_frame(strands, root_normals.as_deref().unwrap_or(&growth), head)?;
        let (distance, fov_deg, style) = shell(&frame, params);
        Ok(GroomView { frame, distance, fov_deg, style, render_size: params.render_size, root_normals })
    }

    /// Grey render of `strands` (the layout the view was made for, or any
    /// groom when there are no root normals) from polar `ψ` / azimuth `δ`
    /// (degrees) at `size²` pixels; strands keep their width relative to the
    /// picture.
    pub fn render(
        &self,
        strands: &FlatStrands,
        polar_deg: f32,
        azimuth_deg: f32,
        size: usize,
    ) -> Result<Image, PipelineError> {
        self.render_colored(strands, None, polar_deg, azimuth_deg, size)
    }

    /// [`GroomView::render`] in `colors`, one per point of `strands` (a
    /// file's own colours); `None` draws white strands.
    pub fn render_colored(
        &self,
        strands: &FlatStrands,
        colors: Option<&[[f32; 3]]>,
        polar_deg: f32,
        azimuth_deg: f32,
        size: usize,
    ) -> Result<Image, PipelineError> {
        let eye = add(self.frame.centre, scale(self.frame.direction(polar_deg, azimuth_deg), self.distance));
        let cam = SplatCamera::look_at(eye, self.frame.centre, self.frame.up, self.fov_deg, size, size)?;
        let style = StrandStyle { width: self.style.width * self.render_size as f32 / size as f32, ..self.style };
        let normals = self.root_normals.as_deref().filter(|n| n.len() == strands.strand_count());
        let s = Strands { points: &strands.points, offsets: &strands.offsets, colors, root_normals: normals };
        Ok(render(&s, &cam, &style)?.0)
    }
}
