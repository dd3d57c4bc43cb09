//! Nearest-point lookup on a uniform grid: binds Gaussians and prior points to the skinning
//! weights of the closest template vertex.

use glam::{IVec3, Vec3};
use std::collections::HashMap;

/// Points bucketed into cubic cells for nearest-neighbour queries.
#[derive(Debug, Clone)]
pub struct PointGrid {
    cell: f32,
    cells: HashMap<IVec3, Vec<u32>>,
    points: Vec<Vec3>,
}

impl PointGrid {
    /// Buckets `points` into cells of side `cell` (non-finite points are left out).
    pub fn new(points: &[Vec3], cell: f32) -> Self {
        let mut cells: HashMap<IVec3, Vec<u32>> = HashMap::new();
        for (i, p) in points.iter().enumerate() {
            if p.is_finite() {
                cells
                    .entry((*p / cell).floor().as_ivec3())
                    .or_default()
                    .push(i as u32);
            }
        }
        Self {
            cell,
            cells,
            points: points.to_vec(),
        }
    }

    /// A grid whose cell suits points spread over a surface: about two points per occupied
    /// cell, from the points' bounding box and count.
    pub fn for_surface(points: &[Vec3]) -> Self {
        let (lo, hi) = points
            .iter()
            .filter(|p| p.is_finite())
            .fold((Vec3::MAX, Vec3::MIN), |(l, h), p| (l.min(*p), h.max(*p)));
        let extent = (hi - lo).max_element().max(1e-6);
        let cell = (extent / (points.len() as f32).sqrt().max(1.0) * 1.5).max(1e-4);
        Self::new(points, cell)
    }

    /// Index of the point nearest to `q` (ties: lowest index); `None` when the grid is empty
    /// or `q` is not finite.
    pub fn nearest(&self, q: Vec3) -> Option<usize> {
        if self.cells.is_empty() || !q.is_finite() {
            return None;
        }
        let c = (q / self.cell).floor().as_ivec3();
        let mut best: Option<(f32, u32)> = None;
        for r in 0..i32::MAX {
            for dz in -r..=r {
                for dy in -r..=r {
                    for dx in -r..=r {
                        if dx.abs().max(dy.abs()).max(dz.abs()) != r {
                            continue;
                        }
                        if let Some(ids) = self.cells.get(&(c + IVec3::new(dx, dy, dz))) {
                            for &i in ids {
                                let d = self.points[i as usize].distance_squared(q);
                                if best.is_none_or(|(bd, bi)| d < bd || (d == bd && i < bi)) {
                                    best = Some((d, i));
                                }
                            }
                        }
                    }
                }
            }
            // Points in rings beyond `r` are at least `r · cell` away.
            if let Some((d, i)) = best {
                if d.sqrt() <= r as f32 * self.cell {
                    return Some(i as usize);
                }
            }
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn grid_nearest_agrees_with_brute_force() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let pts: Vec<Vec3> = (0..2000)
            .map(|_| {
                Vec3::new(
                    rng.gen_range(-1.0..1.0),
                    rng.gen_range(0.0..2.0),
                    rng.gen_range(-0.3..0.3),
                )
            })
            .collect();
        let grid = PointGrid::new(&pts, 0.05);
        for _ in 0..500 {
            let q = Vec3::new(
                rng.gen_range(-1.5..1.5),
                rng.gen_range(-0.5..2.5),
                rng.gen_range(-1.0..1.0),
            );
            let brute = (0..pts.len())
                .min_by(|a, b| {
                    pts[*a]
                        .distance_squared(q)
                        .total_cmp(&pts[*b].distance_squared(q))
                })
                .unwrap();
            assert_eq!(grid.nearest(q), Some(brute), "query {q}");
        }
        assert_eq!(PointGrid::new(&[], 0.1).nearest(Vec3::ZERO), None);
        let surface = PointGrid::for_surface(&pts);
        for _ in 0..200 {
            let q = Vec3::new(rng.gen_range(-3.0..3.0), rng.gen_range(-1.0..3.0), 0.5);
            let (a, b) = (grid.nearest(q).unwrap(), surface.nearest(q).unwrap());
            assert_eq!(
                pts[a].distance_squared(q),
                pts[b].distance_squared(q),
                "{q}"
            );
        }
    }
}
