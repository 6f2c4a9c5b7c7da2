//! A style map over a sequence: each frame's regions are read from that
//! frame, so a simulation's own field (a grid of each frame's file, such
//! as its temperature), a map file per frame (`FILE.vdb:NAME` with FILE a
//! frame pattern) or one map file for all frames places the paintings
//! where that frame's smoke is. `@height` spans the box every frame shares,
//! so a height ramp is fixed in the world and does not slide as the smoke
//! grows. The regions then ride the EMA's fields like the density does
//! ([`nst3d_sequence::ema::Paintings`]).

use std::path::PathBuf;

use anyhow::{Context, Result};
use nst3d_core::{Grid3, UpAxis};
use nst3d_io::vdb::{read_vdb, Transform};
use nst3d_sequence::ema::{SequenceError, Simulation};

use crate::settings::VolumeSettings;
use crate::style_map::{regions, sample, MapBox, MapSource};

/// Where a sequence's frames are stylized: the common box in fine voxels.
pub(crate) struct ShotBox {
    /// Voxels of the common box (margin included).
    pub dims: [usize; 3],
    /// Index of its voxel (0,0,0).
    pub origin: [i32; 3],
    /// Its (refined) index-to-world transform.
    pub transform: Transform,
    /// The frames' smoke inside it (the union of their active boxes):
    /// offset and size in voxels.
    pub inner: ([usize; 3], [usize; 3]),
}

/// The style map of every optimised frame of a sequence.
pub(crate) struct FrameMaps {
    source: MapSource,
    labels: bool,
    paintings: usize,
    /// Frame number and input file of each optimised frame.
    frames: Vec<(i64, PathBuf)>,
    at: ShotBox,
    up: UpAxis,
}

impl FrameMaps {
    /// The map of `s.style_map` for `frames` (number and input file of
    /// each optimised frame of `sim`) in the box `at`, every frame's read
    /// and checked against its smoke before any slow work, so a grid
    /// missing from one frame fails the job up front; `None` without a map.
    pub fn checked(
        s: &VolumeSettings,
        frames: Vec<(i64, PathBuf)>,
        at: ShotBox,
        sim: &dyn Simulation,
    ) -> Result<Option<Self>> {
        let Some(spec) = &s.style_map else { return Ok(None) };
        let source = MapSource::parse(spec)?;
        let labels = source.labels(s.style_map_labels);
        let maps = Self { source, labels, paintings: s.styles().len(), frames, at, up: s.up };
        for t in 0..maps.frames.len() {
            maps.regions(t, &sim.density(t)?)?;
        }
        Ok(Some(maps))
    }

    /// Frame `t`'s region weights over the box, one grid per painting,
    /// given its density there (labels are checked where there is smoke).
    pub fn regions(&self, t: usize, density: &Grid3) -> Result<Vec<Grid3>> {
        let (frame, input) = &self.frames[t];
        let source = self.source.at_frame(*frame)?;
        let file = match source {
            MapSource::Input(_) => Some(read_vdb(input)?),
            _ => None,
        };
        let b = &self.at;
        let at = MapBox { dims: b.dims, origin: b.origin, transform: &b.transform, inner: b.inner, up: self.up };
        let map = sample(&source, file.as_ref().map(|f| (f, input.as_path())), &at, self.labels)
            .with_context(|| format!("frame {frame}"))?;
        regions(&map, density, self.paintings, self.labels).with_context(|| format!("frame {frame}"))
    }

    /// [`FrameMaps::regions`] for the sweeps ([`nst3d_sequence::ema::RegionsOf`]).
    pub fn sweep_regions(&self, t: usize, density: &Grid3) -> Result<Vec<Grid3>, SequenceError> {
        self.regions(t, density).map_err(|e| SequenceError::Frame { frame: t, message: format!("{e:#}") })
    }
}
