//! The official LHM / LHM++ motion format: one SMPL-X JSON per frame, as written by
//! `engine/pose_estimation/video2motion.py` and read by `core/runners/infer/utils.py`.
//!
//! Keys: `betas` (10+), `root_pose` (3), `body_pose` (21×3), `jaw_pose`, `leye_pose`,
//! `reye_pose` (3 each), `lhand_pose`, `rhand_pose` (15×3 each), `trans` (3), `focal` (fx, fy),
//! `princpt` (cx, cy), optional `img_size_wh` (w, h), `pad_ratio` and `expr`. Rotations are
//! axis-angle (radians); poses may be nested (`[[x, y, z], ...]`) or flat lists.
//! An optional FLAME sidecar (the same file name under `flame_params/` instead of
//! `smplx_params/`) replaces the jaw pose with `posecode[3..6]` and the eyes with `eyecode`.
//!
//! Camera: the official renderer puts the camera at the origin with identity extrinsics in the
//! OpenCV/ROS optical frame (x right, y down, z forward); the body is placed in camera space by
//! `root_pose` and `trans`. The render size is `W = 2·cx`, `H = 2·cy`.

use std::path::{Path, PathBuf};

use glam::{Quat, Vec3};
use serde_json::Value;

use crate::body::{BodyError, Pose, SMPLX_JOINT_NAMES};

/// SMPL-X body joints in `body_pose` (joints 1..=21).
pub const BODY_JOINTS: usize = 21;
/// Joints per hand in `lhand_pose` / `rhand_pose`.
pub const HAND_JOINTS: usize = 15;

/// Pinhole camera of one motion frame (camera at the origin, optical frame axes).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionCamera {
    /// Focal length along u (pixels).
    pub fx: f32,
    /// Focal length along v (pixels).
    pub fy: f32,
    /// Principal point u (pixels).
    pub cx: f32,
    /// Principal point v (pixels).
    pub cy: f32,
    /// Render width `2·cx`, rounded (pixels).
    pub width: u32,
    /// Render height `2·cy`, rounded (pixels).
    pub height: u32,
}

/// One frame of official SMPL-X motion.
#[derive(Debug, Clone, PartialEq)]
pub struct SmplxFrame {
    /// Shape coefficients.
    pub betas: Vec<f32>,
    /// Global orientation (axis-angle).
    pub root_pose: Vec3,
    /// Body joints 1..=21 (axis-angle).
    pub body_pose: Vec<Vec3>,
    /// Jaw (axis-angle).
    pub jaw_pose: Vec3,
    /// Left eye (axis-angle).
    pub leye_pose: Vec3,
    /// Right eye (axis-angle).
    pub reye_pose: Vec3,
    /// Left hand joints (axis-angle).
    pub lhand_pose: Vec<Vec3>,
    /// Right hand joints (axis-angle).
    pub rhand_pose: Vec<Vec3>,
    /// Translation in camera space (metres).
    pub trans: Vec3,
    /// Focal lengths (fx, fy).
    pub focal: [f32; 2],
    /// Principal point (cx, cy).
    pub princpt: [f32; 2],
    /// Source image size (w, h), when given.
    pub img_size_wh: Option<[f32; 2]>,
    /// Padding ratio of the source image, when given.
    pub pad_ratio: Option<f32>,
    /// FLAME expression coefficients (`expr`, or the sidecar's `expcode`), when given.
    pub expr: Option<Vec<f32>>,
}

/// Axis-angle vector to a quaternion.
pub fn axis_angle(v: Vec3) -> Quat {
    let angle = v.length();
    if angle < 1e-12 {
        Quat::IDENTITY
    } else {
        Quat::from_axis_angle(v / angle, angle)
    }
}

/// Reads one JSON object from `path`.
fn read_object(path: &Path) -> Result<serde_json::Map<String, Value>, BodyError> {
    let text = std::fs::read_to_string(path).map_err(|e| BodyError::io(path, e))?;
    match serde_json::from_str::<Value>(&text) {
        Ok(Value::Object(m)) => Ok(m),
        Ok(_) => Err(BodyError::format(path.display(), "not a JSON object")),
        Err(e) => Err(BodyError::format(path.display(), e.to_string())),
    }
}

