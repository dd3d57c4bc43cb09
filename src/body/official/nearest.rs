//! Nearest template vertex of many points, on a uniform grid (the prior binds each of its
//! 160K points to the nearest SMPL-X vertex, as the official code does with `knn_points`).

use std::collections::HashMap;

use glam::{IVec3, Vec3};
use rayon::prelude::*;

/// Index of the nearest of `targets` for every point of `queries` (`targets` non-empty).
pub fn nearest_indices(queries: &[Vec3], targets: &[Vec3]) -> Vec<u32> {
    let (lo, hi) = targets
        .iter()
        .fold((Vec3::MAX, Vec3::MIN), |(l, h), p| (l.min(*p), h.max(*p)));
    let extent = (hi - lo).max_element().max(1e-6);
    // About 2 targets per occupied cell on a surface.
    let cell = (extent / (targets.len() as f32).sqrt().max(1.0) * 1.5).max(1e-4);
    let key = |p: Vec3| ((p - lo) / cell).floor().as_ivec3();
    let mut cells: HashMap<IVec3, Vec<u32>> = HashMap::new();
    for (i, p) in targets.iter().enumerate() {
        cells.entry(key(*p)).or_default().push(i as u32);
    }
    queries
        .par_iter()
        .map(|q| {
            let c = key(*q);
            let mut best = (f32::INFINITY, 0u32);
            for r in 0i32.. {
                for dz in -r..=r {
                    for dy in -r..=r {
                        for dx in -r..=r {
                            if dx.abs().max(dy.abs()).max(dz.abs()) != r {
                                continue;
                            }
                            if let Some(ids) = cells.get(&(c + IVec3::new(dx, dy, dz))) {
                                for &i in ids {
                                    let d = targets[i as usize].distance_squared(*q);
                                    if d < best.0 || (d == best.0 && i < best.1) {
                                        best = (d, i);
                                    }
                                }
                            }
                        }
                    }
                }
                // Anything in a farther ring is at least r · cell away.
                if best.0.sqrt() <= r as f32 * cell || r > 100_000 {
                    return best.1;
                }
            }
            best.1
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_search_agrees_with_brute_force() {
        let targets: Vec<Vec3> = (0..500)
            .map(|i| {
                let t = i as f32;
                Vec3::new(
                    (t * 0.37).sin(),
                    (t * 0.11).cos() * 2.0,
                    (t * 0.73).sin() * 0.3,
                )
            })
            .collect();
        let queries: Vec<Vec3> = (0..300)
            .map(|i| {
                let t = i as f32 * 1.3;
                Vec3::new(t.cos() * 1.5, (t * 0.5).sin() * 3.0, (t * 0.2).cos())
            })
            .collect();
        let got = nearest_indices(&queries, &targets);
        for (q, g) in queries.iter().zip(&got) {
            let d = targets[*g as usize].distance_squared(*q);
            let best = targets
                .iter()
                .map(|t| t.distance_squared(*q))
                .fold(f32::INFINITY, f32::min);
            assert_eq!(d, best);
        }
    }
}
