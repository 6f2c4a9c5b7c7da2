//! The cameras Θ a volume is stylized and previewed from, built for a
//! dense box of voxels: the front camera, camera sets around the box
//! (omniview, ring) turned to the file's up axis, and shot cameras from a
//! camera file mapped into the box's index space (docs/guide/volumes.md).

use anyhow::{bail, Result};
use nst3d_io::vdb::Transform;
use nst3d_render::{Camera, CameraRig, Projection};

use crate::settings::{UpAxis, VolumeSettings};

/// A camera set as named on the command line.
#[derive(Clone, Debug, PartialEq)]
pub enum CameraSet {
    /// The default front camera.
    Front,
    /// `omniview:N`: N Poisson-disk cameras on a sphere (Sec. 4).
    Omniview(usize),
    /// `ring:N[:ELEV]`: a turntable of N cameras at ELEV degrees.
    Ring(usize, f32),
}

/// How the cameras of a set look: projection, field of view, up axis and
/// the seed of random placements.
#[derive(Clone, Copy, Debug)]
pub struct Lens {
    /// Camera projection.
    pub projection: Projection,
    /// Vertical field of view, degrees.
    pub fov: f32,
    /// The file's up axis.
    pub up: UpAxis,
    /// Seed of the omniview placement.
    pub seed: u64,
}

impl Lens {
    /// The lens a job's settings describe.
    pub fn of(s: &VolumeSettings) -> Self {
        Self { projection: s.projection, fov: s.fov, up: s.up, seed: s.camera_seed }
    }
}

impl CameraSet {
    /// Parses `front`, `omniview:N` or `ring:N[:ELEV]`.
    pub fn parse(s: &str) -> Result<Self> {
        let parts: Vec<&str> = s.split(':').collect();
        let count = |p: &str| -> Result<usize> {
            match p.parse::<usize>() {
                Ok(n) if (1..=1024).contains(&n) => Ok(n),
                _ => bail!("camera set '{s}': count must be a whole number from 1 to 1024"),
            }
        };
        match parts.as_slice() {
            ["front"] => Ok(Self::Front),
            ["omniview", n] => Ok(Self::Omniview(count(n)?)),
            ["ring", n] => Ok(Self::Ring(count(n)?, 0.0)),
            ["ring", n, e] => match e.parse::<f32>() {
                Ok(el) if (-89.0..=89.0).contains(&el) => Ok(Self::Ring(count(n)?, el)),
                _ => bail!("camera set '{s}': elevation must be degrees in [-89, 89]"),
            },
            _ => bail!("unknown camera set '{s}' (expected front, omniview:N or ring:N[:ELEV])"),
        }
    }

    /// The cameras for a grid of `dims` voxels. Omniview and ring cameras
    /// are built around +y and turned so their axis is the file's up axis.
    pub fn cameras(&self, lens: &Lens, dims: [usize; 3]) -> Vec<Camera> {
        // Frame y is index z, frame z is index −y (`UpAxis::from_y_up`): the
        // ring's first camera then sits on the −y side, as the z-up front camera.
        let yup_dims = match lens.up {
            UpAxis::Y => dims,
            UpAxis::Z => [dims[0], dims[2], dims[1]],
        };
        let turn = |v| lens.up.from_y_up(v);
        let cams = match *self {
            Self::Front => return vec![front_camera(dims, lens.up, lens.projection, lens.fov)],
            Self::Omniview(n) => nst3d_render::omniview(n, lens.seed, yup_dims, lens.projection),
            Self::Ring(n, el) => nst3d_render::ring(n, el, yup_dims, lens.projection),
        };
        let (c_frame, c_index) = (yup_dims.map(|n| (n as f32 - 1.0) * 0.5), dims.map(|n| (n as f32 - 1.0) * 0.5));
        let point = |p: [f32; 3]| {
            let r = turn(std::array::from_fn(|a| p[a] - c_frame[a]));
            std::array::from_fn(|a| c_index[a] + r[a])
        };
        cams.into_iter().map(|c| Camera { eye: point(c.eye), target: point(c.target), up: turn(c.up), ..c }).collect()
    }
}

