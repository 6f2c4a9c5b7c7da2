//! A [`SequenceStylizer`]'s state between frames as bytes, so a farm task
//! killed in the middle of an animated groom resumes after its last finished
//! frame instead of starting over (each frame depends on the one before:
//! the EMA blends towards its field and the 1€ filter towards its output).
//!
//! The state is what [`SequenceStylizer::stylize_frame`] carries forward:
//! the first frame's topology and locked cameras, the previous frame's
//! samples, optimized velocities, undeformed and output strands and flicker
//! renders, the 1€ filter's history, and the running sums of the report.
//! Everything is stored bit for bit (little-endian `f32`/`f64`), so a
//! resumed run continues exactly as the uninterrupted one would.
//!
//! Layout: the magic `NST3DSQ1`, then the fields in the order of
//! [`SequenceStylizer::save_state`], each vector as a `u64` length and its
//! elements, each option as a `u8` flag. A caller's own numbers ride along
//! in `extra`.

use nst3d_core::Image;
use nst3d_splat::{SplatOutput, StrandStyle};

use super::{LockedView, Previous, SequenceError, SequenceStylizer};
use crate::pipeline::ViewFrame;
use crate::strands::FlatStrands;
use crate::temporal::OneEuroHistory;
use nst3d_core::math::V3;

/// First bytes of a saved state (format version 1).
const MAGIC: &[u8; 8] = b"NST3DSQ1";

/// Longest vector a state may claim: more than any groom fits in memory,
/// so a corrupt length fails here rather than in an allocation.
const MAX_LEN: u64 = 1 << 32;

#[derive(Default)]
struct Writer(Vec<u8>);

impl Writer {
    fn u64(&mut self, x: u64) {
        self.0.extend_from_slice(&x.to_le_bytes());
    }
    fn f32(&mut self, x: f32) {
        self.0.extend_from_slice(&x.to_le_bytes());
    }
    fn f64(&mut self, x: f64) {
        self.0.extend_from_slice(&x.to_le_bytes());
    }
    fn flag(&mut self, x: bool) {
        self.0.push(x as u8);
    }
    fn f32s(&mut self, xs: &[f32]) {
        self.u64(xs.len() as u64);
        xs.iter().for_each(|&x| self.f32(x));
    }
    fn v3s(&mut self, xs: &[V3]) {
        self.u64(xs.len() as u64);
        xs.iter().flatten().for_each(|&x| self.f32(x));
    }
    fn usizes(&mut self, xs: &[usize]) {
        self.u64(xs.len() as u64);
        xs.iter().for_each(|&x| self.u64(x as u64));
    }
    fn strands(&mut self, s: &FlatStrands) {
        self.v3s(&s.points);
        self.usizes(&s.offsets);
    }
    fn image(&mut self, img: &Image) {
        self.usizes(&[img.channels, img.height, img.width]);
        self.f32s(&img.data);
    }
}

struct Reader<'b> {
    bytes: &'b [u8],
    at: usize,
}

fn corrupt(what: &str) -> SequenceError {
    SequenceError::State(format!("saved sequence state is truncated or corrupt ({what})"))
}

impl<'b> Reader<'b> {
    fn take(&mut self, n: usize, what: &str) -> Result<&'b [u8], SequenceError> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.bytes.len()).ok_or_else(|| corrupt(what))?;
        let s = &self.bytes[self.at..end];
        self.at = end;
        Ok(s)
    }
    fn u64(&mut self, what: &str) -> Result<u64, SequenceError> {
        Ok(u64::from_le_bytes(self.take(8, what)?.try_into().expect("8 bytes")))
    }
    fn f32(&mut self, what: &str) -> Result<f32, SequenceError> {
        Ok(f32::from_le_bytes(self.take(4, what)?.try_into().expect("4 bytes")))
    }
    fn f64(&mut self, what: &str) -> Result<f64, SequenceError> {
        Ok(f64::from_le_bytes(self.take(8, what)?.try_into().expect("8 bytes")))
    }
    fn flag(&mut self, what: &str) -> Result<bool, SequenceError> {
        match self.take(1, what)?[0] {
            0 => Ok(false),
            1 => Ok(true),
            _ => Err(corrupt(what)),
        }
    }
    fn len(&mut self, elem_bytes: usize, what: &str) -> Result<usize, SequenceError> {
        let n = self.u64(what)?;
        // A length the rest of the buffer cannot hold is corruption.
        if n > MAX_LEN || n as usize * elem_bytes > self.bytes.len() - self.at {
            return Err(corrupt(what));
        }
        Ok(n as usize)
    }
    fn f32s(&mut self, what: &str) -> Result<Vec<f32>, SequenceError> {
        let n = self.len(4, what)?;
        (0..n).map(|_| self.f32(what)).collect()
    }
    fn v3s(&mut self, what: &str) -> Result<Vec<V3>, SequenceError> {
        let n = self.len(12, what)?;
        (0..n).map(|_| self.v3(what)).collect()
    }
    fn usizes(&mut self, what: &str) -> Result<Vec<usize>, SequenceError> {
        let n = self.len(8, what)?;
        (0..n).map(|_| Ok(self.u64(what)? as usize)).collect()
    }
    fn strands(&mut self, what: &str) -> Result<FlatStrands, SequenceError> {
        let points = self.v3s(what)?;
        let offsets = self.usizes(what)?;
        let ok = offsets.first() == Some(&0)
            && offsets.last() == Some(&points.len())
            && offsets.windows(2).all(|w| w[0] <= w[1]);
        if !ok {
            return Err(corrupt(what));
        }
        Ok(FlatStrands { points, offsets })
    }
    fn image(&mut self, what: &str) -> Result<Image, SequenceError> {
        let dims = self.usizes(what)?;
        let data = self.f32s(what)?;
        match dims[..] {
            [c, h, w] if c.checked_mul(h).and_then(|x| x.checked_mul(w)) == Some(data.len()) => {
                Ok(Image::from_vec(c, h, w, data))
            }
            _ => Err(corrupt(what)),
        }
    }
    fn v3(&mut self, what: &str) -> Result<V3, SequenceError> {
        Ok([self.f32(what)?, self.f32(what)?, self.f32(what)?])
    }
}

