//! An animated groom stylized frame by frame with the temporal coherency of
//! Sec. 3.3 ([`SequenceStylizer`]: EMA on the velocities, 1€ filter on the
//! points). Every frame's groom is read once up front and its topology
//! checked against the first, so a bad frame 200 fails in seconds, not
//! after hours. One output (and preview) is written per frame as soon as it
//! is done, then the whole stylizer state, so a killed job resumes after
//! its last finished frame and ends bit-identical to an uninterrupted one.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use nst3d_core::Reporter;
use nst3d_core::{Groom, UpAxis};
use nst3d_features::Vgg19;
use nst3d_io::groom::{read_groom, read_groom_file};
use nst3d_io::mesh::read_mesh;
use nst3d_job::{default_work_dir, settings_key, FrameSpec, JobId, Resume, State, StateFiles};
use nst3d_strands::{
    check_topology, FlatStrands, Flow, FrameResult, SequenceMap, SequenceParams, SequenceStylizer, TemporalParams,
};

use crate::axis;
use crate::checks::Checks;
use crate::output::{attribute_notes, write_groom};
use crate::preview::write_preview;
use crate::settings::{frame_path, is_pattern};
use crate::settings::{OutFormat, StrandSettings, Temporal};
use crate::single::with_axis;
use crate::NO_MESH;

/// Name of the saved sequence state in the work folder.
pub const STATE_FILE: &str = "strands.state";

/// What a groom sequence's state file says it is.
pub const STATE_KIND: &str = "groom sequence";

/// What an animated-groom job did.
#[derive(Clone, Debug)]
pub struct GroomSequenceReport {
    /// The sequence's losses and flicker ([`SequenceStylizer::report`]).
    pub sequence: nst3d_strands::SequenceReport,
    /// The temporal settings used.
    pub temporal: TemporalParams,
    /// Which filters ran.
    pub mode: Temporal,
    /// The preset's name.
    pub preset: &'static str,
    /// Iterations per frame over all scales.
    pub iterations: u32,
    /// Square render size.
    pub render_size: usize,
    /// The worst lengths and collisions over the frames.
    pub worst: Checks,
}

/// The temporal settings of the sequence (Table 1's, or Long Hair's for a
/// preset without them, said in a note) and the stylizer's parameters:
/// which filters run, the EMA's clock and the flow the EMA follows.
fn sequence_params(
    s: &StrandSettings,
    first: &Groom,
    up: UpAxis,
    reporter: &mut dyn Reporter,
) -> Result<(SequenceParams, TemporalParams)> {
    let stylize = s.stylize_params(first.strand_count());
    StrandSettings::check_memory(&stylize, first.strand_count())?;
    reporter.status(&stylize.look_line());
    let (temporal, borrowed) = s.temporal_params();
    if borrowed {
        reporter.note(&format!(
            "preset {} has no temporal parameters in Table 1; using Long Hair's (override with --ema-sigma, \
             --ema-nu, --one-euro-*)",
            s.preset.params().name
        ));
    }
    let mut params = SequenceParams::new(stylize, temporal);
    (params.ema, params.one_euro) = match s.temporal {
        Temporal::EmaOneEuro => (true, true),
        Temporal::Ema => (true, false),
        Temporal::OneEuro => (false, true),
        Temporal::Off => (false, false),
    };
    params.ema_clock = s.ema_clock;
    // The style flow is a velocity in the file's axes.
    params.flow = match s.style_flow {
        None => Flow::Animation,
        Some(v) => Flow::Style(up.to_y_up(v)),
    };
    Ok((params, temporal))
}

/// Every frame's mesh of a mesh pattern must exist before the first frame runs.
fn check_meshes(frames: &[i64], mesh_at: &dyn Fn(i64) -> Result<Option<PathBuf>>) -> Result<()> {
    for &f in frames {
        let p = mesh_at(f)?.expect("a mesh pattern");
        if !p.exists() {
            bail!("{}: mesh of frame {f} not found", p.display());
        }
    }
    Ok(())
}

