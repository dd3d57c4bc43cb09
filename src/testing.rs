//! Helpers shared by the crate's unit tests, the integration tests and the benchmarks that
//! compare two computations. Not part of the API.

use candle_core::Tensor;

/// Values that can be compared element by element: `f32` slices, vectors and tensors (any
/// dtype and device, read as f32 in row-major order).
pub trait Values {
    /// The values, flattened.
    fn values(&self) -> Vec<f32>;
}

impl Values for [f32] {
    fn values(&self) -> Vec<f32> {
        self.to_vec()
    }
}

impl Values for Vec<f32> {
    fn values(&self) -> Vec<f32> {
        self.clone()
    }
}

impl<const N: usize> Values for [f32; N] {
    fn values(&self) -> Vec<f32> {
        self.to_vec()
    }
}

impl Values for Tensor {
    fn values(&self) -> Vec<f32> {
        self.flatten_all()
            .and_then(|t| t.to_dtype(candle_core::DType::F32))
            .and_then(|t| t.to_vec1())
            .expect("tensor values")
    }
}

/// `max |a − b|` over all elements; panics when `a` and `b` differ in shape.
pub fn max_abs_diff<A: Values + ?Sized, B: Values + ?Sized>(a: &A, b: &B) -> f32 {
    let (a, b) = (a.values(), b.values());
    assert_eq!(a.len(), b.len(), "max_abs_diff: different sizes");
    a.iter()
        .zip(&b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

/// The log lines written while `f` runs on this thread, at warn level and above.
pub fn warnings_logged(f: impl FnOnce()) -> String {
    use std::sync::{Arc, Mutex};
    #[derive(Clone, Default)]
    struct Buf(Arc<Mutex<Vec<u8>>>);
    impl std::io::Write for Buf {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            self.0.lock().expect("log buffer").extend_from_slice(b);
            Ok(b.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }
    let buf = Buf::default();
    let writer = buf.clone();
    let subscriber = tracing_subscriber::fmt()
        .with_max_level(tracing::Level::WARN)
        .with_ansi(false)
        .with_writer(move || writer.clone())
        .finish();
    tracing::subscriber::with_default(subscriber, f);
    let text = buf.0.lock().expect("log buffer").clone();
    String::from_utf8_lossy(&text).into_owned()
}

/// Bytes of every file below `dir` (panics on an unreadable entry).
pub fn bytes_under(dir: &std::path::Path) -> u64 {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .map(|p| match p.is_dir() {
            true => bytes_under(&p),
            false => std::fs::metadata(&p).unwrap().len(),
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slices_vectors_and_tensors_compare_alike() {
        let a = vec![1.0f32, -2.0, 3.0];
        let b = [1.5f32, -2.0, 2.0];
        assert_eq!(max_abs_diff(&a, &b), 1.0);
        assert_eq!(max_abs_diff(&a[..], &b[..]), 1.0);
        let ta = Tensor::from_vec(a, (3,), &candle_core::Device::Cpu).unwrap();
        let tb = Tensor::from_slice(&b, (3,), &candle_core::Device::Cpu).unwrap();
        assert_eq!(max_abs_diff(&ta, &tb), 1.0);
    }
}
