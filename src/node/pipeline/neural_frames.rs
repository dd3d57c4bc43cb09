//! The neural path of the rendered frames (`outputs.renderer: neural`, reference §1.3 (i)):
//! splat the posed Gaussians' latent features in front of the white background feature, decode
//! the feature image with the network's DPT neural renderer, and hand its RGB (and mask, as
//! alpha) on as an ordinary [`RenderOutput`], so ROS 2, iceoryx2 and PNG outputs get it
//! unchanged.
//!
//! Data flows one way: [`NeuralFrames`] holds, from construction on, a clone of the model's
//! [`NeuralRenderer`] (its tensors are shared) and the background feature; nothing calls back
//! into the reconstructor per frame.
//!
//! Device: the renderer runs where the model lives. On the CPU the rasteriser's channels-last
//! feature image is viewed as `[1, C, H, W]` without a copy, which the renderer's channels-last
//! kernels read in place. With `outputs.render_device: cuda` the CUDA rasteriser's features
//! are downloaded into the [`RenderOutput`] first (and uploaded again when the model is on a
//! GPU): correct, not fast. A GPU-resident version would keep the CUDA rasteriser's
//! `GpuFrame::features` (`[H, W, C]` on candle's stream, `src/splat/cuda/device.rs`, rendered
//! from one `CudaScene` per batch) and feed `features.permute((2, 0, 1)).unsqueeze(0)` to a
//! renderer whose weights live on the same CUDA device (`model.device: cuda`), downloading only
//! the 4-channel output.

use super::render::FrameRasterizer;
use crate::config::RendererChoice;
use crate::model::dpt::NeuralRenderer;
use crate::model::RgbKind;
use crate::splat::{Camera, Gaussians, RenderOptions, RenderOutput};
use candle_core::{DType, Device, Tensor};
use glam::Vec3;

/// The renderer could not be set up as configured.
#[derive(Debug, thiserror::Error)]
pub enum RendererSetupError {
    /// `outputs.renderer: neural` with a neural renderer that cannot read the features.
    #[error(
        "outputs.renderer: neural: the network's Gaussians carry {features} feature channels \
         (gs_head.gs_query_dim) but its neural renderer reads {renderer} \
         (neural_renderer.in_channels); use outputs.renderer: gaussians"
    )]
    WidthMismatch {
        /// Feature channels per Gaussian.
        features: usize,
        /// Channels the neural renderer reads.
        renderer: usize,
    },
    /// `outputs.renderer: neural` with a background feature of another width than the
    /// renderer reads (the official `background_embedding` is 128 wide whatever
    /// `gs_query_dim` is).
    #[error(
        "outputs.renderer: neural: the network's background feature has {background} channels \
         (renderer.background_embedding) but its neural renderer reads {renderer} \
         (neural_renderer.in_channels); use outputs.renderer: gaussians"
    )]
    BackgroundMismatch {
        /// Channels of the background feature.
        background: usize,
        /// Channels the neural renderer reads.
        renderer: usize,
    },
    /// A tensor of the neural renderer could not be prepared.
    #[error("outputs.renderer: neural: {0}")]
    Candle(#[from] candle_core::Error),
}

/// How the node makes its frames, after `auto` is resolved.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameSource {
    /// Splat the Gaussians' RGB.
    Gaussians,
    /// Splat the features, decode with the DPT neural renderer.
    Neural,
}

/// The chosen frame source and why (logged at startup).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RendererDecision {
    /// What renders the frames.
    pub source: FrameSource,
    /// Why, in words.
    pub reason: String,
}

