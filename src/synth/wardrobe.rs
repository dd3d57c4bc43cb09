//! A dressed person's wardrobe: a seeded choice of garments from the library (a one-piece, or
//! a top and a bottom from the same outfit or mixed, sometimes a long coat over them; shoes;
//! a hair style or none; sometimes a hat), a material per garment region, and skin and hair
//! tones spanning real ones.

use super::material::{
    contrast_color, material_rng, random_material, FabricStyle, Material, Pattern,
};
use super::outfit::Rgb;
use crate::body::{GarmentKind, GarmentLibrary, GarmentRegion};
use glam::Vec3;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// Skin tones from very light to very dark (interpolated between neighbours).
pub const SKIN_TONES: [Rgb; 7] = [
    [0.98, 0.84, 0.74],
    [0.95, 0.77, 0.64],
    [0.87, 0.66, 0.52],
    [0.76, 0.55, 0.4],
    [0.6, 0.41, 0.28],
    [0.44, 0.29, 0.19],
    [0.28, 0.18, 0.12],
];

/// Natural hair colours (black to platinum, red, grey) and a few dyed ones (last three).
pub const HAIR_COLORS: [Rgb; 13] = [
    [0.04, 0.035, 0.03],
    [0.1, 0.065, 0.04],
    [0.2, 0.12, 0.07],
    [0.36, 0.24, 0.14],
    [0.55, 0.4, 0.24],
    [0.78, 0.64, 0.4],
    [0.9, 0.85, 0.7],
    [0.45, 0.15, 0.06],
    [0.68, 0.33, 0.12],
    [0.5, 0.5, 0.5],
    [0.2, 0.3, 0.75],
    [0.85, 0.35, 0.6],
    [0.25, 0.6, 0.4],
];

/// How the head looks without a hair mesh.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scalp {
    /// A hair mesh is worn.
    Covered,
    /// Hair painted on the skin of the crown and the back of the head (a buzz cut).
    Painted,
    /// Bald.
    Bald,
}

/// One garment worn, with a material per region.
#[derive(Debug, Clone, PartialEq)]
pub struct WornGarment {
    /// Index into the library.
    pub index: usize,
    /// Material of each [`GarmentRegion`], by its `u8` value.
    pub materials: Vec<Material>,
}

/// Everything a dressed person wears, and their skin and hair.
#[derive(Debug, Clone, PartialEq)]
pub struct Wardrobe {
    /// The garments.
    pub garments: Vec<WornGarment>,
    /// Skin tone.
    pub skin: Rgb,
    /// Hair colour (of a hair mesh or painted hair).
    pub hair: Rgb,
    /// The head without a hair mesh.
    pub scalp: Scalp,
}

fn pick(rng: &mut ChaCha8Rng, options: &[usize]) -> Option<usize> {
    (!options.is_empty()).then(|| options[rng.gen_range(0..options.len())])
}

fn lerp(a: Rgb, b: Rgb, t: f32) -> Rgb {
    [0, 1, 2].map(|i| a[i] + (b[i] - a[i]) * t)
}

