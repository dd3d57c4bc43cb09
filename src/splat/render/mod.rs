//! CPU splatting rasteriser with the 3DGS reference semantics, in named stages:
//! [`project`] (EWA projection, SH colour, culling) → [`bin`] (global depth radix sort, then
//! stable binning into 16×16 tiles) → [`blend`] (front-to-back compositing, SIMD over half
//! tile rows). Each stage runs inside a `tracing` span and maps onto one kernel of a future
//! CUDA path. Work is spread with rayon (Gaussians in `project`, groups of tile rows in `bin`,
//! bands of tiles in `blend`); the output is bit-identical for any thread count and any
//! instruction set. A [`Rasterizer`] keeps the per-frame buffers between frames.

pub(crate) mod bin;
pub(crate) mod blend;
pub(crate) mod project;
#[cfg(test)]
mod tests;

use super::camera::Camera;
use super::gaussians::Gaussians;
use blend::{BandOut, BlendInput};
use glam::Vec3;
use rayon::prelude::*;

/// Tile side in pixels (3DGS `BLOCK_X = BLOCK_Y = 16`).
pub const TILE: usize = 16;

/// Rendering settings.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderOptions {
    /// Background colour behind the Gaussians.
    pub background: Vec3,
    /// Render the Gaussians' feature channels too (when they have any).
    pub render_features: bool,
    /// Background features (one per channel); empty means zeros.
    pub background_features: Vec<f32>,
    /// Near plane (metres along the optical axis); closer Gaussians are culled.
    pub near: f32,
    /// Far plane (metres).
    pub far: f32,
    /// Screen-space low-pass added to the 2D covariance diagonal (pixels², 3DGS: 0.3).
    pub low_pass: f32,
}

impl Default for RenderOptions {
    fn default() -> Self {
        Self {
            background: Vec3::ZERO,
            render_features: false,
            background_features: Vec::new(),
            near: 0.01,
            far: 100.0,
            low_pass: 0.3,
        }
    }
}

impl RenderOptions {
    /// Feature channels a render of Gaussians with `feature_channels` channels produces (0
    /// unless [`RenderOptions::render_features`]).
    pub fn rendered_channels(&self, feature_channels: usize) -> usize {
        if self.render_features {
            feature_channels
        } else {
            0
        }
    }

    /// The background features for `channels` rendered channels (missing ones are 0).
    pub fn background_features_for(&self, channels: usize) -> Vec<f32> {
        let mut features = self.background_features.clone();
        features.resize(channels, 0.0);
        features
    }
}

/// A rendered frame; all maps row-major, top row first.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RenderOutput {
    /// Width (pixels).
    pub width: u32,
    /// Height (pixels).
    pub height: u32,
    /// Linear RGB, `H × W × 3` (not clamped).
    pub rgb: Vec<f32>,
    /// Accumulated opacity `1 − T`, `H × W`.
    pub alpha: Vec<f32>,
    /// Expected depth `Σ wᵢ zᵢ / Σ wᵢ` along the optical axis (metres; 0 where alpha is 0), `H × W`.
    pub depth: Vec<f32>,
    /// Feature channels rendered (0 without features).
    pub feature_channels: usize,
    /// Features blended like the colour, plus `T ·` background features, `H × W × C`.
    pub features: Vec<f32>,
}

impl RenderOutput {
    /// The RGB map as an 8-bit image (clamped to `[0, 1]`, rounded).
    pub fn to_rgb8(&self) -> image::RgbImage {
        let bytes = self
            .rgb
            .iter()
            .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
            .collect();
        image::RgbImage::from_raw(self.width, self.height, bytes)
            .expect("rgb holds H × W × 3 values")
    }

    /// RGB of pixel `(u, v)`.
    pub fn pixel(&self, u: u32, v: u32) -> Vec3 {
        let o = 3 * (v as usize * self.width as usize + u as usize);
        Vec3::new(self.rgb[o], self.rgb[o + 1], self.rgb[o + 2])
    }
}

/// Wall-clock time of each stage of one render, with the work sizes (for benchmarks).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RasterStageTimes {
    /// Projection and culling (seconds).
    pub project: f64,
    /// Tile binning and per-tile depth sort (seconds).
    pub bin_sort: f64,
    /// Blending (seconds).
    pub blend: f64,
    /// Gaussians that survived culling.
    pub visible: usize,
    /// (tile, splat) pairs after binning.
    pub tile_pairs: usize,
}

