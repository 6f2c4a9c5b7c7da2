//! nst3d's volume jobs, each one library call from files to files:
//!
//! - [`stylize`]: one OpenVDB frame ([`stylize_frame_file`], paper Sec. 3)
//!   or a whole simulation with the EMA of Algorithm 1
//!   ([`stylize_sequence_files`], Sec. 3.2), chunked for a farm;
//! - [`judge`]: how much closer to a painting a file is than a baseline,
//!   from held-out cameras, grey and in colour;
//! - [`preview`]: pictures of smoke drawn by the same transmittance renderer.
//!
//! A front end fills a [`VolumeSettings`] (or [`PreviewSettings`]) once,
//! passes a [`Reporter`] for progress and messages, and gets a typed report
//! back; errors are `anyhow` chains whose messages, joined, make the one
//! line a user sees. The numerical stages live in their own crates
//! (`stylize`, `render`, `features`, `loss`, `sequence`); this crate turns
//! files, grids and camera sets into their inputs and their results back
//! into files.

#![warn(missing_docs)]

pub mod cameras;
pub mod dense;
pub mod feedforward;
pub mod frame;
pub mod judge;
pub mod judge_map;
pub mod look;
pub mod map_preview;
pub mod output;
pub mod preview;
pub mod seam;
pub mod sequence;
mod sequence_map;
pub mod settings;
pub mod simulation;
pub mod style;
pub mod style_map;
pub mod summary;
pub mod upsample;

pub use cameras::{front_camera, turntable, CameraSet, Cameras, Lens};
pub use feedforward::{stylize_with_model, LoadedModel, ModelReport};
pub use frame::{stylize_frame_file, stylize_grid, FrameReport, StylizedGrid};
pub use judge::{judge, JudgeSettings, Ratios, Verdict};
pub use judge_map::{judge_map, MapVerdict};
pub use look::{HeldOut, PREVIEW_HEIGHT};
pub use nst3d_core::{Reporter, Silent};
pub use preview::{preview, PreviewReport, PreviewSettings};
pub use seam::{Seam, SeamSummary};
pub use sequence::{flicker_of_outputs, stylize_sequence_files, SequenceReport, SequenceSummary};
pub use settings::{ModelSettings, SequenceSettings, UpAxis, VolumeSettings};
pub use upsample::Upsample;

/// What a volume job did: one frame, or a sequence.
#[derive(Clone, Debug)]
pub enum VolumeReport {
    /// A single frame was stylized.
    Frame(FrameReport),
    /// A sequence (or chunk) was stylized, or had nothing left to do.
    Sequence(SequenceReport),
    /// Frames were stylized by a trained network.
    Model(ModelReport),
}

/// Runs the volume job `settings` describes: with a trained model when it
/// has [`VolumeSettings::model`], else a sequence when it has
/// [`VolumeSettings::sequence`], else one frame.
pub fn stylize(settings: &VolumeSettings, reporter: &mut dyn Reporter) -> anyhow::Result<VolumeReport> {
    check_outputs(settings)?;
    Ok(match (&settings.model, &settings.sequence) {
        (Some(m), _) => VolumeReport::Model(stylize_with_model(settings, m, reporter)?),
        (None, Some(_)) => VolumeReport::Sequence(stylize_sequence_files(settings, reporter)?),
        (None, None) => VolumeReport::Frame(stylize_frame_file(settings, reporter)?),
    })
}

/// The outputs checked before any work (`io::atomic::check_output`): a
/// `.vdb` that is not the input and whose folder takes a file (for a
/// sequence, the first frame's), and a `.png` preview.
fn check_outputs(s: &VolumeSettings) -> anyhow::Result<()> {
    use nst3d_io::atomic::check_output;
    use std::path::PathBuf;
    let (input, out) = match &s.sequence {
        Some(q) => {
            let f = nst3d_job::FrameSpec::parse(&q.frames)?.frames()[0];
            let at = |p: &std::path::Path| -> anyhow::Result<PathBuf> {
                Ok(PathBuf::from(nst3d_job::expand_pattern(&p.to_string_lossy(), f)?))
            };
            if s.input == s.out {
                anyhow::bail!("--out {} is the input pattern: nst3d never overwrites its input", s.out.display());
            }
            (at(&s.input)?, at(&s.out)?)
        }
        None => (s.input.clone(), s.out.clone()),
    };
    check_output("--out", &out, &["vdb"], &[&input]).map_err(anyhow::Error::msg)?;
    if let Some(p) = &s.preview {
        check_output("--preview", p, &["png"], &[]).map_err(anyhow::Error::msg)?;
    }
    Ok(())
}
