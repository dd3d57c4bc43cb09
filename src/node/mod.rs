//! The node's ROS 2 face and the synchronous state machines behind it.
//!
//! Messages come in through [`ros`] (live subscriptions) or [`replay`] (a bag) as the
//! [`inputs`] events, through one bounded [`input_queue`]; images are decoded and
//! cropped/resized by [`crate::reconstruct`], views are kept per person by [`frame_store`],
//! [`scheduler`] decides when to reconstruct, and [`pipeline`] runs it all and fans the avatar
//! and frames out through [`outputs`] (ROS 2, shared memory, files).
//!
//! What is async: [`ros`] (ros2-client subscription tasks on tokio), [`record`] (the recorder
//! is one future), [`signal`] (the SIGINT/SIGTERM future) and the receiving side of
//! [`input_queue`] (`recv().await`; sending, `try_recv` and the blocking `recv_timeout` the
//! live loop uses are plain calls). [`run`] starts the tokio runtime for those and drives the
//! synchronous [`pipeline`] on the calling thread. Everything else is synchronous:
//! [`inputs`], [`frame_store`], [`scheduler`], [`names`], [`rejections`] and [`timings`] are
//! sans-io, driven by the caller; [`pipeline`], [`replay`] (which reads the bag) and
//! [`outputs`] (which write the files and hand messages to DDS and shared memory) make plain
//! blocking calls.

pub mod frame_store;
pub mod input_errors;
pub mod input_queue;
pub mod inputs;
pub mod memory_trim;
pub mod names;
pub mod outputs;
pub mod pipeline;
pub mod preview;
pub mod record;
pub mod rejections;
pub mod replay;
pub mod ros;
pub mod run;
pub mod scheduler;
pub mod signal;
pub mod tf_buffer;
pub mod timings;
