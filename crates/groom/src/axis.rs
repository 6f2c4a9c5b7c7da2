//! The up axis of a groom job. The strand pipeline works y-up (its cameras
//! circle +y, its previews stand on it); a z-up groom — everything Blender
//! writes — and its mesh are turned into that frame before the work and the
//! result is turned back before it is written, so the file keeps its axis.
//! The turn only swaps and negates coordinates ([`UpAxis::to_y_up`]): a
//! z-up groom and its y-up copy stylize to the same bits.

use std::borrow::Cow;

use nst3d_core::{Groom, TriMesh, UpAxis};
use nst3d_io::groom::GroomFile;
use nst3d_strands::FlatStrands;

/// The axis a job on `input` runs with: `flag` when given (`--up`), else
/// the USD layer's `upAxis`, else y (USD's default, and the hair formats'
/// cyHair, USC-HairSalon). The note says when the flag overrides the layer.
pub fn resolve(flag: Option<UpAxis>, input: &GroomFile) -> (UpAxis, Option<String>) {
    let layer = input.usd_primvars.up_axis.as_deref().and_then(UpAxis::from_usd);
    match (flag, layer) {
        (Some(f), Some(l)) if f != l => {
            (f, Some(format!("the layer says upAxis = \"{}\"; --up {f} overrides it", l.usd_name())))
        }
        (Some(f), _) => (f, None),
        (None, l) => (l.unwrap_or(UpAxis::Y), None),
    }
}

/// `groom` in the y-up frame (borrowed when it already is).
pub fn groom_to_y_up(groom: &Groom, up: UpAxis) -> Cow<'_, Groom> {
    if up == UpAxis::Y {
        return Cow::Borrowed(groom);
    }
    let mut g = groom.clone();
    for s in &mut g.strands {
        s.points.iter_mut().for_each(|p| *p = up.to_y_up(*p));
    }
    Cow::Owned(g)
}

/// `mesh` (vertices and normals) in the y-up frame.
pub fn mesh_to_y_up(mesh: &TriMesh, up: UpAxis) -> Cow<'_, TriMesh> {
    if up == UpAxis::Y {
        return Cow::Borrowed(mesh);
    }
    let mut m = mesh.clone();
    m.vertices.iter_mut().for_each(|p| *p = up.to_y_up(*p));
    if let Some(n) = &mut m.normals {
        n.iter_mut().for_each(|p| *p = up.to_y_up(*p));
    }
    Cow::Owned(m)
}

/// Strands of the y-up frame back in the file's axes.
pub fn strands_from_y_up(mut strands: FlatStrands, up: UpAxis) -> FlatStrands {
    if up != UpAxis::Y {
        strands.points.iter_mut().for_each(|p| *p = up.from_y_up(*p));
    }
    strands
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::Strand;

    #[test]
    fn a_z_up_groom_goes_to_y_up_and_back_to_the_bit() {
        let g = Groom { strands: vec![Strand::new(vec![[0.1, 0.2, 0.3], [0.1, -0.7, 1.3e-3]])] };
        let y = groom_to_y_up(&g, UpAxis::Z);
        assert_eq!(y.strands[0].points[0], [0.1, 0.3, -0.2], "z becomes y, y becomes -z");
        let back = strands_from_y_up(FlatStrands::from_groom(&y).unwrap(), UpAxis::Z);
        assert_eq!(back, FlatStrands::from_groom(&g).unwrap());
        assert!(matches!(groom_to_y_up(&g, UpAxis::Y), Cow::Borrowed(_)));
    }

    #[test]
    fn the_flag_wins_over_the_layer_and_says_so() {
        let mut input = GroomFile::default();
        assert_eq!(resolve(None, &input), (UpAxis::Y, None));
        assert_eq!(resolve(Some(UpAxis::Z), &input), (UpAxis::Z, None));
        input.usd_primvars.up_axis = Some("Z".into());
        assert_eq!(resolve(None, &input), (UpAxis::Z, None));
        assert_eq!(resolve(Some(UpAxis::Z), &input), (UpAxis::Z, None));
        let (up, note) = resolve(Some(UpAxis::Y), &input);
        assert_eq!(up, UpAxis::Y);
        assert!(note.unwrap().contains("overrides"));
    }
}
