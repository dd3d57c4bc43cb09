//! The light the views were taken in, fitted with the avatar so that its colours stay albedo.
//!
//! Each view shows a Gaussian's albedo `ρ` times
//! `g_v ⊙ (A + K · max(0, n · k̂) · lit + F · max(0, n · f̂))`: an ambient light `A`, a key
//! light of colour `K` from direction `k̂` that the avatar's own body can shadow (`lit` is 0 in
//! its cast shadow, found by marching towards the light through the cells the posed
//! Gaussians fill), a fill light `F` from `f̂`, and each view's own exposure and white balance
//! `g_v` (a camera's). `n` is the Gaussian's posed normal (its template vertex's, turned by its
//! skinning rotation).
//!
//! Albedo and light trade off: only their product is seen. The fit fixes that freedom after
//! each step: the views' gains average 1 (in logarithm, per channel), and the brightest-lit
//! surface is lit by 1 in luminance ([`Light::brightest`]: `A + K` when the fill shines from
//! elsewhere), the convention the colours taken from the photos already follow
//! ([`crate::reconstruct::delight`]).

use crate::reconstruct::delight::KeyLight;
use crate::reconstruct::surface::{in_shadow, occupied_cells};
use glam::{Affine3A, Quat, Vec3};

/// Light reaching a surface that faces the key light (luminance), the albedo convention.
const FACING: f32 = 1.0;
/// Rec. 709 luminance weights.
const LUMA: Vec3 = Vec3::new(0.2126, 0.7152, 0.0722);
/// Pull of each view's log gain towards 0 (cameras are roughly exposed).
const GAIN_PRIOR: f32 = 0.02;

/// The fitted light and each view's gain.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Light {
    log_ambient: Vec3,
    log_key: Vec3,
    key_dir: Vec3,
    log_fill: Vec3,
    fill_dir: Vec3,
    /// Per view, the log of its gain.
    log_gain: Vec<Vec3>,
    /// Per Gaussian, its canonical normal.
    pub normals: Vec<Vec3>,
}

/// Gradients of [`Light`]'s parameters.
#[derive(Debug, Clone, Default)]
pub(crate) struct LightGrads {
    log_ambient: Vec3,
    log_key: Vec3,
    key_dir: Vec3,
    log_fill: Vec3,
    fill_dir: Vec3,
    log_gain: Vec<Vec3>,
}

/// Adam state of the light's parameters.
#[derive(Debug, Clone, Default)]
pub(crate) struct LightAdam {
    t: i32,
    m: Vec<f32>,
    v: Vec<f32>,
}

impl Light {
    /// A light for `views` views starting from the key light `key` the colours were de-lit by
    /// (its direction and strength; none: a light from above and in front) and each view's
    /// fitted exposure, over Gaussians with canonical `normals`.
    pub fn new(key: &KeyLight, exposures: &[f32], normals: Vec<Vec3>) -> Self {
        let (dir, strength) = if key.key != Vec3::ZERO {
            (key.key.normalize(), key.strength.max(Vec3::splat(0.05)))
        } else {
            // No light found: a faint one from above in front, which the fit strengthens only
            // where the views show shading.
            (Vec3::new(0.0, 0.7, 0.7).normalize(), Vec3::splat(0.05))
        };
        // A + K = FACING with K = strength · A.
        let ambient = Vec3::splat(FACING) / (Vec3::ONE + strength);
        let key_colour = ambient * strength;
        let fill_dir = Vec3::new(-dir.x, 0.25, -dir.z).normalize_or(Vec3::Y);
        Self {
            log_ambient: ambient.ln(),
            log_key: key_colour.ln(),
            key_dir: dir,
            log_fill: (ambient * 0.3).ln(),
            fill_dir,
            log_gain: exposures.iter().map(|e| Vec3::splat(*e)).collect(),
            normals,
        }
    }

    /// Ambient, key and fill colours, the key and fill directions and each view's gain.
    pub fn summary(&self) -> (Vec3, Vec3, Vec3, Vec3, Vec3, Vec<Vec3>) {
        (
            self.log_ambient.exp(),
            self.log_key.exp(),
            self.key_direction(),
            self.log_fill.exp(),
            self.fill_dir.normalize_or(Vec3::Y),
            self.log_gain.iter().map(|g| g.exp()).collect(),
        )
    }

    /// The key light's unit direction.
    pub fn key_direction(&self) -> Vec3 {
        self.key_dir.normalize_or(Vec3::Y)
    }

