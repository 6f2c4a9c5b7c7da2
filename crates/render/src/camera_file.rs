//! The artist's shot camera for eq. 1, read from a Houdini-style JSON file
//! (paper Sec. 5.1, "Perspective Camera": camera parameters are extracted
//! from the Houdini setup so the differentiable renderer sees what Mantra
//! will render). The sampled camera sets (omniview, turntable) are in
//! `sphere.rs`.
//!
//! Camera files are in WORLD space; [`CameraRig::at_frame`] maps them into the
//! grid's index space (voxel units, voxel centres at integer coordinates), the
//! space [`Camera`] lives in.
//!
//! # Camera file format
//! One camera, or a keyed path:
//! ```json
//! {"position": [0, 1, 10], "look_at": [0, 1, 0], "up": [0, 1, 0],
//!  "projection": "perspective", "focal": 50, "aperture": 41.4214,
//!  "resx": 1920, "resy": 1080}
//! {"resx": 1280, "resy": 720,
//!  "frames": {"1": {"position": [0, 1, 10], "look_at": [0, 1, 0]},
//!             "24": {"position": [10, 1, 0], "look_at": [0, 1, 0], "fov": 30}}}
//! ```
//! Keys: `position` (required); `look_at` (+ optional `up`, default +y) or
//! `rotation` (degrees, Houdini's XYZ rotate order, camera looking down its
//! local −z with +y up); `projection` (`"perspective"` default, or
//! `"orthographic"`); the field of view either as Houdini's `focal` (mm,
//! default 50) and horizontal `aperture` (mm, default 41.4214), or as a
//! vertical `fov` in degrees; `resx`, `resy` (default 1920 x 1080) and
//! `pixel_aspect` (default 1) for the film aspect; `ortho_width` (world
//! units, default 2). In a path, keys beside `frames` are defaults every frame
//! may override. Unknown keys are errors, so a typo never silently falls
//! back to a default.

use crate::camera::{Camera, Projection};
use nst3d_core::math::{add, cross, dot, norm, sub, unit};
use serde_json::{Map, Value};
use std::path::Path;

/// Why a camera file could not be used; every message is one line naming the
/// file and, for content problems, the offending key (dotted path, e.g.
/// `frames.24.look_at`).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CameraFileError {
    /// The file could not be read.
    #[error("cannot read camera file {file}: {reason}")]
    Read {
        /// File name.
        file: String,
        /// The I/O error.
        reason: String,
    },
    /// The file is not JSON.
    #[error("camera file {file} is not valid JSON: {reason}")]
    Json {
        /// File name.
        file: String,
        /// The parser's message.
        reason: String,
    },
    /// A key is missing, mistyped, out of range or contradicts another.
    #[error("camera file {file}: key \"{key}\": {problem}")]
    Key {
        /// File name.
        file: String,
        /// Dotted path of the key.
        key: String,
        /// What is wrong with it.
        problem: String,
    },
}

/// How a keyed camera is aimed, as written in the file: the two forms are
/// interpolated channel by channel, as Houdini's linear keys would.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Aim {
    /// Looks at a world point with an approximate up direction.
    LookAt {
        /// World point looked at.
        target: [f64; 3],
        /// Approximate world up (re-orthogonalised against the view).
        up: [f64; 3],
    },
    /// Euler angles in degrees, rotate order X then Y then Z.
    Rotation([f64; 3]),
}

/// One camera key in world space with its field of view already resolved
/// from focal length and aperture.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraKey {
    /// Orthographic or perspective.
    pub projection: Projection,
    /// World eye position.
    pub position: [f64; 3],
    /// Orientation.
    pub aim: Aim,
    /// Vertical field of view in degrees.
    pub fov_y_deg: f64,
    /// Film width / height.
    pub aspect: f64,
    /// Houdini's orthographic width in world units. Kept for the caller: the
    /// renderer fits its orthographic window to the grid, because pattern
    /// scale must not depend on zoom (paper Sec. 5.1).
    pub ortho_width: f64,
}

