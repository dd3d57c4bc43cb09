//! Which bones of a skeleton carry which body segment, and which joints are BlazePose
//! landmarks: one table for the MakeHuman rig and one for the SMPL-X joints, so the solver
//! produces the same motion for either.
//!
//! MakeHuman splits the upper arm, forearm, thigh and shin into two bones each
//! (`upperarm01`/`upperarm02`, ...). The first bone of each pair carries the swing and the
//! twist of the whole segment; the second stays at rest, except `lowerarm02`, MakeHuman's
//! forearm twist bone, which carries the forearm's pronation (the part of the hand's
//! rotation about the forearm), so the wrist bone is left with the hand's swing. SMPL-X has
//! no twist bone: its wrist carries the whole hand rotation. The spine's bend is shared by
//! three bones (MakeHuman `spine04`, `spine03`, `spine02`; SMPL-X `spine1`–`spine3`), a
//! quarter, a half and a quarter, so the bend's mean pivot sits near the lumbar spine.

use super::PoseSolveError;
use crate::body::Skeleton;
use glam::Vec3;

/// The skeleton families the solver knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SkeletonKind {
    /// The 163-bone MakeHuman rig of the embedded template.
    MakeHuman,
    /// The 55 SMPL-X joints ([`crate::body::SMPLX_JOINT_NAMES`]).
    SmplX,
}

impl SkeletonKind {
    /// The family of `skeleton`, told by its bone names.
    pub fn detect(skeleton: &Skeleton) -> Result<Self, PoseSolveError> {
        if skeleton.bone_index("upperarm01.L").is_some() {
            Ok(Self::MakeHuman)
        } else if skeleton.bone_index("left_shoulder").is_some() {
            Ok(Self::SmplX)
        } else {
            Err(PoseSolveError::UnknownSkeleton)
        }
    }

    /// Human-readable name.
    pub fn name(self) -> &'static str {
        match self {
            Self::MakeHuman => "MakeHuman",
            Self::SmplX => "SMPL-X",
        }
    }
}

