//! Seeded synthetic Gaussian scenes for tests and benchmarks: Gaussians on the surface of a
//! body-like set of capsules (head, torso, arms, legs; `+Y` up, about 1.75 m tall, standing on
//! `y = 0`, facing `+Z`), sized like LHM++'s (a centimetre or so).

use super::gaussians::{rgb_to_sh_dc, Gaussians};
use glam::{Quat, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A capsule: segment `a → b` with radius `r`, plus a base colour.
struct Capsule {
    a: Vec3,
    b: Vec3,
    r: f32,
    colour: Vec3,
}

fn body_capsules() -> Vec<Capsule> {
    let skin = Vec3::new(0.85, 0.65, 0.5);
    let shirt = Vec3::new(0.2, 0.35, 0.7);
    let trousers = Vec3::new(0.25, 0.25, 0.3);
    let c = |a: [f32; 3], b: [f32; 3], r: f32, colour: Vec3| Capsule {
        a: a.into(),
        b: b.into(),
        r,
        colour,
    };
    vec![
        c([0.0, 1.58, 0.0], [0.0, 1.68, 0.0], 0.1, skin),
        c([0.0, 1.0, 0.0], [0.0, 1.38, 0.0], 0.17, shirt),
        c([-0.2, 1.42, 0.0], [-0.45, 1.1, 0.0], 0.05, shirt),
        c([0.2, 1.42, 0.0], [0.45, 1.1, 0.0], 0.05, shirt),
        c([-0.45, 1.1, 0.0], [-0.55, 0.85, 0.05], 0.04, skin),
        c([0.45, 1.1, 0.0], [0.55, 0.85, 0.05], 0.04, skin),
        c([-0.1, 0.95, 0.0], [-0.12, 0.5, 0.0], 0.08, trousers),
        c([0.1, 0.95, 0.0], [0.12, 0.5, 0.0], 0.08, trousers),
        c([-0.12, 0.5, 0.0], [-0.13, 0.08, 0.0], 0.06, trousers),
        c([0.12, 0.5, 0.0], [0.13, 0.08, 0.0], 0.06, trousers),
    ]
}

/// `n` Gaussians on a body-like surface, reproducible from `seed`: log-normal scales around
/// 0.8 cm, random orientations, opacities in `[0.5, 1]`, per-part colours with noise (SH degree
/// 0), and `feature_channels` uniform features in `[-1, 1]`.
pub fn body_cloud(n: usize, feature_channels: usize, seed: u64) -> Gaussians {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let capsules = body_capsules();
    let areas: Vec<f32> = capsules
        .iter()
        .map(|c| std::f32::consts::TAU * c.r * ((c.b - c.a).length() + 2.0 * c.r))
        .collect();
    let total: f32 = areas.iter().sum();
    let mut g = Gaussians {
        positions: Vec::with_capacity(n),
        scales: Vec::with_capacity(n),
        rotations: Vec::with_capacity(n),
        opacities: Vec::with_capacity(n),
        sh_degree: 0,
        sh: Vec::with_capacity(n),
        feature_channels,
        features: Vec::with_capacity(n * feature_channels),
    };
    for _ in 0..n {
        let mut pick = rng.gen::<f32>() * total;
        let mut ci = 0;
        while ci + 1 < capsules.len() && pick > areas[ci] {
            pick -= areas[ci];
            ci += 1;
        }
        let c = &capsules[ci];
        let t: f32 = rng.gen_range(-0.1..1.1);
        let axis_point = c.a.lerp(c.b, t.clamp(0.0, 1.0));
        let dir = loop {
            let v = Vec3::new(
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0..1.0),
            );
            let l = v.length();
            if l > 1e-3 && l <= 1.0 {
                break v / l;
            }
        };
        let along = (c.b - c.a).normalize();
        // Inside the segment, keep the offset radial; at the caps, any direction.
        let radial = if (0.0..=1.0).contains(&t) {
            dir.reject_from_normalized(along).normalize_or_zero()
        } else {
            dir
        };
        let radial = if radial == Vec3::ZERO {
            along.any_orthonormal_vector()
        } else {
            radial
        };
        g.positions.push(axis_point + radial * c.r);
        let s: f32 = 0.008 * (rng.gen_range(-0.5f32..0.5)).exp();
        g.scales.push(Vec3::new(
            s * rng.gen_range(0.6..1.4),
            s * rng.gen_range(0.6..1.4),
            s * rng.gen_range(0.2..0.5),
        ));
        let q = Quat::from_xyzw(
            rng.gen_range(-1.0..1.0),
            rng.gen_range(-1.0..1.0),
            rng.gen_range(-1.0..1.0),
            rng.gen_range(-1.0..1.0),
        );
        g.rotations.push(if q.length() > 1e-3 {
            q.normalize()
        } else {
            Quat::IDENTITY
        });
        g.opacities.push(rng.gen_range(0.5..1.0));
        let noise = Vec3::new(
            rng.gen_range(-0.05..0.05),
            rng.gen_range(-0.05..0.05),
            rng.gen_range(-0.05..0.05),
        );
        g.sh.push(rgb_to_sh_dc(
            (c.colour + noise).clamp(Vec3::ZERO, Vec3::ONE),
        ));
        for _ in 0..feature_channels {
            g.features.push(rng.gen_range(-1.0..1.0));
        }
    }
    g
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_seed_gives_the_same_cloud_and_it_is_valid() {
        let a = body_cloud(500, 2, 7);
        assert_eq!(a, body_cloud(500, 2, 7));
        assert_ne!(a, body_cloud(500, 2, 8));
        a.validate().unwrap();
        let ys: Vec<f32> = a.positions.iter().map(|p| p.y).collect();
        let (lo, hi) = ys
            .iter()
            .fold((f32::MAX, f32::MIN), |(l, h), y| (l.min(*y), h.max(*y)));
        assert!(
            lo > -0.05 && hi < 1.85 && hi - lo > 1.5,
            "body-sized: {lo}..{hi}"
        );
    }
}
