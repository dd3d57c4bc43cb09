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

    /// The shaded colour of `surface` seen along unit `view` (from the point to the camera).
    pub fn shade(&self, surface: &Surface, view: Vec3) -> Vec3 {
        if self.is_flat() {
            return surface.albedo;
        }
        let n = if surface.normal.dot(view) < 0.0 {
            -surface.normal
        } else {
            surface.normal
        };
        let direct_scale = 1.0 - DIRECT_OCCLUSION * (1.0 - surface.occlusion);
        let mut diffuse = self.ambient * surface.occlusion;
        let mut specular = Vec3::ZERO;
        let shininess = 8.0 + 56.0 * surface.gloss;
        for (k, light) in self.lights.iter().enumerate() {
            let cos = n.dot(light.direction);
            if cos <= 0.0 {
                continue;
            }
            let reach = direct_scale * if k == 0 { surface.key_visibility } else { 1.0 };
            diffuse += light.color * cos * reach;
            let half = (light.direction + view).normalize_or(n);
            specular +=
                light.color * (0.5 * surface.gloss * n.dot(half).max(0.0).powf(shininess) * reach);
        }
        surface.albedo * diffuse + specular
    }

    /// `posed` (the person's avatar posed) with its colours replaced by the shaded colours
    /// seen from a camera at `eye`, the key light reaching each Gaussian by `key_visibility`
    /// (all of it without); the albedo goes into 3 feature channels when `albedo_features`
    /// is set.
    pub fn lit(
        &self,
        person: &DressedPerson,
        posed: &Gaussians,
        eye: Vec3,
        key_visibility: Option<&[f32]>,
        albedo_features: bool,
    ) -> Gaussians {
        let albedo = person.albedo();
        let mut out = posed.clone();
        for (i, (sh, a)) in out.sh.iter_mut().zip(&albedo).enumerate() {
            let surface = Surface {
                albedo: *a,
                normal: posed.rotations[i] * Vec3::Z,
                occlusion: person.occlusion[i],
                gloss: person.gloss[i],
                key_visibility: key_visibility.map_or(1.0, |v| v[i]),
            };
            let view = (eye - posed.positions[i]).normalize_or(Vec3::Z);
            *sh = rgb_to_sh_dc(self.shade(&surface, view));
        }
        if albedo_features {
            out.feature_channels = 3;
            out.features = albedo.iter().flat_map(|a| a.to_array()).collect();
        }
        out
    }
}

/// What shading needs of one surface point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Surface {
    /// Unlit colour.
    pub albedo: Vec3,
    /// Unit normal (posed).
    pub normal: Vec3,
    /// Ambient occlusion (1 open).
    pub occlusion: f32,
    /// Gloss (0 matte).
    pub gloss: f32,
    /// How much of the key light (the first light) reaches the point: 0 in a cast shadow.
    pub key_visibility: f32,
}

impl Surface {
    /// A fully open, matte point lit by every light.
    pub fn new(albedo: Vec3, normal: Vec3) -> Self {
        Self {
            albedo,
            normal,
            occlusion: 1.0,
            gloss: 0.0,
            key_visibility: 1.0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn flat_lighting_keeps_the_albedo_and_lambert_follows_the_normal() {
        let albedo = Vec3::new(0.2, 0.5, 0.8);
        let at = |normal: Vec3| Surface::new(albedo, normal);
        assert_eq!(Lighting::flat().shade(&at(Vec3::X), Vec3::Z), albedo);
        let key = Lighting {
            ambient: Vec3::splat(0.2),
            lights: vec![Light {
                direction: Vec3::Y,
                color: Vec3::ONE,
            }],
        };
        let up = key.shade(&at(Vec3::Y), Vec3::Z);
        let side = key.shade(&at(Vec3::X), Vec3::Z);
        let tilted = key.shade(&at(Vec3::new(1.0, 1.0, 0.0).normalize()), Vec3::Z);
        assert!((up - albedo * 1.2).length() < 1e-5);
        assert!((side - albedo * 0.2).length() < 1e-5);
        assert!((tilted - albedo * (0.2 + 0.5f32.sqrt())).length() < 1e-5);
        // Occlusion darkens; a cast shadow leaves the ambient light; a back face seen from
        // behind is lit as its front.
        let enclosed = Surface {
            occlusion: 0.2,
            ..at(Vec3::Y)
        };
        assert!(key.shade(&enclosed, Vec3::Z).x < up.x);
        let shadowed = Surface {
            key_visibility: 0.0,
            ..at(Vec3::Y)
        };
        assert!((key.shade(&shadowed, Vec3::Z) - albedo * 0.2).length() < 1e-5);
        assert_eq!(key.shade(&at(-Vec3::Y), Vec3::Y), up);
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
