//! Text USD (`.usda`) `BasisCurves`: a small reader for the subset grooms
//! use and a writer of one clean curves layer.
//!
//! The reader parses the whole layer (prims, attributes, metadata, time
//! samples) and gathers every *defined* `BasisCurves` prim in file order
//! (`def` specifiers only: `over`/`class` subtrees and prims with
//! `active = false` are not drawn by USD either, so they are skipped).
//! Per prim: `curveVertexCounts` and `points` (required), `widths` or
//! `primvars:widths` and `primvars:displayColor` with their `interpolation`
//! (constant, uniform, varying, vertex), expanded to one value per point.
//! [`read_usda_curves_file`](crate::groom::read_usda_curves_file) also keeps every other `primvars:*` attribute
//! of those prims as text ([`UsdPrimvars`], see [`mod@primvars`]) for the
//! writer to put back unchanged. When an attribute only has
//! `.timeSamples`, the earliest sample is used. Transforms: the
//! `xformOpOrder` of the prim and all its ancestors is applied, with
//! translate, scale, rotateX/Y/Z, rotateXYZ (and the other five orders),
//! orient and transform ops, `!resetXformStack!`, and `!invert!` on
//! translate (the pivot idiom). Other inverted ops are refused as
//! unsupported rather than silently ignored. Widths are not scaled by the
//! transform. Sublayers, references and payloads are followed by
//! `super::usd`; not read: inherits, specializes, `variantSet` blocks
//! (skipped), normals. `upAxis` and
//! `metersPerUnit` are not applied (points are returned in the layer's own
//! axes and units); [`read_usda_curves_file`](crate::groom::read_usda_curves_file) reports them so the writer
//! can declare the same.
//! `type`, `basis` and `wrap` only matter for mapping `varying` primvars;
//! the points are kept as the prim's control points whatever the basis.
//!
//! One file per job: [`lexer`] splits the text into tokens, [`parse`] builds
//! the prim tree, [`xform`] turns `xformOp`s into matrices, [`curves`] walks
//! the tree into strands, [`mod@primvars`] gathers the other primvars
//! ([`strand_values`] reads one of them as a number per strand), and
//! [`mod@write`] writes a layer. Reading a whole stage (one layer in any of
//! USD's forms and the layers it points to) is `super::usd`'s job.

pub(crate) mod curves;
mod lexer;
pub(crate) mod parse;
pub(crate) mod primvars;
mod strand_values;
pub(crate) mod write;
pub(crate) mod xform;

pub use primvars::{UsdPrimvar, UsdPrimvars};
pub use write::{write_usda_curves, write_usda_curves_with};
