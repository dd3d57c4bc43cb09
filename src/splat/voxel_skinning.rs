//! Diffused voxel skinning: skinning weights spread from surface points into a voxel grid
//! around the body, looked up by trilinear interpolation, for points that moved off the
//! surface (LHM++ `CanoBlendWeightVolume`).
//!
//! Building: every grid node takes the weights of its nearest surface point (a brushfire
//! propagation over the 6-neighbour grid from the nodes around each point); nodes farther than
//! one voxel from the surface are then smoothed by Jacobi diffusion (mean of themselves and
//! their 6 neighbours), so weights change gradually away from the body. Weights stay sparse
//! (top [`MAX_INFLUENCES`] bones, renormalised) at every step.

use crate::body::{SkinWeights, MAX_INFLUENCES};
use glam::Vec3;
use rayon::prelude::*;
use std::collections::VecDeque;
use thiserror::Error;

/// Why a voxel skinning volume cannot be built.
#[derive(Debug, Error, PartialEq)]
pub enum VoxelSkinningError {
    /// Points and weight rows disagree in number, or there are none.
    #[error("voxel skinning needs one weight row per surface point: {points} points, {rows} rows")]
    Rows {
        /// Surface points.
        points: usize,
        /// Weight rows.
        rows: usize,
    },
    /// The voxel size is not positive, or the grid would be too large.
    #[error("voxel size {voxel_size} m gives a grid of {nodes} nodes (limit {limit})")]
    Grid {
        /// Voxel size (metres).
        voxel_size: f32,
        /// Nodes the grid would have.
        nodes: usize,
        /// Most nodes allowed.
        limit: usize,
    },
}

/// Most grid nodes a volume may have (≈ 0.5 GB of sparse weights).
const MAX_NODES: usize = 20_000_000;

type Row = ([u16; MAX_INFLUENCES], [f32; MAX_INFLUENCES]);

/// A skinning-weight volume: sparse weights at the nodes of a regular grid.
#[derive(Debug, Clone, PartialEq)]
pub struct VoxelSkinning {
    /// Position of node `(0, 0, 0)`.
    pub origin: Vec3,
    /// Node spacing (metres).
    pub voxel_size: f32,
    /// Nodes along x, y, z.
    pub dims: [usize; 3],
    rows: Vec<Row>,
}

/// Sums sparse weight rows and keeps the strongest bones.
#[derive(Default)]
struct Accumulator {
    entries: Vec<(u16, f32)>,
}

impl Accumulator {
    fn add(&mut self, row: &Row, scale: f32) {
        for (&bone, &weight) in row.0.iter().zip(&row.1) {
            let w = weight * scale;
            if w > 0.0 {
                match self.entries.iter_mut().find(|e| e.0 == bone) {
                    Some(e) => e.1 += w,
                    None => self.entries.push((bone, w)),
                }
            }
        }
    }

    /// Top bones by weight (ties by bone index), renormalised; clears the accumulator.
    fn take(&mut self) -> Row {
        self.entries
            .sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        let mut row: Row = ([0; MAX_INFLUENCES], [0.0; MAX_INFLUENCES]);
        let kept = self.entries.len().min(MAX_INFLUENCES);
        let sum: f32 = self.entries[..kept].iter().map(|e| e.1).sum();
        for (k, e) in self.entries[..kept].iter().enumerate() {
            row.0[k] = e.0;
            row.1[k] = if sum > 0.0 { e.1 / sum } else { 0.0 };
        }
        self.entries.clear();
        row
    }
}

