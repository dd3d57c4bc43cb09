//! Rendered outputs of the node: virtual cameras orbiting the person, the pose that drives the
//! avatar (latest BodyPose, or the built-in walk for demos), splatting into [`RenderedFrame`]s
//! that publishers convert to 8-bit wherever they need it (a `Vec` for ROS 2 and PNG, a loaned
//! shared-memory sample for iceoryx2). Frames are rasterised on the CPU or, with
//! `outputs.render_device: cuda`, on the GPU ([`FrameRasterizer`]), from the Gaussians' RGB or,
//! with `outputs.renderer: neural`, from their features through the network's DPT neural
//! renderer ([`NeuralFrames`]).

use super::neural_frames::NeuralFrames;
use crate::avatar::Avatar;
use crate::body::{motion, Pose, Skeleton};
use crate::config::RenderDevice;
#[cfg(feature = "cuda")]
use crate::splat::cuda::{CudaRasterizer, CudaScene};
use crate::splat::{Camera, Gaussians, Intrinsics, Rasterizer, RenderOptions, RenderOutput};
use glam::Vec3;
use image::RgbImage;
use std::sync::OnceLock;

/// Frames per second of the built-in walk cycle (its keys are 24 fps Blender frames).
const WALK_FPS: f32 = 24.0;

/// Virtual cameras around the canonical body, all looking at its middle.
#[derive(Debug, Clone)]
pub struct VirtualCameras {
    cameras: Vec<Camera>,
}

impl VirtualCameras {
    /// `count` cameras evenly spaced on a ring around a body of `height` metres, `size`²
    /// pixels, camera 0 in front of the person (+Z).
    pub fn ring(count: u32, size: u32, height: f32) -> Self {
        let fov_y = 0.75f32;
        let intrinsics = Intrinsics::from_fov_y(size, size, fov_y);
        let distance = 0.62 * height / (0.5 * fov_y).tan();
        let target = Vec3::new(0.0, 0.5 * height, 0.0);
        let cameras = (0..count as usize)
            .map(|i| {
                Camera::orbit(
                    i,
                    count as usize,
                    distance,
                    0.1 * height,
                    target,
                    intrinsics,
                )
            })
            .collect();
        Self { cameras }
    }

    /// The cameras.
    pub fn cameras(&self) -> &[Camera] {
        &self.cameras
    }
}

/// Nanoseconds since the epoch by this machine's clock (0 if it is set before 1970).
pub fn unix_now_ns() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as i64)
}

/// The pose the avatar is shown in at `time_s`: the latest received pose if any, else the
/// built-in walk cycle.
pub fn display_pose(latest: Option<&Pose>, time_s: f32) -> Pose {
    latest
        .cloned()
        .unwrap_or_else(|| motion::walk_pose(time_s * WALK_FPS))
}

/// One virtual camera's render: the rasteriser's float image, converted to rgb8 only on
/// demand (at most once), or straight into a caller's buffer.
#[derive(Debug)]
pub struct RenderedFrame {
    output: RenderOutput,
    rgb8: OnceLock<RgbImage>,
}

impl RenderedFrame {
    /// Wraps a render.
    pub fn new(output: RenderOutput) -> Self {
        Self {
            output,
            rgb8: OnceLock::new(),
        }
    }

    /// Pixels per row.
    pub fn width(&self) -> u32 {
        self.output.width
    }

    /// Rows.
    pub fn height(&self) -> u32 {
        self.output.height
    }

    /// The rasteriser's output (linear RGB floats, alpha, depth).
    pub fn output(&self) -> &RenderOutput {
        &self.output
    }

    /// The frame as an rgb8 image (converted on first use, then cached).
    pub fn rgb8(&self) -> &RgbImage {
        self.rgb8.get_or_init(|| self.output.to_rgb8())
    }

    /// Writes the rgb8 pixels (`width × height × 3` bytes, the same values as
    /// [`RenderedFrame::rgb8`]) into `dest`, e.g. a loaned shared-memory sample.
    /// Panics if `dest` has another length.
    pub fn write_rgb8(&self, dest: &mut [u8]) {
        assert_eq!(dest.len(), self.output.rgb.len(), "rgb8 destination size");
        if let Some(image) = self.rgb8.get() {
            dest.copy_from_slice(image.as_raw());
            return;
        }
        for (d, v) in dest.iter_mut().zip(&self.output.rgb) {
            *d = (v.clamp(0.0, 1.0) * 255.0).round() as u8;
        }
    }
}

