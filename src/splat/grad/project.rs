//! Backward through the EWA projection: from each splat's screen-space gradients to its
//! Gaussian's world position, scales, quaternion, opacity and colour.

use super::blend::SplatGrad;
use super::GaussianGrads;
use crate::splat::camera::Camera;
use crate::splat::gaussians::Gaussians;
use crate::splat::render::project::Splat2D;
use crate::splat::render::RenderOptions;
use glam::{Mat2, Mat3, Vec3, Vec4};
use rayon::prelude::*;

/// Per Gaussian, the gradients with respect to its stored attributes.
pub(super) fn backward(
    gaussians: &Gaussians,
    splats: &[Option<Splat2D>],
    camera: &Camera,
    options: &RenderOptions,
    grads: &[SplatGrad],
) -> GaussianGrads {
    let n = gaussians.len();
    let view = camera.camera_from_world();
    let w = Mat3::from(view.matrix3);
    let k = camera.intrinsics;
    let (width, height) = (k.width as f32, k.height as f32);
    let lim_x = (
        k.cx / k.fx + 0.3 * width / k.fx,
        (width - k.cx) / k.fx + 0.3 * width / k.fx,
    );
    let lim_y = (
        k.cy / k.fy + 0.3 * height / k.fy,
        (height - k.cy) / k.fy + 0.3 * height / k.fy,
    );
    let per: Vec<Option<Gradient>> = (0..n)
        .into_par_iter()
        .with_min_len(1024)
        .map(|i| {
            let g = splats[i].as_ref()?;
            let d = &grads[i];
            if *d == SplatGrad::default() {
                return None;
            }
            Some(gaussian_backward(
                gaussians, i, g, d, w, &view, k, lim_x, lim_y, options,
            ))
        })
        .collect();
    let mut out = GaussianGrads::zeros(n);
    for (i, g) in per.into_iter().enumerate() {
        if let Some(g) = g {
            out.positions[i] = g.position;
            out.scales[i] = g.scale;
            out.rotations[i] = g.rotation;
            out.opacities[i] = g.opacity;
            out.colours[i] = g.colour;
            out.means_2d[i] = grads[i].mean;
        }
    }
    out
}

/// One Gaussian's gradients.
struct Gradient {
    position: Vec3,
    scale: Vec3,
    rotation: Vec4,
    opacity: f32,
    colour: Vec3,
}

