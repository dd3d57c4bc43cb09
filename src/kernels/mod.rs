//! Hand-written CPU kernels, shared by the LHM++ network (`model`) and any other network of the
//! crate, that replace chains of stock candle ops on the hot path: a fused
//! tiled attention ([`fused_attention`]); linear layers with the bias, exact or tanh GELU and
//! the gated residual add fused into one matrix product ([`linear`]); LayerNorm
//! ([`layer_norm`]); softmax ([`softmax`]); and the vectorisable exponential and GELU they use
//! ([`fast_exp`], [`gelu`]). Each falls back to candle's ops off the CPU or for dtypes other
//! than f32, except bf16: [`bf16`] holds the bf16 products with f32 accumulation (AVX512-BF16
//! `vdpbf16ps`, AVX2 + FMA or a portable kernel) that bf16 linear layers and attention run on, LayerNorm
//! widens bf16 rows to f32. The DPT neural renderer's CPU path works on channels-last maps ([`feature_map`])
//! with tiled-gemm convolutions ([`conv2d`], 3×3 ones by Winograd F(4×4, 3×3) in
//! [`winograd`], [`conv_transpose`]) and a bilinear resize ([`upsample`]). All of them reach the
//! `gemm` crate through one checked call (`matmul`). The perception networks (MobileNet-style
//! graphs on one NHWC image in a buffer arena) use slice kernels of their own: register-blocked
//! products for 1×1 and k×k convolutions ([`pointwise`], [`conv_nhwc`]), 1×1 convolutions over
//! mostly-zero weights ([`sparse_pointwise`]), depthwise convolution
//! ([`depthwise`]) and the small NHWC operations ([`nhwc`]).

pub mod bf16;
pub mod conv2d;
pub mod conv_nhwc;
pub mod conv_transpose;
pub mod depthwise;
pub mod fast_exp;
pub mod feature_map;
pub mod fused_attention;
pub mod gelu;
#[cfg(target_arch = "x86_64")]
mod gemm_avx2;
pub mod layer_norm;
pub mod linear;
mod matmul;
pub mod nhwc;
pub mod parallel;
pub mod pointwise;
pub mod softmax;
pub mod sparse_pointwise;
pub mod upsample;
pub mod winograd;

use candle_core::backend::BackendStorage;
use candle_core::{CpuStorage, Layout};

/// The f32 values of a contiguous CPU operand from its start offset; `op` and `what` name the
/// operation and the operand in the error.
pub(crate) fn contiguous_f32<'a>(
    storage: &'a CpuStorage,
    layout: &Layout,
    op: &str,
    what: &str,
) -> candle_core::Result<&'a [f32]> {
    let CpuStorage::F32(data) = storage else {
        candle_core::bail!("{op}: {what} is {:?}, expected f32", storage.dtype());
    };
    match layout.contiguous_offsets() {
        Some((a, b)) => Ok(&data[a..b]),
        None => candle_core::bail!("{op}: {what} is not contiguous"),
    }
}