/// Why the frame rasteriser could not be set up.
#[derive(Debug, thiserror::Error)]
pub enum FrameRasterizerError {
    /// `outputs.render_device` names something this binary cannot render on.
    #[error("outputs.render_device: `{0}` is not available in this build (cpu, or cuda with the `cuda` feature)")]
    Unsupported(String),
    /// The CUDA device could not be opened.
    #[error("outputs.render_device: cuda: {0}")]
    Cuda(String),
}

/// The rasteriser the node renders its frames with (its buffers are kept between frames).
#[derive(Debug)]
pub enum FrameRasterizer {
    /// The CPU rasteriser.
    Cpu(Rasterizer),
    /// The CUDA rasteriser on GPU 0 (a frame it fails on is rendered on the CPU instead).
    #[cfg(feature = "cuda")]
    Cuda(Box<CudaRasterizer>),
}

impl FrameRasterizer {
    /// The rasteriser for `outputs.render_device` (`cpu` or `cuda`).
    pub fn new(device: RenderDevice) -> Result<Self, FrameRasterizerError> {
        match device {
            RenderDevice::Cpu => Ok(Self::Cpu(Rasterizer::new())),
            #[cfg(feature = "cuda")]
            RenderDevice::Cuda => {
                let dev = candle_core::Device::new_cuda(0)
                    .map_err(|e| FrameRasterizerError::Cuda(e.to_string()))?;
                let r = CudaRasterizer::new(&dev)
                    .map_err(|e| FrameRasterizerError::Cuda(e.to_string()))?;
                Ok(Self::Cuda(Box::new(r)))
            }
            #[cfg(not(feature = "cuda"))]
            other => Err(FrameRasterizerError::Unsupported(other.to_string())),
        }
    }

    /// Renders `gaussians` from every camera.
    pub fn render_all(
        &mut self,
        gaussians: &Gaussians,
        cameras: &[Camera],
        options: &RenderOptions,
    ) -> Vec<RenderOutput> {
        match self {
            Self::Cpu(r) => cameras
                .iter()
                .map(|c| {
                    let mut out = RenderOutput::default();
                    r.render_into(gaussians, c, options, &mut out);
                    out
                })
                .collect(),
            // An empty avatar is only background: not worth zero-sized GPU buffers.
            #[cfg(feature = "cuda")]
            Self::Cuda(_) if gaussians.is_empty() => cameras
                .iter()
                .map(|c| crate::splat::render(gaussians, c, options))
                .collect(),
            #[cfg(feature = "cuda")]
            Self::Cuda(r) => {
                let device = r.device().clone();
                let rendered = CudaScene::from_gaussians(gaussians, &device).and_then(|scene| {
                    cameras
                        .iter()
                        .map(|c| r.render(&scene, c, options)?.to_render_output())
                        .collect::<Result<Vec<_>, _>>()
                });
                match rendered {
                    Ok(frames) => frames,
                    Err(e) => {
                        tracing::error!("CUDA rasteriser failed, rendering on the CPU: {e}");
                        cameras
                            .iter()
                            .map(|c| crate::splat::render(gaussians, c, options))
                            .collect()
                    }
                }
            }
        }
    }
}

/// What makes the node's frames: the rasteriser, and the neural renderer when
/// `outputs.renderer` resolved to `neural` (set up once, at pipeline construction).
#[derive(Debug)]
pub struct FrameRenderer {
    rasterizer: FrameRasterizer,
    neural: Option<NeuralFrames>,
}

impl FrameRenderer {
    /// Frames from the Gaussians' RGB (`neural: None`) or through `neural`.
    pub fn new(rasterizer: FrameRasterizer, neural: Option<NeuralFrames>) -> Self {
        Self { rasterizer, neural }
    }

    /// Whether frames go through the neural renderer.
    pub fn is_neural(&self) -> bool {
        self.neural.is_some()
    }
}

/// Poses `avatar` with `pose` on `skeleton` (the avatar's own body's; its features travel with
/// the Gaussians) and renders every virtual camera on a white background with `renderer`.
pub fn render_frames(
    avatar: &Avatar,
    skeleton: &Skeleton,
    pose: &Pose,
    cameras: &VirtualCameras,
    renderer: &mut FrameRenderer,
) -> Vec<RenderedFrame> {
    let matrices = skeleton.skinning_matrices(pose);
    let posed = avatar.animate(&matrices);
    let outputs = match &renderer.neural {
        Some(neural) => neural.render(&mut renderer.rasterizer, &posed, cameras.cameras()),
        None => {
            let options = RenderOptions {
                background: Vec3::ONE,
                ..RenderOptions::default()
            };
            renderer
                .rasterizer
                .render_all(&posed, cameras.cameras(), &options)
        }
    };
    outputs.into_iter().map(RenderedFrame::new).collect()
}
