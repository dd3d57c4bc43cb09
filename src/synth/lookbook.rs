//! Pictures of dressed people: each person in the rest pose from the front, the side and the
//! back, unlit (albedo), then lit by a random lighting from the front, side by side.

use super::dressed::DressedPerson;
use super::lighting::Lighting;
use super::person::SynthError;
use crate::body::Pose;
use crate::splat::{render, Camera, Intrinsics, RenderOptions};
use glam::Vec3;
use image::RgbImage;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// The captions of the sheet's columns.
const CAPTIONS: [&str; 4] = [
    "front (albedo)",
    "side (albedo)",
    "back (albedo)",
    "front, lit",
];

/// Height of the caption band above the first row, pixels.
const BAND: u32 = 28;

/// The views of one person: (azimuth from the front in radians, lit).
const VIEWS: [(f32, bool); 4] = [
    (0.0, false),
    (std::f32::consts::FRAC_PI_2, false),
    (std::f32::consts::PI, false),
    (0.0, true),
];

/// A sheet with one row per seed: front, side, back (albedo) and front lit, `size` pixels
/// square each, on white, with `points` Gaussians per person, under a band of captions.
pub fn lookbook(seeds: &[u64], size: u32, points: usize) -> Result<RgbImage, SynthError> {
    let mut sheet = RgbImage::from_pixel(
        size * VIEWS.len() as u32,
        size * seeds.len() as u32 + BAND,
        image::Rgb([255; 3]),
    );
    for (col, caption) in CAPTIONS.iter().enumerate() {
        let x = col as u32 * size + 8;
        crate::picture::draw_text(&mut sheet, x, 6, caption, 2, crate::picture::INK);
    }
    let white = RenderOptions {
        background: Vec3::ONE,
        ..RenderOptions::default()
    };
    for (row, &seed) in seeds.iter().enumerate() {
        let person = DressedPerson::new(seed, points)?;
        let matrices = person
            .template
            .skeleton
            .try_skinning_matrices(&Pose::identity())
            .map_err(|e| SynthError::Pose(e.to_string()))?;
        let posed = person.avatar.animate(&matrices);
        let height = person.template.height();
        let target = Vec3::new(0.0, 0.5 * height, 0.0);
        let lighting = Lighting::random(&mut ChaCha8Rng::seed_from_u64(seed));
        let shadow = match lighting.lights.first() {
            Some(key) => Some(person.light_visibility(&matrices, &posed, key.direction)?),
            None => None,
        };
        for (col, (azimuth, lit)) in VIEWS.iter().enumerate() {
            let eye = target + Vec3::new(azimuth.sin(), 0.1, azimuth.cos()) * 3.2 * height / 1.7;
            let camera = Camera::look_at(
                eye,
                target,
                Vec3::Y,
                Intrinsics::from_fov_y(size, size, 0.6),
            );
            let gaussians = if *lit {
                lighting.lit(&person, &posed, eye, shadow.as_deref(), false)
            } else {
                posed.clone()
            };
            let image = render(&gaussians, &camera, &white).to_rgb8();
            image::imageops::replace(
                &mut sheet,
                &image,
                (col as u32 * size) as i64,
                (row as u32 * size + BAND) as i64,
            );
        }
    }
    Ok(sheet)
}
