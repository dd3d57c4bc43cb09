//! Where BlazePose's 33 landmarks sit on a body template.
//!
//! # MakeHuman (the embedded template), chosen by inspecting its rig and mesh
//! Joints of the rig (bone heads):
//! * shoulders: `upperarm01.L/R` (the glenohumeral joint; `shoulder01` is the clavicle's
//!   end, 5 cm inwards and above);
//! * elbows `lowerarm01`, wrists `wrist`, hips `upperleg01` (the femoral heads, 11 cm either
//!   side of the midline), knees `lowerleg01`, ankles `foot`;
//! * index and little-finger knuckles: `finger2-1`, `finger5-1` (MCP joints, as BlazePose
//!   marks "knuckle 1"); thumb: `finger1-3` (the thumb's second knuckle, its IP joint).
//!
//! Small vertex sets (their skinned mean), by rules on the part labels, so that reshaped
//! MakeHuman templates get them too:
//! * nose: the frontmost `head` vertices (within 1 mm of the largest z): the nose tip;
//! * eye centre: the frontmost vertices of `eye_cavity.L/R` (within 1 mm), the middle of
//!   the eye opening; inner and outer eye corners: the cavity's vertices nearest to and
//!   furthest from the midline (within 1 mm of the extreme |x|);
//! * ears: the `head` vertices within 5 mm of the head's widest point on that side (the
//!   outer rim of the ear, at eye height);
//! * mouth corners: among the `mouth_cavity` vertices within 25 mm of its front, those
//!   furthest from the midline (within 1 mm): the lip commissures;
//! * heels: the rearmost `foot.L/R` vertices (within 5 mm of the smallest z);
//! * foot index: the foremost `foot.L/R` vertices (within 3 mm of the largest z), the tips
//!   of the big and second toes.
//!
//! # SMPL-X
//! Body and hand landmarks are SMPL-X joints (`left_shoulder`, `left_elbow`, `left_wrist`,
//! `left_index1`, `left_pinky1`, `left_thumb3`, `left_hip`, `left_knee`, `left_ankle`, ...).
//! Face, heel and toe landmarks have no joint; they are carried over from the MakeHuman
//! template as offsets from its `head` joint (face) and ankle (heel, toe), scaled by the
//! ratio of the two skeletons' head-to-ankle heights, and fixed to SMPL-X's `head` and
//! ankle. Both rest poses hold the head level and the feet flat, facing +Z, so the offsets
//! keep their meaning. (SMPL-X's own landmark vertex ids would need the licensed mesh.)

use super::skeleton_map::{BoneMap, SkeletonKind};
use super::PoseSolveError;
use crate::body::{BodyTemplate, Pose};
use crate::perception::{LandmarkId, BODY_LANDMARKS};
use glam::Vec3;
use std::sync::OnceLock;

/// Where one landmark sits on a template.
#[derive(Debug, Clone, PartialEq)]
pub struct LandmarkAnchor {
    /// The bone whose motion carries the landmark.
    pub bone: usize,
    /// Rest position (canonical frame, metres).
    pub rest: Vec3,
    /// Template vertices whose skinned mean is the landmark; empty when the landmark is a
    /// point fixed to `bone` (a joint, or a point carried over from another template).
    pub vertices: Vec<usize>,
}

/// The 33 landmarks of one template, in [`LandmarkId`] order.
#[derive(Debug, Clone, PartialEq)]
pub struct LandmarkRig {
    /// One anchor per landmark.
    pub anchors: Vec<LandmarkAnchor>,
}

impl LandmarkRig {
    /// The landmarks of `template` (MakeHuman rig or SMPL-X joints; see the module doc).
    pub fn new(template: &BodyTemplate) -> Result<Self, PoseSolveError> {
        let map = BoneMap::new(&template.skeleton)?;
        match map.kind {
            SkeletonKind::MakeHuman => makehuman(template, &map),
            SkeletonKind::SmplX => Ok(smplx(template, &map, makehuman_reference()?)),
        }
    }

    /// Rest positions, in [`LandmarkId`] order.
    pub fn rest(&self) -> [Vec3; BODY_LANDMARKS] {
        std::array::from_fn(|i| self.anchors[i].rest)
    }

    /// Landmark positions on `template` posed by `pose` (world frame): vertex landmarks by
    /// linear blend skinning, the others moved with their bone.
    pub fn posed(&self, template: &BodyTemplate, pose: &Pose) -> [Vec3; BODY_LANDMARKS] {
        let m = template.skeleton.skinning_matrices(pose);
        std::array::from_fn(|i| {
            let a = &self.anchors[i];
            if a.vertices.is_empty() {
                return m[a.bone].transform_point3(a.rest);
            }
            let sum: Vec3 = a
                .vertices
                .iter()
                .map(|&v| {
                    template
                        .skin
                        .blended(v, &m)
                        .transform_point3(template.vertices[v])
                })
                .sum();
            sum / a.vertices.len() as f32
        })
    }
}

