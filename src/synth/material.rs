//! Procedural fabric materials for garment regions: solid colours, stripes, checks, dots,
//! denim-like twill noise and heathered knits, with prints (logos) on the front or the back,
//! and two-tone garments whose back panel differs from the front.
//!
//! A material is evaluated at a rest-pose canonical point of the template at its rest shape
//! (so patterns do not stretch with body shape) with that point's rest normal: the front is
//! where the normal points towards +Z (the way the person faces).

use super::outfit::Rgb;
use glam::{Vec2, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Garment colours: neutrals, denims and earth tones most often, some vivid ones.
pub const GARMENT_PALETTE: [Rgb; 26] = [
    [0.05, 0.05, 0.06],
    [0.18, 0.18, 0.2],
    [0.45, 0.45, 0.46],
    [0.72, 0.72, 0.7],
    [0.92, 0.92, 0.9],
    [0.9, 0.85, 0.72],
    [0.76, 0.66, 0.5],
    [0.58, 0.53, 0.36],
    [0.38, 0.25, 0.15],
    [0.7, 0.5, 0.32],
    [0.09, 0.12, 0.28],
    [0.22, 0.32, 0.52],
    [0.34, 0.37, 0.2],
    [0.45, 0.08, 0.13],
    [0.1, 0.3, 0.18],
    [0.8, 0.12, 0.1],
    [0.95, 0.5, 0.12],
    [0.95, 0.84, 0.22],
    [0.2, 0.62, 0.3],
    [0.1, 0.52, 0.55],
    [0.45, 0.68, 0.88],
    [0.15, 0.28, 0.72],
    [0.45, 0.2, 0.58],
    [0.94, 0.6, 0.68],
    [0.78, 0.2, 0.48],
    [0.96, 0.96, 0.95],
];

/// A repeating pattern over a base colour.
#[derive(Debug, Clone, PartialEq)]
pub enum Pattern {
    /// The base colour only.
    Solid,
    /// Bands of `color`: `period` metres, `duty` of each period in `color`, along `axis`
    /// (unit vector in the x–y plane: (0, 1) horizontal bands, (1, 0) vertical ones).
    Stripes {
        /// Stripe colour.
        color: Rgb,
        /// Period (metres).
        period: f32,
        /// Fraction of the period in the stripe colour.
        duty: f32,
        /// Direction across the bands.
        axis: Vec2,
    },
    /// Checks of `color` over the base: `period` metres squares in x and y (seen from the
    /// front or the back; stretched on the sides).
    Checks {
        /// Second colour.
        color: Rgb,
        /// Square side (metres).
        period: f32,
    },
    /// Dots of `color`, `radius` metres, on a `period` metres grid.
    Dots {
        /// Dot colour.
        color: Rgb,
        /// Grid period (metres).
        period: f32,
        /// Dot radius (metres).
        radius: f32,
    },
    /// Denim-like: diagonal twill lines and speckle of ±`strength` around the base.
    Denim {
        /// Relative variation.
        strength: f32,
    },
    /// Heathered knit: speckle of ±`strength`.
    Heather {
        /// Relative variation.
        strength: f32,
    },
}

/// Shape of a print.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PrintShape {
    /// A filled disc.
    Disc,
    /// A ring.
    Ring,
    /// A filled square.
    Square,
    /// A five-pointed star.
    Star,
    /// Three bars of text-like blocks.
    Lettering,
    /// A triangle pointing up.
    Triangle,
}

/// A print (logo) on one side of a garment, in the x–y plane of the canonical frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Print {
    /// Its shape.
    pub shape: PrintShape,
    /// Its colour.
    pub color: Rgb,
    /// Centre (x, y) in metres.
    pub centre: Vec2,
    /// Half size (metres).
    pub size: f32,
    /// On the back (else on the front).
    pub back: bool,
}

