//! Hand-written CPU kernels that replace chains of stock candle ops on the hot path: a fused
//! tiled attention ([`fused_attention`]); linear layers with the bias, exact or tanh GELU and
//! the gated residual add fused into one matrix product ([`linear`]); LayerNorm
//! ([`layer_norm`]); softmax ([`softmax`]); and the vectorisable exponential and GELU they use
//! ([`fast_exp`], [`gelu`]). Each falls back to candle's ops off the CPU or for dtypes other
//! than f32.

pub mod fast_exp;
pub mod fused_attention;
pub mod gelu;
pub mod layer_norm;
pub mod linear;
pub mod softmax;
