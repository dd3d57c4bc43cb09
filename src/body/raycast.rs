//! Ray casting against triangle meshes: a bounding-volume hierarchy (binary, median split on
//! the longest axis of the centroids, leaves of at most 4 triangles), every hit or
//! any hit along a ray segment, and ambient occlusion by cosine-weighted hemisphere sampling.

use glam::Vec3;
use rayon::prelude::*;

/// Most triangles in one leaf.
const LEAF_SIZE: usize = 4;

/// One intersection of a ray segment with a mesh triangle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RayHit {
    /// Ray parameter of the hit (`origin + t · direction`).
    pub t: f32,
    /// Index of the triangle in the mesh the hierarchy was built from.
    pub triangle: u32,
    /// Barycentric weights of the triangle's three corners at the hit.
    pub barycentric: Vec3,
    /// Whether the ray leaves through the triangle's front: the triangle's normal (counter-
    /// clockwise winding) points along the ray direction.
    pub exits: bool,
}

#[derive(Debug, Clone, Copy)]
struct Node {
    lo: Vec3,
    hi: Vec3,
    /// Leaf: first triangle in `order`; inner node: index of the left child (right = left + 1).
    start: u32,
    /// Triangles of a leaf; 0 for an inner node.
    count: u32,
}

/// A bounding-volume hierarchy over a triangle mesh's triangles.
#[derive(Debug, Clone, Default)]
pub struct TriangleBvh {
    nodes: Vec<Node>,
    /// Triangle corners in leaf order.
    corners: Vec<[Vec3; 3]>,
    /// Source triangle index of each entry of `corners`.
    order: Vec<u32>,
}

impl TriangleBvh {
    /// Builds the hierarchy over `triangles` (indices into `vertices`).
    pub fn new(vertices: &[Vec3], triangles: &[[u32; 3]]) -> Self {
        let tris: Vec<[Vec3; 3]> = triangles
            .iter()
            .map(|t| t.map(|i| vertices[i as usize]))
            .collect();
        let centroids: Vec<Vec3> = tris.iter().map(|t| (t[0] + t[1] + t[2]) / 3.0).collect();
        let mut order: Vec<u32> = (0..tris.len() as u32).collect();
        let mut nodes = Vec::with_capacity(2 * tris.len() / LEAF_SIZE + 1);
        if !tris.is_empty() {
            nodes.push(Node {
                lo: Vec3::ZERO,
                hi: Vec3::ZERO,
                start: 0,
                count: 0,
            });
            // (node, start, end) still to fill.
            let mut stack = vec![(0usize, 0usize, tris.len())];
            while let Some((node, start, end)) = stack.pop() {
                let (mut lo, mut hi) = (Vec3::MAX, Vec3::MIN);
                let (mut clo, mut chi) = (Vec3::MAX, Vec3::MIN);
                for &i in &order[start..end] {
                    for c in tris[i as usize] {
                        lo = lo.min(c);
                        hi = hi.max(c);
                    }
                    clo = clo.min(centroids[i as usize]);
                    chi = chi.max(centroids[i as usize]);
                }
                nodes[node].lo = lo;
                nodes[node].hi = hi;
                let extent = chi - clo;
                if end - start <= LEAF_SIZE || extent.max_element() <= 0.0 {
                    nodes[node].start = start as u32;
                    nodes[node].count = (end - start) as u32;
                    continue;
                }
                let axis = if extent.x >= extent.y && extent.x >= extent.z {
                    0
                } else if extent.y >= extent.z {
                    1
                } else {
                    2
                };
                let mid = (end - start) / 2;
                order[start..end].select_nth_unstable_by(mid, |a, b| {
                    centroids[*a as usize][axis].total_cmp(&centroids[*b as usize][axis])
                });
                let left = nodes.len();
                let blank = nodes[node];
                nodes.push(blank);
                nodes.push(blank);
                nodes[node].start = left as u32;
                nodes[node].count = 0;
                stack.push((left, start, start + mid));
                stack.push((left + 1, start + mid, end));
            }
        }
        let corners = order.iter().map(|&i| tris[i as usize]).collect();
        Self {
            nodes,
            corners,
            order,
        }
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.corners.len()
    }

    /// True when the hierarchy holds no triangle.
    pub fn is_empty(&self) -> bool {
        self.corners.is_empty()
    }

