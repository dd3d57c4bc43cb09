//! [`CudaRasterizer`]: runs the kernels of `rasterize.cu` on candle's CUDA stream, reading the
//! Gaussians from f32 tensors on the GPU ([`CudaScene`]) and writing the maps into new tensors
//! ([`GpuFrame`]), so that a frame can go on to the neural renderer without leaving the GPU.

use super::params::SplatParams;
use crate::splat::camera::Camera;
use crate::splat::gaussians::{GaussianError, Gaussians};
use crate::splat::render::{RenderOptions, RenderOutput};
use candle_core::cuda_backend::cudarc::driver::{CudaSlice, DevicePtr, DeviceSlice};
use candle_core::op::BackpropOp;
use candle_core::{CudaDevice, CudaStorage, DType, Device, Storage, Tensor};
use std::ffi::{c_char, c_void, CStr};
use std::ptr::NonNull;
use thiserror::Error;

/// `LhmppSplatScene` of `rasterize.h`.
#[repr(C)]
struct SceneC {
    positions: *const f32,
    scales: *const f32,
    rotations: *const f32,
    opacities: *const f32,
    sh: *const f32,
    features: *const f32,
    background_features: *const f32,
}

/// `LhmppSplatImage` of `rasterize.h`.
#[repr(C)]
struct ImageC {
    rgb: *mut f32,
    alpha: *mut f32,
    depth: *mut f32,
    features: *mut f32,
}

/// `LhmppSplatStats` of `rasterize.h`.
#[repr(C)]
#[derive(Default)]
struct StatsC {
    visible: u32,
    tile_pairs: u32,
}

extern "C" {
    fn lhmpp_splat_workspace_new() -> *mut c_void;
    fn lhmpp_splat_workspace_free(workspace: *mut c_void);
    fn lhmpp_splat_render(
        workspace: *mut c_void,
        params: *const SplatParams,
        scene: *const SceneC,
        image: *const ImageC,
        stats: *mut StatsC,
        stream: *mut c_void,
    ) -> i32;
    fn lhmpp_splat_error_string(code: i32) -> *const c_char;
}