impl VoxelSkinning {
    /// Builds a volume covering the points' bounding box plus `padding` (metres) on each side,
    /// then runs `diffusion_steps` smoothing steps on the nodes away from the surface.
    pub fn from_surface(
        points: &[Vec3],
        skin: &SkinWeights,
        voxel_size: f32,
        padding: f32,
        diffusion_steps: usize,
    ) -> Result<Self, VoxelSkinningError> {
        if points.is_empty() || points.len() != skin.len() || skin.weights.len() != skin.bones.len()
        {
            return Err(VoxelSkinningError::Rows {
                points: points.len(),
                rows: skin.len(),
            });
        }
        let (lo, hi) = points
            .iter()
            .fold((Vec3::MAX, Vec3::MIN), |(l, h), p| (l.min(*p), h.max(*p)));
        let origin = lo - Vec3::splat(padding);
        let extent = hi + Vec3::splat(padding) - origin;
        let count = |e: f32| (e / voxel_size).ceil() as usize + 1;
        let dims = [count(extent.x), count(extent.y), count(extent.z)];
        let nodes = dims
            .iter()
            .try_fold(1usize, |a, d| a.checked_mul(*d))
            .unwrap_or(usize::MAX);
        if voxel_size.is_nan() || voxel_size <= 0.0 || nodes > MAX_NODES {
            return Err(VoxelSkinningError::Grid {
                voxel_size,
                nodes,
                limit: MAX_NODES,
            });
        }
        let mut v = Self {
            origin,
            voxel_size,
            dims,
            rows: Vec::new(),
        };
        let nearest = v.nearest_points(points);
        let empty: Row = ([0; MAX_INFLUENCES], [0.0; MAX_INFLUENCES]);
        v.rows = nearest
            .iter()
            .map(|&(p, _)| {
                if p == u32::MAX {
                    empty
                } else {
                    (skin.bones[p as usize], skin.weights[p as usize])
                }
            })
            .collect();
        let frozen: Vec<bool> = nearest
            .iter()
            .map(|&(_, d2)| d2 <= voxel_size * voxel_size)
            .collect();
        for _ in 0..diffusion_steps {
            v.diffuse(&frozen);
        }
        Ok(v)
    }

    fn index(&self, x: usize, y: usize, z: usize) -> usize {
        (z * self.dims[1] + y) * self.dims[0] + x
    }

    fn node_position(&self, i: usize) -> Vec3 {
        let x = i % self.dims[0];
        let y = (i / self.dims[0]) % self.dims[1];
        let z = i / (self.dims[0] * self.dims[1]);
        self.origin + Vec3::new(x as f32, y as f32, z as f32) * self.voxel_size
    }

