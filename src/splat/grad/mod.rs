//! The backward pass of the CPU rasteriser: gradients of a loss on a rendered frame with
//! respect to every Gaussian's position, scale, rotation, opacity and colour.
//!
//! The forward pass is the one renderer everything else uses ([`Rasterizer::render_into`]);
//! this module only reads what it left behind (the projected splats and the depth-sorted tile
//! lists) and walks the same per-pixel sequence backwards, as the 3DGS reference does:
//!
//! 1. [`blend`]: per pixel, a forward sweep over the tile's splats finds the samples the blend
//!    added (the same tests as [`super::render`]'s blend: `power ≤ 0`, `α ≥ 1/255`, stop
//!    before `T` falls under `1e-4`), then a back-to-front sweep gives each sample's
//!    `∂L/∂colour`, `∂L/∂α` and from those `∂L/∂mean₂ᴅ`, `∂L/∂conic` and `∂L/∂opacity`;
//!    tiles run in parallel and are summed in tile order, so the result does not depend on
//!    threading.
//! 2. [`project`]: per Gaussian, back through the EWA projection (conic → 2D covariance →
//!    3D covariance `R S Sᵀ Rᵀ` and the perspective Jacobian, with 3DGS's clamping of the
//!    Jacobian's centre) to the world position, scales and quaternion (through its
//!    normalisation).
//!
//! Exact (up to rounding) wherever the forward is differentiable: the cut-offs (α < 1/255,
//! `power > 0`, `T < 1e-4`, culling) and the 0.99 cap on α are steps whose derivative is
//! taken as zero. Colours are differentiated as the colour the splat shows (the evaluated
//! spherical harmonics); the view direction's effect on higher SH bands is not propagated to
//! the position. `tests` checks every gradient against finite differences.

mod blend;
mod project;
#[cfg(test)]
pub(crate) mod tests;

use super::camera::Camera;
use super::gaussians::Gaussians;
use super::render::{Rasterizer, RenderOptions, RenderOutput};
use glam::{Vec3, Vec4};

/// Gradients of a scalar loss with respect to each Gaussian's attributes, as stored in
/// [`Gaussians`].
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GaussianGrads {
    /// `∂L/∂position` (world, metres).
    pub positions: Vec<Vec3>,
    /// `∂L/∂scale` (linear scales).
    pub scales: Vec<Vec3>,
    /// `∂L/∂rotation` with respect to the stored quaternion's `(x, y, z, w)` (not necessarily
    /// unit: the renderer normalises it).
    pub rotations: Vec<Vec4>,
    /// `∂L/∂opacity`.
    pub opacities: Vec<f32>,
    /// `∂L/∂colour`: the colour the splat shows (zero in a channel clamped at 0).
    pub colours: Vec<Vec3>,
    /// `∂L/∂mean₂ᴅ` in pixels, summed over the pixels (the 3DGS densification signal).
    pub means_2d: Vec<[f32; 2]>,
}

impl GaussianGrads {
    /// Zero gradients for `n` Gaussians.
    pub fn zeros(n: usize) -> Self {
        Self {
            positions: vec![Vec3::ZERO; n],
            scales: vec![Vec3::ZERO; n],
            rotations: vec![Vec4::ZERO; n],
            opacities: vec![0.0; n],
            colours: vec![Vec3::ZERO; n],
            means_2d: vec![[0.0; 2]; n],
        }
    }

    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    /// True when there is no Gaussian.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }
}

/// Gradients flowing into a rendered frame: `∂L/∂rgb` (`H × W × 3`) and `∂L/∂alpha`
/// (`H × W`), laid out as [`RenderOutput`]'s maps.
#[derive(Debug, Clone, Copy)]
pub struct FrameGrads<'a> {
    /// `∂L/∂rgb`, `H × W × 3`.
    pub rgb: &'a [f32],
    /// `∂L/∂alpha`, `H × W`.
    pub alpha: &'a [f32],
}

/// Why a backward pass cannot run.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum GradError {
    /// The frame gradients do not match the rendered frame's size.
    #[error(
        "frame gradients have {rgb} rgb and {alpha} alpha values for a {width}×{height} frame"
    )]
    FrameSize {
        /// rgb values given.
        rgb: usize,
        /// alpha values given.
        alpha: usize,
        /// Frame width.
        width: u32,
        /// Frame height.
        height: u32,
    },
    /// The rasteriser's last frame was not of these Gaussians.
    #[error(
        "the rasteriser's last frame had {splats} splats, not the {gaussians} Gaussians given"
    )]
    StaleForward {
        /// Splats of the last frame.
        splats: usize,
        /// Gaussians given.
        gaussians: usize,
    },
}

/// Renders `gaussians` into `out` with `rasterizer` (the forward everyone uses) and keeps what
/// the backward pass needs in the rasteriser; call [`backward`] with the same arguments next.
pub fn forward(
    rasterizer: &mut Rasterizer,
    gaussians: &Gaussians,
    camera: &Camera,
    options: &RenderOptions,
    out: &mut RenderOutput,
) {
    rasterizer.render_into(gaussians, camera, options, out);
}

/// The gradients of a loss with respect to `gaussians`, given its gradients `frame` with
/// respect to the frame that `rasterizer` last rendered of these Gaussians from `camera`
/// with `options` ([`forward`]).
pub fn backward(
    rasterizer: &Rasterizer,
    gaussians: &Gaussians,
    camera: &Camera,
    options: &RenderOptions,
    frame: FrameGrads<'_>,
) -> Result<GaussianGrads, GradError> {
    let k = camera.intrinsics;
    let pixels = k.width as usize * k.height as usize;
    if frame.rgb.len() != 3 * pixels || frame.alpha.len() != pixels {
        return Err(GradError::FrameSize {
            rgb: frame.rgb.len(),
            alpha: frame.alpha.len(),
            width: k.width,
            height: k.height,
        });
    }
    let splats = rasterizer.splats();
    if splats.len() != gaussians.len() {
        return Err(GradError::StaleForward {
            splats: splats.len(),
            gaussians: gaussians.len(),
        });
    }
    let _span = tracing::trace_span!("render backward", n = gaussians.len()).entered();
    let splat_grads = blend::backward(splats, rasterizer.bins(), camera, options, frame);
    Ok(project::backward(
        gaussians,
        splats,
        camera,
        options,
        &splat_grads,
    ))
}
