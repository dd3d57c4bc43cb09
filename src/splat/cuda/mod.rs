//! The CUDA splatting rasteriser: the CPU rasteriser's stages ([`crate::splat::render`]) as GPU
//! kernels in `rasterize.cu` (project → depth radix sort → tile pairs → tile radix sort →
//! per-tile blend), same semantics, images equal up to float rounding.
//!
//! The kernels and their host code are C++/CUDA behind a small C interface (`rasterize.h`).
//! With the `cuda` feature, `build.rs` compiles them with nvcc and [`CudaRasterizer`] drives them
//! on candle's CUDA stream, so inputs and outputs stay on the GPU as candle tensors. Without a
//! GPU the same source builds against a CPU emulation of CUDA (`emulate.h`), which the tests
//! (`tests/splat_cuda_emulation.rs`) compare with the CPU rasteriser.

mod params;

pub use params::{FlatScene, SplatParams};

#[cfg(feature = "cuda")]
mod device;
#[cfg(feature = "cuda")]
pub use device::{CudaRasterizer, CudaRenderError, CudaScene, GpuFrame};
