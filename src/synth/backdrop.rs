//! Backgrounds behind dressed people's input views: white, solid colours, vertical gradients
//! and block noise as for the plain people, plus textured and photo-like ones: smooth
//! multi-scale value noise over a palette, a room (wall, floor below a horizon, panels such as
//! doors, windows and pictures, shading towards the corners) and out-of-focus blobs.
//! Coordinates are fractions of the image, so a backdrop looks the same at any size.

use super::material::hash3;
use glam::Vec3;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// A rectangle `(x0, y0, x1, y1)` in image fractions with its colour.
type Panel = (f32, f32, f32, f32, Vec3);

/// A background.
#[derive(Debug, Clone, PartialEq)]
pub enum Backdrop {
    /// Plain white (composited after the camera effects, as a segmented photo on white).
    White,
    /// One colour.
    Solid(Vec3),
    /// Top colour to bottom colour.
    Gradient(Vec3, Vec3),
    /// 8-pixel blocks of random colours.
    Blocks(u64),
    /// Value noise at three scales blending three colours.
    Smooth {
        /// Noise seed.
        seed: u64,
        /// The palette.
        colors: [Vec3; 3],
    },
    /// A wall over a floor with panels.
    Room {
        /// Wall colour.
        wall: Vec3,
        /// Floor colour.
        floor: Vec3,
        /// Horizon height (fraction from the top).
        horizon: f32,
        /// Panels on the wall.
        panels: Vec<Panel>,
        /// Texture seed.
        seed: u64,
    },
    /// Out-of-focus discs `(x, y, radius, colour)` over a base colour.
    Bokeh {
        /// Base colour.
        base: Vec3,
        /// The discs.
        blobs: Vec<(f32, f32, f32, Vec3)>,
    },
}

fn color(rng: &mut ChaCha8Rng) -> Vec3 {
    Vec3::new(rng.gen(), rng.gen(), rng.gen())
}

/// A muted colour, as walls and floors are.
fn muted(rng: &mut ChaCha8Rng) -> Vec3 {
    let grey = rng.gen_range(0.25..0.9);
    Vec3::splat(grey).lerp(color(rng), rng.gen_range(0.0..0.35))
}

/// Bilinear value noise of `seed` at lattice scale `cells` per unit, smoothstepped.
fn value_noise(seed: u64, u: f32, v: f32, cells: f32) -> f32 {
    let (x, y) = (u * cells, v * cells);
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let s = |t: f32| t * t * (3.0 - 2.0 * t);
    let (sx, sy) = (s(fx), s(fy));
    let at = |dx: i32, dy: i32| hash3(seed, [x0 as i32 + dx, y0 as i32 + dy, cells as i32]);
    let top = at(0, 0) + (at(1, 0) - at(0, 0)) * sx;
    let bottom = at(0, 1) + (at(1, 1) - at(0, 1)) * sx;
    top + (bottom - top) * sy
}

impl Backdrop {
    /// A random backdrop: white 25%, solid 10%, gradient 10%, blocks 5%, smooth noise 20%,
    /// room 20%, bokeh 10%.
    pub fn random(rng: &mut ChaCha8Rng) -> Self {
        match rng.gen_range(0..100) {
            0..=24 => Backdrop::White,
            25..=34 => Backdrop::Solid(color(rng)),
            35..=44 => Backdrop::Gradient(color(rng), color(rng)),
            45..=49 => Backdrop::Blocks(rng.gen()),
            50..=69 => Backdrop::Smooth {
                seed: rng.gen(),
                colors: [color(rng), muted(rng), color(rng)],
            },
            70..=89 => {
                let panels = (0..rng.gen_range(0..5))
                    .map(|_| {
                        let (x, y) = (rng.gen_range(-0.1..0.9), rng.gen_range(0.0..0.5));
                        let (w, h) = (rng.gen_range(0.08..0.4), rng.gen_range(0.1..0.6));
                        (x, y, x + w, y + h, color(rng) * 0.8)
                    })
                    .collect();
                Backdrop::Room {
                    wall: muted(rng),
                    floor: muted(rng) * 0.7,
                    horizon: rng.gen_range(0.55..0.9),
                    panels,
                    seed: rng.gen(),
                }
            }
            _ => Backdrop::Bokeh {
                base: muted(rng) * 0.6,
                blobs: (0..rng.gen_range(6..20))
                    .map(|_| (rng.gen(), rng.gen(), rng.gen_range(0.03..0.15), color(rng)))
                    .collect(),
            },
        }
    }