/// Renders Gaussians seen by `camera` (see the module doc for the stages).
///
/// Never produces NaN: Gaussians that are non-finite, degenerate, behind the near plane or off
/// screen are culled. Panics only if `gaussians` fails [`Gaussians::validate`]. To render many
/// frames without per-frame allocations, keep a [`Rasterizer`] and call
/// [`Rasterizer::render_into`].
pub fn render(gaussians: &Gaussians, camera: &Camera, options: &RenderOptions) -> RenderOutput {
    render_timed(gaussians, camera, options).0
}

/// [`render`], also returning how long each stage took.
pub fn render_timed(
    gaussians: &Gaussians,
    camera: &Camera,
    options: &RenderOptions,
) -> (RenderOutput, RasterStageTimes) {
    let mut out = RenderOutput::default();
    let times = Rasterizer::default().render_into(gaussians, camera, options, &mut out);
    (out, times)
}

/// The SIMD instruction set the blend stage uses on this CPU (`AVX-512F`, `AVX2` or
/// `baseline`).
pub fn blend_instruction_set() -> &'static str {
    blend::instruction_set()
}

/// Rasteriser state kept between frames: the projected splats and the tile lists, whose
/// buffers are reused, so that a warm rasteriser rendering into a reused [`RenderOutput`]
/// does not allocate per frame.
#[derive(Debug, Default)]
pub struct Rasterizer {
    splats: Vec<Option<project::Splat2D>>,
    bins: bin::TileBins,
    /// Blend with the baseline instruction set only (tests compare it with the SIMD build).
    portable: bool,
}

impl Rasterizer {
    /// A rasteriser with empty buffers (they grow on the first frame).
    pub fn new() -> Self {
        Self::default()
    }

    /// The last frame's projected splats, one per Gaussian (`None` = culled), for the
    /// backward pass ([`crate::splat::grad`]).
    pub(crate) fn splats(&self) -> &[Option<project::Splat2D>] {
        &self.splats
    }

    /// The last frame's depth-sorted tile lists, for the backward pass.
    pub(crate) fn bins(&self) -> &bin::TileBins {
        &self.bins
    }

    /// Renders into `out`, overwriting all of it (its buffers are resized only when the image
    /// size or channel count changed); returns the stage times. Same output as [`render`].
    pub fn render_into(
        &mut self,
        gaussians: &Gaussians,
        camera: &Camera,
        options: &RenderOptions,
        out: &mut RenderOutput,
    ) -> RasterStageTimes {
        let mut times = RasterStageTimes::default();
        let clock = std::time::Instant::now();
        let _span = tracing::debug_span!("render", n = gaussians.len()).entered();
        if let Err(e) = gaussians.validate() {
            panic!("render: invalid Gaussians: {e}");
        }
        let (width, height) = (
            camera.intrinsics.width as usize,
            camera.intrinsics.height as usize,
        );
        project::project(gaussians, camera, options, &mut self.splats);
        times.project = clock.elapsed().as_secs_f64();
        let grid = bin::TileGrid::new(camera.intrinsics.width, camera.intrinsics.height);
        self.bins.build(&self.splats, grid);
        times.bin_sort = clock.elapsed().as_secs_f64() - times.project;
        times.visible = self.bins.visible();
        times.tile_pairs = self.bins.pairs();

        let channels = options.rendered_channels(gaussians.feature_channels);
        let background_features = options.background_features_for(channels);
        out.width = width as u32;
        out.height = height as u32;
        out.feature_channels = channels;
        let pixels = width * height;
        for (buffer, len) in [
            (&mut out.rgb, pixels * 3),
            (&mut out.alpha, pixels),
            (&mut out.depth, pixels),
            (&mut out.features, pixels * channels),
        ] {
            buffer.resize(len, 0.0);
        }
        if pixels == 0 {
            return times;
        }
        let input = BlendInput {
            splats: &self.splats,
            bins: &self.bins,
            grid,
            gaussians,
            options,
            width,
            height,
            channels,
            background_features: &background_features,
        };
        let _blend = tracing::trace_span!("blend", tiles = grid.cols * grid.rows).entered();
        let band_px = TILE * width;
        let mut features = out.features.chunks_mut((band_px * channels).max(1));
        let bands: Vec<_> = out
            .rgb
            .chunks_mut(band_px * 3)
            .zip(out.alpha.chunks_mut(band_px))
            .zip(out.depth.chunks_mut(band_px))
            .map(|((rgb, alpha), depth)| BandOut {
                rgb,
                alpha,
                depth,
                features: if channels > 0 {
                    features.next().expect("one feature band per band")
                } else {
                    &mut []
                },
            })
            .collect();
        bands
            .into_par_iter()
            .enumerate()
            .for_each(|(row, band)| blend::blend_band(row, &input, band, self.portable));
        drop(_blend);
        times.blend = clock.elapsed().as_secs_f64() - times.project - times.bin_sort;
        times
    }
}
