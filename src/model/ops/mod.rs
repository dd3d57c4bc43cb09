//! Hand-written CPU kernels that replace chains of stock candle ops on the hot path:
//! a fused tiled attention ([`fused_attention`]) and the vectorisable exponential it uses
//! ([`fast_exp`]).

pub mod fast_exp;
pub mod fused_attention;