    fn neighbours(&self, i: usize) -> impl Iterator<Item = usize> + '_ {
        let [dx, dy, dz] = self.dims;
        let (x, y, z) = (i % dx, (i / dx) % dy, i / (dx * dy));
        let steps: [(bool, isize); 6] = [
            (x > 0, -1),
            (x + 1 < dx, 1),
            (y > 0, -(dx as isize)),
            (y + 1 < dy, dx as isize),
            (z > 0, -((dx * dy) as isize)),
            (z + 1 < dz, (dx * dy) as isize),
        ];
        steps
            .into_iter()
            .filter(|s| s.0)
            .map(move |s| (i as isize + s.1) as usize)
    }

    /// Per node: (index of the nearest surface point, squared distance), by brushfire.
    fn nearest_points(&self, points: &[Vec3]) -> Vec<(u32, f32)> {
        let n = self.dims.iter().product();
        let mut best = vec![(u32::MAX, f32::INFINITY); n];
        let mut queue = VecDeque::new();
        for (pi, p) in points.iter().enumerate() {
            let c = ((*p - self.origin) / self.voxel_size).floor();
            for corner in 0..8 {
                let o = Vec3::new(
                    (corner & 1) as f32,
                    ((corner >> 1) & 1) as f32,
                    (corner >> 2) as f32,
                );
                let g = (c + o).as_uvec3();
                if g.x as usize >= self.dims[0]
                    || g.y as usize >= self.dims[1]
                    || g.z as usize >= self.dims[2]
                {
                    continue;
                }
                let i = self.index(g.x as usize, g.y as usize, g.z as usize);
                let d2 = self.node_position(i).distance_squared(*p);
                if d2 < best[i].1 {
                    best[i] = (pi as u32, d2);
                    queue.push_back(i);
                }
            }
        }
        while let Some(i) = queue.pop_front() {
            let p = best[i].0;
            let pos = points[p as usize];
            for j in self.neighbours(i) {
                let d2 = self.node_position(j).distance_squared(pos);
                if d2 < best[j].1 {
                    best[j] = (p, d2);
                    queue.push_back(j);
                }
            }
        }
        best
    }

    /// One Jacobi smoothing step over the nodes that are not frozen.
    fn diffuse(&mut self, frozen: &[bool]) {
        let next: Vec<Row> = (0..self.rows.len())
            .into_par_iter()
            .map_init(Accumulator::default, |acc, i| {
                if frozen[i] {
                    return self.rows[i];
                }
                acc.add(&self.rows[i], 1.0);
                for j in self.neighbours(i) {
                    acc.add(&self.rows[j], 1.0);
                }
                acc.take()
            })
            .collect();
        self.rows = next;
    }

    /// Trilinearly interpolated weights at `p` (clamped to the grid, like border padding).
    pub fn lookup(&self, p: Vec3) -> Row {
        let g = ((p - self.origin) / self.voxel_size).clamp(
            Vec3::ZERO,
            Vec3::new(
                self.dims[0] as f32 - 1.0,
                self.dims[1] as f32 - 1.0,
                self.dims[2] as f32 - 1.0,
            ),
        );
        let base = g.floor().as_uvec3();
        let f = g - base.as_vec3();
        let mut acc = Accumulator::default();
        for corner in 0..8usize {
            let (ox, oy, oz) = (corner & 1, (corner >> 1) & 1, corner >> 2);
            let x = (base.x as usize + ox).min(self.dims[0] - 1);
            let y = (base.y as usize + oy).min(self.dims[1] - 1);
            let z = (base.z as usize + oz).min(self.dims[2] - 1);
            let w = (if ox == 1 { f.x } else { 1.0 - f.x })
                * (if oy == 1 { f.y } else { 1.0 - f.y })
                * (if oz == 1 { f.z } else { 1.0 - f.z });
            if w > 0.0 {
                acc.add(&self.rows[self.index(x, y, z)], w);
            }
        }
        acc.take()
    }

    /// Weights for many points (in parallel).
    pub fn skin_points(&self, points: &[Vec3]) -> SkinWeights {
        let rows: Vec<Row> = points.par_iter().map(|p| self.lookup(*p)).collect();
        let (bones, weights) = rows.into_iter().unzip();
        SkinWeights { bones, weights }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points on a vertical cylinder (radius 0.1, y in 0..1) blending bone 0 (bottom) into
    /// bone 1 (top) linearly, plus bone 2 on the +x side.
    fn cylinder(n: usize) -> (Vec<Vec3>, SkinWeights) {
        let mut pts = Vec::new();
        let mut skin = SkinWeights::default();
        for i in 0..n {
            let t = (i as f32 * 0.618_034).fract();
            let a = i as f32 * 2.399_963;
            let p = Vec3::new(0.1 * a.cos(), t, 0.1 * a.sin());
            let side = 0.2 * (a.cos() * 0.5 + 0.5);
            let (w0, w1) = ((1.0 - t) * (1.0 - side), t * (1.0 - side));
            pts.push(p);
            skin.bones.push([0, 1, 2, 0]);
            skin.weights.push([w0, w1, side, 0.0]);
        }
        (pts, skin)
    }

    fn dense(row: &Row) -> [f32; 3] {
        let mut d = [0.0; 3];
        for (&bone, &w) in row.0.iter().zip(&row.1) {
            if w > 0.0 {
                d[bone as usize] += w;
            }
        }
        d
    }

    #[test]
    fn volume_matches_surface_weights_at_surface_points() {
        // Tolerance: the weight field changes by at most ~1.3 per metre here, and a lookup mixes
        // nodes up to one voxel diagonal (1.7 cm) away, so errors stay below 0.03.
        let (pts, skin) = cylinder(6000);
        let vol = VoxelSkinning::from_surface(&pts, &skin, 0.01, 0.1, 10).unwrap();
        let mut max_err = 0.0f32;
        for (i, p) in pts.iter().enumerate().step_by(7) {
            let got = dense(&vol.lookup(*p));
            let want = dense(&(skin.bones[i], skin.weights[i]));
            for (g, w) in got.iter().zip(want) {
                max_err = max_err.max((g - w).abs());
            }
        }
        assert!(
            max_err < 0.03,
            "max weight error at surface points: {max_err}"
        );
    }

    #[test]
    fn off_surface_points_get_normalised_weights_of_the_nearby_bones() {
        let (pts, skin) = cylinder(3000);
        let vol = VoxelSkinning::from_surface(&pts, &skin, 0.02, 0.15, 10).unwrap();
        let w = vol.skin_points(&[
            Vec3::new(0.0, 0.9, 0.0),
            Vec3::new(0.2, 0.1, 0.0),
            Vec3::new(5.0, -3.0, 0.0),
        ]);
        for row in &w.weights {
            assert!((row.iter().sum::<f32>() - 1.0).abs() < 1e-5, "{row:?}");
        }
        let top = dense(&(w.bones[0], w.weights[0]));
        assert!(
            top[1] > 0.6,
            "a point inside near the top follows the top bone: {top:?}"
        );
        let low = dense(&(w.bones[1], w.weights[1]));
        assert!(
            low[0] > 0.6,
            "a point outside near the bottom follows the bottom bone: {low:?}"
        );
    }

    #[test]
    fn mismatched_rows_are_rejected() {
        let (pts, skin) = cylinder(10);
        let err = VoxelSkinning::from_surface(&pts[..5], &skin, 0.01, 0.1, 1).unwrap_err();
        assert_eq!(
            err,
            VoxelSkinningError::Rows {
                points: 5,
                rows: 10
            }
        );
    }
}