/// Resume: the state saved after the last finished frame of this job, if
/// any (`saved`, see [`Resume::load_or_fresh`]), restored into `seq`: the
/// frames done and the worst checks over them.
fn resume(
    seq: &mut SequenceStylizer<'_>,
    saved: Option<State<'_>>,
    (state_path, work): (&Path, &Path),
    frames: &[i64],
    out_at: &dyn Fn(i64) -> Result<PathBuf>,
    reporter: &mut dyn Reporter,
) -> Result<(usize, Checks)> {
    let Some(saved) = saved else {
        return Ok((0, Checks::default()));
    };
    let starts_over = || format!("{} (--force starts over)", state_path.display());
    seq.restore_state(&saved).with_context(starts_over)?;
    let numbers = || -> Result<(usize, Checks), nst3d_job::state::Problem> {
        let worst = Checks {
            vs_input: saved.get("worst.vs_input")?,
            vs_rest: saved.get("worst.vs_rest")?,
            inside: saved.get("worst.inside")?,
        };
        Ok((saved.get("frames_done")?, worst))
    };
    let (done, worst) = numbers().map_err(|e| anyhow::anyhow!("saved state {e}")).with_context(starts_over)?;
    if done > frames.len() {
        bail!(
            "{}: saved state has {done} frames done, the job has {} (--force starts over)",
            state_path.display(),
            frames.len()
        );
    }
    for &f in &frames[..done] {
        let out = out_at(f)?;
        if !out.exists() {
            bail!(
                "{}: output of frame {f} is missing but the saved state in {} has it done; --force starts over",
                out.display(),
                work.display()
            );
        }
    }
    if done == frames.len() {
        reporter.status(&format!("all {done} frames already done (state in {}; --force redoes them)", work.display()));
    } else if let Some(last) = done.checked_sub(1).map(|i| frames[i]) {
        reporter.status(&format!(
            "resuming after frame {last} ({done} of {} done) from {}",
            frames.len(),
            work.display()
        ));
    }
    Ok((done, worst))
}

/// The report line of a written frame.
fn frame_line(f: i64, r: &FrameResult, out: &Path) -> String {
    format!(
        "frame {f}: NNST loss {:.4e} -> {:.4e} (output {:.4e}){}; wrote {}",
        r.eval_before,
        r.optimized.eval_after,
        r.eval_output,
        r.flicker.map_or(String::new(), |k| format!(
            "; flicker {:.5} (raw {:.5}, input {:.5})",
            k.compensated, k.raw, k.input_raw
        )),
        out.display()
    )
}

/// Every frame's groom up front: present, readable, the same topology as
/// the first frame's, which is returned with the up axis its file decides
/// for the whole sequence (`up`: the user's, if set).
fn read_grooms(
    frames: &[i64],
    groom_at: &dyn Fn(i64) -> Result<PathBuf>,
    format: OutFormat,
    up: Option<UpAxis>,
    reporter: &mut dyn Reporter,
) -> Result<(Groom, UpAxis)> {
    let first_path = groom_at(frames[0])?;
    let first_file = read_groom_file(&first_path)?;
    for note in attribute_notes(&first_file, format) {
        reporter.note(&format!("{}: {note}", first_path.display()));
    }
    // The first frame's file decides the axis of the whole sequence.
    let (up, note) = axis::resolve(up, &first_file);
    if let Some(note) = note {
        reporter.note(&format!("{}: {note}", first_path.display()));
    }
    let first = first_file.groom;
    for &f in &frames[1..] {
        let path = groom_at(f)?;
        let g = read_groom(&path)?;
        check_topology(&first, f, &g).with_context(|| path.display().to_string())?;
    }
    Ok((first, up))
}

