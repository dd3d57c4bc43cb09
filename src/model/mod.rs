//! The LHM++ reconstruction network in candle: DINOv2 image encoder, point tokenizer,
//! encoder–decoder Point-Image Transformer, Gaussian head, DPT neural renderer, checkpoints.
//!
//! Every block's constructor takes a `VarBuilder` and uses the official checkpoint key
//! segments, so the same code loads the released LHMPP-700M weights and our smaller presets.

pub mod attention;
pub mod bicubic;
pub mod cache;
pub mod checkpoint;
pub mod config;
pub mod default_weights;
pub mod dpt;
pub mod draws;
pub mod encoder;
pub mod frame_block;
pub mod gs_head;
pub mod hub;
pub mod joint_block;
pub mod lhmpp;
pub mod point;
pub mod rgb_kind;
pub mod shape_head;
pub mod tensor_file;
pub mod token_merge;

pub use config::LhmppConfig;
pub use gs_head::GaussianOutput;
pub use lhmpp::{Lhmpp, ViewTokens};
pub use rgb_kind::RgbKind;

/// Builds every tensor of the network for `cfg` from `vb` (used to enumerate checkpoint keys).
pub(crate) fn build_network(
    cfg: &LhmppConfig,
    vb: candle_nn::VarBuilder,
) -> candle_core::Result<()> {
    Lhmpp::new(cfg, vb).map(|_| ())
}