/// The 33 landmarks of `template` posed by `pose` (world frame, metres): see the module doc
/// for where each sits.
pub fn template_landmarks(
    template: &BodyTemplate,
    pose: &Pose,
) -> Result<[Vec3; BODY_LANDMARKS], PoseSolveError> {
    Ok(LandmarkRig::new(template)?.posed(template, pose))
}

/// Which landmark a joint or vertex rule fills, for the two sides.
fn joint_landmarks(map: &BoneMap) -> Vec<(LandmarkId, usize)> {
    use LandmarkId::*;
    let mut out = Vec::with_capacity(18);
    for (side, ids) in [
        (
            0,
            [
                LeftShoulder,
                LeftElbow,
                LeftWrist,
                LeftIndex,
                LeftPinky,
                LeftThumb,
                LeftHip,
                LeftKnee,
                LeftAnkle,
            ],
        ),
        (
            1,
            [
                RightShoulder,
                RightElbow,
                RightWrist,
                RightIndex,
                RightPinky,
                RightThumb,
                RightHip,
                RightKnee,
                RightAnkle,
            ],
        ),
    ] {
        let bones = [
            map.upper_arm[side],
            map.forearm[side],
            map.hand[side],
            map.index_knuckle[side],
            map.pinky_knuckle[side],
            map.thumb_knuckle[side],
            map.thigh[side],
            map.shin[side],
            map.foot[side],
        ];
        out.extend(ids.into_iter().zip(bones));
    }
    out
}

fn makehuman(template: &BodyTemplate, map: &BoneMap) -> Result<LandmarkRig, PoseSolveError> {
    use LandmarkId::*;
    let skeleton = &template.skeleton;
    let mut anchors: Vec<Option<LandmarkAnchor>> = vec![None; BODY_LANDMARKS];
    for (id, bone) in joint_landmarks(map) {
        anchors[id.index()] = Some(LandmarkAnchor {
            bone,
            rest: skeleton.joints[bone],
            vertices: Vec::new(),
        });
    }
    let finder = VertexFinder { template };
    let head = finder.part("head", Nose)?;
    let mut rules: Vec<(LandmarkId, Vec<usize>)> =
        vec![(Nose, finder.extreme(&head, 0.001, |v| v.z))];
    for (sign, side, [inner, centre, outer, ear, mouth, heel, toe]) in [
        (
            1.0f32,
            "L",
            [
                LeftEyeInner,
                LeftEye,
                LeftEyeOuter,
                LeftEar,
                MouthLeft,
                LeftHeel,
                LeftFootIndex,
            ],
        ),
        (
            -1.0,
            "R",
            [
                RightEyeInner,
                RightEye,
                RightEyeOuter,
                RightEar,
                MouthRight,
                RightHeel,
                RightFootIndex,
            ],
        ),
    ] {
        let eye = finder.part(&format!("eye_cavity.{side}"), centre)?;
        rules.push((inner, finder.extreme(&eye, 0.001, |v| -v.x * sign)));
        rules.push((centre, finder.extreme(&eye, 0.001, |v| v.z)));
        rules.push((outer, finder.extreme(&eye, 0.001, |v| v.x * sign)));
        let head_side = finder.filter(&head, |v| v.x * sign > 0.0);
        let head_side = finder.nonempty(head_side, ear, "head, that side")?;
        rules.push((ear, finder.extreme(&head_side, 0.005, |v| v.x * sign)));
        let mouth_all = finder.part("mouth_cavity", mouth)?;
        let front = finder.extreme(&mouth_all, 0.025, |v| v.z);
        let front_side = finder.filter(&front, |v| v.x * sign > 0.0);
        let front_side = finder.nonempty(front_side, mouth, "mouth_cavity front, that side")?;
        rules.push((mouth, finder.extreme(&front_side, 0.001, |v| v.x * sign)));
        let foot = finder.part(&format!("foot.{side}"), heel)?;
        rules.push((heel, finder.extreme(&foot, 0.005, |v| -v.z)));
        rules.push((toe, finder.extreme(&foot, 0.003, |v| v.z)));
    }
    for (id, vertices) in rules {
        let rest =
            vertices.iter().map(|&v| template.vertices[v]).sum::<Vec3>() / vertices.len() as f32;
        anchors[id.index()] = Some(LandmarkAnchor {
            bone: dominant_bone(template, &vertices),
            rest,
            vertices,
        });
    }
    Ok(LandmarkRig {
        anchors: anchors
            .into_iter()
            .map(|a| a.expect("every landmark has a rule"))
            .collect(),
    })
}

/// Vertex searches over one template.
struct VertexFinder<'a> {
    template: &'a BodyTemplate,
}