impl Print {
    /// Whether the print paints the point at (x, y) on side `back`.
    pub fn covers(&self, p: Vec2, back: bool) -> bool {
        if back != self.back {
            return false;
        }
        // Seen from behind, x runs the other way; mirror so the print reads the same.
        let mut q = (p - self.centre) / self.size;
        if self.back {
            q.x = -q.x;
        }
        match self.shape {
            PrintShape::Disc => q.length() <= 1.0,
            PrintShape::Ring => (0.6..=1.0).contains(&q.length()),
            PrintShape::Square => q.abs().max_element() <= 1.0,
            PrintShape::Triangle => q.y >= -0.8 && q.y <= 1.0 - 1.8 * q.x.abs(),
            PrintShape::Star => {
                let r = q.length();
                let a = q.y.atan2(q.x) + std::f32::consts::FRAC_PI_2;
                let lobe = (2.5 * a).cos().abs();
                r <= 0.45 + 0.55 * lobe.powf(3.0)
            }
            PrintShape::Lettering => {
                // Three rows of blocky glyphs with gaps.
                if q.x.abs() > 1.0 || q.y.abs() > 0.6 {
                    return false;
                }
                let row = ((q.y + 0.6) / 0.4).floor();
                let in_row = (q.y + 0.6) - row * 0.4 < 0.28;
                let glyph = ((q.x + 1.0) / 0.25).floor();
                let in_glyph = (q.x + 1.0) - glyph * 0.25 < 0.19;
                let hash = ((row as i32 * 7 + glyph as i32 * 13) % 5) != 0;
                in_row && in_glyph && hash
            }
        }
    }
}

/// One region's material.
#[derive(Debug, Clone, PartialEq)]
pub struct Material {
    /// Base colour.
    pub base: Rgb,
    /// Pattern over the base.
    pub pattern: Pattern,
    /// A different back panel: its colour (two-tone garments).
    pub back: Option<Rgb>,
    /// A print on the front or the back.
    pub print: Option<Print>,
    /// Seed of the speckle noise.
    pub seed: u64,
    /// Glossiness for lighting: 0 matte fabric, up to 1 leather or satin.
    pub gloss: f32,
}

