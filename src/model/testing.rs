//! Helpers shared by the model's unit tests.

use candle_core::Tensor;

/// `max |a − b|` over all elements (shapes must broadcast equal), as f32.
pub fn max_abs_diff(a: &Tensor, b: &Tensor) -> f32 {
    (a - b)
        .and_then(|d| d.abs())
        .and_then(|d| d.flatten_all())
        .and_then(|d| d.to_dtype(candle_core::DType::F32))
        .and_then(|d| d.max(0))
        .and_then(|d| d.to_scalar::<f32>())
        .expect("max_abs_diff: tensors of different shapes or devices")
}
