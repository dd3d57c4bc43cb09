//! Synthetic people with ground truth: seeded body and outfit, camera rigs, rendered views
//! written to rosbag2-layout MCAP bags (`lhmpp synth`), used by the demo, the replay tests and
//! `lhmpp eval`.

pub mod capture;
pub mod dataset;
pub mod motion;
pub mod outfit;
pub mod person;
pub mod random_pose;
pub mod scene;
pub mod stream;

pub use capture::{write_synthetic_bag, CameraMode, SynthOptions, SynthPose, SynthSummary};
pub use person::{SynthError, SyntheticPerson};
pub use scene::{Rig, RigCamera};