/// All numbers of `v` (nested lists flattened), or `None` if anything else is found.
fn flatten(v: &Value, out: &mut Vec<f32>) -> bool {
    match v {
        Value::Number(n) => n.as_f64().map(|x| out.push(x as f32)).is_some(),
        Value::Array(items) => items.iter().all(|i| flatten(i, out)),
        _ => false,
    }
}

/// Field access that names the file and key in every error.
struct Fields<'a> {
    origin: String,
    map: &'a serde_json::Map<String, Value>,
}

impl Fields<'_> {
    fn numbers(&self, key: &str) -> Result<Option<Vec<f32>>, BodyError> {
        let Some(v) = self.map.get(key) else {
            return Ok(None);
        };
        let mut out = Vec::new();
        if !flatten(v, &mut out) {
            return Err(BodyError::format(
                &self.origin,
                format!("`{key}`: expected numbers or nested lists of numbers"),
            ));
        }
        if let Some(i) = out.iter().position(|x| !x.is_finite()) {
            return Err(BodyError::format(
                &self.origin,
                format!("`{key}`: value {i} is not finite"),
            ));
        }
        Ok(Some(out))
    }

    fn exact(&self, key: &str, n: usize, what: &str) -> Result<Vec<f32>, BodyError> {
        let v = self
            .numbers(key)?
            .ok_or_else(|| BodyError::missing(&self.origin, key))?;
        if v.len() != n {
            return Err(BodyError::format(
                &self.origin,
                format!("`{key}`: expected {n} numbers ({what}), got {}", v.len()),
            ));
        }
        Ok(v)
    }

    fn vec3(&self, key: &str) -> Result<Vec3, BodyError> {
        Ok(Vec3::from_slice(&self.exact(
            key,
            3,
            "axis-angle or xyz",
        )?))
    }

    fn vec3s(&self, key: &str, joints: usize) -> Result<Vec<Vec3>, BodyError> {
        let v = self.exact(key, 3 * joints, &format!("{joints}×3 axis-angle"))?;
        Ok(v.chunks_exact(3).map(Vec3::from_slice).collect())
    }

    fn pair(&self, key: &str) -> Result<[f32; 2], BodyError> {
        let v = self.exact(key, 2, "two values")?;
        Ok([v[0], v[1]])
    }
}

impl SmplxFrame {
    /// Parses one per-frame JSON (and its FLAME sidecar, if present); errors name the file
    /// and the key.
    pub fn from_file(path: &Path) -> Result<Self, BodyError> {
        let map = read_object(path)?;
        let f = Fields {
            origin: path.display().to_string(),
            map: &map,
        };
        let betas = f
            .numbers("betas")?
            .ok_or_else(|| BodyError::missing(&f.origin, "betas"))?;
        let mut frame = Self {
            betas,
            root_pose: f.vec3("root_pose")?,
            body_pose: f.vec3s("body_pose", BODY_JOINTS)?,
            jaw_pose: f.vec3("jaw_pose")?,
            leye_pose: f.vec3("leye_pose")?,
            reye_pose: f.vec3("reye_pose")?,
            lhand_pose: f.vec3s("lhand_pose", HAND_JOINTS)?,
            rhand_pose: f.vec3s("rhand_pose", HAND_JOINTS)?,
            trans: f.vec3("trans")?,
            focal: f.pair("focal")?,
            princpt: f.pair("princpt")?,
            img_size_wh: match f.map.contains_key("img_size_wh") {
                true => Some(f.pair("img_size_wh")?),
                false => None,
            },
            pad_ratio: match f.numbers("pad_ratio")? {
                None => None,
                Some(v) if v.len() == 1 => Some(v[0]),
                Some(v) => {
                    return Err(BodyError::format(
                        &f.origin,
                        format!("`pad_ratio`: expected one number, got {}", v.len()),
                    ))
                }
            },
            expr: f.numbers("expr")?,
        };
        if frame.focal.iter().any(|v| *v <= 0.0) || frame.princpt.iter().any(|v| *v <= 0.0) {
            return Err(BodyError::format(
                &f.origin,
                "`focal` and `princpt` must be positive",
            ));
        }
        if let Some(sidecar) = flame_sidecar(path) {
            frame.apply_flame(&sidecar)?;
        }
        Ok(frame)
    }

