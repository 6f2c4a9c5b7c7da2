//! Which axis of a file points up. Houdini, Maya, USD's default and the
//! hair formats of the literature (cyHair, USC-HairSalon) are y-up; Blender
//! is z-up. The pipelines work y-up and turn a z-up input into that frame
//! and back with [`UpAxis::to_y_up`] / [`UpAxis::from_y_up`]: a quarter turn
//! about +x, which only swaps and negates coordinates, so the round trip is
//! exact to the bit and a z-up file and its y-up copy stylize identically.

use crate::math::V3;

/// Which index or world axis points up in a file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum UpAxis {
    /// Houdini, Maya, USD's default: +y up, characters face +z.
    Y,
    /// Blender, the OpenUSD volume sample: +z up, characters face −y.
    Z,
}

crate::named_enum!(UpAxis, "an up axis", { Y => "y", Z => "z" });

impl UpAxis {
    /// A point or direction of the file in the y-up frame: for z-up,
    /// `(x, y, z) ↦ (x, z, −y)` (Blender's front, −y, becomes +z).
    pub fn to_y_up(self, p: V3) -> V3 {
        match self {
            UpAxis::Y => p,
            UpAxis::Z => [p[0], p[2], -p[1]],
        }
    }

    /// The inverse of [`UpAxis::to_y_up`]: a y-up point back in the file's axes.
    pub fn from_y_up(self, p: V3) -> V3 {
        match self {
            UpAxis::Y => p,
            UpAxis::Z => [p[0], -p[2], p[1]],
        }
    }

    /// The axis a USD layer's `upAxis` names (`"Y"` or `"Z"`).
    pub fn from_usd(name: &str) -> Option<Self> {
        match name {
            "Y" => Some(UpAxis::Y),
            "Z" => Some(UpAxis::Z),
            _ => None,
        }
    }

    /// The name a USD layer's `upAxis` takes.
    pub fn usd_name(self) -> &'static str {
        match self {
            UpAxis::Y => "Y",
            UpAxis::Z => "Z",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn z_up_turns_into_y_up_and_back_exactly() {
        let p = [0.1f32, -2.5e-3, 7.0e5];
        for up in [UpAxis::Y, UpAxis::Z] {
            assert_eq!(up.from_y_up(up.to_y_up(p)), p);
            assert_eq!(up.to_y_up(up.from_y_up(p)), p);
        }
        // Blender's up and front become the y-up frame's.
        assert_eq!(UpAxis::Z.to_y_up([0.0, 0.0, 1.0]), [0.0, 1.0, 0.0]);
        assert_eq!(UpAxis::Z.to_y_up([0.0, -1.0, 0.0]), [0.0, 0.0, 1.0]);
        // A rotation, not a mirror: x × y = z survives.
        let (x, y) = (UpAxis::Z.to_y_up([1.0, 0.0, 0.0]), UpAxis::Z.to_y_up([0.0, 1.0, 0.0]));
        assert_eq!(crate::math::cross(x, y), UpAxis::Z.to_y_up([0.0, 0.0, 1.0]));
        assert_eq!(UpAxis::from_usd("Z"), Some(UpAxis::Z));
        assert_eq!(UpAxis::from_usd("X"), None);
    }
}