/// Resolves `outputs.renderer` for a network whose Gaussians' RGB is `rgb`, with `features`
/// feature channels per Gaussian, a `background`-wide background feature and a neural
/// renderer reading `renderer_in` channels. `neural` with mismatched widths is an error naming
/// both; `auto` then falls back to `gaussians`.
pub fn choose_renderer(
    choice: RendererChoice,
    rgb: RgbKind,
    features: usize,
    background: usize,
    renderer_in: usize,
) -> Result<RendererDecision, RendererSetupError> {
    let fits = features == renderer_in && background == renderer_in && features > 0;
    let decision = |source, reason: String| Ok(RendererDecision { source, reason });
    match (choice, rgb) {
        (RendererChoice::Gaussians, RgbKind::DisplayReady) => {
            decision(FrameSource::Gaussians, "outputs.renderer: gaussians".into())
        }
        (RendererChoice::Gaussians, RgbKind::Latent) => decision(
            FrameSource::Gaussians,
            "outputs.renderer: gaussians, although the checkpoint's Gaussian RGB is not \
             display-ready: frames show a latent intermediate, not colours"
                .into(),
        ),
        (RendererChoice::Neural, _) if !fits && features == renderer_in && features > 0 => {
            Err(RendererSetupError::BackgroundMismatch {
                background,
                renderer: renderer_in,
            })
        }
        (RendererChoice::Neural, _) if !fits => Err(RendererSetupError::WidthMismatch {
            features,
            renderer: renderer_in,
        }),
        (RendererChoice::Neural, _) => decision(
            FrameSource::Neural,
            format!("outputs.renderer: neural ({features} feature channels)"),
        ),
        (RendererChoice::Auto, RgbKind::DisplayReady) => decision(
            FrameSource::Gaussians,
            "outputs.renderer: auto: the checkpoint's Gaussian RGB is display-ready".into(),
        ),
        (RendererChoice::Auto, RgbKind::Latent) if fits => decision(
            FrameSource::Neural,
            format!(
                "outputs.renderer: auto: the checkpoint's Gaussian RGB is not display-ready and \
                 its neural renderer reads the Gaussians' {features} feature channels"
            ),
        ),
        (RendererChoice::Auto, RgbKind::Latent) if features == renderer_in && features > 0 => {
            decision(
                FrameSource::Gaussians,
                format!(
                    "outputs.renderer: auto: the checkpoint's Gaussian RGB is not display-ready, \
                     but its background feature is {background} wide and its neural renderer \
                     reads {renderer_in} channels: frames show the latent RGB"
                ),
            )
        }
        (RendererChoice::Auto, RgbKind::Latent) => decision(
            FrameSource::Gaussians,
            format!(
                "outputs.renderer: auto: the checkpoint's Gaussian RGB is not display-ready, but \
                 its neural renderer reads {renderer_in} channels and the Gaussians carry \
                 {features}: frames show the latent RGB"
            ),
        ),
    }
}

/// Splats features and decodes them with the DPT neural renderer, per virtual camera.
#[derive(Debug, Clone)]
pub struct NeuralFrames {
    renderer: NeuralRenderer,
    background_features: Vec<f32>,
    channels: usize,
    patch: u32,
    device: Device,
    dtype: DType,
}

impl NeuralFrames {
    /// The neural path with `renderer` (on the model's device, in the model's dtype) and the
    /// feature splatted behind the avatar (`GsHead::background_feature(1.0)`: white, `[C]`).
    pub fn new(
        renderer: NeuralRenderer,
        background_feature: &Tensor,
    ) -> Result<Self, RendererSetupError> {
        let cfg = renderer.config();
        let (channels, patch) = (cfg.in_channels, cfg.patch_size as u32);
        let background_features = background_feature
            .to_dtype(DType::F32)?
            .flatten_all()?
            .to_vec1::<f32>()?;
        if background_features.len() != channels {
            return Err(RendererSetupError::WidthMismatch {
                features: background_features.len(),
                renderer: channels,
            });
        }
        Ok(Self {
            device: background_feature.device().clone(),
            dtype: background_feature.dtype(),
            renderer,
            background_features,
            channels,
            patch,
        })
    }

    /// Feature channels the renderer reads.
    pub fn channels(&self) -> usize {
        self.channels
    }

    /// `camera` with its image enlarged to multiples of the renderer's patch (fx, fy, cx, cy
    /// kept: the extra rows and columns are added right and below, so the top-left
    /// `width × height` of the padded image is `camera`'s image).
    pub fn padded_camera(&self, camera: &Camera) -> Camera {
        let up = |v: u32| v.div_ceil(self.patch) * self.patch;
        let mut padded = *camera;
        padded.intrinsics.width = up(camera.intrinsics.width);
        padded.intrinsics.height = up(camera.intrinsics.height);
        padded
    }

    /// Rasteriser options of the feature splat: white background, the background feature.
    pub fn options(&self) -> RenderOptions {
        RenderOptions {
            background: Vec3::ONE,
            render_features: true,
            background_features: self.background_features.clone(),
            ..RenderOptions::default()
        }
    }

