//! Stage 1, project: each Gaussian to a 2D screen-space Gaussian (EWA splatting).
//!
//! Per Gaussian, independently (one CUDA thread each in a GPU port): transform the centre to the
//! optical frame, cull outside `near..far`, build the 3D covariance `R S Sᵀ Rᵀ`, project it with
//! the perspective Jacobian (centre clamped to 1.3× the image as in 3DGS/gsplat), add the 0.3 px
//! low-pass to the diagonal, invert it to the conic, evaluate the view-dependent SH colour, and
//! cull anything degenerate or non-finite so that no NaN can reach the blend. (The arithmetic
//! is kept in this order on purpose: committed fixtures, such as the demo bag's rendered
//! held-out views, are reproduced bit for bit.)

use super::RenderOptions;
use crate::splat::camera::Camera;
use crate::splat::gaussians::Gaussians;
use crate::splat::sh::eval_sh;
use glam::{Mat3A, Vec3A};
use rayon::prelude::*;

/// Alpha below which a sample is skipped (3DGS: 1/255).
pub(crate) const MIN_ALPHA: f32 = 1.0 / 255.0;

/// A Gaussian as seen by the camera: everything the blend stage needs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Splat2D {
    /// Centre in pixels (`u`, `v`; integer = pixel centre).
    pub mean: [f32; 2],
    /// Inverse 2D covariance `(a, b, c)` of `[a b; b c]`.
    pub conic: [f32; 3],
    /// Opacity in `(1/255, 1]`.
    pub opacity: f32,
    /// Optical-frame depth `z` (metres, > near).
    pub depth: f32,
    /// View-dependent colour.
    pub rgb: [f32; 3],
    /// Binning radius: `ceil(3σ)` of the larger eigenvalue (pixels).
    pub radius: f32,
    /// Half extents of the box outside which alpha < 1/255 (pixels, with a 0.5 px margin).
    pub extent: [f32; 2],
    /// `ln(1/255 / opacity)`: samples with a lower power have alpha < 1/255.
    pub min_power: f32,
    /// Index of the source Gaussian (for its feature row).
    pub index: u32,
}

/// Projects every Gaussian into `out` (resized to one entry per Gaussian, its allocation
/// reused); `None` where the Gaussian is culled.
pub(crate) fn project(
    gaussians: &Gaussians,
    camera: &Camera,
    options: &RenderOptions,
    out: &mut Vec<Option<Splat2D>>,
) {
    let _span = tracing::trace_span!("project", n = gaussians.len()).entered();
    let view = camera.camera_from_world();
    let w = view.matrix3;
    let center = camera.center();
    let k = camera.intrinsics;
    let (width, height) = (k.width as f32, k.height as f32);
    // Clamp limits for the Jacobian (gsplat: 30% beyond each image border).
    let lim_x_pos = (width - k.cx) / k.fx + 0.3 * width / k.fx;
    let lim_x_neg = k.cx / k.fx + 0.3 * width / k.fx;
    let lim_y_pos = (height - k.cy) / k.fy + 0.3 * height / k.fy;
    let lim_y_neg = k.cy / k.fy + 0.3 * height / k.fy;
    let check_features = options.render_features && gaussians.feature_channels > 0;

    (0..gaussians.len())
        .into_par_iter()
        .with_min_len(1024)
        .map(|i| {
            let opacity = gaussians.opacities[i];
            if opacity.is_nan() || opacity < MIN_ALPHA {
                return None;
            }
            let opacity = opacity.min(1.0);
            let pos = gaussians.positions[i];
            let p = view.transform_point3(pos);
            if p.z.is_nan() || p.z <= options.near || p.z >= options.far {
                return None;
            }
            let scale = gaussians.scales[i];
            let q = gaussians.rotations[i];
            let qlen = q.length();
            if qlen.is_nan() || qlen <= 1e-12 || !scale.is_finite() || !pos.is_finite() {
                return None;
            }
            // SIMD matrices (`Mat3A`): the same operations in the same order as `Mat3`.
            let m = Mat3A::from_quat(q / qlen) * Mat3A::from_diagonal(scale);
            let sigma_cam = w * (m * m.transpose()) * w.transpose();

            let inv_z = 1.0 / p.z;
            let tx = p.z * (p.x * inv_z).clamp(-lim_x_neg, lim_x_pos);
            let ty = p.z * (p.y * inv_z).clamp(-lim_y_neg, lim_y_pos);
            let j0 = Vec3A::new(k.fx * inv_z, 0.0, -k.fx * tx * inv_z * inv_z);
            let j1 = Vec3A::new(0.0, k.fy * inv_z, -k.fy * ty * inv_z * inv_z);
            let s_j0 = sigma_cam * j0;
            let a = j0.dot(s_j0) + options.low_pass;
            let b = j1.dot(s_j0);
            let c = j1.dot(sigma_cam * j1) + options.low_pass;
            let det = a * c - b * b;
            if det.is_nan() || det <= 0.0 || !det.is_finite() {
                return None;
            }
            let inv_det = 1.0 / det;
            let conic = [c * inv_det, -b * inv_det, a * inv_det];
            if !conic.iter().all(|v| v.is_finite()) {
                return None;
            }
            let mid = 0.5 * (a + c);
            let lambda = mid + (mid * mid - det).max(0.1).sqrt();
            let radius = (3.0 * lambda.sqrt()).ceil();
            let mean = [k.fx * p.x * inv_z + k.cx, k.fy * p.y * inv_z + k.cy];
            if !(radius.is_finite() && mean[0].is_finite() && mean[1].is_finite()) {
                return None;
            }
            if mean[0] + radius < -0.5
                || mean[0] - radius > width - 0.5
                || mean[1] + radius < -0.5
                || mean[1] - radius > height - 0.5
            {
                return None;
            }
            let min_power = (MIN_ALPHA / opacity).ln();
            let t = 2.0 * (opacity / MIN_ALPHA).ln();
            let extent = [(t * a).sqrt() + 0.5, (t * c).sqrt() + 0.5];

            let dir = (pos - center).normalize_or_zero();
            let rgb = eval_sh(gaussians.sh_degree, gaussians.sh_of(i), dir);
            if !rgb.is_finite() {
                return None;
            }
            if check_features && !gaussians.features_of(i).iter().all(|v| v.is_finite()) {
                return None;
            }
            Some(Splat2D {
                mean,
                conic,
                opacity,
                depth: p.z,
                rgb: rgb.to_array(),
                radius,
                extent,
                min_power,
                index: i as u32,
            })
        })
        .collect_into_vec(out);
}
