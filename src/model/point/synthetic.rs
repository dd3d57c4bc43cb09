//! A synthetic body-shaped point cloud (capsules for torso, head, arms, legs) for tests and
//! benchmarks of the point backbone: uniform surface samples with outward normals, in metres,
//! z up, standing on z = 0, roughly the size of an adult.

use rand::{Rng, SeedableRng};

/// One capsule: segment `a`–`b`, radius `r`.
struct Capsule {
    a: [f32; 3],
    b: [f32; 3],
    r: f32,
}

impl Capsule {
    fn area(&self) -> f32 {
        let len = dist(self.a, self.b);
        2.0 * std::f32::consts::PI * self.r * len + 4.0 * std::f32::consts::PI * self.r * self.r
    }
}

fn dist(a: [f32; 3], b: [f32; 3]) -> f32 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

fn body() -> Vec<Capsule> {
    let c = |a: [f32; 3], b: [f32; 3], r: f32| Capsule { a, b, r };
    vec![
        c([0.0, 0.0, 1.0], [0.0, 0.0, 1.40], 0.15),      // torso
        c([0.0, 0.0, 1.60], [0.0, 0.0, 1.66], 0.10),     // head
        c([0.0, 0.0, 1.44], [0.0, 0.0, 1.52], 0.05),     // neck
        c([-0.20, 0.0, 1.42], [-0.45, 0.0, 1.15], 0.05), // left upper arm
        c([-0.45, 0.0, 1.15], [-0.60, 0.0, 0.90], 0.04), // left forearm
        c([0.20, 0.0, 1.42], [0.45, 0.0, 1.15], 0.05),   // right upper arm
        c([0.45, 0.0, 1.15], [0.60, 0.0, 0.90], 0.04),   // right forearm
        c([-0.10, 0.0, 0.90], [-0.14, 0.0, 0.50], 0.08), // left thigh
        c([-0.14, 0.0, 0.50], [-0.16, 0.0, 0.08], 0.06), // left shin
        c([0.10, 0.0, 0.90], [0.14, 0.0, 0.50], 0.08),   // right thigh
        c([0.14, 0.0, 0.50], [0.16, 0.0, 0.08], 0.06),   // right shin
    ]
}

/// `n` points sampled uniformly (by area) on the capsule body, with unit outward normals.
/// Deterministic for a given `seed`.
pub fn body_surface_points(n: usize, seed: u64) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
    let parts = body();
    let areas: Vec<f32> = parts.iter().map(Capsule::area).collect();
    let total: f32 = areas.iter().sum();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut points = Vec::with_capacity(n);
    let mut normals = Vec::with_capacity(n);
    while points.len() < n {
        let mut pick = rng.gen::<f32>() * total;
        let mut part = &parts[parts.len() - 1];
        for (p, &a) in parts.iter().zip(&areas) {
            if pick < a {
                part = p;
                break;
            }
            pick -= a;
        }
        // Uniform point on the capsule: the cylinder with probability L / (L + 2r), else one of
        // the two hemispherical caps (together a full sphere of radius r).
        let dir = random_unit(&mut rng);
        let axis = sub(part.b, part.a);
        let len = dist(part.a, part.b).max(1e-6);
        let u = [axis[0] / len, axis[1] / len, axis[2] / len];
        let (centre, normal) = if rng.gen::<f32>() < len / (len + 2.0 * part.r) {
            let t: f32 = rng.gen();
            let d = dot(dir, u);
            let radial = sub(dir, scale(u, d));
            let rl = dot(radial, radial).sqrt();
            if rl < 1e-6 {
                continue;
            }
            (add(part.a, scale(axis, t)), scale(radial, 1.0 / rl))
        } else if dot(dir, u) < 0.0 {
            (part.a, dir)
        } else {
            (part.b, dir)
        };
        points.push(add(centre, scale(normal, part.r)));
        normals.push(normal);
    }
    (points, normals)
}

fn random_unit(rng: &mut impl Rng) -> [f32; 3] {
    loop {
        let v = [
            rng.gen_range(-1.0f32..1.0),
            rng.gen_range(-1.0f32..1.0),
            rng.gen_range(-1.0f32..1.0),
        ];
        let l = dot(v, v);
        if l > 1e-4 && l <= 1.0 {
            return scale(v, 1.0 / l.sqrt());
        }
    }
}

fn add(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn scale(a: [f32; 3], s: f32) -> [f32; 3] {
    [a[0] * s, a[1] * s, a[2] * s]
}

fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_have_unit_normals_and_stand_on_the_ground() {
        let (p, n) = body_surface_points(5_000, 1);
        assert_eq!(p.len(), 5_000);
        for v in &n {
            assert!((dot(*v, *v) - 1.0).abs() < 1e-4);
        }
        let zmin = p.iter().map(|q| q[2]).fold(f32::INFINITY, f32::min);
        let zmax = p.iter().map(|q| q[2]).fold(f32::NEG_INFINITY, f32::max);
        assert!(zmin > -0.01 && zmin < 0.1, "{zmin}");
        assert!(zmax > 1.7 && zmax < 1.8, "{zmax}");
    }
}
