//! The checks an artist would make on a stylized groom: how much each
//! strand's length changed, and whether points went inside the mesh.

use anyhow::{bail, Result};
use nst3d_io::groom::Groom;
use nst3d_io::mesh::TriMesh;
use nst3d_strands::pipeline::{max_length_change, polyline_length, StrandScene};
use nst3d_strands::{FlatStrands, MeshBvh};

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
        let written =
            FlatStrands { points: vec![[0.0; 3], [0.0, 2.0, 0.0], [0.0; 3], [0.0, 1.0, 0.0]], offsets: vec![0, 2, 4] };
        let e = largest_length_change(&[1.0], &written).unwrap_err().to_string();
        assert!(e.contains("2 strands written for an input of 1"), "{e}");
        assert!((largest_length_change(&[1.0, 1.0], &written).unwrap() - 1.0).abs() < 1e-12);
    }
}