    /// Calls `visit` for every leaf entry whose box the segment `origin + t · direction`,
    /// `t ∈ (0, t_max]`, crosses; stops when `visit` returns true (and returns true).
    fn walk(
        &self,
        origin: Vec3,
        direction: Vec3,
        t_max: f32,
        mut visit: impl FnMut(usize) -> bool,
    ) -> bool {
        if self.nodes.is_empty() {
            return false;
        }
        let inv = direction.recip();
        let mut stack = [0u32; 64];
        let mut top = 1usize;
        while top > 0 {
            top -= 1;
            let node = self.nodes[stack[top] as usize];
            let t0 = (node.lo - origin) * inv;
            let t1 = (node.hi - origin) * inv;
            let near = t0.min(t1).max_element().max(0.0);
            let far = t0.max(t1).min_element().min(t_max);
            // NaN (a zero direction component on the slab's plane) counts as a crossing.
            if near > far {
                continue;
            }
            if node.count > 0 {
                let s = node.start as usize;
                for k in s..s + node.count as usize {
                    if visit(k) {
                        return true;
                    }
                }
            } else if top + 2 <= stack.len() {
                stack[top] = node.start;
                stack[top + 1] = node.start + 1;
                top += 2;
            }
        }
        false
    }

    /// The hit of the segment with leaf entry `k`, if any.
    fn intersect(&self, k: usize, origin: Vec3, direction: Vec3, t_max: f32) -> Option<RayHit> {
        // Möller–Trumbore, two-sided.
        let [a, b, c] = self.corners[k];
        let (e1, e2) = (b - a, c - a);
        let p = direction.cross(e2);
        let det = e1.dot(p);
        if det.abs() < 1e-12 {
            return None;
        }
        let inv = 1.0 / det;
        let s = origin - a;
        let u = s.dot(p) * inv;
        if !(0.0..=1.0).contains(&u) {
            return None;
        }
        let q = s.cross(e1);
        let v = direction.dot(q) * inv;
        if v < 0.0 || u + v > 1.0 {
            return None;
        }
        let t = e2.dot(q) * inv;
        (t > 0.0 && t <= t_max).then(|| RayHit {
            t,
            triangle: self.order[k],
            barycentric: Vec3::new(1.0 - u - v, u, v),
            // det = (d × e2) · e1 = −d · (e1 × e2): negative when the ray runs along the normal.
            exits: det < 0.0,
        })
    }

    /// Every hit of the segment `origin + t · direction`, `t ∈ (0, t_max]`, appended to `out`
    /// (unsorted).
    pub fn hits(&self, origin: Vec3, direction: Vec3, t_max: f32, out: &mut Vec<RayHit>) {
        self.walk(origin, direction, t_max, |k| {
            if let Some(hit) = self.intersect(k, origin, direction, t_max) {
                out.push(hit);
            }
            false
        });
    }

    /// Whether the segment `origin + t · direction`, `t ∈ (0, t_max]`, hits any triangle.
    pub fn any_hit(&self, origin: Vec3, direction: Vec3, t_max: f32) -> bool {
        self.walk(origin, direction, t_max, |k| {
            self.intersect(k, origin, direction, t_max).is_some()
        })
    }

    /// The nearest hit of the segment, if any.
    pub fn first_hit(&self, origin: Vec3, direction: Vec3, t_max: f32) -> Option<RayHit> {
        let mut best: Option<RayHit> = None;
        let mut limit = t_max;
        self.walk(origin, direction, t_max, |k| {
            if let Some(hit) = self.intersect(k, origin, direction, limit) {
                if best.is_none_or(|b| hit.t < b.t) {
                    limit = hit.t;
                    best = Some(hit);
                }
            }
            false
        });
        best
    }
}

/// `count` fixed unit directions of a cosine-weighted hemisphere around +Z (a Fibonacci spiral
/// over the unit disc lifted onto the hemisphere: deterministic, evenly spread).
pub fn cosine_hemisphere(count: usize) -> Vec<Vec3> {
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    (0..count)
        .map(|i| {
            let r = ((i as f32 + 0.5) / count as f32).sqrt();
            let phi = golden * i as f32;
            let (x, y) = (r * phi.cos(), r * phi.sin());
            Vec3::new(x, y, (1.0 - r * r).max(0.0).sqrt())
        })
        .collect()
}

