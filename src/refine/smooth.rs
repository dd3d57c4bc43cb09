//! The albedo prior: a Gaussian's albedo is like its neighbours' on the body (garments and
//! skin are mostly of one colour over a patch), with a robust penalty so that a seam or a
//! print's edge can stay sharp. Without it, a fit of colours and light cannot tell the light
//! from the albedo (a person standing still shows each Gaussian in one light only), and the
//! avatar keeps the shading of the views in its colours.

use glam::{IVec3, Vec3};
use std::collections::HashMap;

/// Neighbours within this distance (metres) count.
const RADIUS: f32 = 0.03;
/// At most this many neighbours per Gaussian (the nearest).
const MAX_NEIGHBOURS: usize = 6;
/// Smoothing of the Charbonnier penalty (colour units): differences well above it cost by
/// their size, not its square, so edges survive.
const EPSILON: f32 = 0.03;

/// Each Gaussian's nearest neighbours (pairs `(i, j)` with `i < j`, each once).
pub(crate) fn neighbour_pairs(positions: &[Vec3]) -> Vec<(u32, u32)> {
    let cell = |p: Vec3| (p / RADIUS).floor().as_ivec3();
    let mut grid: HashMap<IVec3, Vec<u32>> = HashMap::new();
    for (i, p) in positions.iter().enumerate() {
        if p.is_finite() {
            grid.entry(cell(*p)).or_default().push(i as u32);
        }
    }
    let mut pairs = Vec::new();
    let mut near: Vec<(f32, u32)> = Vec::new();
    for (i, p) in positions.iter().enumerate() {
        if !p.is_finite() {
            continue;
        }
        near.clear();
        let c = cell(*p);
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let Some(list) = grid.get(&(c + IVec3::new(dx, dy, dz))) else {
                        continue;
                    };
                    for &j in list {
                        let d = positions[j as usize].distance_squared(*p);
                        if j as usize != i && d <= RADIUS * RADIUS {
                            near.push((d, j));
                        }
                    }
                }
            }
        }
        near.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        for &(_, j) in near.iter().take(MAX_NEIGHBOURS) {
            let (a, b) = (i as u32, j);
            pairs.push((a.min(b), a.max(b)));
        }
    }
    pairs.sort_unstable();
    pairs.dedup();
    pairs
}

/// The prior's value `weight / N · Σ ρ(albedoᵢ − albedoⱼ)` over the pairs, adding its
/// gradient to `grads`.
pub(crate) fn albedo_prior(
    albedo: &[Vec3],
    pairs: &[(u32, u32)],
    weight: f32,
    grads: &mut [Vec3],
) -> f32 {
    let scale = weight / albedo.len().max(1) as f32;
    let mut total = 0.0f64;
    for &(i, j) in pairs {
        let d = albedo[i as usize] - albedo[j as usize];
        let root = (d * d + Vec3::splat(EPSILON * EPSILON)).powf(0.5);
        total += (root - Vec3::splat(EPSILON)).element_sum() as f64;
        let g = d / root * scale;
        grads[i as usize] += g;
        grads[j as usize] -= g;
    }
    (total as f32) * scale
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn near_points_pair_up_and_far_ones_do_not() {
        let p = [
            Vec3::ZERO,
            Vec3::new(0.01, 0.0, 0.0),
            Vec3::new(0.0, 0.02, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
        ];
        let pairs = neighbour_pairs(&p);
        assert_eq!(pairs, vec![(0, 1), (0, 2), (1, 2)]);
    }

    #[test]
    fn the_prior_gradient_matches_finite_differences() {
        let albedo = vec![
            Vec3::new(0.2, 0.5, 0.7),
            Vec3::new(0.25, 0.1, 0.7),
            Vec3::new(0.9, 0.5, 0.65),
        ];
        let pairs = vec![(0, 1), (0, 2), (1, 2)];
        let mut grads = vec![Vec3::ZERO; 3];
        albedo_prior(&albedo, &pairs, 0.5, &mut grads);
        let h = 1e-3;
        for i in 0..3 {
            for c in 0..3 {
                let (mut a, mut b) = (albedo.clone(), albedo.clone());
                a[i][c] += h;
                b[i][c] -= h;
                let mut sink = vec![Vec3::ZERO; 3];
                let n = (albedo_prior(&a, &pairs, 0.5, &mut sink)
                    - albedo_prior(&b, &pairs, 0.5, &mut sink))
                    / (2.0 * h);
                assert!(
                    (n - grads[i][c]).abs() < 1e-3,
                    "{i} {c}: {n} vs {}",
                    grads[i][c]
                );
            }
        }
    }
}
