//! The lines a front end prints after a volume job: what was stylized, the
//! loss before and after, and (with held-out cameras) the views the
//! optimiser never saw. `nst3d volume` prints them as they are.

use crate::{SequenceReport, VolumeReport};

/// `""` for one, `"s"` for any other count.
pub fn plural(n: usize) -> &'static str {
    if n == 1 {
        ""
    } else {
        "s"
    }
}

impl VolumeReport {
    /// The report's lines; `eval_cameras` names the held-out camera set the
    /// settings asked for (a single frame's `--eval-cameras`).
    pub fn lines(&self, eval_cameras: Option<&str>) -> Vec<String> {
        let mut out = Vec::new();
        match self {
            VolumeReport::Frame(r) => {
                if let Some(h) = &r.held_out {
                    let cams = eval_cameras.unwrap_or("");
                    let (before, after) = h.means();
                    out.push(format!("held-out cameras {cams}: mean style loss {before:.4e} -> {after:.4e}"));
                    let (worst, view) = h.worst();
                    let each: Vec<String> =
                        h.before.iter().zip(&h.after).map(|(b, a)| format!("{b:.4e}->{a:.4e}")).collect();
                    out.push(format!(
                        "held-out cameras {cams}: per view {}; worst view {} of {}, ratio {worst:.3}",
                        each.join(" "),
                        view + 1,
                        h.before.len()
                    ));
                }
                out.push(format!(
                    "{}: grid '{}' {}x{}x{} stylized ({:?} mode, {} camera{}); style loss {:.4e} -> {:.4e} ({:.0}% lower); wrote {}",
                    r.input.display(),
                    r.grid,
                    r.dims[0],
                    r.dims[1],
                    r.dims[2],
                    r.mode,
                    r.cameras,
                    plural(r.cameras),
                    r.loss_before,
                    r.loss_after,
                    100.0 * r.loss_drop(),
                    r.out.display()
                ));
            }
            VolumeReport::Model(r) => out.push(format!(
                "{} frame{} stylized by {} ({:.2} Mvoxels/s of the frames' boxes){}{}; wrote {}",
                r.frames,
                plural(r.frames),
                match r.models {
                    1 => format!("the {:?}-mode model", r.mode),
                    n => format!("{n} {:?}-mode models blended by the style map", r.mode),
                },
                r.voxels as f64 / r.seconds.max(1e-9) / 1e6,
                if r.skipped > 0 { format!(", {} kept or copied unchanged", r.skipped) } else { String::new() },
                r.flicker.map_or(String::new(), |f| format!("; flicker {f:.5}")),
                r.out
            )),
            VolumeReport::Sequence(SequenceReport::NothingToDo { frames, start, end }) => {
                out.push(format!("all {frames} frames {start}-{end} already exist; nothing to do (--force redoes them)"));
            }
            VolumeReport::Sequence(SequenceReport::Done(s)) => out.push(format!(
                "{} frames stylized ({:?} mode, EMA {}, {} camera{}); mean style loss {:.4e}; flicker {:.5}; {}wrote {}",
                s.stylized,
                s.mode,
                s.ema,
                s.cameras,
                plural(s.cameras),
                s.mean_loss,
                s.flicker,
                if s.unchanged > 0 { format!("{} empty frames copied unchanged; ", s.unchanged) } else { String::new() },
                s.output
            )),
        }
        out
    }
}