/// Where a job's cameras come from: a named set or a camera file.
pub enum Cameras {
    /// The same set for every frame, in the dense box's index space.
    Set(CameraSet, Lens),
    /// A shot camera or path, mapped per frame.
    Rig(CameraRig),
}

impl Cameras {
    /// The camera file if there is one, else the named set.
    pub fn of(s: &VolumeSettings) -> Result<Self> {
        Ok(match &s.camera_file {
            Some(p) => Self::Rig(CameraRig::from_json_file(p)?),
            None => Self::Set(CameraSet::parse(&s.cameras)?, Lens::of(s)),
        })
    }

    /// Θ at `frame` for a dense box of `dims` whose voxel (0,0,0) is index
    /// `origin` of a grid with `transform`.
    pub fn at(&self, frame: f64, dims: [usize; 3], transform: &Transform, origin: [i32; 3]) -> Vec<Camera> {
        match self {
            Self::Set(set, lens) => set.cameras(lens, dims),
            Self::Rig(rig) => vec![rig.at_frame(frame, &dense_index_to_world(transform, origin))],
        }
    }
}

/// Index-to-world matrix of a dense box starting at index `origin`: the
/// grid's transform after a translation by the origin.
pub fn dense_index_to_world(transform: &Transform, origin: [i32; 3]) -> [[f64; 4]; 4] {
    let mut m = transform.index_to_world;
    for r in 0..3 {
        m[r][3] += (0..3).map(|c| transform.index_to_world[r][c] * origin[c] as f64).sum::<f64>();
    }
    m
}

/// A front camera for a grid of `dims` voxels: looking at the centre from
/// the side where the up axis stays vertical in the picture.
pub fn front_camera(dims: [usize; 3], up: UpAxis, projection: Projection, fov: f32) -> Camera {
    let c = dims.map(|n| (n as f32 - 1.0) * 0.5);
    let extent = dims.iter().copied().max().unwrap_or(1) as f32;
    let (dir, upv) = match up {
        // z up: look along +y from the -y side (x to the right).
        UpAxis::Z => ([0.0, 1.0, 0.0], [0.0, 0.0, 1.0]),
        // y up: look along -z from the +z side, as Houdini's default camera.
        UpAxis::Y => ([0.0, 0.0, -1.0], [0.0, 1.0, 0.0]),
    };
    // Horizontal extent over vertical extent of the grid as seen from this side.
    let aspect = match up {
        UpAxis::Z => dims[0] as f32 / dims[2].max(1) as f32,
        UpAxis::Y => dims[0] as f32 / dims[1].max(1) as f32,
    };
    // Far enough that the grid's bounding sphere fits the field of view.
    let half = (fov.to_radians() * 0.5).tan().min(1e3);
    let radius = 0.5 * 3f32.sqrt() * extent;
    let dist = radius / (half * aspect.min(1.0)).max(1e-3) + radius;
    let eye = [0, 1, 2].map(|a| c[a] - dir[a] * dist);
    Camera { projection, eye, target: c, up: upv, fov_y_deg: fov, aspect }
}

/// `count` [`nst3d_render::ring`] cameras around the grid, starting at the
/// front view of [`front_camera`] and turning towards +x. `ring` turns
/// about +y; for a z-up file the ring is rotated +90° about x, which maps
/// its front camera (eye on +z, +y up) onto the z-up front camera (eye on
/// −y, +z up).
pub fn turntable(count: usize, elevation: f32, dims: [usize; 3], up: UpAxis, projection: Projection) -> Vec<Camera> {
    let cams = nst3d_render::ring(count, elevation, dims, projection);
    match up {
        UpAxis::Y => cams,
        UpAxis::Z => {
            let rot = |v| UpAxis::Z.from_y_up(v);
            cams.into_iter()
                .map(|c| {
                    let rel = rot(std::array::from_fn(|a| c.eye[a] - c.target[a]));
                    Camera { eye: std::array::from_fn(|a| c.target[a] + rel[a]), up: rot(c.up), ..c }
                })
                .collect()
        }
    }
}
