//! Hand-written CPU kernels that replace chains of stock candle ops on the hot path:
//! a fused tiled attention ([`fused_attention`]), linear layers with the bias and exact GELU
//! fused into one matrix product ([`linear`]), LayerNorm ([`layer_norm`]), and the vectorisable
//! exponential and erf they use ([`fast_exp`], [`gelu`]). Each falls back to candle's ops off
//! the CPU or for dtypes other than f32.

pub mod fast_exp;
pub mod fused_attention;
pub mod gelu;
pub mod layer_norm;
pub mod linear;
