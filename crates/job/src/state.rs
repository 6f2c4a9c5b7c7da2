//! One format for everything a resumable job saves: a volume sequence's
//! per-frame fields and its sweep checkpoint, an animated groom's state
//! between frames, a training run's checkpoint. A state file is a
//! `.safetensors` file: the arrays as tensors (`F32`, `F64` or `U64`, kept
//! bit for bit, so a resumed run continues exactly), and string metadata:
//!
//! * `format` = `nst3d-state`, `format_version` = [`VERSION`];
//! * `kind`: which job wrote it ([`JobId::kind`]);
//! * `fingerprint`: the job's hash ([`JobId::hash`], 16 hex digits) and
//!   `settings`: the settings text it was taken over, for a person reading
//!   the file;
//! * the job's own counters and scalars (steps, frames done, the random
//!   generator), each a string that parses back to the same value (Rust
//!   prints floats with the fewest digits that round-trip).
//!
//! Any safetensors reader opens a state file, and a bad one is refused with
//! the reason: truncated or corrupt, not a state, a newer version, another
//! kind of job, a different job, or a state of an older nst3d.

use std::borrow::Cow;
use std::collections::BTreeMap;
use std::path::Path;

use nst3d_weights::{Tensor, Values};

use crate::JobId;

/// The `format` metadata value of every state file.
pub const FORMAT: &str = "nst3d-state";

/// The `format_version` this nst3d writes and reads.
pub const VERSION: u32 = 1;

/// Metadata keys every state file has; [`State::set`] refuses them.
const RESERVED: [&str; 5] = ["format", "format_version", "kind", "fingerprint", "settings"];

/// Why bytes are not a state this job can resume from.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum Problem {
    /// A state file of an nst3d from before this format.
    #[error("was written by an older nst3d, in a format this one no longer reads")]
    OldFormat,
    /// Not a state file at all, or a broken one.
    #[error("is truncated or corrupt ({0})")]
    Corrupt(String),
    /// A state of a newer (or unknown) format version.
    #[error("has format version {0}; this nst3d reads version {VERSION}")]
    Version(String),
    /// A state another kind of job wrote.
    #[error("belongs to a {found}, not a {expected}")]
    OtherKind {
        /// The kind in the file.
        found: String,
        /// The kind asked for.
        expected: String,
    },
    /// A state of the same kind of job with other settings or inputs.
    #[error("belongs to a different {0} (other settings, inputs, painting or thread count)")]
    OtherJob(String),
}

/// A job's saved state: named arrays and string metadata. Arrays may be
/// borrowed from the job while it is written (`'a`); a state read from a
/// file owns them.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct State<'a> {
    meta: BTreeMap<String, String>,
    tensors: BTreeMap<String, Tensor<'a>>,
}

/// Whether `bytes` are one of the state files nst3d wrote before this
/// format: the volume sequence's frame states (`NST3DFS1`) and checkpoint
/// line, the groom sequence's state (`NST3DSQ1`), and the training
/// checkpoint's length-prefixed model followed by a second safetensors part
/// (a state file has its JSON header at byte 8; that one at byte 16).
fn is_old_format(bytes: &[u8]) -> bool {
    let framed = bytes.len() > 16
        && bytes[8] != b'{'
        && bytes[16] == b'{'
        && u64::from_le_bytes(bytes[..8].try_into().expect("8 bytes")) <= bytes.len() as u64 - 8;
    bytes.starts_with(b"NST3DFS1")
        || bytes.starts_with(b"NST3DSQ1")
        || bytes.starts_with(b"nst3d-checkpoint ")
        || framed
}

impl<'a> State<'a> {
    /// An empty state of the job `id`.
    pub fn new(id: &JobId) -> Self {
        let mut meta = BTreeMap::new();
        meta.insert("format".to_string(), FORMAT.to_string());
        meta.insert("format_version".to_string(), VERSION.to_string());
        meta.insert("kind".to_string(), id.kind.clone());
        meta.insert("fingerprint".to_string(), id.fingerprint());
        meta.insert("settings".to_string(), id.settings.clone());
        Self { meta, tensors: BTreeMap::new() }
    }

