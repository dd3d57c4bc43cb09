//! LHM++ streaming human-avatar reconstruction node.
//!
//! Data flows one way:
//! `node` (messages in) → `reconstruct` (decode, preprocess) → frame store → `reconstruct`
//! (`Reconstructor`: `model` + `body`) → `avatar` → `splat` (render) → `node` / `transport` /
//! `bag` (publish, record).
//!
//! [`reconstruct`] is the synchronous "frames → avatar" API that the node, [`eval`] and the
//! tests share. `reconstruct`, `body`, `model` and `splat` are synchronous and never import
//! `node`, `transport` or `bag`. `body` and `transport` import nothing from the crate, `kernels`
//! (the CPU kernels) only the SIMD and test helpers, `model` only `kernels` and those helpers, `splat` only `body` and those; `tests/module_layers.rs`
//! checks it.

pub mod avatar;
pub mod bag;
pub mod body;
pub mod compact;
pub mod config;
pub mod eval;
pub mod kernels;
pub mod model;
pub mod msgs;
pub mod node;
pub mod perception;
pub mod picture;
pub mod reconstruct;
mod simd;
pub mod splat;
pub mod synth;
#[doc(hidden)]
pub mod testing;
pub mod tracking;
pub mod transport;
pub mod web;