    /// Per Gaussian, whether the key light reaches it (1) or its body shadows it (0), for
    /// Gaussians posed at `posed` by `transforms`.
    pub fn lit(&self, posed: &[Vec3], transforms: &[(Affine3A, Quat)]) -> Vec<f32> {
        let cells = occupied_cells(posed);
        let dir = self.key_direction();
        posed
            .iter()
            .zip(transforms)
            .zip(&self.normals)
            .map(|((p, (_, r)), n)| {
                let n = *r * *n;
                if in_shadow(&cells, *p + n * 0.02, dir) {
                    0.0
                } else {
                    1.0
                }
            })
            .collect()
    }

    /// Per Gaussian, the light view `view` shows it in, posed by `transforms`, with the key
    /// light reaching it by `lit`.
    pub fn shading(&self, view: usize, transforms: &[(Affine3A, Quat)], lit: &[f32]) -> Vec<Vec3> {
        let (a, k, f) = (
            self.log_ambient.exp(),
            self.log_key.exp(),
            self.log_fill.exp(),
        );
        let gain = self.log_gain[view].exp();
        let (kd, fd) = (self.key_direction(), self.fill_dir.normalize_or(Vec3::Y));
        self.normals
            .iter()
            .zip(transforms)
            .zip(lit)
            .map(|((n, (_, r)), lit)| {
                let n = *r * *n;
                gain * (a + k * (n.dot(kd).max(0.0) * lit) + f * n.dot(fd).max(0.0))
            })
            .collect()
    }

    /// Adds to `grads` the gradient of a loss whose gradient with respect to each Gaussian's
    /// shown colour (`albedo ⊙ shading`) in view `view` is `d_colour`.
    pub fn accumulate(
        &self,
        view: usize,
        transforms: &[(Affine3A, Quat)],
        lit: &[f32],
        albedo: &[Vec3],
        d_colour: &[Vec3],
        grads: &mut LightGrads,
    ) {
        let (a, k, f) = (
            self.log_ambient.exp(),
            self.log_key.exp(),
            self.log_fill.exp(),
        );
        let gain = self.log_gain[view].exp();
        let (kd, fd) = (self.key_direction(), self.fill_dir.normalize_or(Vec3::Y));
        let mut g = LightGrads {
            log_gain: vec![Vec3::ZERO; self.log_gain.len()],
            ..LightGrads::default()
        };
        let mut d_kd = Vec3::ZERO;
        let mut d_fd = Vec3::ZERO;
        for i in 0..self.normals.len() {
            let d = d_colour[i];
            if d == Vec3::ZERO {
                continue;
            }
            let n = transforms[i].1 * self.normals[i];
            let q = d * albedo[i] * gain;
            let (ck, cf) = (n.dot(kd), n.dot(fd));
            let key_on = if ck > 0.0 { lit[i] } else { 0.0 };
            let light = a + k * (ck.max(0.0) * lit[i]) + f * cf.max(0.0);
            g.log_gain[view] += q * light;
            g.log_ambient += q * a;
            g.log_key += q * k * (ck.max(0.0) * lit[i]);
            g.log_fill += q * f * cf.max(0.0);
            d_kd += n * (q.dot(k) * key_on);
            if cf > 0.0 {
                d_fd += n * q.dot(f);
            }
        }
        g.key_dir = through_normalise(self.key_dir, d_kd);
        g.fill_dir = through_normalise(self.fill_dir, d_fd);
        grads.add(&g);
    }

    /// Zero gradients for this light.
    pub fn zero_grads(&self) -> LightGrads {
        LightGrads {
            log_gain: vec![Vec3::ZERO; self.log_gain.len()],
            ..LightGrads::default()
        }
    }

    /// One Adam step of rate `lr` on the light, then the gauge fixed (see the module doc):
    /// returns the factor every albedo must be multiplied by to keep what the views show.
    pub fn step(
        &mut self,
        grads: &LightGrads,
        adam: &mut LightAdam,
        lr: f32,
        fitted: &[usize],
    ) -> Vec3 {
        let mut grads = grads.clone();
        for &v in fitted {
            grads.log_gain[v] += self.log_gain[v] * (2.0 * GAIN_PRIOR);
        }
        let mut x = self.flat();
        let g = grads.flat();
        adam.step(&mut x, &g, lr);
        self.unflat(&x);
        // The fitted views' gains average 1: the rest goes into the light.
        let mean =
            fitted.iter().map(|v| self.log_gain[*v]).sum::<Vec3>() / fitted.len().max(1) as f32;
        for v in fitted {
            self.log_gain[*v] -= mean;
        }
        self.log_ambient += mean;
        self.log_key += mean;
        self.log_fill += mean;
        // The brightest-lit surface gets FACING in luminance: the rest goes into the albedo.
        let c = (FACING / self.brightest()).ln();
        self.log_ambient += Vec3::splat(c);
        self.log_key += Vec3::splat(c);
        self.log_fill += Vec3::splat(c);
        Vec3::splat((-c).exp())
    }