    /// Decodes the feature render `splat` of a padded camera into the `width × height` frame:
    /// the renderer's RGB and mask (as alpha), cropped to the top-left corner; depth is the
    /// splat's. The output carries no feature channels.
    pub fn decode(
        &self,
        splat: &RenderOutput,
        width: u32,
        height: u32,
    ) -> candle_core::Result<RenderOutput> {
        let (pw, ph, c) = (
            splat.width as usize,
            splat.height as usize,
            splat.feature_channels,
        );
        let (w, h) = (width as usize, height as usize);
        if c != self.channels || w > pw || h > ph {
            candle_core::bail!(
                "neural frames: a {pw}x{ph} splat with {c} feature channels cannot make a \
                 {w}x{h} frame for a renderer reading {} channels",
                self.channels
            );
        }
        // [H, W, C] viewed as [1, C, H, W]: the channels-last layout the CPU kernels read.
        let features = Tensor::from_slice(&splat.features, (ph, pw, c), &Device::Cpu)?
            .to_device(&self.device)?
            .to_dtype(self.dtype)?
            .permute((2, 0, 1))?
            .unsqueeze(0)?;
        let (rgb, mask) = self.renderer.forward(&features)?;
        let planar = |t: &Tensor| -> candle_core::Result<Vec<f32>> {
            t.to_device(&Device::Cpu)?
                .to_dtype(DType::F32)?
                .flatten_all()?
                .to_vec1::<f32>()
        };
        let (rgb, mask) = (planar(&rgb)?, planar(&mask)?);
        let plane = pw * ph;
        let mut out = RenderOutput {
            width,
            height,
            rgb: Vec::with_capacity(3 * w * h),
            alpha: Vec::with_capacity(w * h),
            depth: Vec::with_capacity(w * h),
            feature_channels: 0,
            features: Vec::new(),
        };
        for y in 0..h {
            for x in 0..w {
                let i = y * pw + x;
                out.rgb.extend([rgb[i], rgb[plane + i], rgb[2 * plane + i]]);
                out.alpha.push(mask[i]);
                out.depth.push(splat.depth.get(i).copied().unwrap_or(0.0));
            }
        }
        Ok(out)
    }

    /// Renders the posed Gaussians (with this renderer's feature channels) from every camera:
    /// one feature splat per padded camera, decoded and cropped to the camera's size. A frame
    /// the renderer fails on is logged and replaced by the splat's (latent) RGB.
    pub fn render(
        &self,
        rasterizer: &mut FrameRasterizer,
        posed: &Gaussians,
        cameras: &[Camera],
    ) -> Vec<RenderOutput> {
        let padded: Vec<Camera> = cameras.iter().map(|c| self.padded_camera(c)).collect();
        let splats = rasterizer.render_all(posed, &padded, &self.options());
        splats
            .iter()
            .zip(cameras)
            .map(|(splat, cam)| {
                let (w, h) = (cam.intrinsics.width, cam.intrinsics.height);
                self.decode(splat, w, h).unwrap_or_else(|e| {
                    tracing::error!("neural renderer failed, publishing the splat's RGB: {e}");
                    crop_rgb(splat, w, h)
                })
            })
            .collect()
    }
}