/// A deterministic hash of a 3D lattice cell and `seed` to [0, 1).
pub fn hash3(seed: u64, c: [i32; 3]) -> f32 {
    let mut h = seed ^ 0x9E37_79B9_7F4A_7C15;
    for v in c {
        h = (h ^ (v as u32 as u64)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        h ^= h >> 31;
    }
    (h >> 40) as f32 / (1u64 << 24) as f32
}

fn scaled(c: Rgb, s: f32) -> Rgb {
    c.map(|v| (v * s).clamp(0.0, 1.0))
}

impl Material {
    /// A plain material of colour `base`.
    pub fn solid(base: Rgb) -> Self {
        Self {
            base,
            pattern: Pattern::Solid,
            back: None,
            print: None,
            seed: 0,
            gloss: 0.0,
        }
    }

    /// The colour at rest point `p` with rest normal `n`.
    pub fn albedo(&self, p: Vec3, n: Vec3) -> Rgb {
        let back = n.z < 0.0;
        let xy = Vec2::new(p.x, p.y);
        if let Some(print) = &self.print {
            if print.covers(xy, back) {
                return print.color;
            }
        }
        let base = match (back, self.back) {
            (true, Some(b)) => b,
            _ => self.base,
        };
        let speckle = |strength: f32, cell: f32| {
            let c = (p / cell).floor();
            1.0 + strength * (2.0 * hash3(self.seed, [c.x as i32, c.y as i32, c.z as i32]) - 1.0)
        };
        match &self.pattern {
            Pattern::Solid => base,
            Pattern::Stripes {
                color,
                period,
                duty,
                axis,
            } => {
                let t = (xy.dot(*axis) / period).rem_euclid(1.0);
                if t < *duty {
                    *color
                } else {
                    base
                }
            }
            Pattern::Checks { color, period } => {
                let (i, j) = (xy / *period).floor().as_ivec2().into();
                if (i + j).rem_euclid(2) == 0 {
                    *color
                } else {
                    base
                }
            }
            Pattern::Dots {
                color,
                period,
                radius,
            } => {
                let cell = (xy / *period).round() * *period;
                if xy.distance(cell) <= *radius {
                    *color
                } else {
                    base
                }
            }
            Pattern::Denim { strength } => {
                let twill = ((p.x + p.y) / 0.006).rem_euclid(1.0) < 0.5;
                let s = speckle(*strength, 0.004) * if twill { 1.05 } else { 0.93 };
                scaled(base, s)
            }
            Pattern::Heather { strength } => scaled(base, speckle(*strength, 0.005)),
        }
    }
}

/// A colour from [`GARMENT_PALETTE`] (neutral ones twice as likely) with a little jitter.
pub fn garment_color(rng: &mut ChaCha8Rng) -> Rgb {
    let i = if rng.gen_bool(0.5) {
        rng.gen_range(0..15)
    } else {
        rng.gen_range(0..GARMENT_PALETTE.len())
    };
    let s = rng.gen_range(0.88..1.1);
    scaled(GARMENT_PALETTE[i], s)
}

/// A colour that stands out against `base`.
pub fn contrast_color(rng: &mut ChaCha8Rng, base: Rgb) -> Rgb {
    let luma = |c: Rgb| 0.3 * c[0] + 0.59 * c[1] + 0.11 * c[2];
    for _ in 0..8 {
        let c = garment_color(rng);
        let d: f32 = (0..3).map(|i| (c[i] - base[i]).abs()).sum();
        if d > 0.45 || (luma(c) - luma(base)).abs() > 0.3 {
            return c;
        }
    }
    if luma(base) > 0.5 {
        [0.05, 0.05, 0.06]
    } else {
        [0.95, 0.95, 0.93]
    }
}

/// What a random fabric may look like.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FabricStyle {
    /// Shirts, jackets, dresses: any pattern, prints, two-tone backs.
    Upper,
    /// Trousers, skirts: solids, denims, some checks and stripes.
    Lower,
    /// Details, shoes: plain or slightly glossy.
    Plain,
}

/// A random material for `style`, seeded by `rng`.
pub fn random_material(rng: &mut ChaCha8Rng, style: FabricStyle) -> Material {
    let seed = rng.gen();
    let mut m = Material {
        seed,
        ..Material::solid(garment_color(rng))
    };
    match style {
        FabricStyle::Plain => {
            m.gloss = rng.gen_range(0.0..0.6);
            return m;
        }
        FabricStyle::Lower => {
            match rng.gen_range(0..100) {
                0..=34 => {
                    let t = rng.gen_range(0.15..0.5);
                    m.base = [t * 0.45, t * 0.62, t * 1.25];
                    m.pattern = Pattern::Denim {
                        strength: rng.gen_range(0.08..0.2),
                    };
                }
                35..=44 => {
                    m.pattern = Pattern::Checks {
                        color: contrast_color(rng, m.base),
                        period: rng.gen_range(0.02..0.06),
                    }
                }
                45..=52 => {
                    m.pattern = Pattern::Stripes {
                        color: contrast_color(rng, m.base),
                        period: rng.gen_range(0.03..0.1),
                        duty: rng.gen_range(0.1..0.5),
                        axis: Vec2::X,
                    }
                }
                _ => {}
            }
            return m;
        }
        FabricStyle::Upper => {}
    }
    m.pattern = match rng.gen_range(0..100) {
        0..=39 => Pattern::Solid,
        40..=57 => Pattern::Stripes {
            color: contrast_color(rng, m.base),
            period: rng.gen_range(0.02..0.12),
            duty: rng.gen_range(0.2..0.6),
            axis: match rng.gen_range(0..6) {
                0 => Vec2::X,
                1 => Vec2::new(1.0, 1.0).normalize(),
                _ => Vec2::Y,
            },
        },
        58..=68 => Pattern::Checks {
            color: contrast_color(rng, m.base),
            period: rng.gen_range(0.015..0.07),
        },
        69..=76 => Pattern::Dots {
            color: contrast_color(rng, m.base),
            period: rng.gen_range(0.03..0.07),
            radius: rng.gen_range(0.006..0.014),
        },
        77..=84 => Pattern::Denim {
            strength: rng.gen_range(0.06..0.15),
        },
        _ => Pattern::Heather {
            strength: rng.gen_range(0.05..0.15),
        },
    };
    // Backs that differ from fronts: prints on one side, two-tone panels.
    if rng.gen_bool(0.35) {
        let shape = [
            PrintShape::Disc,
            PrintShape::Ring,
            PrintShape::Square,
            PrintShape::Star,
            PrintShape::Lettering,
            PrintShape::Triangle,
        ][rng.gen_range(0..6)];
        let back = rng.gen_bool(0.45);
        m.print = Some(Print {
            shape,
            color: contrast_color(rng, m.base),
            centre: Vec2::new(rng.gen_range(-0.04..0.04), rng.gen_range(1.16..1.3)),
            size: rng.gen_range(0.05..if back { 0.14 } else { 0.1 }),
            back,
        });
    }
    if rng.gen_bool(0.15) {
        m.back = Some(contrast_color(rng, m.base));
    }
    m.gloss = rng.gen_range(0.0..0.25);
    m
}

