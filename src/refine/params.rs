//! The quantities a fit moves, per canonical Gaussian, and the Adam optimiser that moves them.

use crate::avatar::Avatar;
use crate::body::SkinWeights;
use crate::splat::{rgb_to_sh_dc, sh_dc_to_rgb, Gaussians};
use glam::{Quat, Vec3, Vec4};

/// Lowest and highest opacity a fitted Gaussian starts from (keeps its logit finite).
const OPACITY_RANGE: (f32, f32) = (1e-3, 0.995);

/// The fitted avatar's canonical Gaussians in the form the optimiser moves.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Params {
    /// Centres (canonical, metres).
    pub position: Vec<Vec3>,
    /// Natural logarithms of the scales.
    pub log_scale: Vec<Vec3>,
    /// Orientations (xyzw, not kept unit: the renderer normalises).
    pub rotation: Vec<Vec4>,
    /// Opacity logits.
    pub opacity_logit: Vec<f32>,
    /// Albedo (degree-0 colour) in `[0, 1]`.
    pub colour: Vec<Vec3>,
    /// Where each centre is pulled back to (the network's, or where a grown Gaussian began).
    pub anchor: Vec<Vec3>,
    /// Higher SH bands, kept as they are (`rest_per` per Gaussian).
    pub sh_rest: Vec<[f32; 3]>,
    /// SH coefficients per Gaussian beyond the DC term.
    pub rest_per: usize,
    /// SH degree.
    pub sh_degree: usize,
    /// Skinning rows.
    pub skin: SkinWeights,
}

/// `ln(p / (1 − p))`.
fn logit(p: f32) -> f32 {
    let p = p.clamp(OPACITY_RANGE.0, OPACITY_RANGE.1);
    (p / (1.0 - p)).ln()
}

/// `1 / (1 + e^-x)`.
pub(crate) fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

impl Params {
    /// The avatar's Gaussians as fit parameters.
    pub fn from_avatar(avatar: &Avatar) -> Self {
        let g = &avatar.canonical;
        let k = g.sh_per_gaussian();
        let rest_per = k - 1;
        let sh_rest = (0..g.len())
            .flat_map(|i| g.sh[i * k + 1..(i + 1) * k].iter().copied())
            .collect();
        Self {
            position: g.positions.clone(),
            log_scale: g
                .scales
                .iter()
                .map(|s| s.max(Vec3::splat(1e-6)).ln())
                .collect(),
            rotation: g.rotations.iter().map(|q| Vec4::from(*q)).collect(),
            opacity_logit: g.opacities.iter().map(|o| logit(*o)).collect(),
            colour: (0..g.len()).map(|i| sh_dc_to_rgb(g.sh[i * k])).collect(),
            anchor: g.positions.clone(),
            sh_rest,
            rest_per,
            sh_degree: g.sh_degree,
            skin: avatar.skin.clone(),
        }
    }

    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.position.len()
    }

    /// The canonical Gaussians these parameters describe.
    pub fn gaussians(&self) -> Gaussians {
        let k = self.rest_per + 1;
        let mut sh = Vec::with_capacity(self.len() * k);
        for (i, c) in self.colour.iter().enumerate() {
            sh.push(rgb_to_sh_dc(*c));
            sh.extend_from_slice(&self.sh_rest[i * self.rest_per..(i + 1) * self.rest_per]);
        }
        Gaussians {
            positions: self.position.clone(),
            scales: self.log_scale.iter().map(|s| s.exp()).collect(),
            rotations: self
                .rotation
                .iter()
                .map(|q| Quat::from_vec4(*q).normalize())
                .collect(),
            opacities: self.opacity_logit.iter().map(|x| sigmoid(*x)).collect(),
            sh_degree: self.sh_degree,
            sh,
            feature_channels: 0,
            features: Vec::new(),
        }
    }

    /// Appends a copy of Gaussian `i` (same skin row and SH bands) with the given centre,
    /// log-scale and opacity logit; its anchor is where it starts.
    pub fn push_copy(&mut self, i: usize, position: Vec3, log_scale: Vec3, opacity_logit: f32) {
        self.position.push(position);
        self.anchor.push(position);
        self.log_scale.push(log_scale);
        self.rotation.push(self.rotation[i]);
        self.opacity_logit.push(opacity_logit);
        self.colour.push(self.colour[i]);
        let rest: Vec<[f32; 3]> = self.sh_rest[i * self.rest_per..(i + 1) * self.rest_per].to_vec();
        self.sh_rest.extend(rest);
        self.skin.bones.push(self.skin.bones[i]);
        self.skin.weights.push(self.skin.weights[i]);
    }
}