/// Ambient occlusion of surface points: the fraction of `rays` cosine-weighted hemisphere
/// directions around each normal that leave the scene unblocked within `range` metres (1 =
/// open, 0 = enclosed). Rays start 1 mm above the surface; each point's ray set is turned by a
/// per-point angle about its normal so neighbours do not share a banding pattern.
pub fn ambient_occlusion(
    scene: &TriangleBvh,
    points: &[Vec3],
    normals: &[Vec3],
    rays: usize,
    range: f32,
) -> Vec<f32> {
    let dirs = cosine_hemisphere(rays.max(1));
    points
        .par_iter()
        .zip(normals)
        .enumerate()
        .map(|(i, (p, n))| {
            let n = n.normalize_or(Vec3::Y);
            let (t, b) = n.any_orthonormal_pair();
            let turn = (i as f32 * 2.399_963).sin_cos();
            let (t, b) = (t * turn.1 + b * turn.0, b * turn.1 - t * turn.0);
            let origin = *p + n * 1e-3;
            let open = dirs
                .iter()
                .filter(|d| !scene.any_hit(origin, t * d.x + b * d.y + n * d.z, range))
                .count();
            open as f32 / dirs.len() as f32
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// A closed unit cube centred at the origin, outward-facing.
    fn cube() -> (Vec<Vec3>, Vec<[u32; 3]>) {
        let v: Vec<Vec3> = (0..8)
            .map(|i| {
                Vec3::new(
                    if i & 1 == 0 { -0.5 } else { 0.5 },
                    if i & 2 == 0 { -0.5 } else { 0.5 },
                    if i & 4 == 0 { -0.5 } else { 0.5 },
                )
            })
            .collect();
        let quads = [
            [0, 2, 3, 1],
            [4, 5, 7, 6],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 4, 6, 2],
            [1, 3, 7, 5],
        ];
        let t = quads
            .iter()
            .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
            .collect();
        (v, t)
    }

    #[test]
    fn a_ray_through_a_cube_enters_then_exits() {
        let (v, t) = cube();
        let bvh = TriangleBvh::new(&v, &t);
        let mut hits = Vec::new();
        bvh.hits(Vec3::new(0.1, 0.2, -2.0), Vec3::Z, 10.0, &mut hits);
        hits.sort_by(|a, b| a.t.total_cmp(&b.t));
        assert_eq!(hits.len(), 2, "{hits:?}");
        assert!((hits[0].t - 1.5).abs() < 1e-5 && !hits[0].exits);
        assert!((hits[1].t - 2.5).abs() < 1e-5 && hits[1].exits);
        let first = bvh.first_hit(Vec3::new(0.1, 0.2, -2.0), Vec3::Z, 10.0);
        assert_eq!(first.map(|h| h.triangle), Some(hits[0].triangle));
        assert!(!bvh.any_hit(Vec3::new(0.1, 0.2, -2.0), Vec3::Z, 1.4));
        assert!(!bvh.any_hit(Vec3::new(0.7, 0.2, -2.0), Vec3::Z, 10.0));
        // From inside, the only hit is an exit.
        let out = bvh
            .first_hit(Vec3::ZERO, Vec3::new(1.0, 0.3, 0.1), 10.0)
            .unwrap();
        assert!(out.exits && (out.t - 0.5).abs() < 1e-5);
    }

    #[test]
    fn the_hierarchy_finds_what_brute_force_finds() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let v: Vec<Vec3> = (0..600)
            .map(|_| Vec3::new(rng.gen(), rng.gen(), rng.gen()))
            .collect();
        let t: Vec<[u32; 3]> = (0..200).map(|k| [3 * k, 3 * k + 1, 3 * k + 2]).collect();
        let bvh = TriangleBvh::new(&v, &t);
        let flat = TriangleBvh {
            nodes: vec![Node {
                lo: Vec3::splat(-1.0),
                hi: Vec3::splat(2.0),
                start: 0,
                count: t.len() as u32,
            }],
            corners: t.iter().map(|x| x.map(|i| v[i as usize])).collect(),
            order: (0..t.len() as u32).collect(),
        };
        for _ in 0..300 {
            let o = Vec3::new(rng.gen(), rng.gen(), rng.gen()) * 1.4 - 0.2;
            let d = Vec3::new(rng.gen(), rng.gen(), rng.gen()) * 2.0 - 1.0;
            let (mut a, mut b) = (Vec::new(), Vec::new());
            bvh.hits(o, d, 0.8, &mut a);
            flat.hits(o, d, 0.8, &mut b);
            let key = |h: &Vec<RayHit>| {
                let mut k: Vec<u32> = h.iter().map(|x| x.triangle).collect();
                k.sort();
                k
            };
            assert_eq!(key(&a), key(&b));
            assert_eq!(bvh.any_hit(o, d, 0.8), !b.is_empty());
        }
    }

    #[test]
    fn occlusion_is_open_on_a_plane_and_closed_inside_a_box() {
        let (v, t) = cube();
        let bvh = TriangleBvh::new(&v, &t);
        let ao = ambient_occlusion(
            &bvh,
            &[Vec3::new(0.0, 0.5, 0.0), Vec3::ZERO],
            &[Vec3::Y, Vec3::Y],
            32,
            5.0,
        );
        assert_eq!(ao, vec![1.0, 0.0]);
        let dirs = cosine_hemisphere(64);
        let mean_z = dirs.iter().map(|d| d.z).sum::<f32>() / 64.0;
        // E[cos θ] under a cosine-weighted hemisphere is 2/3.
        assert!((mean_z - 2.0 / 3.0).abs() < 0.02, "{mean_z}");
    }
}
