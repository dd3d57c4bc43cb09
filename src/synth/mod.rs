//! Synthetic people with ground truth: seeded body and outfit, camera rigs, rendered views
//! written to rosbag2-layout MCAP bags (`lhmpp synth`), used by the demo, the replay tests and
//! `lhmpp eval`.

pub mod backdrop;
pub mod camera_fx;
pub mod capture;
pub mod crowd;
pub mod dataset;
pub mod dressed;
pub mod dressing_room;
pub mod lighting;
pub mod lookbook;
pub mod material;
pub mod motion;
pub mod outfit;
pub mod person;
pub mod random_pose;
pub mod scene;
pub mod stream;
pub mod wardrobe;

pub use capture::{
    write_bag, write_synthetic_bag, CameraMode, SynthOptions, SynthPose, SynthSummary,
};
pub use dataset::Realism;
pub use dressed::DressedPerson;
pub use person::{SynthError, SyntheticPerson};
pub use scene::{Rig, RigCamera};