impl SequenceStylizer<'_> {
    /// The state after the frames stylized so far, with the caller's own
    /// numbers `extra` (e.g. how many frames of its list are done), as bytes
    /// for [`SequenceStylizer::restore_state`]. The settings are not saved:
    /// the caller restores into a stylizer made with the same ones.
    pub fn save_state(&self, extra: &[f64]) -> Vec<u8> {
        let mut w = Writer::default();
        w.0.extend_from_slice(MAGIC);
        w.flag(self.topology.is_some());
        if let Some(t) = &self.topology {
            w.usizes(t);
        }
        w.flag(self.view.is_some());
        if let Some(v) = &self.view {
            let f = &v.frame;
            for x in f.centre.iter().chain([&f.radius]).chain(&f.front).chain(&f.up).chain(&f.side) {
                w.f32(*x);
            }
            w.f32(v.distance);
            w.f32(v.fov_deg);
            let s = &v.style;
            for x in [s.width, s.length_sigma, s.root_shade, s.tip_shade, s.root_opacity, s.tip_opacity]
                .iter()
                .chain(&s.background)
                .chain(&[s.visibility_threshold, s.dilation])
            {
                w.f32(*x);
            }
            w.flag(matches!(s.output, SplatOutput::GreyAlpha));
        }
        w.flag(self.previous.is_some());
        if let Some(p) = &self.previous {
            w.v3s(&p.samples);
            w.v3s(&p.velocities);
            w.strands(&p.undeformed);
            w.strands(&p.output);
            w.image(&p.render_output);
            w.image(&p.render_input);
        }
        let history = self.filter.history();
        w.flag(history.is_some());
        if let Some((x, d)) = history {
            w.v3s(x);
            w.v3s(d);
        }
        self.sums.iter().chain(&self.flicker_sums).for_each(|&s| w.f64(s));
        w.u64(self.frames as u64);
        w.u64(self.pairs as u64);
        w.u64(extra.len() as u64);
        extra.iter().for_each(|&x| w.f64(x));
        w.0
    }

    /// Puts back a state from [`SequenceStylizer::save_state`]; the next
    /// [`SequenceStylizer::stylize_frame`] continues as if this stylizer
    /// had run the saved frames. Returns the saved `extra`. A truncated or
    /// foreign buffer is an error and leaves the stylizer as it was.
    pub fn restore_state(&mut self, bytes: &[u8]) -> Result<Vec<f64>, SequenceError> {
        let SavedState { topology, view, previous, history, sums, flicker_sums, frames, pairs, extra } =
            SavedState::parse(bytes)?;
        let mut filter = self.filter.clone();
        filter.set_history(history).map_err(|e| SequenceError::State(e.to_string()))?;
        self.topology = topology;
        self.view = view;
        self.previous = previous;
        self.filter = filter;
        self.sums = sums;
        self.flicker_sums = flicker_sums;
        self.frames = frames;
        self.pairs = pairs;
        Ok(extra)
    }
}

/// A saved state, read and checked but not yet put into a stylizer.
pub struct SavedState {
    topology: Option<Vec<usize>>,
    view: Option<LockedView>,
    previous: Option<Previous>,
    history: Option<OneEuroHistory>,
    sums: [f64; 4],
    flicker_sums: [f64; 3],
    frames: usize,
    pairs: usize,
    extra: Vec<f64>,
}

