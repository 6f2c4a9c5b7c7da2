//! A [`SequenceStylizer`]'s state between frames, so a farm task killed in
//! the middle of an animated groom resumes after its last finished frame
//! instead of starting over (each frame depends on the one before: the EMA
//! blends towards its field and the 1€ filter towards its output).
//!
//! The state is what [`SequenceStylizer::stylize_frame`] carries forward:
//! the first frame's topology and locked cameras, the previous frame's
//! samples, optimized velocities, undeformed and output strands and flicker
//! renders, the 1€ filter's history, and the running sums of the report.
//! It is kept in the jobs' one state format ([`nst3d_job::State`]), every
//! number bit for bit (`f32`, `f64` and `u64` arrays), so a resumed run
//! continues exactly as the uninterrupted one would:
//!
//! * `topology` (`u64`), when a frame was seen;
//! * `view` (26 `f32`: centre, radius, front, up, side, distance, field of
//!   view, the strand look) and the metadata `view.output`, once locked;
//! * `previous.samples`, `previous.velocities` (`[n, 3]`),
//!   `previous.undeformed.points`, `previous.output.points` (`[p, 3]`) with
//!   their `.offsets` (`u64`), `previous.render_output`,
//!   `previous.render_input` (`[c, h, w]`), after the first frame;
//! * `one_euro.x`, `one_euro.d` (`[n, 3]`), the filter's history;
//! * `sums` (4 `f64`), `flicker_sums` (3 `f64`) and the metadata `frames`
//!   and `pairs`.
//!
//! The caller's own numbers (frames of its list done, ...) ride along as
//! more metadata of the same state.

use nst3d_core::Image;
use nst3d_job::state::Problem;
use nst3d_job::State;
use nst3d_splat::{SplatOutput, StrandStyle};

use super::{LockedView, Previous, SequenceError, SequenceStylizer};
use crate::pipeline::ViewFrame;
use crate::strands::FlatStrands;
use crate::temporal::OneEuroHistory;
use nst3d_core::math::V3;

fn corrupt(e: Problem) -> SequenceError {
    SequenceError::State(format!("saved sequence state {e}"))
}

fn bad(what: &str) -> SequenceError {
    corrupt(Problem::Corrupt(what.to_string()))
}

fn put_v3s<'a>(st: &mut State<'a>, name: &str, xs: &'a [V3]) {
    st.put_f32(name, &[xs.len(), 3], xs.as_flattened());
}

fn put_strands<'a>(st: &mut State<'a>, name: &str, s: &'a FlatStrands) {
    put_v3s(st, &format!("{name}.points"), &s.points);
    let offsets: Vec<u64> = s.offsets.iter().map(|&o| o as u64).collect();
    st.put_u64(&format!("{name}.offsets"), &[offsets.len()], offsets);
}

fn put_image<'a>(st: &mut State<'a>, name: &str, img: &'a Image) {
    st.put_f32(name, &[img.channels, img.height, img.width], &img.data[..]);
}

fn v3s(st: &State<'_>, name: &str) -> Result<Vec<V3>, SequenceError> {
    match st.f32s(name).map_err(corrupt)? {
        (&[n, 3], data) if data.len() == 3 * n => Ok(data.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()),
        _ => Err(bad(name)),
    }
}

fn usizes(st: &State<'_>, name: &str) -> Result<Vec<usize>, SequenceError> {
    let (_, data) = st.u64s(name).map_err(corrupt)?;
    data.iter().map(|&x| usize::try_from(x).map_err(|_| bad(name))).collect()
}

fn strands(st: &State<'_>, name: &str) -> Result<FlatStrands, SequenceError> {
    let points = v3s(st, &format!("{name}.points"))?;
    let offsets = usizes(st, &format!("{name}.offsets"))?;
    let ok = offsets.first() == Some(&0)
        && offsets.last() == Some(&points.len())
        && offsets.windows(2).all(|w| w[0] <= w[1]);
    if !ok {
        return Err(bad(name));
    }
    Ok(FlatStrands { points, offsets })
}

fn image(st: &State<'_>, name: &str) -> Result<Image, SequenceError> {
    match st.f32s(name).map_err(corrupt)? {
        (&[c, h, w], data) => Ok(Image::from_vec(c, h, w, data.to_vec())),
        _ => Err(bad(name)),
    }
}