/// Gradients of the loss with respect to [`Params`] (same layout).
#[derive(Debug, Clone, Default, PartialEq)]
pub(crate) struct ParamGrads {
    pub position: Vec<Vec3>,
    pub log_scale: Vec<Vec3>,
    pub rotation: Vec<Vec4>,
    pub opacity_logit: Vec<f32>,
    pub colour: Vec<Vec3>,
}

impl ParamGrads {
    /// Zeros for `n` Gaussians.
    pub fn zeros(n: usize) -> Self {
        Self {
            position: vec![Vec3::ZERO; n],
            log_scale: vec![Vec3::ZERO; n],
            rotation: vec![Vec4::ZERO; n],
            opacity_logit: vec![0.0; n],
            colour: vec![Vec3::ZERO; n],
        }
    }
}

/// Learning rates of the parameter groups.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Rates {
    pub position: f32,
    pub log_scale: f32,
    pub rotation: f32,
    pub opacity_logit: f32,
    pub colour: f32,
}

/// Adam's moment estimates for one group of scalars.
#[derive(Debug, Clone, Default)]
pub(crate) struct Moments {
    m: Vec<f32>,
    v: Vec<f32>,
}

impl Moments {
    /// One Adam step of `x` (its `t`-th) along the gradient `g` at learning rate `lr`.
    pub fn step(&mut self, x: &mut [f32], g: &[f32], lr: f32, t: i32) {
        const B1: f32 = 0.9;
        const B2: f32 = 0.999;
        const EPS: f32 = 1e-15;
        self.m.resize(x.len(), 0.0);
        self.v.resize(x.len(), 0.0);
        let c1 = 1.0 - B1.powi(t);
        let c2 = 1.0 - B2.powi(t);
        for (((x, g), m), v) in x.iter_mut().zip(g).zip(&mut self.m).zip(&mut self.v) {
            *m = B1 * *m + (1.0 - B1) * g;
            *v = B2 * *v + (1.0 - B2) * g * g;
            let mh = *m / c1;
            let vh = *v / c2;
            *x -= lr * mh / (vh.sqrt() + EPS);
        }
    }
}

/// Adam (Kingma & Ba) over every parameter group, one learning rate per group.
#[derive(Debug, Clone, Default)]
pub(crate) struct Adam {
    t: i32,
    groups: [Moments; 5],
}

impl Adam {
    /// One step of every group.
    pub fn step(&mut self, p: &mut Params, g: &ParamGrads, rates: &Rates) {
        self.t += 1;
        let t = self.t;
        let [pos, scale, rot, opacity, colour] = &mut self.groups;
        pos.step(
            bytemuck::cast_slice_mut(&mut p.position),
            bytemuck::cast_slice(&g.position),
            rates.position,
            t,
        );
        scale.step(
            bytemuck::cast_slice_mut(&mut p.log_scale),
            bytemuck::cast_slice(&g.log_scale),
            rates.log_scale,
            t,
        );
        rot.step(
            bytemuck::cast_slice_mut(&mut p.rotation),
            bytemuck::cast_slice(&g.rotation),
            rates.rotation,
            t,
        );
        opacity.step(
            &mut p.opacity_logit,
            &g.opacity_logit,
            rates.opacity_logit,
            t,
        );
        colour.step(
            bytemuck::cast_slice_mut(&mut p.colour),
            bytemuck::cast_slice(&g.colour),
            rates.colour,
            t,
        );
        for c in &mut p.colour {
            *c = c.clamp(Vec3::ZERO, Vec3::ONE);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Adam walks a quadratic bowl to its bottom.
    #[test]
    fn adam_finds_the_bottom_of_a_bowl() {
        let mut m = Moments::default();
        let mut x = vec![3.0f32, -2.0];
        for t in 1..=500 {
            let g: Vec<f32> = x.iter().map(|v| 2.0 * (v - 1.0)).collect();
            m.step(&mut x, &g, 0.05, t);
        }
        assert!(x.iter().all(|v| (v - 1.0).abs() < 1e-2), "{x:?}");
    }
}
