//! BlazePose's 33 body landmarks: their order, names and left/right pairs, and one landmark as
//! the landmark model reports it.

use glam::Vec3;

/// Number of body landmarks (the model reports 39: these 33 and 6 auxiliary ones).
pub const BODY_LANDMARKS: usize = 33;

/// The landmarks in the model's output order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(usize)]
pub enum LandmarkId {
    /// Tip of the nose.
    Nose = 0,
    /// Inner corner of the left eye.
    LeftEyeInner,
    /// Centre of the left eye.
    LeftEye,
    /// Outer corner of the left eye.
    LeftEyeOuter,
    /// Inner corner of the right eye.
    RightEyeInner,
    /// Centre of the right eye.
    RightEye,
    /// Outer corner of the right eye.
    RightEyeOuter,
    /// Left ear.
    LeftEar,
    /// Right ear.
    RightEar,
    /// Left corner of the mouth.
    MouthLeft,
    /// Right corner of the mouth.
    MouthRight,
    /// Left shoulder joint.
    LeftShoulder,
    /// Right shoulder joint.
    RightShoulder,
    /// Left elbow.
    LeftElbow,
    /// Right elbow.
    RightElbow,
    /// Left wrist.
    LeftWrist,
    /// Right wrist.
    RightWrist,
    /// Left little-finger knuckle.
    LeftPinky,
    /// Right little-finger knuckle.
    RightPinky,
    /// Left index-finger knuckle.
    LeftIndex,
    /// Right index-finger knuckle.
    RightIndex,
    /// Left thumb.
    LeftThumb,
    /// Right thumb.
    RightThumb,
    /// Left hip joint.
    LeftHip,
    /// Right hip joint.
    RightHip,
    /// Left knee.
    LeftKnee,
    /// Right knee.
    RightKnee,
    /// Left ankle.
    LeftAnkle,
    /// Right ankle.
    RightAnkle,
    /// Left heel.
    LeftHeel,
    /// Right heel.
    RightHeel,
    /// Tip of the left foot (big toe).
    LeftFootIndex,
    /// Tip of the right foot (big toe).
    RightFootIndex,
}

impl LandmarkId {
    /// Every landmark, in output order.
    pub const ALL: [LandmarkId; BODY_LANDMARKS] = [
        Self::Nose,
        Self::LeftEyeInner,
        Self::LeftEye,
        Self::LeftEyeOuter,
        Self::RightEyeInner,
        Self::RightEye,
        Self::RightEyeOuter,
        Self::LeftEar,
        Self::RightEar,
        Self::MouthLeft,
        Self::MouthRight,
        Self::LeftShoulder,
        Self::RightShoulder,
        Self::LeftElbow,
        Self::RightElbow,
        Self::LeftWrist,
        Self::RightWrist,
        Self::LeftPinky,
        Self::RightPinky,
        Self::LeftIndex,
        Self::RightIndex,
        Self::LeftThumb,
        Self::RightThumb,
        Self::LeftHip,
        Self::RightHip,
        Self::LeftKnee,
        Self::RightKnee,
        Self::LeftAnkle,
        Self::RightAnkle,
        Self::LeftHeel,
        Self::RightHeel,
        Self::LeftFootIndex,
        Self::RightFootIndex,
    ];

    /// Index in the model's output.
    pub fn index(self) -> usize {
        self as usize
    }

    /// snake_case name, as MediaPipe names it (`left_shoulder`).
    pub fn name(self) -> &'static str {
        LANDMARK_NAMES[self as usize]
    }
}

/// snake_case names in output order.
pub const LANDMARK_NAMES: [&str; BODY_LANDMARKS] = [
    "nose",
    "left_eye_inner",
    "left_eye",
    "left_eye_outer",
    "right_eye_inner",
    "right_eye",
    "right_eye_outer",
    "left_ear",
    "right_ear",
    "mouth_left",
    "mouth_right",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_pinky",
    "right_pinky",
    "left_index",
    "right_index",
    "left_thumb",
    "right_thumb",
    "left_hip",
    "right_hip",
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
    "left_heel",
    "right_heel",
    "left_foot_index",
    "right_foot_index",
];

/// Bones drawn between landmarks in overlays (MediaPipe's body connections, face omitted).
pub const SKELETON_EDGES: [(LandmarkId, LandmarkId); 22] = {
    use LandmarkId::*;
    [
        (LeftShoulder, RightShoulder),
        (LeftShoulder, LeftElbow),
        (LeftElbow, LeftWrist),
        (LeftWrist, LeftPinky),
        (LeftWrist, LeftIndex),
        (LeftWrist, LeftThumb),
        (RightShoulder, RightElbow),
        (RightElbow, RightWrist),
        (RightWrist, RightPinky),
        (RightWrist, RightIndex),
        (RightWrist, RightThumb),
        (LeftShoulder, LeftHip),
        (RightShoulder, RightHip),
        (LeftHip, RightHip),
        (LeftHip, LeftKnee),
        (LeftKnee, LeftAnkle),
        (LeftAnkle, LeftHeel),
        (LeftHeel, LeftFootIndex),
        (RightHip, RightKnee),
        (RightKnee, RightAnkle),
        (RightAnkle, RightHeel),
        (RightHeel, RightFootIndex),
    ]
};

/// One landmark: a position and how much to trust it.
///
/// In image landmarks `position` is (x, y) in pixels of the full frame and z a relative depth
/// in the same pixel scale (smaller is nearer the camera, the hips' midpoint at about 0); in
/// world landmarks it is metres, origin between the hips, axes as the camera's (x right, y
/// down, z away from the camera).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Landmark {
    /// Position (see the type's documentation for units and axes).
    pub position: Vec3,
    /// Probability that the landmark is visible (not occluded), in [0, 1].
    pub visibility: f32,
    /// Probability that the landmark lies inside the frame, in [0, 1].
    pub presence: f32,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_index_their_names() {
        for (i, id) in LandmarkId::ALL.iter().enumerate() {
            assert_eq!(id.index(), i);
        }
        assert_eq!(LandmarkId::LeftShoulder.name(), "left_shoulder");
        assert_eq!(LandmarkId::RightFootIndex.index(), 32);
    }
}