/// A shot camera: one camera for all frames, or keys at frames interpolated
/// linearly and held outside the keyed range.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraRig {
    /// Keys sorted by frame; a static camera is a single key.
    keys: Vec<(f64, CameraKey)>,
}

/// Default Houdini camera: 50 mm lens on a 41.4214 mm aperture (45° horizontal).
const DEFAULT_FOCAL: f64 = 50.0;
const DEFAULT_APERTURE: f64 = 41.4214;
const DEFAULT_RES: [f64; 2] = [1920.0, 1080.0];
const DEFAULT_ORTHO_WIDTH: f64 = 2.0;

/// Keys a camera object may carry.
const CAMERA_KEYS: [&str; 13] = [
    "position",
    "look_at",
    "rotation",
    "up",
    "projection",
    "focal",
    "aperture",
    "fov",
    "resx",
    "resy",
    "pixel_aspect",
    "ortho_width",
    "frames",
];

/// Parses one file's content, remembering its name for error messages.
struct Parser<'a> {
    file: &'a str,
}

impl Parser<'_> {
    fn err(&self, key: &str, problem: impl Into<String>) -> CameraFileError {
        CameraFileError::Key { file: self.file.to_string(), key: key.to_string(), problem: problem.into() }
    }

    fn number(&self, obj: &Map<String, Value>, prefix: &str, key: &str) -> Result<Option<f64>, CameraFileError> {
        let Some(v) = obj.get(key) else { return Ok(None) };
        let path = join(prefix, key);
        match v.as_f64() {
            Some(x) if x.is_finite() => Ok(Some(x)),
            _ => Err(self.err(&path, format!("expected a finite number, got {v}"))),
        }
    }

    fn positive(&self, obj: &Map<String, Value>, prefix: &str, key: &str) -> Result<Option<f64>, CameraFileError> {
        match self.number(obj, prefix, key)? {
            Some(x) if x <= 0.0 => Err(self.err(&join(prefix, key), format!("must be positive, got {x}"))),
            x => Ok(x),
        }
    }

    fn vec3(&self, obj: &Map<String, Value>, prefix: &str, key: &str) -> Result<Option<[f64; 3]>, CameraFileError> {
        let Some(v) = obj.get(key) else { return Ok(None) };
        let bad = || self.err(&join(prefix, key), format!("expected [x, y, z] of finite numbers, got {v}"));
        let arr = v.as_array().filter(|a| a.len() == 3).ok_or_else(bad)?;
        let mut out = [0.0; 3];
        for (o, x) in out.iter_mut().zip(arr) {
            *o = x.as_f64().filter(|x| x.is_finite()).ok_or_else(bad)?;
        }
        Ok(Some(out))
    }

    /// One camera object (path defaults already merged in).
    fn camera(&self, obj: &Map<String, Value>, prefix: &str) -> Result<CameraKey, CameraFileError> {
        if let Some(k) = obj.keys().find(|k| !CAMERA_KEYS.contains(&k.as_str())) {
            return Err(self.err(&join(prefix, k), format!("unknown key (known: {})", CAMERA_KEYS.join(", "))));
        }
        let key = |k: &str| join(prefix, k);
        let position = self.vec3(obj, prefix, "position")?.ok_or_else(|| self.err(&key("position"), "missing"))?;
        let projection = match obj.get("projection") {
            None => Projection::Perspective,
            Some(v) => match v.as_str() {
                Some("perspective") => Projection::Perspective,
                Some("orthographic") => Projection::Orthographic,
                _ => {
                    return Err(
                        self.err(&key("projection"), format!("expected \"perspective\" or \"orthographic\", got {v}"))
                    )
                }
            },
        };
        let aim = match (self.vec3(obj, prefix, "look_at")?, self.vec3(obj, prefix, "rotation")?) {
            (Some(_), Some(_)) => return Err(self.err(&key("rotation"), "give either look_at or rotation, not both")),
            (None, None) => return Err(self.err(&key("look_at"), "missing (or give rotation)")),
            (None, Some(r)) => {
                if obj.contains_key("up") {
                    return Err(self.err(&key("up"), "the up vector is implied by rotation"));
                }
                Aim::Rotation(r)
            }
            (Some(target), None) => {
                let up = self.vec3(obj, prefix, "up")?.unwrap_or([0.0, 1.0, 0.0]);
                let dir = sub(target, position);
                if norm(dir) < 1e-12 {
                    return Err(self.err(&key("look_at"), "coincides with position"));
                }
                if norm(cross(dir, up)) < 1e-6 * norm(dir) * norm(up).max(1e-300) || norm(up) < 1e-12 {
                    return Err(self.err(&key("up"), "is zero or parallel to the view direction"));
                }
                Aim::LookAt { target, up }
            }
        };
        let res = [
            self.positive(obj, prefix, "resx")?.unwrap_or(DEFAULT_RES[0]),
            self.positive(obj, prefix, "resy")?.unwrap_or(DEFAULT_RES[1]),
        ];
        let aspect = res[0] * self.positive(obj, prefix, "pixel_aspect")?.unwrap_or(1.0) / res[1];
        let fov_y_deg = match self.number(obj, prefix, "fov")? {
            Some(fov) => {
                if let Some(k) = ["focal", "aperture"].into_iter().find(|k| obj.contains_key(*k)) {
                    return Err(self.err(&key(k), "give either fov or focal/aperture, not both"));
                }
                if !(fov > 0.0 && fov < 180.0) {
                    return Err(self.err(&key("fov"), format!("must be in (0, 180) degrees, got {fov}")));
                }
                fov
            }
            None => {
                let focal = self.positive(obj, prefix, "focal")?.unwrap_or(DEFAULT_FOCAL);
                let aperture = self.positive(obj, prefix, "aperture")?.unwrap_or(DEFAULT_APERTURE);
                fov_y_from_lens(focal, aperture, aspect)
            }
        };
        let ortho_width = self.positive(obj, prefix, "ortho_width")?.unwrap_or(DEFAULT_ORTHO_WIDTH);
        Ok(CameraKey { projection, position, aim, fov_y_deg, aspect, ortho_width })
    }

    fn rig(&self, root: &Value) -> Result<CameraRig, CameraFileError> {
        let root = root.as_object().ok_or_else(|| self.err("(root)", "expected a JSON object"))?;
        let Some(frames) = root.get("frames") else {
            return Ok(CameraRig { keys: vec![(0.0, self.camera(root, "")?)] });
        };
        let frames = frames.as_object().ok_or_else(|| self.err("frames", "expected an object of frame: camera"))?;
        if frames.is_empty() {
            return Err(self.err("frames", "has no keys"));
        }
        let defaults: Map<String, Value> =
            root.iter().filter(|(k, _)| *k != "frames").map(|(k, v)| (k.clone(), v.clone())).collect();
        let mut keys: Vec<(f64, CameraKey, String)> = Vec::with_capacity(frames.len());
        for (name, cam) in frames {
            let prefix = format!("frames.{name}");
            let frame = name
                .trim()
                .parse::<f64>()
                .ok()
                .filter(|f| f.is_finite())
                .ok_or_else(|| self.err(&prefix, "is not a frame number"))?;
            let obj = cam.as_object().ok_or_else(|| self.err(&prefix, "expected a camera object"))?;
            if obj.contains_key("frames") {
                return Err(self.err(&join(&prefix, "frames"), "paths cannot nest"));
            }
            // Frame keys override the path-wide defaults; a frame's own look_at
            // or fov must also drop a default rotation or focal, or they would conflict.
            let mut merged = defaults.clone();
            for (a, b) in [
                ("look_at", "rotation"),
                ("rotation", "look_at"),
                ("rotation", "up"),
                ("fov", "focal"),
                ("fov", "aperture"),
            ] {
                if obj.contains_key(a) && !obj.contains_key(b) {
                    merged.remove(b);
                }
            }
            if ["focal", "aperture"].iter().any(|k| obj.contains_key(*k)) && !obj.contains_key("fov") {
                merged.remove("fov");
            }
            merged.extend(obj.iter().map(|(k, v)| (k.clone(), v.clone())));
            let key = self.camera(&merged, &prefix)?;
            if let Some((_, _, other)) = keys.iter().find(|(f, _, _)| *f == frame) {
                return Err(self.err(&prefix, format!("same frame as key \"{other}\"")));
            }
            keys.push((frame, key, name.clone()));
        }
        keys.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (_, first, first_name) = &keys[0];
        for (_, k, name) in &keys[1..] {
            if k.projection != first.projection {
                return Err(
                    self.err(&format!("frames.{name}.projection"), format!("differs from key \"{first_name}\""))
                );
            }
            if matches!(k.aim, Aim::LookAt { .. }) != matches!(first.aim, Aim::LookAt { .. }) {
                return Err(self.err(
                    &format!("frames.{name}"),
                    format!(
                        "mixes look_at and rotation with key \"{first_name}\"; keys must interpolate the same channels"
                    ),
                ));
            }
        }
        Ok(CameraRig { keys: keys.into_iter().map(|(f, k, _)| (f, k)).collect() })
    }
}