    /// Applies a FLAME sidecar: `expcode` → expression, `posecode[3..6]` → jaw,
    /// `eyecode` (6) → left and right eye.
    fn apply_flame(&mut self, path: &Path) -> Result<(), BodyError> {
        let map = read_object(path)?;
        let f = Fields {
            origin: path.display().to_string(),
            map: &map,
        };
        if let Some(e) = f.numbers("expcode")? {
            self.expr = Some(e);
        }
        if let Some(p) = f.numbers("posecode")? {
            if p.len() < 6 {
                return Err(BodyError::format(
                    &f.origin,
                    format!("`posecode`: expected 6 numbers, got {}", p.len()),
                ));
            }
            self.jaw_pose = Vec3::from_slice(&p[3..6]);
        }
        if f.map.contains_key("eyecode") {
            let e = f.exact("eyecode", 6, "left and right eye axis-angle")?;
            self.leye_pose = Vec3::from_slice(&e[..3]);
            self.reye_pose = Vec3::from_slice(&e[3..]);
        }
        Ok(())
    }

    /// The frame as a [`Pose`] of an SMPL-X skeleton (joint names [`SMPLX_JOINT_NAMES`]):
    /// `root_pose` becomes the root rotation about the pelvis, `trans` the root translation
    /// (SMPL-X model frame; a template shifted into the canonical frame adds its own offset).
    pub fn pose(&self) -> Pose {
        let mut pose = Pose::identity();
        let locals = std::iter::empty()
            .chain(self.body_pose.iter().enumerate().map(|(i, v)| (1 + i, *v)))
            .chain([
                (22, self.jaw_pose),
                (23, self.leye_pose),
                (24, self.reye_pose),
            ])
            .chain(
                self.lhand_pose
                    .iter()
                    .enumerate()
                    .map(|(i, v)| (25 + i, *v)),
            )
            .chain(
                self.rhand_pose
                    .iter()
                    .enumerate()
                    .map(|(i, v)| (40 + i, *v)),
            );
        for (joint, v) in locals {
            if v != Vec3::ZERO {
                pose.rotations
                    .insert(SMPLX_JOINT_NAMES[joint].to_string(), axis_angle(v));
            }
        }
        pose.root_rotation = axis_angle(self.root_pose);
        pose.root_translation = self.trans;
        pose
    }

    /// The frame's camera (identity extrinsics, optical frame).
    pub fn camera(&self) -> MotionCamera {
        MotionCamera {
            fx: self.focal[0],
            fy: self.focal[1],
            cx: self.princpt[0],
            cy: self.princpt[1],
            width: (2.0 * self.princpt[0]).round() as u32,
            height: (2.0 * self.princpt[1]).round() as u32,
        }
    }
}

/// The FLAME sidecar of a motion JSON: `.../smplx_params/X.json` → `.../flame_params/X.json`.
pub fn flame_sidecar(path: &Path) -> Option<PathBuf> {
    let dir = path.parent()?;
    if dir.file_name()? != "smplx_params" {
        return None;
    }
    let candidate = dir.parent()?.join("flame_params").join(path.file_name()?);
    candidate.is_file().then_some(candidate)
}

/// A motion sequence: the frames of a folder of per-frame JSONs, in file-name order.
#[derive(Debug, Clone, PartialEq)]
pub struct SmplxMotion {
    /// The file of each frame.
    pub files: Vec<PathBuf>,
    /// The frames.
    pub frames: Vec<SmplxFrame>,
}

impl SmplxMotion {
    /// Loads every `*.json` of `dir` (or of `dir/smplx_params` when that exists), sorted by
    /// file name.
    pub fn from_dir(dir: &Path) -> Result<Self, BodyError> {
        let nested = dir.join("smplx_params");
        let dir = if nested.is_dir() {
            nested
        } else {
            dir.to_path_buf()
        };
        let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
            .map_err(|e| BodyError::io(&dir, e))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_file() && p.extension().is_some_and(|x| x == "json"))
            .collect();
        files.sort();
        if files.is_empty() {
            return Err(BodyError::format(
                dir.display(),
                "no per-frame SMPL-X .json files",
            ));
        }
        let frames = files
            .iter()
            .map(|f| SmplxFrame::from_file(f))
            .collect::<Result<_, _>>()?;
        Ok(Self { files, frames })
    }

    /// Number of frames.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// True when there is no frame.
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }
}