/// The 26 numbers of a locked view: its frame, distance and field of view,
/// then the strand look (the output kind is metadata).
fn view_numbers(v: &LockedView) -> Vec<f32> {
    let f = &v.frame;
    let s = &v.style;
    let mut out: Vec<f32> =
        f.centre.iter().chain([&f.radius]).chain(&f.front).chain(&f.up).chain(&f.side).copied().collect();
    out.extend([v.distance, v.fov_deg]);
    out.extend([s.width, s.length_sigma, s.root_shade, s.tip_shade, s.root_opacity, s.tip_opacity]);
    out.extend(s.background);
    out.extend([s.visibility_threshold, s.dilation]);
    out
}

fn view(st: &State<'_>) -> Result<Option<LockedView>, SequenceError> {
    if !st.has("view") {
        return Ok(None);
    }
    let (_, x) = st.f32s("view").map_err(corrupt)?;
    let output = match st.text("view.output") {
        Some("grey_alpha") => SplatOutput::GreyAlpha,
        Some("rgb") => SplatOutput::Rgb,
        _ => return Err(bad("view.output")),
    };
    let &[c0, c1, c2, radius, f0, f1, f2, u0, u1, u2, s0, s1, s2, distance, fov_deg, ref look @ ..] = x else {
        return Err(bad("view"));
    };
    let &[width, length_sigma, root_shade, tip_shade, root_opacity, tip_opacity, b0, b1, b2, visibility_threshold, dilation] =
        look
    else {
        return Err(bad("view"));
    };
    let style = StrandStyle {
        width,
        length_sigma,
        root_shade,
        tip_shade,
        root_opacity,
        tip_opacity,
        background: [b0, b1, b2],
        visibility_threshold,
        dilation,
        output,
    };
    let frame = ViewFrame { centre: [c0, c1, c2], radius, front: [f0, f1, f2], up: [u0, u1, u2], side: [s0, s1, s2] };
    Ok(Some(LockedView { frame, distance, fov_deg, style }))
}

fn previous(st: &State<'_>) -> Result<Option<Previous>, SequenceError> {
    if !st.has("previous.samples") {
        return Ok(None);
    }
    let p = Previous {
        samples: v3s(st, "previous.samples")?,
        velocities: v3s(st, "previous.velocities")?,
        undeformed: strands(st, "previous.undeformed")?,
        output: strands(st, "previous.output")?,
        render_output: image(st, "previous.render_output")?,
        render_input: image(st, "previous.render_input")?,
    };
    // What the next frame reads side by side must be of one size; the
    // next frame checks the rest against its own groom.
    let images = |i: &Image| (i.channels, i.height, i.width);
    if p.velocities.len() != p.samples.len()
        || p.output.offsets != p.undeformed.offsets
        || images(&p.render_output) != images(&p.render_input)
    {
        return Err(bad("previous frame"));
    }
    Ok(Some(p))
}

fn sums<const N: usize>(st: &State<'_>, name: &str) -> Result<[f64; N], SequenceError> {
    st.f64s(name).map_err(corrupt)?.1.try_into().map_err(|_| bad(name))
}

