//! Motion for the MakeHuman template: the looping walk cycle, the T-pose, and the pose specs
//! the CLIs accept (`rest`, `tpose`, `walk:12`, `walk:0..60`).
//!
//! The walk combines the torso and head of the keyframed MakeHuman walk cycle
//! (`assets/body/walk.json`: Blender F-curves of `root`, `spine01`–`spine05`, `neck01`, `head`,
//! `clavicle.L/R`, evaluated as cubic Béziers and converted from Blender bone space into
//! [`Pose`] rotations with the bones' rest orientations) with the generated FK limb gait of
//! [`gait`]. The root's forward progression is removed (walking in place) and its sway kept;
//! [`walk_pose`] then grounds each frame (lowest foot vertex at y = 0). The cycle is 40 frames
//! long and loops.

mod clip;
pub mod gait;
pub mod official;
mod spec;

pub use clip::{Channel, ChannelProperty, KeyframeClip};
pub use spec::{parse_pose_spec, PoseSpec};

use super::{BodyError, BodyTemplate, Pose, Skeleton};
use glam::{Quat, Vec3};
use std::collections::{BTreeMap, HashMap};
use std::sync::OnceLock;

/// The committed walk-cycle channels.
pub const WALK_JSON: &str = include_str!("../../../assets/body/walk.json");
/// The committed T-pose rotations.
pub const TPOSE_JSON: &str = include_str!("../../../assets/body/tpose.json");

/// Frames per walk cycle.
pub const WALK_PERIOD_FRAMES: f32 = 40.0;

/// T-pose file content: Blender XYZ Euler rotations in each bone's local rest axes.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct EulerPose {
    /// Where the rotations come from.
    pub source: String,
    /// XYZ Euler angles (radians) per bone, in the bone's local (Blender rest) axes.
    pub bone_rotations: BTreeMap<String, [f32; 3]>,
}

struct Embedded {
    template: BodyTemplate,
    walk: KeyframeClip,
    tpose: Pose,
    /// Vertices labelled `foot.*`, used to keep the walk on the ground.
    foot_vertices: Vec<usize>,
}

fn embedded() -> &'static Embedded {
    static EMBEDDED: OnceLock<Embedded> = OnceLock::new();
    EMBEDDED.get_or_init(|| {
        let template = BodyTemplate::load_default().expect("embedded template is valid");
        let walk: KeyframeClip =
            serde_json::from_str(WALK_JSON).expect("embedded walk.json is valid");
        let tpose: EulerPose =
            serde_json::from_str(TPOSE_JSON).expect("embedded tpose.json is valid");
        let tpose = euler_pose(&template.skeleton, &tpose).expect("tpose bones are rig bones");
        let foot_vertices = foot_vertices(&template);
        Embedded {
            template,
            walk,
            tpose,
            foot_vertices,
        }
    })
}

/// Blender's XYZ Euler rotation (X applied first).
pub fn blender_euler_xyz(angles: [f32; 3]) -> Quat {
    Quat::from_rotation_z(angles[2])
        * Quat::from_rotation_y(angles[1])
        * Quat::from_rotation_x(angles[0])
}

/// Converts bone-space Euler rotations into a [`Pose`] for `skeleton`.
pub fn euler_pose(skeleton: &Skeleton, euler: &EulerPose) -> Result<Pose, BodyError> {
    let mut pose = Pose::identity();
    let mut unknown = Vec::new();
    for (bone, angles) in &euler.bone_rotations {
        match skeleton.bone_index(bone) {
            Some(i) => {
                let q = skeleton.bone_local_to_canonical(i, blender_euler_xyz(*angles));
                pose.rotations.insert(bone.clone(), q);
            }
            None => unknown.push(bone.clone()),
        }
    }
    if unknown.is_empty() {
        Ok(pose)
    } else {
        Err(BodyError::UnknownBones(unknown))
    }
}

/// The MakeHuman T-pose (arms horizontal) relative to the canonical A-pose.
pub fn tpose() -> Pose {
    embedded().tpose.clone()
}

/// Walk-cycle pose at `frame` (any real number; loops every [`WALK_PERIOD_FRAMES`]) for the
/// embedded template, grounded: the root is moved vertically so that the lowest foot vertex
/// touches y = 0 (the clip's own vertical bob is replaced by this contact constraint).
pub fn walk_pose(frame: f32) -> Pose {
    let e = embedded();
    let pose = walk_pose_with(&e.template.skeleton, &e.walk, frame);
    ground(&e.template, &e.foot_vertices, pose)
}

/// Indices of the vertices whose part name starts with `foot`.
pub fn foot_vertices(template: &BodyTemplate) -> Vec<usize> {
    let is_foot: Vec<bool> = template
        .part_names
        .iter()
        .map(|n| n.starts_with("foot"))
        .collect();
    (0..template.vertices.len())
        .filter(|&i| is_foot[template.part_labels[i] as usize])
        .collect()
}

/// Shifts `pose` vertically so the lowest of `vertices` (posed) lies at y = 0.
pub fn ground(template: &BodyTemplate, vertices: &[usize], mut pose: Pose) -> Pose {
    let m = template.skeleton.skinning_matrices(&pose);
    let lowest = vertices
        .iter()
        .map(|&i| {
            template
                .skin
                .blended(i, &m)
                .transform_point3(template.vertices[i])
                .y
        })
        .fold(f32::INFINITY, f32::min);
    if lowest.is_finite() {
        pose.root_translation.y -= lowest;
    }
    pose
}

/// Walk pose at `frame` for a MakeHuman-named `skeleton` and keyframed torso `clip`
/// (channels of bones the skeleton lacks are skipped).
pub fn walk_pose_with(skeleton: &Skeleton, clip: &KeyframeClip, frame: f32) -> Pose {
    let period = clip.period_frames.max(1.0);
    let f = frame.rem_euclid(period);
    let mut euler: HashMap<&str, [f32; 3]> = HashMap::new();
    let mut location: HashMap<&str, [f32; 3]> = HashMap::new();
    for ch in &clip.channels {
        let axis = ch.axis.min(2);
        match ch.property {
            ChannelProperty::RotationEuler => {
                euler.entry(ch.bone.as_str()).or_default()[axis] = ch.evaluate(f);
            }
            ChannelProperty::Location => {
                // Walking in place: remove the steady forward progression.
                let first = ch.keys.first().map_or(0.0, |k| k[0]);
                let v = ch.evaluate(f) - ch.drift_per_frame() * (f - first);
                location.entry(ch.bone.as_str()).or_default()[axis] = v;
            }
        }
    }
    let mut pose = Pose::identity();
    for (bone, angles) in euler {
        if let Some(i) = skeleton.bone_index(bone) {
            let q = skeleton.bone_local_to_canonical(i, blender_euler_xyz(angles));
            pose.rotations.insert(bone.to_string(), q);
        }
    }
    for (bone, loc) in location {
        if let Some(i) = skeleton.bone_index(bone) {
            pose.root_translation += skeleton.bone_local_vector_to_canonical(i, Vec3::from(loc));
        }
    }
    for (bone, q) in gait::limb_rotations(f, period) {
        if skeleton.bone_index(&bone).is_some() {
            pose.rotations.insert(bone, q);
        }
    }
    pose
}