impl VertexFinder<'_> {
    /// Vertices labelled `part`; an error naming `landmark` when there are none.
    fn part(&self, part: &str, landmark: LandmarkId) -> Result<Vec<usize>, PoseSolveError> {
        let t = self.template;
        let label = t.part_names.iter().position(|p| p == part);
        let found: Vec<usize> = match label {
            Some(l) => (0..t.vertices.len())
                .filter(|&i| t.part_labels[i] as usize == l)
                .collect(),
            None => Vec::new(),
        };
        self.nonempty(found, landmark, &format!("part `{part}`"))
    }

    fn nonempty(
        &self,
        found: Vec<usize>,
        landmark: LandmarkId,
        what: &str,
    ) -> Result<Vec<usize>, PoseSolveError> {
        if found.is_empty() {
            Err(PoseSolveError::NoVertices {
                landmark: landmark.name(),
                reason: format!("no vertices in {what}"),
            })
        } else {
            Ok(found)
        }
    }

    fn filter(&self, set: &[usize], keep: impl Fn(Vec3) -> bool) -> Vec<usize> {
        set.iter()
            .copied()
            .filter(|&i| keep(self.template.vertices[i]))
            .collect()
    }

    /// The vertices of a non-empty `set` whose `key` is within `within` of its maximum.
    fn extreme(&self, set: &[usize], within: f32, key: impl Fn(Vec3) -> f32) -> Vec<usize> {
        let v = &self.template.vertices;
        let max = set.iter().map(|&i| key(v[i])).fold(f32::MIN, f32::max);
        set.iter()
            .copied()
            .filter(|&i| key(v[i]) >= max - within)
            .collect()
    }
}

/// The bone with the largest summed skinning weight over `vertices`.
fn dominant_bone(template: &BodyTemplate, vertices: &[usize]) -> usize {
    let mut total = vec![0.0f32; template.skeleton.len()];
    for &v in vertices {
        for (b, w) in template.skin.bones[v].iter().zip(&template.skin.weights[v]) {
            total[*b as usize] += *w;
        }
    }
    total
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(b.1))
        .map_or(0, |(i, _)| i)
}

/// Face, heel and toe landmarks of the embedded MakeHuman template as offsets from its head
/// joint and ankles, with its head-to-ankle height.
struct Reference {
    /// Per landmark: `None` for joint landmarks, else (anchor joint: head, left ankle or
    /// right ankle, offset from that joint).
    offsets: Vec<Option<(ReferenceJoint, Vec3)>>,
    height: f32,
}

#[derive(Debug, Clone, Copy)]
enum ReferenceJoint {
    Head,
    Ankle(usize),
}

fn makehuman_reference() -> Result<&'static Reference, PoseSolveError> {
    static REFERENCE: OnceLock<Reference> = OnceLock::new();
    if let Some(r) = REFERENCE.get() {
        return Ok(r);
    }
    let template = BodyTemplate::load_default()?;
    let map = BoneMap::new(&template.skeleton)?;
    let rig = makehuman(&template, &map)?;
    let joints = &template.skeleton.joints;
    let reference = build_reference(&rig, &map, joints);
    Ok(REFERENCE.get_or_init(|| reference))
}

fn reference_joint(id: LandmarkId) -> Option<ReferenceJoint> {
    use LandmarkId::*;
    match id {
        Nose | LeftEyeInner | LeftEye | LeftEyeOuter | RightEyeInner | RightEye | RightEyeOuter
        | LeftEar | RightEar | MouthLeft | MouthRight => Some(ReferenceJoint::Head),
        LeftHeel | LeftFootIndex => Some(ReferenceJoint::Ankle(0)),
        RightHeel | RightFootIndex => Some(ReferenceJoint::Ankle(1)),
        _ => None,
    }
}

fn head_to_ankle(map: &BoneMap, joints: &[Vec3]) -> f32 {
    joints[map.head].y - 0.5 * (joints[map.foot[0]].y + joints[map.foot[1]].y)
}

fn joint_of(reference: ReferenceJoint, map: &BoneMap) -> usize {
    match reference {
        ReferenceJoint::Head => map.head,
        ReferenceJoint::Ankle(side) => map.foot[side],
    }
}

fn build_reference(rig: &LandmarkRig, map: &BoneMap, joints: &[Vec3]) -> Reference {
    let offsets = LandmarkId::ALL
        .iter()
        .map(|&id| {
            reference_joint(id)
                .map(|j| (j, rig.anchors[id.index()].rest - joints[joint_of(j, map)]))
        })
        .collect();
    Reference {
        offsets,
        height: head_to_ankle(map, joints),
    }
}

fn smplx(template: &BodyTemplate, map: &BoneMap, reference: &Reference) -> LandmarkRig {
    let joints = &template.skeleton.joints;
    let scale = head_to_ankle(map, joints) / reference.height;
    let mut anchors: Vec<Option<LandmarkAnchor>> = vec![None; BODY_LANDMARKS];
    for (id, bone) in joint_landmarks(map) {
        anchors[id.index()] = Some(LandmarkAnchor {
            bone,
            rest: joints[bone],
            vertices: Vec::new(),
        });
    }
    for (i, offset) in reference.offsets.iter().enumerate() {
        if let Some((joint, offset)) = offset {
            let bone = joint_of(*joint, map);
            anchors[i] = Some(LandmarkAnchor {
                bone,
                rest: joints[bone] + *offset * scale,
                vertices: Vec::new(),
            });
        }
    }
    LandmarkRig {
        anchors: anchors
            .into_iter()
            .map(|a| a.expect("joint or carried-over landmark"))
            .collect(),
    }
}
