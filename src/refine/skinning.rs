//! Posing the fitted canonical Gaussians for a view, and the chain rule back through it.
//!
//! A Gaussian with blended bone transform `A` and rotation `r` (from
//! [`crate::avatar::blend_rows`]) is posed at `A · x` with orientation `r ⊗ q`: the renderer
//! normalises `q`, so the fit keeps the raw quaternion and the gradient passes through the
//! normalisation there. Scales, opacities and albedo are not posed; a view's shading gain
//! divides its light into the albedo it sees.

use super::params::{sigmoid, ParamGrads, Params};
use crate::splat::grad::GaussianGrads;
use crate::splat::{rgb_to_sh_dc, Gaussians};
use glam::{Affine3A, Quat, Vec3, Vec4};

/// The Gaussians `params` describe, posed by `transforms` and shaded by `shading` (empty:
/// unshaded).
pub(crate) fn pose(
    params: &Params,
    transforms: &[(Affine3A, Quat)],
    shading: &[Vec3],
) -> Gaussians {
    let n = params.len();
    let shade = |i: usize| shading.get(i).copied().unwrap_or(Vec3::ONE);
    let k = params.rest_per + 1;
    let mut sh = Vec::with_capacity(n * k);
    for i in 0..n {
        sh.push(rgb_to_sh_dc(params.colour[i] * shade(i)));
        sh.extend_from_slice(&params.sh_rest[i * params.rest_per..(i + 1) * params.rest_per]);
    }
    Gaussians {
        positions: params
            .position
            .iter()
            .zip(transforms)
            .map(|(x, (a, _))| a.transform_point3(*x))
            .collect(),
        scales: params.log_scale.iter().map(|s| s.exp()).collect(),
        rotations: params
            .rotation
            .iter()
            .zip(transforms)
            .map(|(q, (_, r))| *r * Quat::from_vec4(*q))
            .collect(),
        opacities: params.opacity_logit.iter().map(|x| sigmoid(*x)).collect(),
        sh_degree: params.sh_degree,
        sh,
        feature_channels: 0,
        features: Vec::new(),
    }
}

/// Adds to `grads` the gradients with respect to `params` of a loss whose gradients with
/// respect to the Gaussians [`pose`] made are `posed`.
pub(crate) fn accumulate(
    params: &Params,
    transforms: &[(Affine3A, Quat)],
    shading: &[Vec3],
    posed: &GaussianGrads,
    grads: &mut ParamGrads,
) {
    for (i, (a, r)) in transforms.iter().enumerate().take(params.len()) {
        let d_x = posed.positions[i];
        let d_q = posed.rotations[i];
        if d_x == Vec3::ZERO && d_q == Vec4::ZERO && posed.opacities[i] == 0.0 {
            continue;
        }
        grads.position[i] += glam::Mat3::from(a.matrix3).transpose() * d_x;
        // q_posed = L(r) q with L(r) orthogonal: ∂L/∂q = L(r)ᵀ ∂L/∂q_posed = r̄ ⊗ ∂L/∂q_posed.
        grads.rotation[i] += Vec4::from(r.conjugate() * Quat::from_vec4(d_q));
        grads.log_scale[i] += posed.scales[i] * params.log_scale[i].exp();
        let o = sigmoid(params.opacity_logit[i]);
        grads.opacity_logit[i] += posed.opacities[i] * o * (1.0 - o);
        grads.colour[i] += posed.colours[i] * shading.get(i).copied().unwrap_or(Vec3::ONE);
    }
}