    /// The light (luminance) reaching the surface facing the key light best: the ambient light
    /// plus the most the key and fill lights give together to one surface facing both. When
    /// both shine from nearly one side (a fill that is a second key), a surface between them
    /// gets both, and counting the key alone would darken every albedo by what the fill adds;
    /// a fill from the other side is not counted.
    pub fn brightest(&self) -> f32 {
        let k = self.log_key.exp().dot(LUMA);
        let f = self.log_fill.exp().dot(LUMA);
        let (kd, fd) = (self.key_direction(), self.fill_dir.normalize_or(Vec3::Y));
        let both = k * kd + f * fd;
        let n = both.normalize_or_zero();
        // A fill from elsewhere (the other side, behind) is not counted: the key's side is
        // what "facing the light" means.
        let direct = if n.dot(kd) >= 0.0 && n.dot(fd) >= 0.0 {
            both.length().max(k)
        } else {
            k
        };
        self.log_ambient.exp().dot(LUMA) + direct
    }

    fn flat(&self) -> Vec<f32> {
        flatten(
            [
                self.log_ambient,
                self.log_key,
                self.key_dir,
                self.log_fill,
                self.fill_dir,
            ],
            &self.log_gain,
        )
    }

    fn unflat(&mut self, x: &[f32]) {
        let at = |k: usize| Vec3::from_slice(&x[3 * k..3 * k + 3]);
        self.log_ambient = at(0);
        self.log_key = at(1);
        self.key_dir = at(2).normalize_or(self.key_dir);
        self.log_fill = at(3);
        self.fill_dir = at(4).normalize_or(self.fill_dir);
        for (v, g) in self.log_gain.iter_mut().enumerate() {
            *g = at(5 + v);
        }
    }
}

impl LightGrads {
    fn add(&mut self, o: &LightGrads) {
        self.log_ambient += o.log_ambient;
        self.log_key += o.log_key;
        self.key_dir += o.key_dir;
        self.log_fill += o.log_fill;
        self.fill_dir += o.fill_dir;
        if self.log_gain.len() < o.log_gain.len() {
            self.log_gain.resize(o.log_gain.len(), Vec3::ZERO);
        }
        for (a, b) in self.log_gain.iter_mut().zip(&o.log_gain) {
            *a += *b;
        }
    }

    fn flat(&self) -> Vec<f32> {
        flatten(
            [
                self.log_ambient,
                self.log_key,
                self.key_dir,
                self.log_fill,
                self.fill_dir,
            ],
            &self.log_gain,
        )
    }
}

/// The light's five vectors then each view's gain, as one vector for the optimiser (the
/// layout `Light::unflat` reads).
fn flatten(lights: [Vec3; 5], gains: &[Vec3]) -> Vec<f32> {
    lights
        .iter()
        .chain(gains)
        .flat_map(|v| v.to_array())
        .collect()
}

impl LightAdam {
    fn step(&mut self, x: &mut [f32], g: &[f32], lr: f32) {
        const B1: f32 = 0.9;
        const B2: f32 = 0.999;
        self.t += 1;
        self.m.resize(x.len(), 0.0);
        self.v.resize(x.len(), 0.0);
        let (c1, c2) = (1.0 - B1.powi(self.t), 1.0 - B2.powi(self.t));
        for i in 0..x.len() {
            self.m[i] = B1 * self.m[i] + (1.0 - B1) * g[i];
            self.v[i] = B2 * self.v[i] + (1.0 - B2) * g[i] * g[i];
            x[i] -= lr * (self.m[i] / c1) / ((self.v[i] / c2).sqrt() + 1e-15);
        }
    }
}