fn join(prefix: &str, key: &str) -> String {
    if prefix.is_empty() {
        key.to_string()
    } else {
        format!("{prefix}.{key}")
    }
}

/// Vertical field of view (degrees) of a lens as Houdini computes it: the
/// aperture is horizontal, `fov_x = 2·atan(aperture / 2 / focal)`, and the
/// vertical aperture is `aperture / aspect` (aspect = film width / height).
pub fn fov_y_from_lens(focal: f64, aperture: f64, aspect: f64) -> f64 {
    2.0 * (aperture / aspect / (2.0 * focal)).atan().to_degrees()
}

impl CameraRig {
    /// Reads a camera file; errors name the file.
    pub fn from_json_file(path: &Path) -> Result<Self, CameraFileError> {
        let name = path.display().to_string();
        let text = std::fs::read_to_string(path)
            .map_err(|e| CameraFileError::Read { file: name.clone(), reason: e.to_string() })?;
        Self::from_json_str(&text, &name)
    }

    /// Parses camera JSON; `name` stands for the file in error messages.
    pub fn from_json_str(s: &str, name: &str) -> Result<Self, CameraFileError> {
        let root: Value = serde_json::from_str(s)
            .map_err(|e| CameraFileError::Json { file: name.to_string(), reason: e.to_string().replace('\n', " ") })?;
        Parser { file: name }.rig(&root)
    }