/// Stylizes the frames `s.frames` of the animated groom `s.groom`.
pub fn stylize_groom_sequence(s: &StrandSettings, reporter: &mut dyn Reporter) -> Result<GroomSequenceReport> {
    let format = OutFormat::of(&s.out)?;
    s.check()?;
    let spec = s.frames.as_deref().context("the job has no frames (set `frames`)")?;
    let frames = FrameSpec::parse(spec)?;
    let frames = frames.frames();
    let groom_at = |f| frame_path(&s.groom, f, "--groom");
    let out_at = |f| frame_path(&s.out, f, "--out");
    if s.out == s.groom {
        bail!("--out {} is the input pattern: nst3d never overwrites its input", s.out.display());
    }
    s.check_outputs(Some(frames[0]))?;
    let mesh_varies = s.mesh.as_deref().is_some_and(is_pattern);
    let mesh_at = |f| -> Result<Option<PathBuf>> {
        match &s.mesh {
            Some(m) if mesh_varies => frame_path(m, f, "--mesh").map(Some),
            m => Ok(m.clone()),
        }
    };

    // Every frame's groom up front: present, readable, same topology.
    let (first, up) = read_grooms(frames, &groom_at, format, s.up, reporter)?;
    let fixed_mesh = if mesh_varies { None } else { s.mesh.as_deref().map(read_mesh).transpose()? };
    let fixed_mesh = fixed_mesh.map(|m| axis::mesh_to_y_up(&m, up).into_owned());
    if s.mesh.is_none() {
        reporter.note(NO_MESH);
    }
    if mesh_varies {
        check_meshes(frames, &mesh_at)?;
    }
    let paintings = s.paintings().iter().map(|p| nst3d_io::image::load_style(p, 1.0)).collect::<Result<Vec<_>, _>>()?;
    let painting = &paintings[0];
    let vgg = Vgg19::load(s.weights.as_deref())?;
    let (mut seq, temporal) = stylizer(s, &vgg, &paintings, (&first, &groom_at(frames[0])?, up), reporter)?;

    // Resume: the state saved after the last finished frame of this job.
    let id = job_id(s, frames, &groom_at, &mesh_at)?;
    let work = match &s.work_dir {
        Some(w) => w.clone(),
        None => default_work_dir(&out_at(frames[0])?, id.hash),
    };
    // Held until the job ends: a second blade on the same job exits here.
    let job = Resume::begin(&work, StateFiles::new(id, "--force starts over")).map_err(anyhow::Error::msg)?;
    let state_path = work.join(STATE_FILE);
    // With --force only our own file goes: the work folder may hold more.
    let saved = job.load_or_fresh(&state_path, s.force)?;
    let (done, mut worst) = resume(&mut seq, saved, (&state_path, &work), frames, &out_at, reporter)?;
    let per_frame: u32 = seq.params().stylize.iterations.iter().sum();
    reporter.begin(per_frame as u64 * (frames.len() - done) as u64);
    for (i, &f) in frames.iter().enumerate().skip(done) {
        let input = read_groom_file(&groom_at(f)?)?;
        let groom = &*axis::groom_to_y_up(&input.groom, up);
        let frame_mesh;
        let mesh = match (&fixed_mesh, mesh_at(f)?) {
            (Some(m), _) => Some(m),
            (None, Some(path)) => {
                frame_mesh = axis::mesh_to_y_up(&read_mesh(&path)?, up).into_owned();
                Some(&frame_mesh)
            }
            (None, None) => None,
        };
        let r = seq.stylize_frame(f, groom, mesh, &mut |r| {
            reporter.step(&format!(
                "frame {f} scale {}/3 iteration {}/{} loss {:.4e}",
                r.scale + 1,
                r.iteration,
                r.iterations,
                r.loss
            ))
        })?;
        let out = out_at(f)?;
        let written = r.scene.to_input_topology(&FlatStrands::from_groom(groom)?, &r.guides)?;
        worst = worst.worst(Checks::new(groom, &r.scene, &r.guides, &written, mesh)?);
        let written = axis::strands_from_y_up(written, up);
        write_groom(&out, format, &written, Some(&with_axis(input, up)), None)?;
        if let Some(p) = &s.preview {
            write_preview(&frame_path(p, f, "--preview")?, &r.scene, &r.strands, None, painting)?;
        }
        reporter.result(&frame_line(f, &r, &out));
        // Outputs first, then the state: a kill in between redoes this frame.
        let mut state = job.files().fresh();
        seq.save_state(&mut state);
        state.set("frames_done", i + 1);
        state.set("worst.vs_input", worst.vs_input);
        state.set("worst.vs_rest", worst.vs_rest);
        state.set("worst.inside", worst.inside);
        job.files().save(&state_path, &state)?;
    }
    reporter.end();
    let p = &seq.params().stylize;
    Ok(GroomSequenceReport {
        sequence: seq.report(),
        temporal,
        mode: s.temporal,
        preset: p.preset.name,
        iterations: per_frame,
        render_size: p.render_size,
        worst,
    })
}

/// The sequence's stylizer toward `paintings`, with the style map if the
/// job has one: its values read from the first frame (`first`, read from
/// its path, in the axes `up` names), since strands keep their identity.
fn stylizer<'a>(
    s: &StrandSettings,
    vgg: &'a Vgg19,
    paintings: &'a [nst3d_core::Image],
    (first, path, up): (&Groom, &Path, UpAxis),
    reporter: &mut dyn Reporter,
) -> Result<(SequenceStylizer<'a>, TemporalParams)> {
    let map = crate::style_map::map_values(s, path, &axis::groom_to_y_up(first, up))?;
    let (params, temporal) = sequence_params(s, first, up, reporter)?;
    let mut seq = SequenceStylizer::new(vgg, &paintings[0], params)?;
    if let Some(values) = map {
        let kind = crate::style_map::kind(s);
        seq = seq.with_map(SequenceMap { paintings: paintings.iter().collect(), values, kind });
    }
    Ok((seq, temporal))
}

/// Everything a strand sequence's saved state depends on: the settings
/// (not `force`, `work_dir`), the painting's contents, and every frame's
/// groom and mesh by path, size and modification time. The thread count is
/// included: results are reproducible bit for bit only on the same count.
fn job_id(
    s: &StrandSettings,
    frames: &[i64],
    groom_at: &dyn Fn(i64) -> Result<PathBuf>,
    mesh_at: &dyn Fn(i64) -> Result<Option<PathBuf>>,
) -> Result<JobId> {
    let mut a = s.clone();
    (a.force, a.work_dir) = (false, None);
    let mut stamped = Vec::with_capacity(2 * frames.len());
    for &f in frames {
        stamped.push(groom_at(f)?);
        stamped.extend(mesh_at(f)?);
    }
    let mut contents: Vec<PathBuf> = s.paintings().iter().map(|p| p.to_path_buf()).collect();
    contents.extend(s.style_map.as_deref().filter(|m| m.ends_with(".txt")).map(PathBuf::from));
    Ok(JobId::new(STATE_KIND, settings_key(&a, true), &contents, &stamped)?)
}
