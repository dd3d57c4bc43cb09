//! What a real camera does to a rendered view: exposure and white-balance errors, lens blur,
//! sensor noise (read noise plus shot noise growing with the signal) and a JPEG round trip.

use glam::Vec3;
use image::RgbImage;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// One view's camera effects.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraEffects {
    /// Exposure gain.
    pub exposure: f32,
    /// Per-channel white-balance gains.
    pub white_balance: Vec3,
    /// Gaussian blur σ (pixels; 0 = none).
    pub blur: f32,
    /// Read noise σ (in [0, 1] units).
    pub read_noise: f32,
    /// Shot noise: σ = `shot_noise · √value`.
    pub shot_noise: f32,
    /// JPEG quality of a round trip (none without).
    pub jpeg_quality: Option<u8>,
    /// Seed of the noise.
    pub seed: u64,
}

impl CameraEffects {
    /// No effect: the image is only clamped and rounded to 8 bits.
    pub fn none() -> Self {
        Self {
            exposure: 1.0,
            white_balance: Vec3::ONE,
            blur: 0.0,
            read_noise: 0.0,
            shot_noise: 0.0,
            jpeg_quality: None,
            seed: 0,
        }
    }

    /// Random effects: exposure 0.75–1.2, white balance ±10% red against blue with a ±4%
    /// green tint, blur σ 0.3–1.2 px on 60% of views, read noise 0.3–2%, shot noise up to 2%,
    /// a JPEG round trip at quality 35–95 on half of them.
    pub fn random(rng: &mut ChaCha8Rng) -> Self {
        let t = rng.gen_range(-1.0f32..1.0);
        let tint = rng.gen_range(-0.04f32..0.04);
        Self {
            exposure: rng.gen_range(0.75..1.2),
            white_balance: Vec3::new(1.0 + 0.1 * t, 1.0 + tint, 1.0 - 0.1 * t),
            blur: if rng.gen_bool(0.6) {
                rng.gen_range(0.3..1.2)
            } else {
                0.0
            },
            read_noise: rng.gen_range(0.003..0.02),
            shot_noise: rng.gen_range(0.0..0.02),
            jpeg_quality: rng.gen_bool(0.5).then(|| rng.gen_range(35..=95)),
            seed: rng.gen(),
        }
    }

    /// Applies the effects to a `width × height` linear RGB image (row-major, 3 per pixel).
    pub fn apply(&self, rgb: &[f32], width: u32, height: u32) -> RgbImage {
        let (w, h) = (width as usize, height as usize);
        let gain = self.white_balance * self.exposure;
        let mut img: Vec<f32> = rgb
            .chunks_exact(3)
            .flat_map(|p| (Vec3::from_slice(p) * gain).to_array())
            .collect();
        if self.blur > 0.0 {
            blur(&mut img, w, h, self.blur);
        }
        if self.read_noise > 0.0 || self.shot_noise > 0.0 {
            let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
            for v in &mut img {
                let sigma = self.read_noise + self.shot_noise * v.max(0.0).sqrt();
                *v += sigma * normal(&mut rng);
            }
        }
        let bytes: Vec<u8> = img
            .iter()
            .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
            .collect();
        let out = RgbImage::from_raw(width, height, bytes).expect("w × h × 3 bytes");
        match self.jpeg_quality {
            Some(q) => jpeg_round_trip(&out, q).unwrap_or(out),
            None => out,
        }
    }
}

/// A standard normal draw (Box–Muller).
fn normal(rng: &mut ChaCha8Rng) -> f32 {
    let u1: f32 = rng.gen_range(f32::EPSILON..1.0);
    let u2: f32 = rng.gen();
    (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos()
}

/// Separable Gaussian blur of σ `sigma` pixels, edges clamped.
fn blur(img: &mut Vec<f32>, w: usize, h: usize, sigma: f32) {
    let r = (3.0 * sigma).ceil() as i32;
    let kernel: Vec<f32> = (-r..=r)
        .map(|k| (-(k * k) as f32 / (2.0 * sigma * sigma)).exp())
        .collect();
    let total: f32 = kernel.iter().sum();
    let kernel: Vec<f32> = kernel.iter().map(|k| k / total).collect();
    let across = convolve(img, w, h, &kernel, true);
    *img = convolve(&across, w, h, &kernel, false);
}

/// One pass of a centred 1D `kernel` along rows (`horizontal`) or columns.
fn convolve(src: &[f32], w: usize, h: usize, kernel: &[f32], horizontal: bool) -> Vec<f32> {
    let r = (kernel.len() / 2) as i32;
    let mut out = vec![0f32; src.len()];
    for y in 0..h {
        for x in 0..w {
            for c in 0..3 {
                let mut acc = 0.0;
                for (k, weight) in kernel.iter().enumerate() {
                    let d = k as i32 - r;
                    let (sx, sy) = if horizontal {
                        ((x as i32 + d).clamp(0, w as i32 - 1) as usize, y)
                    } else {
                        (x, (y as i32 + d).clamp(0, h as i32 - 1) as usize)
                    };
                    acc += weight * src[(sy * w + sx) * 3 + c];
                }
                out[(y * w + x) * 3 + c] = acc;
            }
        }
    }
    out
}

/// `img` encoded as JPEG at `quality` and decoded again.
fn jpeg_round_trip(img: &RgbImage, quality: u8) -> Option<RgbImage> {
    let mut buffer = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut buffer, quality)
        .encode_image(img)
        .ok()?;
    image::load_from_memory_with_format(&buffer, image::ImageFormat::Jpeg)
        .ok()
        .map(|i| i.to_rgb8())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn checker(w: u32, h: u32) -> Vec<f32> {
        (0..w * h)
            .flat_map(|i| {
                let v = if ((i % w) / 4 + (i / w) / 4) % 2 == 0 {
                    0.8
                } else {
                    0.2
                };
                [v, v, v]
            })
            .collect()
    }

    #[test]
    fn no_effect_only_quantises() {
        let img = CameraEffects::none().apply(&checker(16, 8), 16, 8);
        assert_eq!(img.get_pixel(0, 0).0, [204; 3]);
        assert_eq!(img.get_pixel(4, 0).0, [51; 3]);
    }

    #[test]
    fn effects_blur_noise_tint_and_repeat_per_seed() {
        let fx = CameraEffects {
            exposure: 1.1,
            white_balance: Vec3::new(1.1, 1.0, 0.9),
            blur: 1.0,
            read_noise: 0.01,
            shot_noise: 0.01,
            jpeg_quality: Some(60),
            seed: 3,
        };
        let src = checker(32, 32);
        let a = fx.apply(&src, 32, 32);
        assert_eq!(a, fx.apply(&src, 32, 32));
        let mean = |c: usize| a.pixels().map(|p| p.0[c] as f32).sum::<f32>() / 1024.0;
        assert!(mean(0) > mean(2) + 10.0, "{} vs {}", mean(0), mean(2));
        // Blur softens the checker's edges: neighbours across an edge come closer.
        let edge = (a.get_pixel(3, 1).0[1] as i32 - a.get_pixel(4, 1).0[1] as i32).abs();
        assert!(edge < 120, "{edge}");
        let other = CameraEffects {
            seed: 4,
            ..fx.clone()
        }
        .apply(&src, 32, 32);
        assert_ne!(a, other);
    }
}