    /// Colour at pixel (`x`, `y`) of a `w × h` image.
    pub fn at(&self, x: u32, y: u32, w: u32, h: u32) -> Vec3 {
        let (u, v) = (
            (x as f32 + 0.5) / w.max(1) as f32,
            (y as f32 + 0.5) / h.max(1) as f32,
        );
        match self {
            Backdrop::White => Vec3::ONE,
            Backdrop::Solid(c) => *c,
            Backdrop::Gradient(a, b) => a.lerp(*b, v),
            Backdrop::Blocks(seed) => {
                let c = [0u64, 1, 2].map(|k| hash3(*seed ^ k, [(x / 8) as i32, (y / 8) as i32, 0]));
                Vec3::from(c)
            }
            Backdrop::Smooth { seed, colors } => {
                let n = 0.55 * value_noise(*seed, u, v, 3.0)
                    + 0.3 * value_noise(*seed ^ 1, u, v, 9.0)
                    + 0.15 * value_noise(*seed ^ 2, u, v, 30.0);
                if n < 0.5 {
                    colors[0].lerp(colors[1], n * 2.0)
                } else {
                    colors[1].lerp(colors[2], (n - 0.5) * 2.0)
                }
            }
            Backdrop::Room {
                wall,
                floor,
                horizon,
                panels,
                seed,
            } => {
                let grain = 0.92 + 0.16 * value_noise(*seed, u, v, 40.0);
                let corner = 1.0 - 0.25 * ((u - 0.5).powi(2) + (v - 0.4).powi(2));
                let base = if v > *horizon {
                    // Floor boards: bands converging on the horizon.
                    let depth = (v - horizon) / (1.0 - horizon).max(1e-3);
                    let band = (((u - 0.5) / (0.2 + depth)) * 6.0).rem_euclid(1.0) < 0.06;
                    *floor * if band { 0.8 } else { 1.0 }
                } else {
                    panels
                        .iter()
                        .rev()
                        .find(|(x0, y0, x1, y1, _)| {
                            (*x0..*x1).contains(&u) && (*y0..*y1).contains(&v)
                        })
                        .map_or(*wall, |p| p.4)
                };
                base * grain * corner
            }
            Backdrop::Bokeh { base, blobs } => {
                let mut c = *base;
                for &(bx, by, r, col) in blobs {
                    let d = ((u - bx).powi(2) + (v - by).powi(2)).sqrt() / r;
                    let a = (1.0 - d).clamp(0.0, 1.0).powf(0.5) * 0.6;
                    c = c.lerp(col, a);
                }
                c
            }
        }
        .clamp(Vec3::ZERO, Vec3::ONE)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn backdrops_are_deterministic_bounded_and_varied() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let all: Vec<Backdrop> = (0..200).map(|_| Backdrop::random(&mut rng)).collect();
        for kind in ["White", "Smooth", "Room", "Bokeh"] {
            assert!(
                all.iter().any(|b| format!("{b:?}").starts_with(kind)),
                "{kind}"
            );
        }
        for b in all.iter().take(40) {
            let mut distinct = std::collections::HashSet::new();
            for (x, y) in [(0, 0), (63, 10), (20, 60), (40, 40), (5, 50)] {
                let c = b.at(x, y, 64, 64);
                assert!(c.min_element() >= 0.0 && c.max_element() <= 1.0);
                assert_eq!(c, b.at(x, y, 64, 64));
                distinct.insert(format!("{c:?}"));
            }
            if matches!(b, Backdrop::Smooth { .. } | Backdrop::Room { .. }) {
                assert!(distinct.len() > 1, "{b:?} is flat");
            }
        }
    }
}