/// Why a GPU render could not run.
#[derive(Debug, Error)]
pub enum CudaRenderError {
    /// The device or a tensor is not a CUDA one.
    #[error("the CUDA rasteriser needs CUDA tensors, `{0}` is on another device")]
    NotCuda(&'static str),
    /// A scene tensor has the wrong shape or dtype.
    #[error("scene tensor `{name}` is {actual}, expected {expected}")]
    Tensor {
        /// Which tensor (`positions`, `sh`, ...).
        name: &'static str,
        /// Its dtype and shape.
        actual: String,
        /// What the rasteriser needs.
        expected: String,
    },
    /// The Gaussian set is malformed.
    #[error(transparent)]
    Gaussians(#[from] GaussianError),
    /// A candle operation (upload, download, allocation) failed.
    #[error("CUDA tensor operation failed: {0}")]
    Candle(#[from] candle_core::Error),
    /// The kernels reported a CUDA error.
    #[error("CUDA rasteriser failed: {0}")]
    Kernel(String),
}

type Result<T> = std::result::Result<T, CudaRenderError>;

/// Gaussians on the GPU, as contiguous f32 tensors (`N` Gaussians, `K = (degree + 1)²`).
#[derive(Debug, Clone)]
pub struct CudaScene {
    positions: Tensor,
    scales: Tensor,
    rotations: Tensor,
    opacities: Tensor,
    sh: Tensor,
    sh_degree: usize,
    features: Option<Tensor>,
}

impl CudaScene {
    /// Uploads a Gaussian set to `device`.
    pub fn from_gaussians(gaussians: &Gaussians, device: &Device) -> Result<Self> {
        gaussians.validate()?;
        let n = gaussians.len();
        let k = gaussians.sh_per_gaussian();
        let flat = |v: &[f32], shape: &[usize]| Tensor::from_slice(v, shape, device);
        Self::from_tensors(
            flat(bytemuck::cast_slice(&gaussians.positions), &[n, 3])?,
            flat(bytemuck::cast_slice(&gaussians.scales), &[n, 3])?,
            flat(bytemuck::cast_slice(&gaussians.rotations), &[n, 4])?,
            flat(&gaussians.opacities, &[n])?,
            flat(bytemuck::cast_slice(&gaussians.sh), &[n, k, 3])?,
            gaussians.sh_degree,
            (gaussians.feature_channels > 0)
                .then(|| flat(&gaussians.features, &[n, gaussians.feature_channels]))
                .transpose()?,
        )
    }

    /// A scene from tensors already on the GPU (e.g. the network's Gaussian head): positions
    /// `[N,3]`, linear scales `[N,3]`, rotations `[N,4]` (x y z w), opacities `[N]`, SH
    /// `[N,(degree+1)²,3]`, optional features `[N,C]`; f32 on one CUDA device (made contiguous).
    #[allow(clippy::too_many_arguments)]
    pub fn from_tensors(
        positions: Tensor,
        scales: Tensor,
        rotations: Tensor,
        opacities: Tensor,
        sh: Tensor,
        sh_degree: usize,
        features: Option<Tensor>,
    ) -> Result<Self> {
        if sh_degree > crate::splat::gaussians::MAX_SH_DEGREE {
            return Err(GaussianError::ShDegree(sh_degree).into());
        }
        let n = positions.dims().first().copied().unwrap_or(0);
        let k = (sh_degree + 1) * (sh_degree + 1);
        let check = |name: &'static str, t: Tensor, want: Vec<usize>| -> Result<Tensor> {
            if t.dtype() != DType::F32 || t.dims() != want.as_slice() {
                return Err(CudaRenderError::Tensor {
                    name,
                    actual: format!("{:?} {:?}", t.dtype(), t.dims()),
                    expected: format!("F32 {want:?}"),
                });
            }
            if !t.device().is_cuda() {
                return Err(CudaRenderError::NotCuda(name));
            }
            Ok(t.contiguous()?)
        };
        let features = match features {
            Some(f) => {
                let c = f.dims().get(1).copied().unwrap_or(0);
                Some(check("features", f, vec![n, c])?)
            }
            None => None,
        };
        Ok(Self {
            positions: check("positions", positions, vec![n, 3])?,
            scales: check("scales", scales, vec![n, 3])?,
            rotations: check("rotations", rotations, vec![n, 4])?,
            opacities: check("opacities", opacities, vec![n])?,
            sh: check("sh", sh, vec![n, k, 3])?,
            sh_degree,
            features,
        })
    }

    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.opacities.dims()[0]
    }

    /// True when the scene holds no Gaussian.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Feature channels per Gaussian (0 without features).
    pub fn feature_channels(&self) -> usize {
        self.features.as_ref().map_or(0, |f| f.dims()[1])
    }
}

/// A frame rendered on the GPU: the maps as f32 tensors on the device.
#[derive(Debug, Clone)]
pub struct GpuFrame {
    /// Linear RGB `[H, W, 3]`.
    pub rgb: Tensor,
    /// Accumulated opacity `[H, W]`.
    pub alpha: Tensor,
    /// Expected depth `[H, W]` (0 where alpha is 0).
    pub depth: Tensor,
    /// Features `[H, W, C]` when rendered.
    pub features: Option<Tensor>,
    /// Gaussians that survived culling.
    pub visible: usize,
    /// (tile, Gaussian) pairs blended.
    pub tile_pairs: usize,
}

impl GpuFrame {
    /// Copies the maps to the host, in the CPU rasteriser's layout.
    pub fn to_render_output(&self) -> Result<RenderOutput> {
        let (height, width) = self.alpha.dims2()?;
        let flat = |t: &Tensor| t.flatten_all()?.to_vec1::<f32>();
        Ok(RenderOutput {
            width: width as u32,
            height: height as u32,
            rgb: flat(&self.rgb)?,
            alpha: flat(&self.alpha)?,
            depth: flat(&self.depth)?,
            feature_channels: self.features.as_ref().map_or(0, |f| f.dims()[2]),
            features: self
                .features
                .as_ref()
                .map(flat)
                .transpose()?
                .unwrap_or_default(),
        })
    }
}

/// The CUDA rasteriser of one device; keeps its scratch buffers between frames.
#[derive(Debug)]
pub struct CudaRasterizer {
    device: CudaDevice,
    tensor_device: Device,
    workspace: NonNull<c_void>,
}

// SAFETY: the workspace is only touched through `&mut self`, on the device's stream.
unsafe impl Send for CudaRasterizer {}

impl Drop for CudaRasterizer {
    fn drop(&mut self) {
        let _ = self.device.cuda_stream().context().bind_to_thread();
        // The last frame's blend may still be reading the workspace.
        let _ = self.tensor_device.synchronize();
        // SAFETY: created by `lhmpp_splat_workspace_new`, freed once, after the stream is idle.
        unsafe { lhmpp_splat_workspace_free(self.workspace.as_ptr()) }
    }
}

/// Device address of a contiguous f32 CUDA tensor's first element.
fn tensor_ptr(t: &Tensor, name: &'static str) -> Result<*const f32> {
    let (storage, layout) = t.storage_and_layout();
    let Storage::Cuda(cuda) = &*storage else {
        return Err(CudaRenderError::NotCuda(name));
    };
    let slice = cuda.as_cuda_slice::<f32>()?;
    let view = slice.slice(layout.start_offset()..);
    let (ptr, _sync) = view.device_ptr(view.stream());
    Ok(ptr as *const f32)
}

fn slice_ptr(s: &CudaSlice<f32>) -> *mut f32 {
    let (ptr, _sync) = s.device_ptr(s.stream());
    ptr as *mut f32
}

impl CudaRasterizer {
    /// A rasteriser on `device` (which must be a CUDA device).
    pub fn new(device: &Device) -> Result<Self> {
        let Device::Cuda(cuda) = device else {
            return Err(CudaRenderError::NotCuda("device"));
        };
        // SAFETY: plain allocation of the C++ workspace object.
        let workspace = NonNull::new(unsafe { lhmpp_splat_workspace_new() })
            .ok_or_else(|| CudaRenderError::Kernel("cannot allocate the workspace".into()))?;
        Ok(Self {
            device: cuda.clone(),
            tensor_device: device.clone(),
            workspace,
        })
    }

