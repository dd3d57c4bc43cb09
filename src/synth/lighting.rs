//! Lighting of dressed people for rendered views: ambient light scaled by each Gaussian's
//! ambient occlusion, Lambert key and fill lights (directions, colours and intensities drawn
//! per sample: studio, overcast or hard sun), a Blinn–Phong highlight by gloss, all with the
//! normals the pose gives (each Gaussian's normal turns with its skinning rotation) and lit
//! from either side (a surface seen from behind is lit as its back face).
//!
//! [`Lighting::flat`] is no lighting at all: the shaded colour is the albedo.

use super::dressed::DressedPerson;
use crate::splat::{rgb_to_sh_dc, Gaussians};
use glam::Vec3;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// A directional light.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Light {
    /// Unit direction towards the light (world frame).
    pub direction: Vec3,
    /// Colour times intensity.
    pub color: Vec3,
}

/// The lights of one sample.
#[derive(Debug, Clone, PartialEq)]
pub struct Lighting {
    /// Ambient colour times intensity (scaled by ambient occlusion).
    pub ambient: Vec3,
    /// Directional lights.
    pub lights: Vec<Light>,
}

/// Share of a light's direct contribution that ambient occlusion also dims (a cheap stand-in
/// for self-shadowing in creases).
const DIRECT_OCCLUSION: f32 = 0.6;

/// A light colour of temperature `t` in −1 (cool) ..= 1 (warm), about unit luminance.
fn temperature(t: f32) -> Vec3 {
    Vec3::new(1.0 + 0.14 * t, 1.0 + 0.02 * t, 1.0 - 0.2 * t)
}

/// A unit direction from azimuth (about +Y, from +Z) and elevation (radians).
fn direction(azimuth: f32, elevation: f32) -> Vec3 {
    let (sa, ca) = azimuth.sin_cos();
    let (se, ce) = elevation.sin_cos();
    Vec3::new(sa * ce, se, ca * ce)
}

impl Lighting {
    /// No lighting: shading returns the albedo unchanged.
    pub fn flat() -> Self {
        Self {
            ambient: Vec3::ONE,
            lights: Vec::new(),
        }
    }

    /// Whether this is [`Lighting::flat`].
    pub fn is_flat(&self) -> bool {
        self.lights.is_empty() && self.ambient == Vec3::ONE
    }

    /// A random lighting: 20% overcast (strong ambient, a weak key), 65% studio or indoor
    /// (ambient, a key from above at any azimuth, a fill from the other side), 15% hard sun
    /// (weak ambient, a strong key); light colours from cool to warm.
    pub fn random(rng: &mut ChaCha8Rng) -> Self {
        let tau = std::f32::consts::TAU;
        let key_dir = direction(rng.gen_range(0.0..tau), rng.gen_range(0.17..1.2));
        let key_color = temperature(rng.gen_range(-1.0..1.0));
        let ambient_color = temperature(rng.gen_range(-0.6..0.6));
        let kind = rng.gen_range(0..100);
        let (ambient, key, fill) = match kind {
            0..=19 => (rng.gen_range(0.75..1.0), rng.gen_range(0.1..0.3), 0.0),
            20..=84 => (
                rng.gen_range(0.25..0.5),
                rng.gen_range(0.6..1.0),
                rng.gen_range(0.1..0.35),
            ),
            _ => (rng.gen_range(0.15..0.3), rng.gen_range(0.9..1.3), 0.0),
        };
        let mut lights = vec![Light {
            direction: key_dir,
            color: key_color * key,
        }];
        if fill > 0.0 {
            let azimuth =
                key_dir.x.atan2(key_dir.z) + std::f32::consts::PI + rng.gen_range(-1.0..1.0);
            lights.push(Light {
                direction: direction(azimuth, rng.gen_range(0.0..0.5)),
                color: temperature(rng.gen_range(-1.0..1.0)) * fill,
            });
        }
        Self {
            ambient: ambient_color * ambient,
            lights,
        }
    }