    /// Sets the metadata `key` to `value`'s text.
    ///
    /// # Panics
    /// On a key of the format's own (a programming error).
    pub fn set(&mut self, key: &str, value: impl std::fmt::Display) {
        assert!(!RESERVED.contains(&key), "metadata key {key} is the state format's");
        self.meta.insert(key.to_string(), value.to_string());
    }

    /// The metadata `key` parsed as a `T`; missing or unparseable is corruption.
    pub fn get<T: std::str::FromStr>(&self, key: &str) -> Result<T, Problem> {
        let text = self.meta.get(key).ok_or_else(|| Problem::Corrupt(format!("no '{key}'")))?;
        text.parse().map_err(|_| Problem::Corrupt(format!("'{key}' is '{text}'")))
    }

    /// The metadata `key` as it is stored, if present.
    pub fn text(&self, key: &str) -> Option<&str> {
        self.meta.get(key).map(String::as_str)
    }

    /// Every metadata key and value (the format's own included).
    pub fn metadata(&self) -> &BTreeMap<String, String> {
        &self.meta
    }

    /// Stores an array of `f32` of `shape` under `name` (replacing one of that name).
    ///
    /// # Panics
    /// If the values do not fill the shape (a programming error).
    pub fn put_f32(&mut self, name: &str, shape: &[usize], values: impl Into<Cow<'a, [f32]>>) {
        self.put(name, shape, Values::F32(values.into()));
    }

    /// Stores an array of `f64` (see [`State::put_f32`]).
    pub fn put_f64(&mut self, name: &str, shape: &[usize], values: impl Into<Cow<'a, [f64]>>) {
        self.put(name, shape, Values::F64(values.into()));
    }

    /// Stores an array of `u64` (see [`State::put_f32`]).
    pub fn put_u64(&mut self, name: &str, shape: &[usize], values: impl Into<Cow<'a, [u64]>>) {
        self.put(name, shape, Values::U64(values.into()));
    }

    fn put(&mut self, name: &str, shape: &[usize], values: Values<'a>) {
        assert_eq!(shape.iter().product::<usize>(), values.len(), "array {name}: shape vs values");
        self.tensors.insert(name.to_string(), Tensor { shape: shape.to_vec(), values });
    }

    /// Whether an array `name` is stored.
    pub fn has(&self, name: &str) -> bool {
        self.tensors.contains_key(name)
    }