    /// A rig of one camera for all frames.
    pub fn fixed(key: CameraKey) -> Self {
        Self { keys: vec![(0.0, key)] }
    }

    /// First and last keyed frame; `None` for a single camera.
    pub fn frame_range(&self) -> Option<(f64, f64)> {
        (self.keys.len() > 1).then(|| (self.keys[0].0, self.keys[self.keys.len() - 1].0))
    }

    /// The keys, sorted by frame (a single camera is one key at frame 0).
    pub fn keys(&self) -> &[(f64, CameraKey)] {
        &self.keys
    }

    /// The world-space camera at `frame`: each channel (position, look-at or
    /// rotation, up, field of view, aspect, ortho width) linear between the
    /// surrounding keys, held before the first key and after the last.
    pub fn key_at(&self, frame: f64) -> CameraKey {
        let keys = &self.keys;
        let last = keys.len() - 1;
        // NaN holds the first key.
        if frame.is_nan() || frame <= keys[0].0 {
            return keys[0].1;
        }
        if frame >= keys[last].0 {
            return keys[last].1;
        }
        let i = keys.partition_point(|(f, _)| *f <= frame) - 1;
        let ((f0, a), (f1, b)) = (&keys[i], &keys[i + 1]);
        let t = (frame - f0) / (f1 - f0);
        let lerp = |x: f64, y: f64| x + t * (y - x);
        let lerp3 = |x: [f64; 3], y: [f64; 3]| std::array::from_fn(|i| lerp(x[i], y[i]));
        let position = lerp3(a.position, b.position);
        let aim = match (a.aim, b.aim) {
            (Aim::LookAt { target: ta, up: ua }, Aim::LookAt { target: tb, up: ub }) => {
                let target = lerp3(ta, tb);
                let up = lerp3(ua, ub);
                // Opposite key ups can cancel or line up with the view; the
                // earlier key's up is the least surprising fallback.
                let dir = sub(target, position);
                let ok = |u: [f64; 3]| norm(cross(dir, u)) > 1e-6 * norm(dir) * norm(u) && norm(u) > 1e-12;
                let up = [up, ua, ub].into_iter().find(|&u| ok(u)).unwrap_or(up);
                Aim::LookAt { target, up }
            }
            (Aim::Rotation(ra), Aim::Rotation(rb)) => Aim::Rotation(lerp3(ra, rb)),
            // The parser rejects mixed paths; hold the earlier key if one is built by hand.
            (aim, _) => aim,
        };
        CameraKey {
            projection: a.projection,
            position,
            aim,
            fov_y_deg: lerp(a.fov_y_deg, b.fov_y_deg),
            aspect: lerp(a.aspect, b.aspect),
            ortho_width: lerp(a.ortho_width, b.ortho_width),
        }
    }