    /// The (CUDA) device this rasteriser renders on.
    pub fn device(&self) -> &Device {
        &self.tensor_device
    }

    /// Renders `scene` from `camera`. The maps stay on the GPU; the call waits once for the
    /// stream (to size the tile lists), the blend is left queued on candle's stream.
    pub fn render(
        &mut self,
        scene: &CudaScene,
        camera: &Camera,
        options: &RenderOptions,
    ) -> Result<GpuFrame> {
        let channels = options.rendered_channels(scene.feature_channels());
        let params = SplatParams::for_scene(
            camera,
            options,
            scene.len(),
            scene.sh_degree,
            scene.feature_channels(),
        );
        let (w, h) = (params.width as usize, params.height as usize);
        let pixels = w * h;
        let background = (channels > 0)
            .then(|| {
                let values = options.background_features_for(channels);
                Tensor::from_slice(&values, channels, &self.tensor_device)
            })
            .transpose()?;
        let features_in = match (&scene.features, channels) {
            (Some(f), c) if c > 0 => tensor_ptr(f, "features")?,
            _ => std::ptr::null(),
        };
        let scene_c = SceneC {
            positions: tensor_ptr(&scene.positions, "positions")?,
            scales: tensor_ptr(&scene.scales, "scales")?,
            rotations: tensor_ptr(&scene.rotations, "rotations")?,
            opacities: tensor_ptr(&scene.opacities, "opacities")?,
            sh: tensor_ptr(&scene.sh, "sh")?,
            features: features_in,
            background_features: match &background {
                Some(b) => tensor_ptr(b, "background_features")?,
                None => std::ptr::null(),
            },
        };
        let alloc = |n: usize| self.device.alloc_zeros::<f32>(n.max(1));
        let (rgb, alpha, depth) = (alloc(pixels * 3)?, alloc(pixels)?, alloc(pixels)?);
        let features = (channels > 0)
            .then(|| alloc(pixels * channels))
            .transpose()?;
        let image = ImageC {
            rgb: slice_ptr(&rgb),
            alpha: slice_ptr(&alpha),
            depth: slice_ptr(&depth),
            features: features.as_ref().map_or(std::ptr::null_mut(), slice_ptr),
        };
        let stream = self.device.cuda_stream();
        stream
            .context()
            .bind_to_thread()
            .map_err(|e| CudaRenderError::Kernel(format!("binding the CUDA context: {e}")))?;
        let mut stats = StatsC::default();
        // SAFETY: every pointer is a live device allocation of the size `rasterize.h` asks for
        // (the tensors and slices outlive the call; the kernels are ordered on `stream`, and
        // the outputs are only read through that stream afterwards).
        let code = unsafe {
            lhmpp_splat_render(
                self.workspace.as_ptr(),
                &params,
                &scene_c,
                &image,
                &mut stats,
                stream.cu_stream() as *mut c_void,
            )
        };
        if code != 0 {
            // SAFETY: returns a static NUL-terminated string for any code.
            let text = unsafe { CStr::from_ptr(lhmpp_splat_error_string(code)) };
            return Err(CudaRenderError::Kernel(format!(
                "{} (code {code})",
                text.to_string_lossy()
            )));
        }
        let wrap = |s: CudaSlice<f32>, shape: &[usize]| {
            let storage = Storage::Cuda(CudaStorage::wrap_cuda_slice(s, self.device.clone()));
            Tensor::from_storage(storage, shape, BackpropOp::none(), false)
        };
        Ok(GpuFrame {
            rgb: wrap(rgb, &[h, w, 3]),
            alpha: wrap(alpha, &[h, w]),
            depth: wrap(depth, &[h, w]),
            features: features.map(|f| wrap(f, &[h, w, channels])),
            visible: stats.visible as usize,
            tile_pairs: stats.tile_pairs as usize,
        })
    }

    /// Uploads `gaussians`, renders and downloads the maps (the GPU twin of
    /// [`crate::splat::render`]).
    pub fn render_gaussians(
        &mut self,
        gaussians: &Gaussians,
        camera: &Camera,
        options: &RenderOptions,
    ) -> Result<RenderOutput> {
        let scene = CudaScene::from_gaussians(gaussians, &self.tensor_device)?;
        self.render(&scene, camera, options)?.to_render_output()
    }
}