impl Wardrobe {
    /// The wardrobe of `seed`, chosen from `library`.
    pub fn random(seed: u64, library: &GarmentLibrary) -> Self {
        let mut rng = material_rng(seed);
        let kind = |k| library.of_kind(k);
        let named = |n: &str| library.index_of(n);
        let mut chosen: Vec<usize> = Vec::new();
        let tops = kind(GarmentKind::Top);
        let bottoms = kind(GarmentKind::Bottom);
        let style = rng.gen_range(0..100);
        if style < 14 {
            chosen.extend(pick(&mut rng, &kind(GarmentKind::OnePiece)));
        } else if style < 60 {
            // Top and bottom of one outfit.
            if let Some(top) = pick(&mut rng, &tops) {
                chosen.push(top);
                let stem = library.garments[top]
                    .name
                    .trim_end_matches(".top")
                    .to_string();
                let pair = named(&format!("{stem}.bottom"));
                chosen.extend(pair.or_else(|| pick(&mut rng, &bottoms)));
            }
        } else {
            chosen.extend(pick(&mut rng, &tops));
            chosen.extend(pick(&mut rng, &bottoms));
        }
        // Coats go over a top and a bottom (a one-piece dress would hang out under one).
        if rng.gen_bool(0.18) && style >= 14 {
            chosen.extend(pick(&mut rng, &kind(GarmentKind::Coat)));
        }
        if rng.gen_bool(0.9) {
            chosen.extend(pick(&mut rng, &kind(GarmentKind::Shoes)));
        }
        let scalp = if rng.gen_bool(0.85) {
            chosen.extend(pick(&mut rng, &kind(GarmentKind::Hair)));
            Scalp::Covered
        } else if rng.gen_bool(0.5) {
            Scalp::Painted
        } else {
            Scalp::Bald
        };
        if rng.gen_bool(0.12) {
            chosen.extend(pick(&mut rng, &kind(GarmentKind::Hat)));
        }

        let t = rng.gen_range(0.0..(SKIN_TONES.len() - 1) as f32);
        let k = t.floor() as usize;
        let tone = lerp(SKIN_TONES[k], SKIN_TONES[k + 1], t - k as f32);
        let jitter: Rgb = [0; 3].map(|_| rng.gen_range(0.96..1.04));
        let skin = [0, 1, 2].map(|i| (tone[i] * jitter[i]).min(1.0));
        let hair = if rng.gen_bool(0.93) {
            HAIR_COLORS[rng.gen_range(0..10)]
        } else {
            HAIR_COLORS[rng.gen_range(10..13)]
        };
        let garments = chosen
            .into_iter()
            .map(|index| WornGarment {
                index,
                materials: materials_for(&mut rng, library.garments[index].kind, hair),
            })
            .collect();
        Self {
            garments,
            skin,
            hair,
            scalp,
        }
    }

    /// This wardrobe with a back panel of another colour on every upper garment (tops,
    /// one-pieces, coats) that has none: people whose back differs from their front, seeded by
    /// `seed`.
    pub fn with_contrasting_backs(mut self, seed: u64, library: &GarmentLibrary) -> Self {
        let mut rng = material_rng(seed ^ 0x6261_636b);
        for worn in &mut self.garments {
            let upper = matches!(
                library.garments[worn.index].kind,
                GarmentKind::Top | GarmentKind::OnePiece | GarmentKind::Coat
            );
            let top = &mut worn.materials[GarmentRegion::Top as usize];
            if upper && top.back.is_none() {
                top.back = Some(contrast_color(&mut rng, top.base));
            }
        }
        self
    }

    /// Albedo of the skin at rest point `p` of body part `part` on a body of rest height
    /// `height`.
    pub fn body_albedo(&self, part: &str, p: Vec3, height: f32) -> Rgb {
        let h = p.y / height.max(1e-3);
        match part {
            "head" if self.scalp == Scalp::Painted && (h > 0.93 || (h > 0.87 && p.z < -0.02)) => {
                self.hair
            }
            p if p.starts_with("eye") => [0.1, 0.1, 0.12],
            "mouth_cavity" | "tongue" => [0.55, 0.2, 0.2],
            _ => self.skin,
        }
    }

    /// Albedo of worn garment `k` at rest point `p` with rest normal `n` in `region`.
    pub fn garment_albedo(&self, k: usize, region: GarmentRegion, p: Vec3, n: Vec3) -> Rgb {
        self.garments[k].materials[region as usize].albedo(p, n)
    }

    /// Gloss (0..1) of worn garment `k` in `region`, for lighting.
    pub fn gloss(&self, k: usize, region: GarmentRegion) -> f32 {
        self.garments[k].materials[region as usize].gloss
    }
}