/// A seeded generator for materials of one person.
pub fn material_rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed ^ 0x6d61_7465_7269_616c)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn prints_sit_on_one_side_only() {
        let print = Print {
            shape: PrintShape::Disc,
            color: [1.0, 0.0, 0.0],
            centre: Vec2::new(0.0, 1.2),
            size: 0.08,
            back: true,
        };
        let m = Material {
            print: Some(print),
            ..Material::solid([0.1, 0.1, 0.1])
        };
        let p = Vec3::new(0.01, 1.21, 0.1);
        assert_eq!(m.albedo(p, Vec3::Z), [0.1, 0.1, 0.1]);
        assert_eq!(
            m.albedo(p * Vec3::new(1.0, 1.0, -1.0), -Vec3::Z),
            [1.0, 0.0, 0.0]
        );
        assert_eq!(
            m.albedo(Vec3::new(0.3, 1.21, -0.1), -Vec3::Z),
            [0.1, 0.1, 0.1]
        );
    }

    #[test]
    fn stripes_alternate_with_the_period() {
        let m = Material {
            pattern: Pattern::Stripes {
                color: [1.0; 3],
                period: 0.1,
                duty: 0.5,
                axis: Vec2::Y,
            },
            ..Material::solid([0.0; 3])
        };
        assert_eq!(m.albedo(Vec3::new(0.0, 1.02, 0.1), Vec3::Z), [1.0; 3]);
        assert_eq!(m.albedo(Vec3::new(0.0, 1.07, 0.1), Vec3::Z), [0.0; 3]);
        assert_eq!(m.albedo(Vec3::new(0.2, 1.12, 0.1), Vec3::Z), [1.0; 3]);
    }

    #[test]
    fn random_materials_vary_and_repeat_per_seed() {
        let draw = |seed| {
            let mut rng = material_rng(seed);
            (0..20)
                .map(|_| random_material(&mut rng, FabricStyle::Upper))
                .collect::<Vec<_>>()
        };
        assert_eq!(draw(4), draw(4));
        let all = draw(9);
        assert!(all.iter().any(|m| m.print.is_some()));
        assert!(all.iter().any(|m| m.pattern != Pattern::Solid));
        assert!(all.iter().any(|m| m.pattern == Pattern::Solid));
        for m in &all {
            for c in m.base {
                assert!((0.0..=1.0).contains(&c));
            }
        }
    }
}