impl SequenceStylizer<'_> {
    /// Puts the state after the frames stylized so far into `st` (arrays
    /// borrowed from the stylizer), for [`SequenceStylizer::restore_state`].
    /// The settings are not saved: the caller restores into a stylizer made
    /// with the same ones, and adds its own numbers to `st`.
    pub fn save_state<'s>(&'s self, st: &mut State<'s>) {
        if let Some(t) = &self.topology {
            st.put_u64("topology", &[t.len()], t.iter().map(|&x| x as u64).collect::<Vec<_>>());
        }
        if let Some(v) = &self.view {
            st.put_f32("view", &[26], view_numbers(v));
            st.set("view.output", if matches!(v.style.output, SplatOutput::GreyAlpha) { "grey_alpha" } else { "rgb" });
        }
        if let Some(p) = &self.previous {
            put_v3s(st, "previous.samples", &p.samples);
            put_v3s(st, "previous.velocities", &p.velocities);
            put_strands(st, "previous.undeformed", &p.undeformed);
            put_strands(st, "previous.output", &p.output);
            put_image(st, "previous.render_output", &p.render_output);
            put_image(st, "previous.render_input", &p.render_input);
        }
        if let Some((x, d)) = self.filter.history() {
            put_v3s(st, "one_euro.x", x);
            put_v3s(st, "one_euro.d", d);
        }
        st.put_f64("sums", &[4], &self.sums[..]);
        st.put_f64("flicker_sums", &[3], &self.flicker_sums[..]);
        st.set("frames", self.frames);
        st.set("pairs", self.pairs);
    }

    /// Puts back a state from [`SequenceStylizer::save_state`]; the next
    /// [`SequenceStylizer::stylize_frame`] continues as if this stylizer
    /// had run the saved frames. A state that lacks a part, or whose parts
    /// disagree, is an error and leaves the stylizer as it was.
    pub fn restore_state(&mut self, st: &State<'_>) -> Result<(), SequenceError> {
        let SavedState { topology, view, previous, history, sums, flicker_sums, frames, pairs } =
            SavedState::parse(st)?;
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
        Ok(())
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
}

impl SavedState {
    /// Reads what [`SequenceStylizer::save_state`] put into a state: a
    /// missing part, or parts that disagree in size, are errors. Needs no
    /// stylizer, so the fuzz harness calls it directly.
    pub fn parse(st: &State<'_>) -> Result<SavedState, SequenceError> {
        let topology = if st.has("topology") { Some(usizes(st, "topology")?) } else { None };
        let history = match st.has("one_euro.x") {
            true => Some((v3s(st, "one_euro.x")?, v3s(st, "one_euro.d")?)),
            false => None,
        };
        if history.as_ref().is_some_and(|(x, d)| x.len() != d.len()) {
            return Err(bad("1€ history"));
        }
        Ok(SavedState {
            topology,
            view: view(st)?,
            previous: previous(st)?,
            history,
            sums: sums(st, "sums")?,
            flicker_sums: sums(st, "flicker_sums")?,
            frames: st.get("frames").map_err(corrupt)?,
            pairs: st.get("pairs").map_err(corrupt)?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_job::JobId;

    fn id() -> JobId {
        JobId { kind: "groom sequence".into(), hash: 3, settings: String::new() }
    }

    /// A state with only a previous frame of `samples` samples and
    /// `velocities` velocities (both strands 1 × 2 points, 3×1×1 renders).
    fn with_previous(samples: usize, velocities: usize) -> State<'static> {
        let mut st = State::new(&id());
        st.put_f32("previous.samples", &[samples, 3], vec![0.0; 3 * samples]);
        st.put_f32("previous.velocities", &[velocities, 3], vec![0.0; 3 * velocities]);
        for part in ["undeformed", "output"] {
            st.put_f32(&format!("previous.{part}.points"), &[2, 3], vec![0.0; 6]);
            st.put_u64(&format!("previous.{part}.offsets"), &[2], vec![0, 2]);
        }
        for part in ["render_output", "render_input"] {
            st.put_f32(&format!("previous.{part}"), &[3, 1, 1], vec![0.5; 3]);
        }
        st.put_f64("sums", &[4], vec![0.0; 4]);
        st.put_f64("flicker_sums", &[3], vec![0.0; 3]);
        st.set("frames", 1);
        st.set("pairs", 0);
        st
    }

    #[test]
    fn parts_that_disagree_in_size_are_refused() {
        assert!(SavedState::parse(&with_previous(3, 3)).is_ok());
        let e = SavedState::parse(&with_previous(3, 2)).err().expect("refused").to_string();
        assert!(e.contains("previous frame"), "{e}");
        let mut no_sums = with_previous(3, 3);
        no_sums.put_f64("sums", &[3], vec![0.0; 3]);
        assert!(SavedState::parse(&no_sums).is_err());
        let mut offsets = with_previous(3, 3);
        offsets.put_u64("previous.output.offsets", &[2], vec![0, 3]);
        assert!(SavedState::parse(&offsets).is_err());
        let mut half_view = with_previous(3, 3);
        half_view.put_f32("view", &[13], vec![0.0; 13]);
        half_view.set("view.output", "rgb");
        assert!(SavedState::parse(&half_view).is_err());
    }
}