    /// The renderer's camera at `frame` in the index space of a grid whose
    /// `index_to_world` matrix (column vectors, translation in column 3) is
    /// given. A singular matrix yields a non-finite camera, which
    /// [`Camera::view`] rejects; see [`CameraKey::to_index_space`].
    pub fn at_frame(&self, frame: f64, index_to_world: &[[f64; 4]; 4]) -> Camera {
        self.key_at(frame).to_index_space(index_to_world)
    }
}

impl CameraKey {
    /// World-space eye basis `(forward, up)`, orthonormal.
    pub fn basis(&self) -> ([f64; 3], [f64; 3]) {
        match self.aim {
            Aim::LookAt { target, up } => {
                let f = unit(sub(target, self.position));
                let r = unit(cross(f, up));
                (f, cross(r, f))
            }
            Aim::Rotation(deg) => {
                let m = rotation_xyz(deg);
                (mat3_mul(&m, [0.0, 0.0, -1.0]), mat3_mul(&m, [0.0, 1.0, 0.0]))
            }
        }
    }

    /// This camera in a grid's index space. Eye and look-at point map as
    /// points, the view and up directions as directions, through the inverse
    /// of `index_to_world`. Under non-uniform voxel sizes angles are not
    /// preserved, so the field of view is re-measured: the vertical and
    /// horizontal tangents are those of the mapped frustum edges (averaged
    /// over opposite edges when a shear makes them asymmetric). A rotation
    /// camera's target is put one world unit ahead (only its direction
    /// matters to the renderer). An index-to-world matrix with negative
    /// determinant mirrors the picture left-right, which [`Camera`] cannot
    /// express. A singular matrix gives NaN coordinates.
    pub fn to_index_space(&self, index_to_world: &[[f64; 4]; 4]) -> Camera {
        let Some(inv) = world_to_index(index_to_world) else {
            return Camera {
                projection: self.projection,
                eye: [f32::NAN; 3],
                target: [f32::NAN; 3],
                up: [f32::NAN; 3],
                fov_y_deg: self.fov_y_deg as f32,
                aspect: self.aspect as f32,
            };
        };
        let lin = |v: [f64; 3]| -> [f64; 3] { std::array::from_fn(|r| (0..3).map(|c| inv[r][c] * v[c]).sum()) };
        let point = |p: [f64; 3]| -> [f64; 3] {
            let l = lin(p);
            std::array::from_fn(|r| l[r] + inv[r][3])
        };
        let (fw, uw) = self.basis();
        let rw = cross(fw, uw);
        let eye = point(self.position);
        let target = match self.aim {
            Aim::LookAt { target, .. } => point(target),
            Aim::Rotation(_) => point(add(self.position, fw)),
        };
        let (fi, ui, ri) = (lin(fw), lin(uw), lin(rw));
        let f = unit(fi);
        let r = unit(cross(f, ui));
        let u = cross(r, f);
        // Tangent of the mapped edge direction `fi ± tan·edge` about the index-space axes.
        let half_tan = |tan: f64, edge: [f64; 3], axis: [f64; 3]| {
            let side = |s: f64| {
                let d = add(fi, edge.map(|x| s * tan * x));
                (dot(d, axis) / dot(d, f)).abs()
            };
            0.5 * (side(1.0) + side(-1.0))
        };
        let tan_y = (self.fov_y_deg.to_radians() * 0.5).tan();
        let tan_x = tan_y * self.aspect;
        let (ty, tx) = (half_tan(tan_y, ui, u), half_tan(tan_x, ri, r));
        Camera {
            projection: self.projection,
            eye: eye.map(|x| x as f32),
            target: target.map(|x| x as f32),
            up: u.map(|x| x as f32),
            fov_y_deg: (2.0 * ty.atan()).to_degrees() as f32,
            aspect: (tx / ty) as f32,
        }
    }
}

