//! Procedural clothing: seeded colours for skin, hair, shirt (optionally striped), trousers and
//! shoes, assigned from body-part labels and height on the canonical template.

use glam::Vec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Linear RGB in [0, 1].
pub type Rgb = [f32; 3];

/// A seeded outfit; `color` paints one canonical surface point.
#[derive(Debug, Clone, PartialEq)]
pub struct Outfit {
    /// Skin tone.
    pub skin: Rgb,
    /// Hair colour (top and back of the head).
    pub hair: Rgb,
    /// Shirt base colour.
    pub shirt: Rgb,
    /// Horizontal stripes on the shirt: colour and period in metres.
    pub stripes: Option<(Rgb, f32)>,
    /// Trousers.
    pub trousers: Rgb,
    /// Shoes.
    pub shoes: Rgb,
    /// Short sleeves (forearms show skin).
    pub short_sleeves: bool,
    /// The shirt's back (points behind the body's mid-plane, z < 0), when it differs from
    /// the front.
    pub shirt_back: Option<Rgb>,
}

const SKIN_TONES: [Rgb; 5] = [
    [0.96, 0.80, 0.69],
    [0.89, 0.67, 0.53],
    [0.78, 0.57, 0.44],
    [0.55, 0.38, 0.26],
    [0.36, 0.23, 0.15],
];

fn vivid(rng: &mut ChaCha8Rng) -> Rgb {
    // A saturated colour: one channel high, one low, one random, shuffled.
    let mut c = [
        rng.gen_range(0.75..0.95),
        rng.gen_range(0.05..0.25),
        rng.gen_range(0.1..0.9),
    ];
    let k = rng.gen_range(0..3);
    c.rotate_left(k);
    if rng.gen_bool(0.5) {
        c.swap(0, 1);
    }
    c
}

impl Outfit {
    /// A deterministic outfit for `seed`.
    pub fn random(seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x6f75_7466_6974);
        let skin = SKIN_TONES[rng.gen_range(0..SKIN_TONES.len())];
        let hair_level = rng.gen_range(0.05..0.45);
        let hair = [hair_level, hair_level * 0.75, hair_level * 0.5];
        let shirt = vivid(&mut rng);
        let stripes = rng
            .gen_bool(0.5)
            .then(|| (vivid(&mut rng), rng.gen_range(0.04..0.1)));
        let t = rng.gen_range(0.1..0.5);
        let trousers = if rng.gen_bool(0.5) {
            [t * 0.5, t * 0.6, t * 1.6] // denim-like
        } else {
            [t, t * 0.9, t * 0.8]
        };
        let s = rng.gen_range(0.05..0.9);
        Self {
            skin,
            hair,
            shirt,
            stripes,
            trousers,
            shoes: [s, s, s],
            short_sleeves: rng.gen_bool(0.5),
            shirt_back: None,
        }
    }

    /// This outfit with a shirt whose back is another vivid colour, seeded by `seed`: a person
    /// whose back differs from their front.
    pub fn with_contrasting_back(mut self, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x6261_636b);
        let far = |c: Rgb| (0..3).map(|i| (c[i] - self.shirt[i]).abs()).sum::<f32>() > 0.6;
        let mut back = vivid(&mut rng);
        for _ in 0..16 {
            if far(back) {
                break;
            }
            back = vivid(&mut rng);
        }
        self.shirt_back = Some(back);
        self
    }

    /// Colour of a canonical point with body-part name `part` at position `p` (metres, +Y up,
    /// soles at y = 0, facing +Z) on a body of height `height`.
    pub fn color(&self, part: &str, p: Vec3, height: f32) -> Rgb {
        let h = p.y / height.max(1e-3);
        match part {
            "head" => {
                // Hair over the crown and the back of the head.
                if h > 0.93 || (h > 0.87 && p.z < -0.02) {
                    self.hair
                } else {
                    self.skin
                }
            }
            p if p.starts_with("hand") => self.skin,
            p if p.starts_with("foot") => self.shoes,
            p if p.starts_with("eye") => [0.1, 0.1, 0.12],
            "mouth_cavity" | "tongue" => [0.55, 0.2, 0.2],
            _ => {
                if h < 0.52 {
                    self.trousers
                } else if h > 0.83 || (self.short_sleeves && p.x.abs() > 0.24 * height) {
                    self.skin // neck, or forearms below short sleeves
                } else {
                    match (self.stripes, self.shirt_back) {
                        (_, Some(back)) if p.z < 0.0 => back,
                        (Some((c, period)), _) if (p.y / period).rem_euclid(1.0) < 0.5 => c,
                        _ => self.shirt,
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outfits_are_deterministic_per_seed_and_differ_across_seeds() {
        assert_eq!(Outfit::random(7), Outfit::random(7));
        let distinct = (0..8)
            .map(|s| Outfit::random(s).shirt)
            .collect::<Vec<_>>()
            .windows(2)
            .filter(|w| w[0] != w[1])
            .count();
        assert!(distinct >= 6);
    }

    #[test]
    fn parts_get_their_garments() {
        let o = Outfit::random(3);
        let h = 1.7;
        assert_eq!(o.color("foot.L", Vec3::new(0.1, 0.05, 0.1), h), o.shoes);
        assert_eq!(o.color("hand.R", Vec3::new(-0.7, 1.0, 0.0), h), o.skin);
        assert_eq!(o.color("body", Vec3::new(0.1, 0.5, 0.0), h), o.trousers);
        let torso = o.color("body", Vec3::new(0.0, 1.2, 0.1), h);
        assert!(torso == o.shirt || o.stripes.is_some_and(|(c, _)| c == torso));
        assert!(o.color("head", Vec3::new(0.0, 1.69, 0.0), h) == o.hair);
    }

    #[test]
    fn a_contrasting_back_paints_only_the_back_of_the_shirt() {
        let o = Outfit::random(3).with_contrasting_back(3);
        let back = o.shirt_back.unwrap();
        let h = 1.7;
        assert_eq!(o.color("body", Vec3::new(0.0, 1.2, -0.1), h), back);
        assert_ne!(o.color("body", Vec3::new(0.0, 1.2, 0.1), h), back);
        assert_eq!(o.color("body", Vec3::new(0.0, 0.5, -0.1), h), o.trousers);
        let d: f32 = (0..3).map(|i| (back[i] - o.shirt[i]).abs()).sum();
        assert!(
            d > 0.3,
            "back {back:?} too close to the front {:?}",
            o.shirt
        );
    }
}
