//! The groups of bones the solver drives and the rotations it produces.

use glam::Quat;

/// The groups of bones solved (and held) together, each from its own landmarks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Segment {
    /// Root rotation (hips, shoulders).
    Root,
    /// Spine bones (hips, shoulders).
    Spine,
    /// Neck and head (a left–right face pair, a face point, shoulders).
    Head,
    /// Left upper arm (shoulder, elbow).
    LeftUpperArm,
    /// Right upper arm.
    RightUpperArm,
    /// Left forearm (elbow, wrist).
    LeftForearm,
    /// Right forearm.
    RightForearm,
    /// Left hand and forearm twist (wrist, index and little-finger knuckles).
    LeftHand,
    /// Right hand.
    RightHand,
    /// Left thigh (hip, knee).
    LeftThigh,
    /// Right thigh.
    RightThigh,
    /// Left shin (knee, ankle).
    LeftShin,
    /// Right shin.
    RightShin,
    /// Left foot (ankle, heel, foot index).
    LeftFoot,
    /// Right foot.
    RightFoot,
}

impl Segment {
    /// Number of segments.
    pub const COUNT: usize = 15;

    /// Every segment, in solving order.
    pub const ALL: [Segment; Self::COUNT] = [
        Self::Root,
        Self::Spine,
        Self::Head,
        Self::LeftUpperArm,
        Self::RightUpperArm,
        Self::LeftForearm,
        Self::RightForearm,
        Self::LeftHand,
        Self::RightHand,
        Self::LeftThigh,
        Self::RightThigh,
        Self::LeftShin,
        Self::RightShin,
        Self::LeftFoot,
        Self::RightFoot,
    ];

    /// Position in [`Segment::ALL`].
    pub fn index(self) -> usize {
        self as usize
    }
}

/// Root rotation and per-bone local rotations (indexed like the skeleton's bones).
#[derive(Debug, Clone, PartialEq)]
pub struct BoneRotations {
    /// Root rotation (world axes).
    pub root: Quat,
    /// Local rotation per bone.
    pub locals: Vec<Quat>,
}

impl BoneRotations {
    /// The rest pose of a skeleton with `bones` bones.
    pub fn rest(bones: usize) -> Self {
        Self {
            root: Quat::IDENTITY,
            locals: vec![Quat::IDENTITY; bones],
        }
    }
}

/// A solved frame.
#[derive(Debug, Clone, PartialEq)]
pub struct SolvedPose {
    /// The rotations (fallback rotations for unsolved segments).
    pub rotations: BoneRotations,
    /// Per segment ([`Segment::index`]): whether its landmarks were seen and it was solved.
    pub solved: [bool; Segment::COUNT],
}
