//! Anchor points: area-weighted uniform samples of the template surface carrying everything
//! needed to animate them (skinning weights, part label, normal).

use super::convert::top_k;
use super::{vertex_normals, BodyTemplate, SkinWeights};
use glam::Vec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Points sampled on the template surface in the canonical pose.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct AnchorPoints {
    /// Positions (metres, canonical frame).
    pub positions: Vec<Vec3>,
    /// Unit normals (barycentric blend of the vertex normals).
    pub normals: Vec<Vec3>,
    /// Skinning weights: barycentric blend of the corners' weights, re-reduced to top 4.
    pub skin: SkinWeights,
    /// Part label of the nearest triangle corner.
    pub part_labels: Vec<u8>,
    /// Source triangle per point.
    pub triangles: Vec<u32>,
    /// Barycentric coordinates in the source triangle.
    pub barycentric: Vec<Vec3>,
}

impl AnchorPoints {
    /// Number of points.
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    /// True when there are no points.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }
}

impl BodyTemplate {
    /// Samples `n` points uniformly by area over the surface, deterministically for `seed`
    /// (ChaCha8): a triangle by inverse CDF of areas, then a uniform point inside it.
    pub fn sample_anchors(&self, n: usize, seed: u64) -> AnchorPoints {
        let mut cdf = Vec::with_capacity(self.triangles.len());
        let mut total = 0.0f64;
        for t in &self.triangles {
            let [a, b, c] = t.map(|i| self.vertices[i as usize]);
            total += 0.5 * (b - a).cross(c - a).length() as f64;
            cdf.push(total);
        }
        let normals = vertex_normals(&self.vertices, &self.triangles);
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut out = AnchorPoints::default();
        if total <= 0.0 {
            return out;
        }
        for _ in 0..n {
            let target = rng.gen::<f64>() * total;
            let tri = cdf.partition_point(|&c| c <= target).min(cdf.len() - 1);
            let (r1, r2): (f32, f32) = (rng.gen(), rng.gen());
            let s = r1.sqrt();
            let bary = Vec3::new(1.0 - s, s * (1.0 - r2), s * r2);
            let idx = self.triangles[tri].map(|i| i as usize);
            let corner = |k: usize| self.vertices[idx[k]];
            out.positions
                .push(corner(0) * bary.x + corner(1) * bary.y + corner(2) * bary.z);
            let normal =
                normals[idx[0]] * bary.x + normals[idx[1]] * bary.y + normals[idx[2]] * bary.z;
            out.normals.push(normal.normalize_or_zero());
            let mut influences = Vec::with_capacity(12);
            for (k, &v) in idx.iter().enumerate() {
                for (b, w) in self.skin.bones[v].iter().zip(&self.skin.weights[v]) {
                    influences.push((*b, w * bary[k]));
                }
            }
            let (bones, weights) = top_k(&influences)
                .unwrap_or_else(|| (self.skin.bones[idx[0]], self.skin.weights[idx[0]]));
            out.skin.bones.push(bones);
            out.skin.weights.push(weights);
            let nearest = (0..3)
                .max_by(|&a, &b| bary[a].total_cmp(&bary[b]))
                .unwrap_or(0);
            out.part_labels.push(self.part_labels[idx[nearest]]);
            out.triangles.push(tri as u32);
            out.barycentric.push(bary);
        }
        out
    }
}
