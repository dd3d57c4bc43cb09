//! The node's ROS 2 face and the pure state machines behind it.
//!
//! Messages come in through [`ros`] (subscriptions → one bounded [`input_queue`] of
//! `InputEvent`s), images are decoded and cropped/resized by [`crate::reconstruct`], views are
//! kept per person by [`frame_store`], and [`scheduler`] decides when to reconstruct. Only [`ros`] is async; everything else is sans-io and driven by the caller.

pub mod frame_store;
pub mod input_errors;
pub mod input_queue;
pub mod names;
pub mod pipeline;
pub mod preview;
pub mod publishers;
pub mod record;
pub mod rejections;
pub mod replay;
pub mod ros;
pub mod run;
pub mod scheduler;
