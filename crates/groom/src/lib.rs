//! nst3d's groom jobs, each one library call from files to files:
//!
//! - [`stylize_groom_file`]: one groom (strand style transfer paper, Alg. 1);
//! - [`stylize_groom_sequence`]: an animated groom with the EMA and 1€
//!   filter of Sec. 3.3, resumable after a kill;
//! - [`generate`]: the procedural fur ball and grass patch of Table 1;
//! - [`bench::strands_iter`]: the `strands-iter` benchmark's work.
//!
//! A front end fills a [`StrandSettings`] (or [`GenerateSettings`]) once,
//! passes a [`Reporter`] for progress and messages, and gets a typed report
//! back. The paper's stages live in `nst3d-strands` (deformation field,
//! densification, constraints, the stylization loop), the renderer in
//! `nst3d-splat`, the loss in `nst3d-loss`; this crate reads the groom and
//! its mesh, runs them, and writes the result in the input's topology.

#![warn(missing_docs)]

pub mod axis;
pub mod bench;
pub mod checks;
pub mod generate;
pub mod judge;
pub mod output;
pub mod preview;
pub mod sequence;
pub mod settings;
pub mod single;
pub mod style_map;
pub mod summary;

pub use checks::Checks;
pub use generate::{generate, GenerateKind, GenerateReport, GenerateSettings};
pub use nst3d_core::{Reporter, Silent, UpAxis};
pub use output::is_groom_file;
pub use preview::{preview_groom, GroomPreviewReport, GroomPreviewSettings, PREVIEW_HEIGHT};
pub use sequence::{stylize_groom_sequence, GroomSequenceReport, STATE_FILE};
pub use settings::{OutFormat, StrandSettings, Temporal};
pub use single::{stylize_groom, stylize_groom_file, GroomReport, StylizedGroom};

/// Said once on stderr when a groom comes without its mesh.
pub(crate) const NO_MESH: &str =
    "no --mesh: strands are not kept out of a head (no collision handling) and all are drawn (no visibility culling)";