/// `∂L/∂v` of `L(v / |v|)` given `∂L/∂(v/|v|)`.
fn through_normalise(v: Vec3, d: Vec3) -> Vec3 {
    let len = v.length().max(1e-6);
    let u = v / len;
    (d - u * u.dot(d)) / len
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The light's parameter gradients match finite differences of a loss on the shown colours.
    #[test]
    fn light_gradients_match_finite_differences() {
        let normals: Vec<Vec3> = (0..40)
            .map(|i| {
                let t = i as f32 * 0.7;
                Vec3::new(t.sin(), (t * 0.3).cos(), (t * 1.3).cos()).normalize()
            })
            .collect();
        let key = KeyLight {
            key: Vec3::new(0.3, 0.8, 0.5),
            strength: Vec3::new(1.2, 1.0, 0.9),
            ..KeyLight::none()
        };
        let light = Light::new(&key, &[0.1, -0.2], normals.clone());
        let transforms = vec![(Affine3A::IDENTITY, Quat::from_rotation_y(0.4)); 40];
        let lit: Vec<f32> = (0..40)
            .map(|i| if i % 7 == 0 { 0.0 } else { 1.0 })
            .collect();
        let albedo: Vec<Vec3> = (0..40)
            .map(|i| Vec3::new(0.2 + 0.01 * i as f32, 0.5, 0.8 - 0.01 * i as f32))
            .collect();
        let weights: Vec<Vec3> = (0..40)
            .map(|i| Vec3::new((i as f32).sin(), (i as f32 * 2.0).cos(), 0.3))
            .collect();
        let loss = |l: &Light| -> f64 {
            l.shading(1, &transforms, &lit)
                .iter()
                .zip(&albedo)
                .zip(&weights)
                .map(|((s, a), w)| (*s * *a).dot(*w) as f64)
                .sum()
        };
        let mut grads = light.zero_grads();
        light.accumulate(1, &transforms, &lit, &albedo, &weights, &mut grads);
        let analytic = grads.flat();
        let x0 = light.flat();
        for (k, a) in analytic.iter().enumerate() {
            let h = 1e-3;
            let mut plus = light.clone();
            let mut xp = x0.clone();
            xp[k] += h;
            plus.unflat_raw(&xp);
            let mut minus = light.clone();
            let mut xm = x0.clone();
            xm[k] -= h;
            minus.unflat_raw(&xm);
            let n = ((loss(&plus) - loss(&minus)) / (2.0 * h as f64)) as f32;
            assert!(
                (n - a).abs() < 2e-3 * (1.0 + n.abs()),
                "parameter {k}: analytic {a} numeric {n}"
            );
        }
    }

    /// The gauge puts the brightest-lit surface at FACING, counting a fill that shines from
    /// the key's side, so that such a fill does not darken the albedo.
    #[test]
    fn the_brightest_lit_surface_is_lit_by_one() {
        let key = KeyLight {
            key: Vec3::new(0.0, 0.6, 0.8),
            strength: Vec3::splat(0.5),
            ..KeyLight::none()
        };
        let mut light = Light::new(&key, &[0.0], vec![Vec3::Z]);
        // A fill as strong as the key, from the same side: the surface facing both gets
        // ambient + key + fill.
        light.fill_dir = light.key_direction();
        light.log_fill = light.log_key;
        let (a, k) = (light.log_ambient.exp(), light.log_key.exp());
        let before = (a + 2.0 * k).dot(LUMA);
        assert!((light.brightest() - before).abs() < 1e-5);
        let factor = light.step(&light.zero_grads(), &mut LightAdam::default(), 0.0, &[0]);
        assert!(
            (light.brightest() - FACING).abs() < 1e-4,
            "{}",
            light.brightest()
        );
        // The albedo takes what the light gave up: what the views show is unchanged.
        assert!((factor.x - before / FACING).abs() < 1e-4, "{factor}");
        // A fill from behind adds nothing to the surface facing the key.
        light.fill_dir = -light.key_direction();
        let (a, k) = (light.log_ambient.exp(), light.log_key.exp());
        assert!((light.brightest() - (a + k).dot(LUMA)).abs() < 1e-5);
    }

    impl Light {
        /// Sets the parameters without renormalising the directions (finite differences).
        fn unflat_raw(&mut self, x: &[f32]) {
            let at = |k: usize| Vec3::from_slice(&x[3 * k..3 * k + 3]);
            self.log_ambient = at(0);
            self.log_key = at(1);
            self.key_dir = at(2);
            self.log_fill = at(3);
            self.fill_dir = at(4);
            for (v, g) in self.log_gain.iter_mut().enumerate() {
                *g = at(5 + v);
            }
        }
    }
}