/// Bone names of one family; `{s}` stands for the side (`L`/`R` or `left`/`right`).
struct Names {
    spine: [(&'static str, f32); 3],
    neck: &'static str,
    head: &'static str,
    upper_arm: &'static str,
    forearm: &'static str,
    forearm_twist: Option<&'static str>,
    hand: &'static str,
    thigh: &'static str,
    shin: &'static str,
    foot: &'static str,
    index_knuckle: &'static str,
    pinky_knuckle: &'static str,
    thumb_knuckle: &'static str,
    /// Elbow hinge axis (canonical rest axes, left side; the right one is its mirror image)
    /// used when the rest arm is too straight to give it.
    elbow_hinge_left: Vec3,
}

const MAKEHUMAN: Names = Names {
    spine: [("spine04", 0.25), ("spine03", 0.5), ("spine02", 0.25)],
    neck: "neck01",
    head: "head",
    upper_arm: "upperarm01.{s}",
    forearm: "lowerarm01.{s}",
    forearm_twist: Some("lowerarm02.{s}"),
    hand: "wrist.{s}",
    thigh: "upperleg01.{s}",
    shin: "lowerleg01.{s}",
    foot: "foot.{s}",
    // finger1 is the thumb, finger2 the index, finger5 the little finger; `-1` bones start at
    // the knuckle (MCP joint); the thumb's `-3` bone starts at its second knuckle (IP joint).
    index_knuckle: "finger2-1.{s}",
    pinky_knuckle: "finger5-1.{s}",
    thumb_knuckle: "finger1-3.{s}",
    elbow_hinge_left: Vec3::new(-1.0, 0.0, 0.0),
};

const SMPLX: Names = Names {
    spine: [("spine1", 0.25), ("spine2", 0.5), ("spine3", 0.25)],
    neck: "neck",
    head: "head",
    upper_arm: "{s}_shoulder",
    forearm: "{s}_elbow",
    forearm_twist: None,
    hand: "{s}_wrist",
    thigh: "{s}_hip",
    shin: "{s}_knee",
    foot: "{s}_ankle",
    index_knuckle: "{s}_index1",
    pinky_knuckle: "{s}_pinky1",
    thumb_knuckle: "{s}_thumb3",
    // Rest arm along +x: bending the forearm forward (+z) turns about −y.
    elbow_hinge_left: Vec3::new(0.0, -1.0, 0.0),
};

/// Bone indices of the segments the solver drives, per side `[left, right]`.
///
/// The joints of `upper_arm`, `forearm`, `hand`, `thigh`, `shin` and `foot` are the
/// shoulder, elbow, wrist, hip, knee and ankle landmarks; the knuckle bones' joints are the
/// hand landmarks.
#[derive(Debug, Clone, PartialEq)]
pub struct BoneMap {
    /// Skeleton family.
    pub kind: SkeletonKind,
    /// Spine bones, root to chest, and the share of the spine's bend each carries (sum 1).
    pub spine: Vec<(usize, f32)>,
    /// Neck bone (carries the head's position).
    pub neck: usize,
    /// Head bone.
    pub head: usize,
    /// Upper arm (swing and twist).
    pub upper_arm: [usize; 2],
    /// Forearm (elbow bend).
    pub forearm: [usize; 2],
    /// Forearm twist bone (pronation), where the rig has one.
    pub forearm_twist: [Option<usize>; 2],
    /// Hand (wrist bone).
    pub hand: [usize; 2],
    /// Thigh (swing and twist).
    pub thigh: [usize; 2],
    /// Shin (knee bend).
    pub shin: [usize; 2],
    /// Foot (ankle).
    pub foot: [usize; 2],
    /// Bones whose joint is the index knuckle.
    pub index_knuckle: [usize; 2],
    /// Bones whose joint is the little-finger knuckle.
    pub pinky_knuckle: [usize; 2],
    /// Bones whose joint is the thumb landmark.
    pub thumb_knuckle: [usize; 2],
    /// Fallback elbow hinge axes (canonical rest axes).
    pub elbow_hinge: [Vec3; 2],
    /// Knee hinge axis (canonical rest axes): +X, flexion moving the shin backwards.
    pub knee_hinge: Vec3,
}

impl BoneMap {
    /// The map for `skeleton`, whose family is detected from its bone names.
    pub fn new(skeleton: &Skeleton) -> Result<Self, PoseSolveError> {
        let kind = SkeletonKind::detect(skeleton)?;
        let names = match kind {
            SkeletonKind::MakeHuman => &MAKEHUMAN,
            SkeletonKind::SmplX => &SMPLX,
        };
        let find = |name: &str| {
            skeleton
                .bone_index(name)
                .ok_or_else(|| PoseSolveError::MissingBone {
                    skeleton: kind.name(),
                    bone: name.to_string(),
                })
        };
        let sides = |pattern: &str| -> Result<[usize; 2], PoseSolveError> {
            let [l, r] = side_names(kind, pattern);
            Ok([find(&l)?, find(&r)?])
        };
        let spine = names
            .spine
            .iter()
            .map(|(n, w)| Ok((find(n)?, *w)))
            .collect::<Result<Vec<_>, PoseSolveError>>()?;
        let forearm_twist = match names.forearm_twist {
            Some(p) => sides(p)?.map(Some),
            None => [None, None],
        };
        let e = names.elbow_hinge_left;
        Ok(Self {
            kind,
            spine,
            neck: find(names.neck)?,
            head: find(names.head)?,
            upper_arm: sides(names.upper_arm)?,
            forearm: sides(names.forearm)?,
            forearm_twist,
            hand: sides(names.hand)?,
            thigh: sides(names.thigh)?,
            shin: sides(names.shin)?,
            foot: sides(names.foot)?,
            index_knuckle: sides(names.index_knuckle)?,
            pinky_knuckle: sides(names.pinky_knuckle)?,
            thumb_knuckle: sides(names.thumb_knuckle)?,
            // A rotation axis mirrors through the body's midplane as (x, −y, −z).
            elbow_hinge: [e, Vec3::new(e.x, -e.y, -e.z)],
            knee_hinge: Vec3::X,
        })
    }
}

/// `pattern` with `{s}` replaced by the left and the right side's spelling.
fn side_names(kind: SkeletonKind, pattern: &str) -> [String; 2] {
    let (l, r) = match kind {
        SkeletonKind::MakeHuman => ("L", "R"),
        SkeletonKind::SmplX => ("left", "right"),
    };
    [pattern.replace("{s}", l), pattern.replace("{s}", r)]
}
