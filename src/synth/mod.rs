//! Synthetic people with ground truth: seeded body and outfit, cameras, rendered views written
//! to rosbag2-layout MCAP bags (`lhmpp synth`).

pub mod outfit;