    fn tensor(&self, name: &str) -> Result<&Tensor<'a>, Problem> {
        self.tensors.get(name).ok_or_else(|| Problem::Corrupt(format!("no array '{name}'")))
    }

    fn wrong_type(name: &str, t: &Tensor<'_>) -> Problem {
        Problem::Corrupt(format!("array '{name}' holds {}", t.values.dtype()))
    }

    /// The shape and values of the `f32` array `name`.
    pub fn f32s(&self, name: &str) -> Result<(&[usize], &[f32]), Problem> {
        match self.tensor(name)? {
            Tensor { shape, values: Values::F32(v) } => Ok((shape, v)),
            t => Err(Self::wrong_type(name, t)),
        }
    }

    /// The shape and values of the `f64` array `name`.
    pub fn f64s(&self, name: &str) -> Result<(&[usize], &[f64]), Problem> {
        match self.tensor(name)? {
            Tensor { shape, values: Values::F64(v) } => Ok((shape, v)),
            t => Err(Self::wrong_type(name, t)),
        }
    }

    /// The shape and values of the `u64` array `name`.
    pub fn u64s(&self, name: &str) -> Result<(&[usize], &[u64]), Problem> {
        match self.tensor(name)? {
            Tensor { shape, values: Values::U64(v) } => Ok((shape, v)),
            t => Err(Self::wrong_type(name, t)),
        }
    }

    /// Takes the `f32` array `name` out of the state (no copy of a state
    /// read from a file).
    pub fn take_f32s(&mut self, name: &str) -> Result<(Vec<usize>, Vec<f32>), Problem> {
        self.f32s(name)?;
        let t = self.tensors.remove(name).expect("checked above");
        match t.values {
            Values::F32(v) => Ok((t.shape, v.into_owned())),
            _ => unreachable!("checked above"),
        }
    }

    /// Writes the state as a safetensors file to `w` (arrays in name order).
    pub fn write(&self, w: &mut dyn std::io::Write) -> std::io::Result<()> {
        let tensors: Vec<(&str, &Tensor<'_>)> = self.tensors.iter().map(|(n, t)| (n.as_str(), t)).collect();
        nst3d_weights::write_safetensors(w, &tensors, &self.meta)
    }

    /// The state's bytes (see [`State::write`]).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::new();
        self.write(&mut out).expect("writing to memory does not fail");
        out
    }

    /// Reads a state file's bytes: the format and its version are checked,
    /// not whose state it is ([`State::check`]).
    pub fn from_bytes(bytes: &[u8]) -> Result<State<'static>, Problem> {
        if is_old_format(bytes) {
            return Err(Problem::OldFormat);
        }
        let (tensors, meta) = nst3d_weights::parse_safetensors_exact(bytes, Path::new("")).map_err(|e| match e {
            nst3d_weights::WeightsError::Malformed { problem, .. } => Problem::Corrupt(problem),
            other => Problem::Corrupt(other.to_string()),
        })?;
        match meta.get("format").map(String::as_str) {
            Some(FORMAT) => {}
            _ => return Err(Problem::Corrupt("a safetensors file, but not an nst3d state".into())),
        }
        let version = meta.get("format_version").map_or("none", String::as_str);
        if version != VERSION.to_string() {
            return Err(Problem::Version(version.to_string()));
        }
        for key in ["kind", "fingerprint"] {
            if !meta.contains_key(key) {
                return Err(Problem::Corrupt(format!("no '{key}'")));
            }
        }
        Ok(State { meta, tensors })
    }

    /// Whether this is a state of the job `id`: same kind, same fingerprint.
    pub fn check(&self, id: &JobId) -> Result<(), Problem> {
        let kind = self.text("kind").unwrap_or_default();
        if kind != id.kind {
            return Err(Problem::OtherKind { found: kind.to_string(), expected: id.kind.clone() });
        }
        if self.text("fingerprint") != Some(id.fingerprint().as_str()) {
            return Err(Problem::OtherJob(id.kind.clone()));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn id(hash: u64) -> JobId {
        JobId { kind: "test job".into(), hash, settings: "Settings { iters: 3 }".into() }
    }

    fn sample() -> State<'static> {
        let mut s = State::new(&id(0xabc));
        s.set("step", 41u64);
        s.set("position", 0.1f64 + 0.2);
        s.set("paced", true);
        s.put_f32("field", &[2, 3], vec![1.0, -0.0, f32::MIN_POSITIVE, 3.5, f32::MAX, 1e-40]);
        s.put_f64("sums", &[2], vec![0.1, -1e300]);
        s.put_u64("offsets", &[3], vec![0, 2, u64::MAX]);
        s.put_f32("empty", &[0, 4], Vec::new());
        s
    }

    /// Every array and every value comes back bit for bit.
    #[test]
    fn a_state_round_trips_exactly() {
        let s = sample();
        let bytes = s.to_bytes();
        let back = State::from_bytes(&bytes).unwrap();
        assert_eq!(back, s);
        back.check(&id(0xabc)).unwrap();
        assert_eq!(back.get::<u64>("step"), Ok(41));
        assert_eq!(back.get::<f64>("position").map(f64::to_bits), Ok((0.1f64 + 0.2).to_bits()));
        assert_eq!(back.get::<bool>("paced"), Ok(true));
        assert_eq!(back.text("fingerprint"), Some("0000000000000abc"));
        assert_eq!(back.f64s("sums").unwrap().1, [0.1, -1e300]);
        assert_eq!(back.u64s("offsets").unwrap(), (&[3][..], &[0, 2, u64::MAX][..]));
        let mut back = back;
        assert_eq!(back.take_f32s("field").unwrap(), (vec![2, 3], s.f32s("field").unwrap().1.to_vec()));
        assert!(!back.has("field"));
        // The same state always gives the same bytes.
        assert_eq!(sample().to_bytes(), bytes);
    }

    /// Asking for what is not there, or of another type, is an error.
    #[test]
    fn missing_and_mistyped_entries_are_errors() {
        let s = sample();
        assert!(matches!(s.f32s("nothing"), Err(Problem::Corrupt(_))));
        assert!(matches!(s.f32s("sums"), Err(Problem::Corrupt(m)) if m.contains("F64")));
        assert!(matches!(s.u64s("field"), Err(Problem::Corrupt(_))));
        assert!(matches!(s.get::<u64>("missing"), Err(Problem::Corrupt(_))));
        assert!(matches!(s.get::<u64>("position"), Err(Problem::Corrupt(_))));
    }

    /// Every cut of a state file, and a state with any byte changed, is an
    /// error or a well-formed state, never a panic.
    #[test]
    fn truncated_and_corrupted_states_are_errors_not_panics() {
        let bytes = sample().to_bytes();
        for len in 0..bytes.len() {
            assert!(State::from_bytes(&bytes[..len]).is_err(), "cut to {len} bytes read");
        }
        for at in 0..bytes.len() {
            for flip in [0x01, 0x80, 0xff] {
                let mut b = bytes.clone();
                b[at] ^= flip;
                if let Ok(s) = State::from_bytes(&b) {
                    for name in ["field", "sums", "offsets"] {
                        let _ = (s.f32s(name), s.f64s(name), s.u64s(name));
                    }
                }
            }
        }
        let mut longer = bytes.clone();
        longer.push(0);
        assert!(matches!(State::from_bytes(&longer), Err(Problem::Corrupt(_))));
    }

    /// Another job's state, another kind's, another version's and a plain
    /// safetensors file are each refused with their reason.
    #[test]
    fn states_of_other_jobs_and_versions_are_refused() {
        let s = State::from_bytes(&sample().to_bytes()).unwrap();
        assert_eq!(s.check(&id(0xabd)), Err(Problem::OtherJob("test job".into())));
        let other = JobId { kind: "training run".into(), ..id(0xabc) };
        assert!(matches!(s.check(&other), Err(Problem::OtherKind { .. })));
        let mut meta = sample().meta;
        meta.insert("format_version".into(), "2".into());
        let newer = State { meta, tensors: BTreeMap::new() };
        assert_eq!(State::from_bytes(&newer.to_bytes()), Err(Problem::Version("2".into())));
        let model = nst3d_weights::safetensors_bytes(&[("w", &[1], &[1.0])], &BTreeMap::new());
        assert!(matches!(State::from_bytes(&model), Err(Problem::Corrupt(m)) if m.contains("not an nst3d state")));
    }

    /// The three formats nst3d used before are recognised as such.
    #[test]
    fn old_formats_are_recognised() {
        let mut frame = b"NST3DFS1".to_vec();
        frame.extend([0u8; 40]);
        let mut groom = b"NST3DSQ1".to_vec();
        groom.extend([1u8, 0, 0]);
        let line = b"nst3d-checkpoint generation 4 octave 1 octaves 3 sweeps 2\n".to_vec();
        let model = nst3d_weights::safetensors_bytes(&[("w", &[1], &[1.0])], &BTreeMap::new());
        let mut ckpt = (model.len() as u64).to_le_bytes().to_vec();
        ckpt.extend(&model);
        ckpt.extend(&model);
        for old in [frame, groom, line, ckpt] {
            assert_eq!(State::from_bytes(&old), Err(Problem::OldFormat));
        }
        assert!(!is_old_format(&sample().to_bytes()));
    }
}