/// The top-left `width × height` of `splat`'s RGB, alpha and depth.
fn crop_rgb(splat: &RenderOutput, width: u32, height: u32) -> RenderOutput {
    let (pw, w, h) = (splat.width as usize, width as usize, height as usize);
    let rows = |v: &[f32], k: usize| -> Vec<f32> {
        (0..h)
            .flat_map(|y| v[k * y * pw..k * (y * pw + w)].iter().copied())
            .collect()
    };
    RenderOutput {
        width,
        height,
        rgb: rows(&splat.rgb, 3),
        alpha: rows(&splat.alpha, 1),
        depth: rows(&splat.depth, 1),
        feature_channels: 0,
        features: Vec::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::checkpoint::seeded_var_builder;
    use crate::model::dpt::DptConfig;
    use crate::splat::synthetic::body_cloud;
    use crate::splat::Intrinsics;

    fn renderer() -> NeuralRenderer {
        let vb = seeded_var_builder(5, DType::F32, &Device::Cpu);
        NeuralRenderer::new(&DptConfig::tiny(), vb.pp("neural_renderer")).unwrap()
    }

    fn background(c: usize) -> Tensor {
        let v: Vec<f32> = (0..c).map(|i| 0.05 * i as f32 - 0.4).collect();
        Tensor::from_vec(v, c, &Device::Cpu).unwrap()
    }

    #[test]
    fn choice_follows_the_rgb_and_rejects_mismatched_widths() {
        use RendererChoice::*;
        let pick = |c, rgb, f, r| choose_renderer(c, rgb, f, f, r).unwrap().source;
        assert_eq!(
            pick(Auto, RgbKind::DisplayReady, 32, 32),
            FrameSource::Gaussians
        );
        assert_eq!(pick(Auto, RgbKind::Latent, 128, 128), FrameSource::Neural);
        assert_eq!(pick(Auto, RgbKind::Latent, 64, 128), FrameSource::Gaussians);
        assert_eq!(
            pick(Gaussians, RgbKind::Latent, 128, 128),
            FrameSource::Gaussians
        );
        assert_eq!(
            pick(Neural, RgbKind::DisplayReady, 32, 32),
            FrameSource::Neural
        );
        let e = choose_renderer(Neural, RgbKind::Latent, 64, 64, 128)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("outputs.renderer") && e.contains("64") && e.contains("128"),
            "{e}"
        );
        // The official background embedding is 128 wide: features and renderer at 64 cannot
        // splat it; auto falls back, neural says so.
        let d = choose_renderer(Auto, RgbKind::Latent, 64, 128, 64).unwrap();
        assert_eq!(d.source, FrameSource::Gaussians);
        assert!(
            d.reason.contains("background feature is 128"),
            "{}",
            d.reason
        );
        let e = choose_renderer(Neural, RgbKind::Latent, 64, 128, 64)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("background_embedding") && e.contains("128"),
            "{e}"
        );
    }

    /// The neural path's frame is `NeuralRenderer::forward` on the rasteriser's features of
    /// the padded camera (here built as a contiguous NCHW tensor, the renderer's other input
    /// path), cropped to the camera's size.
    #[test]
    fn frame_equals_the_renderer_on_the_splatted_features_cropped() {
        let nr = renderer();
        let c = nr.config().in_channels;
        let frames = NeuralFrames::new(nr.clone(), &background(c)).unwrap();
        let g = body_cloud(3000, c, 9);
        let cam = Camera::orbit(
            1,
            8,
            2.6,
            0.0,
            Vec3::new(0.0, 0.88, 0.0),
            Intrinsics::from_fov_y(40, 33, 0.75),
        );
        let padded = frames.padded_camera(&cam);
        assert_eq!(
            (padded.intrinsics.width, padded.intrinsics.height),
            (42, 35)
        );
        assert_eq!(padded.intrinsics.fx, cam.intrinsics.fx);
        assert_eq!(padded.intrinsics.cx, cam.intrinsics.cx);

        let mut rasterizer = FrameRasterizer::new(crate::config::RenderDevice::Cpu).unwrap();
        let out = frames.render(&mut rasterizer, &g, &[cam]);
        assert_eq!(out.len(), 1);
        let f = &out[0];
        assert_eq!((f.width, f.height), (40, 33));
        assert_eq!((f.rgb.len(), f.alpha.len()), (40 * 33 * 3, 40 * 33));

        let splat = crate::splat::render(&g, &padded, &frames.options());
        assert_eq!(splat.feature_channels, c);
        // The background feature fills pixels no Gaussian covers.
        let corner = &splat.features[..c];
        let bg = background(c).to_vec1::<f32>().unwrap();
        assert!(corner.iter().zip(&bg).all(|(a, b)| (a - b).abs() < 1e-6));
        let (pw, ph) = (42usize, 35usize);
        let mut nchw = vec![0f32; c * ph * pw];
        for (i, px) in splat.features.chunks_exact(c).enumerate() {
            for (ch, v) in px.iter().enumerate() {
                nchw[ch * ph * pw + i] = *v;
            }
        }
        let t = Tensor::from_vec(nchw, (1, c, ph, pw), &Device::Cpu).unwrap();
        let (rgb, mask) = nr.forward(&t).unwrap();
        let rgb = rgb.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let mask = mask.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let mut worst = 0f32;
        for y in 0..33 {
            for x in 0..40 {
                let i = y * pw + x;
                let o = y * 40 + x;
                for k in 0..3 {
                    worst = worst.max((f.rgb[3 * o + k] - rgb[k * ph * pw + i]).abs());
                }
                worst = worst.max((f.alpha[o] - mask[i]).abs());
                assert_eq!(f.depth[o], splat.depth[i]);
            }
        }
        assert!(worst < 1e-4, "neural frame vs renderer: {worst}");
        // The decoded frame is not the splat's RGB (the test can tell the paths apart).
        let rgb_diff = (0..40 * 33)
            .map(|o| (f.rgb[3 * o] - splat.rgb[3 * ((o / 40) * pw + o % 40)]).abs())
            .fold(0f32, f32::max);
        assert!(rgb_diff > 1e-2, "{rgb_diff}");
    }

    #[test]
    fn a_background_of_the_wrong_width_is_refused() {
        let e = NeuralFrames::new(renderer(), &background(7))
            .unwrap_err()
            .to_string();
        assert!(e.contains('7') && e.contains("32"), "{e}");
    }
}