/// Materials of every region of a garment of `kind` (`hair`: the person's hair colour).
fn materials_for(rng: &mut ChaCha8Rng, kind: GarmentKind, hair: Rgb) -> Vec<Material> {
    let upper = random_material(rng, FabricStyle::Upper);
    let sleeve = if rng.gen_bool(0.25) {
        Material {
            print: None,
            ..random_material(rng, FabricStyle::Upper)
        }
    } else {
        Material {
            print: None,
            ..upper.clone()
        }
    };
    let lower = match kind {
        GarmentKind::Coat => Material {
            print: None,
            ..upper.clone()
        },
        GarmentKind::OnePiece if rng.gen_bool(0.5) => Material {
            print: None,
            back: None,
            ..upper.clone()
        },
        _ => random_material(rng, FabricStyle::Lower),
    };
    let detail = Material::solid(contrast_color(rng, upper.base));
    let mut shoe = random_material(rng, FabricStyle::Plain);
    if rng.gen_bool(0.6) {
        shoe.base = [[0.04, 0.04, 0.04], [0.3, 0.18, 0.1], [0.92, 0.92, 0.9]][rng.gen_range(0..3)];
    }
    let sole = Material::solid(
        [[0.9, 0.9, 0.88], [0.06, 0.06, 0.06], [0.55, 0.4, 0.25]][rng.gen_range(0..3)],
    );
    let hair_material = Material {
        pattern: Pattern::Heather {
            strength: rng.gen_range(0.08..0.2),
        },
        seed: rng.gen(),
        gloss: rng.gen_range(0.2..0.6),
        ..Material::solid(hair)
    };
    let hat = random_material(rng, FabricStyle::Plain);
    let mut out = vec![Material::solid([0.5; 3]); GarmentRegion::ALL.len()];
    out[GarmentRegion::Top as usize] = upper;
    out[GarmentRegion::Sleeve as usize] = sleeve;
    out[GarmentRegion::Bottom as usize] = lower;
    out[GarmentRegion::Detail as usize] = detail;
    out[GarmentRegion::Upper as usize] = shoe;
    out[GarmentRegion::Sole as usize] = sole;
    out[GarmentRegion::Hair as usize] = hair_material;
    out[GarmentRegion::Hat as usize] = hat;
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wardrobes_repeat_per_seed_and_dress_most_people_fully() {
        let library = GarmentLibrary::load_default().unwrap();
        assert_eq!(Wardrobe::random(5, &library), Wardrobe::random(5, &library));
        let mut dressed = 0;
        let mut hair = 0;
        for seed in 0..60 {
            let w = Wardrobe::random(seed, &library);
            let kinds: Vec<GarmentKind> = w
                .garments
                .iter()
                .map(|g| library.garments[g.index].kind)
                .collect();
            let full = kinds.contains(&GarmentKind::OnePiece)
                || (kinds.contains(&GarmentKind::Top) && kinds.contains(&GarmentKind::Bottom));
            dressed += full as usize;
            hair += kinds.contains(&GarmentKind::Hair) as usize;
            assert_eq!(
                w.scalp == Scalp::Covered,
                kinds.contains(&GarmentKind::Hair)
            );
        }
        assert_eq!(dressed, 60);
        assert!((40..60).contains(&hair), "{hair}");
    }

    #[test]
    fn contrasting_backs_differ_from_the_front_on_every_upper_garment() {
        let library = GarmentLibrary::load_default().unwrap();
        for seed in 0..20 {
            let plain = Wardrobe::random(seed, &library);
            let backed = plain.clone().with_contrasting_backs(seed, &library);
            assert_eq!(plain.garments.len(), backed.garments.len());
            let mut uppers = 0;
            for (a, b) in plain.garments.iter().zip(&backed.garments) {
                let kind = library.garments[b.index].kind;
                let top = &b.materials[GarmentRegion::Top as usize];
                if matches!(
                    kind,
                    GarmentKind::Top | GarmentKind::OnePiece | GarmentKind::Coat
                ) {
                    uppers += 1;
                    let back = top.back.expect("an upper garment without a back panel");
                    let d: f32 = (0..3).map(|i| (back[i] - top.base[i]).abs()).sum();
                    assert!(d > 0.2 || a.materials[GarmentRegion::Top as usize].back.is_some());
                    // Front and back albedo differ somewhere on the chest (stripes and checks
                    // keep their second colour on both sides).
                    let differ = (0..40).any(|k| {
                        let p = glam::Vec3::new(0.1, 1.1 + 0.005 * k as f32, 0.0);
                        top.albedo(p, glam::Vec3::Z) != top.albedo(p, -glam::Vec3::Z)
                    });
                    assert!(differ, "seed {seed}: the back looks like the front");
                } else {
                    assert_eq!(a, b, "seed {seed}: a non-upper garment changed");
                }
            }
            assert!(uppers >= 1, "seed {seed}: nobody wears an upper garment");
        }
    }
}
