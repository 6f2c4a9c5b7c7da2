//! The lines a front end prints after a groom job: what was stylized, the
//! NNST loss before and after (from the optimised and the held-out views),
//! the artist's checks, the flicker of a sequence, and the judge of a
//! preview. `nst3d strands` and `nst3d preview` print them as they are.

use nst3d_strands::pipeline::HeldOut;

use crate::{GenerateReport, GroomPreviewReport, GroomReport, GroomSequenceReport, Temporal};

/// `""` for one, `"s"` for any other count.
pub fn plural(n: usize) -> &'static str {
    if n == 1 {
        ""
    } else {
        "s"
    }
}

/// The held-out measurement of a summary line.
fn held_out_line(h: &HeldOut) -> String {
    if h.angles.is_empty() {
        return "no held-out views".into();
    }
    format!(
        "hair-only NNST loss from {} held-out views {:.4e} -> {:.4e} ({:+.1}%; re-matched {:.4e})",
        h.angles.len(),
        h.before,
        h.after,
        -100.0 * h.drop(),
        h.after_rematched
    )
}

/// The collision check of a summary line.
fn inside_line(has_mesh: bool, inside: usize) -> String {
    if has_mesh {
        format!("{inside} control points inside the mesh")
    } else {
        "no mesh, no collision check".into()
    }
}

impl GroomReport {
    /// The one-line summary; `has_mesh`: the job had a head mesh (else no
    /// collision check was made).
    pub fn summary(&self, has_mesh: bool) -> String {
        let r = self;
        format!(
            "{}: {} strands ({} control points, as in the input) stylized ({}, {} proxies, {} iterations at {}px); \
             NNST loss {:.4e} -> {:.4e} ({:+.1}%; re-matched on the result {:.4e}); \
             {}; max length change {:.3}% vs input ({:.4}% vs rest); {}; wrote {}",
            r.groom.display(),
            r.strands,
            r.points,
            r.preset,
            r.proxies,
            r.iterations,
            r.render_size,
            r.eval_before,
            r.eval_after,
            -100.0 * r.loss_drop(),
            r.eval_after_rematched,
            held_out_line(&r.held_out),
            100.0 * r.checks.vs_input,
            100.0 * r.checks.vs_rest,
            inside_line(has_mesh, r.checks.inside),
            r.out.display()
        )
    }
}

impl GroomSequenceReport {
    /// The sequence's summary line: mean losses, flicker and the worst checks.
    pub fn summary(&self, has_mesh: bool) -> String {
        let (r, t) = (self, self.temporal);
        let mode = match r.mode {
            Temporal::EmaOneEuro => format!(
                "EMA sigma {} nu {} + 1-euro alpha {} beta {} f_min {} Hz at {} fps",
                t.ema_sigma, t.ema_nu, t.blend_alpha, t.beta, t.min_cutoff_hz, t.fps
            ),
            Temporal::Ema => format!("EMA sigma {} nu {}", t.ema_sigma, t.ema_nu),
            Temporal::OneEuro => {
                format!("1-euro alpha {} beta {} f_min {} Hz at {} fps", t.blend_alpha, t.beta, t.min_cutoff_hz, t.fps)
            }
            Temporal::Off => "per-frame, no temporal filtering".into(),
        };
        let q = &r.sequence;
        format!(
            "sequence: {} frames ({}; {}, {} iterations/frame at {}px); mean NNST loss {:.4e} -> {:.4e} \
             (output {:.4e}, re-matched {:.4e}); flicker {:.5} (motion-compensated), raw frame difference {:.5} \
             (input {:.5}); max length change {:.3}% vs input ({:.4}% vs rest); {}",
            q.frames,
            mode,
            r.preset,
            r.iterations,
            r.render_size,
            q.eval_before,
            q.eval_optimized,
            q.eval_output,
            q.eval_output_rematched,
            q.flicker,
            q.flicker_raw,
            q.flicker_input_raw,
            100.0 * r.worst.vs_input,
            100.0 * r.worst.vs_rest,
            inside_line(has_mesh, r.worst.inside)
        )
    }
}

impl GenerateReport {
    /// What was written.
    pub fn summary(&self) -> String {
        let (r, w) = (self, &self.written);
        format!(
            "wrote {} strands x {} points to {}{}{}",
            r.strands,
            r.points,
            w.first().map_or(String::new(), |p| p.display().to_string()),
            if w.len() > 1 { format!(" .. {} ({} frames)", w[w.len() - 1].display(), w.len()) } else { String::new() },
            r.mesh.as_ref().map_or(String::new(), |m| format!("; mesh {}", m.display()))
        )
    }
}

impl GroomPreviewReport {
    /// The judge's lines: the loss of each picture, and with a comparison
    /// the ratio per picture (lower: nearer the painting) and its median and
    /// worst; in colour, the grey judge of the pictures' luminance too. None
    /// without a painting to judge against.
    pub fn judgement(&self) -> Vec<String> {
        let (r, mut out) = (self, Vec::new());
        if r.input_loss.is_empty() {
            return out;
        }
        let color = !r.input_grey_loss.is_empty();
        let what = if color { "colour style loss" } else { "style loss" };
        let list = |v: &[f32], f: &dyn Fn(f32) -> String| v.iter().map(|x| f(*x)).collect::<Vec<_>>().join(" ");
        out.push(format!("{what} per picture: input {}", list(&r.input_loss, &|x| format!("{x:.4e}"))));
        if r.compare_loss.is_empty() {
            return out;
        }
        out.push(format!("{what} per picture: compare {}", list(&r.compare_loss, &|x| format!("{x:.4e}"))));
        let line = |name: &str, ratios: Vec<f32>| {
            let worst = ratios.iter().copied().fold(f32::NEG_INFINITY, f32::max);
            format!(
                "{name}compare/input per picture {}; median {:.3}, worst {:.3}",
                list(&ratios, &|x| format!("{x:.3}")),
                crate::judge::median(&ratios),
                worst
            )
        };
        if color {
            out.push(line("colour: ", r.ratios()));
            out.push(line("colour, hair only: ", r.hair_ratios()));
            out.push(line("grey: ", r.grey_ratios()));
        } else {
            out.push(line("", r.ratios()));
            out.push(line("hair only: ", r.hair_ratios()));
            out.push(line("hair only, tone matched: ", r.toned_ratios()));
        }
        out
    }
}
