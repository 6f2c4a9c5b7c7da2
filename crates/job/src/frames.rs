//! Frame numbers and file-name patterns, in the forms Houdini, Deadline and
//! OpenCue users type: `smoke_####.vdb` or `smoke_%04d.vdb`, and frame specs
//! like `1-120` or `1-3,5,7-20:2`.

/// Why a frame spec or pattern was refused.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum FramesError {
    /// The spec does not parse.
    #[error("bad frame spec '{spec}': {reason}")]
    BadSpec {
        /// The text given.
        spec: String,
        /// What is wrong with it.
        reason: String,
    },
    /// The pattern has no frame placeholder, or more than one.
    #[error("file pattern '{0}' needs exactly one frame placeholder (#### or %04d)")]
    BadPattern(String),
}

/// Most frames one spec may name: a typo like `1-1000000000` must fail, not
/// allocate.
pub const MAX_FRAMES: usize = 1_000_000;

/// An ordered set of frame numbers without repeats.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FrameSpec {
    frames: Vec<i64>,
}

impl FrameSpec {
    /// Parses `A`, `A-B`, `A-B:STEP`, comma-separated (negative frames as
    /// `-5` or `-10--5`). Frames come out sorted and unique.
    pub fn parse(spec: &str) -> Result<Self, FramesError> {
        let bad = |reason: &str| FramesError::BadSpec { spec: spec.to_string(), reason: reason.to_string() };
        let mut frames = Vec::new();
        for part in spec.split(',').map(str::trim) {
            if part.is_empty() {
                return Err(bad("empty item"));
            }
            let (range, step) = match part.split_once(':') {
                Some((r, s)) => (r, s.trim().parse::<i64>().map_err(|_| bad("step is not a whole number"))?),
                None => (part, 1),
            };
            if step < 1 {
                return Err(bad("step must be at least 1"));
            }
            let (a, b) = split_range(range).ok_or_else(|| bad("expected FRAME or START-END"))?;
            if b < a {
                return Err(bad("range end is before its start"));
            }
            let count = ((b - a) / step + 1) as usize;
            if frames.len() + count > MAX_FRAMES {
                return Err(bad(&format!("more than {MAX_FRAMES} frames")));
            }
            frames.extend((0..count as i64).map(|i| a + i * step));
        }
        frames.sort_unstable();
        frames.dedup();
        Ok(Self { frames })
    }

    /// The frames in increasing order.
    pub fn frames(&self) -> &[i64] {
        &self.frames
    }

    /// Frames that fall inside `[start, end]` (a farm chunk).
    pub fn within(&self, start: i64, end: i64) -> Vec<i64> {
        self.frames.iter().copied().filter(|f| (start..=end).contains(f)).collect()
    }
}

/// `A` or `A-B`, where either number may itself be negative.
fn split_range(s: &str) -> Option<(i64, i64)> {
    let s = s.trim();
    if let Ok(a) = s.parse() {
        return Some((a, a));
    }
    // The separating '-' is the first one that is not a leading sign.
    let bytes = s.as_bytes();
    (1..bytes.len()).filter(|&i| bytes[i] == b'-').find_map(|i| {
        let a = s[..i].trim().parse().ok()?;
        let b = s[i + 1..].trim().parse().ok()?;
        Some((a, b))
    })
}

/// Substitutes `frame` into a pattern: a run of `#` is the zero-padded frame
/// with that many digits (Houdini's `$F4` as `####`), `%0Nd` / `%d` printf
/// style. Exactly one placeholder is allowed.
pub fn expand_pattern(pattern: &str, frame: i64) -> Result<String, FramesError> {
    let hashes = pattern.find('#').map(|start| {
        let len = pattern[start..].bytes().take_while(|&b| b == b'#').count();
        (start, len)
    });
    let printf = pattern.find('%').and_then(|start| {
        let rest = &pattern[start + 1..];
        let digits: String = rest.chars().take_while(|c| c.is_ascii_digit()).collect();
        rest[digits.len()..].starts_with('d').then(|| {
            let width = digits.trim_start_matches('0').parse::<usize>().unwrap_or(0);
            (start, digits.len() + 2, width)
        })
    });
    let (start, len, width) = match (hashes, printf) {
        (Some((s, l)), None) => (s, l, l),
        (None, Some((s, l, w))) => (s, l, w),
        _ => return Err(FramesError::BadPattern(pattern.to_string())),
    };
    let rest = &pattern[start + len..];
    if rest.contains('#') || rest.contains("%d") || rest.contains("%0") {
        return Err(FramesError::BadPattern(pattern.to_string()));
    }
    let number = if frame < 0 {
        format!("-{:0width$}", -frame, width = width.saturating_sub(1))
    } else {
        format!("{frame:0width$}")
    };
    Ok(format!("{}{number}{rest}", &pattern[..start]))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn specs_parse_as_farm_users_write_them() {
        assert_eq!(FrameSpec::parse("1-5").unwrap().frames(), &[1, 2, 3, 4, 5]);
        assert_eq!(FrameSpec::parse("1-3,5,7-20:4").unwrap().frames(), &[1, 2, 3, 5, 7, 11, 15, 19]);
        assert_eq!(FrameSpec::parse("3,1,2,2").unwrap().frames(), &[1, 2, 3]);
        assert_eq!(FrameSpec::parse("-2-1").unwrap().frames(), &[-2, -1, 0, 1]);
        assert_eq!(FrameSpec::parse("-10--8").unwrap().frames(), &[-10, -9, -8]);
        assert_eq!(FrameSpec::parse("1-120").unwrap().within(31, 60).len(), 30);
        for bad in ["", "1-", "a-b", "5-1", "1-10:0", "1,,2", "1-2000000000"] {
            assert!(FrameSpec::parse(bad).is_err(), "{bad} should fail");
        }
    }

    #[test]
    fn patterns_expand_like_houdini_and_printf() {
        assert_eq!(expand_pattern("sim/smoke_####.vdb", 7).unwrap(), "sim/smoke_0007.vdb");
        assert_eq!(expand_pattern("fluid_data_%04d.vdb", 12).unwrap(), "fluid_data_0012.vdb");
        assert_eq!(expand_pattern("f_%d.vdb", 12).unwrap(), "f_12.vdb");
        assert_eq!(expand_pattern("smoke_######.vdb", 3).unwrap(), "smoke_000003.vdb");
        assert_eq!(expand_pattern("s_####.vdb", 12345).unwrap(), "s_12345.vdb");
        assert_eq!(expand_pattern("s_####.vdb", -3).unwrap(), "s_-003.vdb");
        for bad in ["smoke.vdb", "a_##_##.vdb", "a_#_%04d.vdb"] {
            assert!(expand_pattern(bad, 1).is_err(), "{bad} should fail");
        }
    }
}