/// Inverse of an affine column-vector matrix (translation in column 3), or
/// `None` when its 3x3 part is singular relative to its scale.
pub fn world_to_index(m: &[[f64; 4]; 4]) -> Option<[[f64; 4]; 4]> {
    let a = |r: usize, c: usize| m[r][c];
    let cof = |r: usize, c: usize| {
        let (r0, r1) = ((r + 1) % 3, (r + 2) % 3);
        let (c0, c1) = ((c + 1) % 3, (c + 2) % 3);
        a(r0, c0) * a(r1, c1) - a(r0, c1) * a(r1, c0)
    };
    let det: f64 = (0..3).map(|c| a(0, c) * cof(0, c)).sum();
    let scale: f64 = (0..3).map(|c| (0..3).map(|r| a(r, c) * a(r, c)).sum::<f64>().sqrt()).product();
    if !det.is_finite() || det.abs() <= 1e-12 * scale || scale.is_nan() {
        return None;
    }
    let lin: [[f64; 3]; 3] = std::array::from_fn(|r| std::array::from_fn(|c| cof(c, r) / det));
    Some(std::array::from_fn(|r| {
        if r == 3 {
            [0.0, 0.0, 0.0, 1.0]
        } else {
            let t = -(0..3).map(|c| lin[r][c] * m[c][3]).sum::<f64>();
            [lin[r][0], lin[r][1], lin[r][2], t]
        }
    }))
}

/// Houdini's XYZ rotate order: rotate about X first, then Y, then Z, so as a
/// column-vector matrix `R = Rz · Ry · Rx`.
fn rotation_xyz(deg: [f64; 3]) -> [[f64; 3]; 3] {
    let [x, y, z] = deg.map(f64::to_radians);
    let (sx, cx, sy, cy, sz, cz) = (x.sin(), x.cos(), y.sin(), y.cos(), z.sin(), z.cos());
    let rx = [[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]];
    let ry = [[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]];
    let rz = [[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]];
    mat3_mat3(&rz, &mat3_mat3(&ry, &rx))
}

fn mat3_mat3(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    std::array::from_fn(|r| std::array::from_fn(|c| (0..3).map(|k| a[r][k] * b[k][c]).sum()))
}
fn mat3_mul(m: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|r| (0..3).map(|c| m[r][c] * v[c]).sum())
}