    /// The shaded colour of a surface point: `albedo`, unit `normal` (posed), ambient
    /// `occlusion`, `gloss`, unit `view` direction from the point to the camera.
    pub fn shade(
        &self,
        albedo: Vec3,
        normal: Vec3,
        occlusion: f32,
        gloss: f32,
        view: Vec3,
    ) -> Vec3 {
        if self.is_flat() {
            return albedo;
        }
        let n = if normal.dot(view) < 0.0 {
            -normal
        } else {
            normal
        };
        let direct_scale = 1.0 - DIRECT_OCCLUSION * (1.0 - occlusion);
        let mut diffuse = self.ambient * occlusion;
        let mut specular = Vec3::ZERO;
        let shininess = 8.0 + 56.0 * gloss;
        for light in &self.lights {
            let cos = n.dot(light.direction);
            if cos <= 0.0 {
                continue;
            }
            diffuse += light.color * cos * direct_scale;
            let half = (light.direction + view).normalize_or(n);
            specular += light.color * (0.5 * gloss * n.dot(half).max(0.0).powf(shininess));
        }
        albedo * diffuse + specular * direct_scale
    }

    /// `posed` (the person's avatar posed) with its colours replaced by the shaded colours
    /// seen from a camera at `eye`; the albedo goes into 3 feature channels when
    /// `albedo_features` is set.
    pub fn lit(
        &self,
        person: &DressedPerson,
        posed: &Gaussians,
        eye: Vec3,
        albedo_features: bool,
    ) -> Gaussians {
        let albedo = person.albedo();
        let mut out = posed.clone();
        for (i, (sh, a)) in out.sh.iter_mut().zip(&albedo).enumerate() {
            let normal = posed.rotations[i] * Vec3::Z;
            let view = (eye - posed.positions[i]).normalize_or(Vec3::Z);
            let c = self.shade(*a, normal, person.occlusion[i], person.gloss[i], view);
            *sh = rgb_to_sh_dc(c);
        }
        if albedo_features {
            out.feature_channels = 3;
            out.features = albedo.iter().flat_map(|a| a.to_array()).collect();
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn flat_lighting_keeps_the_albedo_and_lambert_follows_the_normal() {
        let albedo = Vec3::new(0.2, 0.5, 0.8);
        assert_eq!(
            Lighting::flat().shade(albedo, Vec3::X, 0.3, 0.5, Vec3::Z),
            albedo
        );
        let key = Lighting {
            ambient: Vec3::splat(0.2),
            lights: vec![Light {
                direction: Vec3::Y,
                color: Vec3::ONE,
            }],
        };
        let up = key.shade(albedo, Vec3::Y, 1.0, 0.0, Vec3::Z);
        let side = key.shade(albedo, Vec3::X, 1.0, 0.0, Vec3::Z);
        let tilted = key.shade(
            albedo,
            Vec3::new(1.0, 1.0, 0.0).normalize(),
            1.0,
            0.0,
            Vec3::Z,
        );
        assert!((up - albedo * 1.2).length() < 1e-5);
        assert!((side - albedo * 0.2).length() < 1e-5);
        assert!((tilted - albedo * (0.2 + 0.5f32.sqrt())).length() < 1e-5);
        // Occlusion darkens; a back face seen from behind is lit as its front.
        assert!(key.shade(albedo, Vec3::Y, 0.2, 0.0, Vec3::Z).x < up.x);
        assert_eq!(key.shade(albedo, -Vec3::Y, 1.0, 0.0, Vec3::Y), up);
    }

    #[test]
    fn random_lightings_vary_and_repeat() {
        let draw = |s| {
            let mut rng = ChaCha8Rng::seed_from_u64(s);
            (0..30)
                .map(|_| Lighting::random(&mut rng))
                .collect::<Vec<_>>()
        };
        assert_eq!(draw(1), draw(1));
        let all = draw(2);
        assert!(all.iter().any(|l| l.lights.len() == 2));
        assert!(all.iter().any(|l| l.lights.len() == 1));
        for l in &all {
            assert!(
                l.lights[0].direction.y > 0.1,
                "the key light comes from above"
            );
        }
    }
}