#[allow(clippy::too_many_arguments)]
fn gaussian_backward(
    gaussians: &Gaussians,
    i: usize,
    splat: &Splat2D,
    d: &SplatGrad,
    w: Mat3,
    view: &glam::Affine3A,
    k: crate::splat::Intrinsics,
    lim_x: (f32, f32),
    lim_y: (f32, f32),
    options: &RenderOptions,
) -> Gradient {
    let pos = gaussians.positions[i];
    let p = view.transform_point3(pos);
    let scale = gaussians.scales[i];
    let q = gaussians.rotations[i];
    let qlen = q.length();
    let qn = q / qlen;
    let r = Mat3::from_quat(qn);
    let m = r * Mat3::from_diagonal(scale);
    let sigma = m * m.transpose();
    let sigma_cam = w * sigma * w.transpose();

    let z = p.z;
    let inv_z = 1.0 / z;
    let (rx, ry) = (p.x * inv_z, p.y * inv_z);
    let clamped_x = rx < -lim_x.0 || rx > lim_x.1;
    let clamped_y = ry < -lim_y.0 || ry > lim_y.1;
    let tx = z * rx.clamp(-lim_x.0, lim_x.1);
    let ty = z * ry.clamp(-lim_y.0, lim_y.1);
    let j0 = Vec3::new(k.fx * inv_z, 0.0, -k.fx * tx * inv_z * inv_z);
    let j1 = Vec3::new(0.0, k.fy * inv_z, -k.fy * ty * inv_z * inv_z);
    let s_j0 = sigma_cam * j0;
    let s_j1 = sigma_cam * j1;
    let a = j0.dot(s_j0) + options.low_pass;
    let b = j1.dot(s_j0);
    let c = j1.dot(s_j1) + options.low_pass;

    // Conic = Cov⁻¹: ∂L/∂Cov = −K G K, the conic's b standing for both off-diagonal entries.
    let det = a * c - b * b;
    let conic = Mat2::from_cols_array(&[c / det, -b / det, -b / det, a / det]);
    let g = Mat2::from_cols_array(&[d.conic[0], 0.5 * d.conic[1], 0.5 * d.conic[1], d.conic[2]]);
    let d_cov = -(conic * g * conic);
    let (da, db, dc) = (
        d_cov.x_axis.x,
        d_cov.y_axis.x + d_cov.x_axis.y,
        d_cov.y_axis.y,
    );

    // a = j0ᵀ Σc j0, b = j1ᵀ Σc j0, c = j1ᵀ Σc j1.
    let d_sigma_cam = outer(j0, j0) * da + outer(j1, j0) * db + outer(j1, j1) * dc;
    let d_j0 = s_j0 * (2.0 * da) + s_j1 * db;
    let d_j1 = s_j0 * db + s_j1 * (2.0 * dc);

    // Σc = W Σ Wᵀ, Σ = M Mᵀ, M = R S.
    let d_sigma = w.transpose() * d_sigma_cam * w;
    let d_m = (d_sigma + d_sigma.transpose()) * m;
    let d_scale = Vec3::new(
        r.x_axis.dot(d_m.x_axis),
        r.y_axis.dot(d_m.y_axis),
        r.z_axis.dot(d_m.z_axis),
    );
    let d_r = Mat3::from_cols(
        d_m.x_axis * scale.x,
        d_m.y_axis * scale.y,
        d_m.z_axis * scale.z,
    );
    let d_qn = rotation_backward(qn, d_r);
    let qv = Vec4::from(qn);
    let d_q = (d_qn - qv * qv.dot(d_qn)) / qlen;

    // The centre: mean = (fx x/z + cx, fy y/z + cy), and the Jacobian's dependence on p.
    let mut d_p = Vec3::new(
        d.mean[0] * k.fx * inv_z,
        d.mean[1] * k.fy * inv_z,
        -(d.mean[0] * k.fx * p.x + d.mean[1] * k.fy * p.y) * inv_z * inv_z,
    );
    let inv_z2 = inv_z * inv_z;
    // j0 = (fx/z, 0, −fx tx/z²): tx = x unclamped, z·limit clamped.
    d_p.z -= d_j0.x * k.fx * inv_z2;
    if clamped_x {
        d_p.z += d_j0.z * k.fx * (tx * inv_z) * inv_z2;
    } else {
        d_p.x -= d_j0.z * k.fx * inv_z2;
        d_p.z += d_j0.z * 2.0 * k.fx * tx * inv_z2 * inv_z;
    }
    d_p.z -= d_j1.y * k.fy * inv_z2;
    if clamped_y {
        d_p.z += d_j1.z * k.fy * (ty * inv_z) * inv_z2;
    } else {
        d_p.y -= d_j1.z * k.fy * inv_z2;
        d_p.z += d_j1.z * 2.0 * k.fy * ty * inv_z2 * inv_z;
    }
    let d_position = w.transpose() * d_p;

    let colour = Vec3::from_array(splat.rgb);
    let d_colour =
        Vec3::from_array(d.rgb) * Vec3::select(colour.cmpgt(Vec3::ZERO), Vec3::ONE, Vec3::ZERO);
    let d_opacity = if gaussians.opacities[i] > 1.0 {
        0.0
    } else {
        d.opacity
    };
    Gradient {
        position: d_position,
        scale: d_scale,
        rotation: d_q,
        opacity: d_opacity,
        colour: d_colour,
    }
}

/// `a bᵀ`.
fn outer(a: Vec3, b: Vec3) -> Mat3 {
    Mat3::from_cols(a * b.x, a * b.y, a * b.z)
}

/// `∂L/∂q` (xyzw) of the rotation matrix of unit `q`, given `∂L/∂R`.
fn rotation_backward(q: glam::Quat, d_r: Mat3) -> Vec4 {
    let (x, y, z, w) = (q.x, q.y, q.z, q.w);
    // Row r, column c of ∂L/∂R (glam stores columns).
    let g = |row: usize, col: usize| d_r.col(col)[row];
    let d_w =
        2.0 * (-z * g(0, 1) + y * g(0, 2) + z * g(1, 0) - x * g(1, 2) - y * g(2, 0) + x * g(2, 1));
    let d_x = 2.0
        * (y * g(0, 1) + z * g(0, 2) + y * g(1, 0) - 2.0 * x * g(1, 1) - w * g(1, 2)
            + z * g(2, 0)
            + w * g(2, 1)
            - 2.0 * x * g(2, 2));
    let d_y = 2.0
        * (-2.0 * y * g(0, 0) + x * g(0, 1) + w * g(0, 2) + x * g(1, 0) + z * g(1, 2)
            - w * g(2, 0)
            + z * g(2, 1)
            - 2.0 * y * g(2, 2));
    let d_z = 2.0
        * (-2.0 * z * g(0, 0) - w * g(0, 1) + x * g(0, 2) + w * g(1, 0) - 2.0 * z * g(1, 1)
            + y * g(1, 2)
            + x * g(2, 0)
            + y * g(2, 1));
    Vec4::new(d_x, d_y, d_z, d_w)
}
