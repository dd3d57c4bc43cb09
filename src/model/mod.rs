//! The LHM++ reconstruction network in candle: DINOv2 image encoder, point tokenizer,
//! encoder–decoder Point-Image Transformer, Gaussian head, DPT neural renderer, checkpoints.

pub mod dpt;
pub mod point;