impl SavedState {
    /// Reads the bytes of [`SequenceStylizer::save_state`]: a truncated or
    /// foreign buffer, a length the buffer cannot hold, or parts that
    /// disagree in size are errors. Needs no stylizer, so the fuzz harness
    /// calls it directly.
    pub fn parse(bytes: &[u8]) -> Result<SavedState, SequenceError> {
        if bytes.len() < MAGIC.len() || &bytes[..MAGIC.len()] != MAGIC {
            return Err(SequenceError::State("not an nst3d strand sequence state (bad magic)".into()));
        }
        let mut r = Reader { bytes, at: MAGIC.len() };
        let topology = if r.flag("topology")? { Some(r.usizes("topology")?) } else { None };
        let view = if r.flag("view")? {
            let (centre, radius) = (r.v3("view")?, r.f32("view")?);
            let (front, up, side) = (r.v3("view")?, r.v3("view")?, r.v3("view")?);
            let (distance, fov_deg) = (r.f32("view")?, r.f32("view")?);
            let mut f = [0.0f32; 11];
            for x in &mut f {
                *x = r.f32("strand look")?;
            }
            let output = if r.flag("strand look")? { SplatOutput::GreyAlpha } else { SplatOutput::Rgb };
            let style = StrandStyle {
                width: f[0],
                length_sigma: f[1],
                root_shade: f[2],
                tip_shade: f[3],
                root_opacity: f[4],
                tip_opacity: f[5],
                background: [f[6], f[7], f[8]],
                visibility_threshold: f[9],
                dilation: f[10],
                output,
            };
            Some(LockedView { frame: ViewFrame { centre, radius, front, up, side }, distance, fov_deg, style })
        } else {
            None
        };
        let previous = if r.flag("previous frame")? {
            Some(Previous {
                samples: r.v3s("samples")?,
                velocities: r.v3s("velocities")?,
                undeformed: r.strands("undeformed strands")?,
                output: r.strands("output strands")?,
                render_output: r.image("output render")?,
                render_input: r.image("input render")?,
            })
        } else {
            None
        };
        let history =
            if r.flag("1€ history")? { Some((r.v3s("1€ history")?, r.v3s("1€ history")?)) } else { None };
        let mut sums = [0.0f64; 4];
        let mut flicker_sums = [0.0f64; 3];
        for s in sums.iter_mut().chain(flicker_sums.iter_mut()) {
            *s = r.f64("report sums")?;
        }
        let (frames, pairs) = (r.u64("frame count")? as usize, r.u64("frame count")? as usize);
        let n = r.len(8, "extra")?;
        let extra = (0..n).map(|_| r.f64("extra")).collect::<Result<Vec<_>, _>>()?;
        if r.at != bytes.len() {
            return Err(corrupt("trailing bytes"));
        }
        // What the next frame reads side by side must be of one size; the
        // next frame checks the rest against its own groom.
        if let Some(p) = &previous {
            let images = |i: &Image| (i.channels, i.height, i.width);
            if p.velocities.len() != p.samples.len()
                || p.output.offsets != p.undeformed.offsets
                || images(&p.render_output) != images(&p.render_input)
            {
                return Err(corrupt("previous frame"));
            }
        }
        if history.as_ref().is_some_and(|(x, d)| x.len() != d.len()) {
            return Err(corrupt("1€ history"));
        }
        Ok(SavedState { topology, view, previous, history, sums, flicker_sums, frames, pairs, extra })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn u64s(xs: &[u64]) -> Vec<u8> {
        xs.iter().flat_map(|x| x.to_le_bytes()).collect()
    }

    /// A state with only a previous frame of `samples` samples and
    /// `velocities` velocities (both strands 1 × 2 points, 1×1×1 renders).
    fn with_previous(samples: u64, velocities: u64) -> Vec<u8> {
        let mut b = MAGIC.to_vec();
        b.extend([0u8, 0, 1]); // no topology, no view, a previous frame
        for n in [samples, velocities] {
            b.extend(u64s(&[n]));
            b.extend(vec![0u8; 12 * n as usize]);
        }
        for _ in 0..2 {
            b.extend(u64s(&[2]));
            b.extend([0u8; 24]);
            b.extend(u64s(&[2, 0, 2]));
        }
        for _ in 0..2 {
            b.extend(u64s(&[3, 1, 1, 1, 1]));
            b.extend(0.5f32.to_le_bytes());
        }
        b.push(0); // no 1€ history
        b.extend([0u8; 7 * 8]);
        b.extend(u64s(&[1, 0, 0]));
        b
    }

    #[test]
    fn parts_that_disagree_in_size_are_refused() {
        assert!(SavedState::parse(&with_previous(3, 3)).is_ok());
        let e = SavedState::parse(&with_previous(3, 2)).err().expect("refused").to_string();
        assert!(e.contains("previous frame"), "{e}");
        let mut trailing = with_previous(3, 3);
        trailing.push(0);
        assert!(SavedState::parse(&trailing).is_err());
    }
}
