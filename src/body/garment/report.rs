//! How well each garment sits: its distance to the skin, and how much of its surface the
//! node's anchor points can reach (the network places each Gaussian at an anchor plus a
//! predicted offset, and the trainer's ACAP loss penalises offsets beyond 2 cm).

use super::{Garment, GarmentLibrary};
use crate::body::{point_triangle_distance, AnchorPoints, BodyTemplate, PointGrid};
use glam::Vec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Reach thresholds of [`GarmentFit::reach`] (metres).
pub const REACH_THRESHOLDS: [f32; 3] = [0.02, 0.05, 0.10];

/// Fit figures of one garment.
#[derive(Debug, Clone, PartialEq)]
pub struct GarmentFit {
    /// Garment name.
    pub name: String,
    /// Vertices.
    pub vertices: usize,
    /// Triangles.
    pub triangles: usize,
    /// Median distance of its vertices to the skin (metres).
    pub skin_median: f32,
    /// 95th percentile of that distance (metres).
    pub skin_p95: f32,
    /// Fraction of its surface (area-uniform samples) within each of [`REACH_THRESHOLDS`] of
    /// the nearest anchor.
    pub reach: [f32; 3],
    /// Fraction of the template's vertices it covers.
    pub covered: f32,
}

fn percentile(sorted: &[f32], q: f32) -> f32 {
    if sorted.is_empty() {
        return f32::NAN;
    }
    sorted[((sorted.len() - 1) as f32 * q).round() as usize]
}

/// `count` area-uniform points on the garment's rest surface, seeded.
pub fn surface_samples(garment: &Garment, count: usize, seed: u64) -> Vec<Vec3> {
    let mut cdf = Vec::with_capacity(garment.triangles.len());
    let mut total = 0.0f64;
    for t in &garment.triangles {
        let [a, b, c] = t.map(|i| garment.vertices[i as usize]);
        total += 0.5 * (b - a).cross(c - a).length() as f64;
        cdf.push(total);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..if total > 0.0 { count } else { 0 })
        .map(|_| {
            let target = rng.gen::<f64>() * total;
            let k = cdf.partition_point(|&c| c <= target).min(cdf.len() - 1);
            let (r1, r2): (f32, f32) = (rng.gen(), rng.gen());
            let s = r1.sqrt();
            let [a, b, c] = garment.triangles[k].map(|i| garment.vertices[i as usize]);
            a * (1.0 - s) + b * (s * (1.0 - r2)) + c * (s * r2)
        })
        .collect()
}

/// Distance from `p` to the skin: the triangles around the nearest skin vertex.
fn skin_distance(p: Vec3, template: &BodyTemplate, grid: &PointGrid, around: &[Vec<u32>]) -> f32 {
    let Some(v) = grid.nearest(p) else {
        return f32::NAN;
    };
    around[v]
        .iter()
        .map(|&t| {
            let [a, b, c] = template.triangles[t as usize].map(|i| template.vertices[i as usize]);
            point_triangle_distance(p, a, b, c)
        })
        .fold(p.distance(template.vertices[v]), f32::min)
}

/// The fit figures of every garment of `library` on `template`, against `anchors` (sampled on
/// the same template), with `samples` surface points per garment.
pub fn fit_report(
    library: &GarmentLibrary,
    template: &BodyTemplate,
    anchors: &AnchorPoints,
    samples: usize,
) -> Vec<GarmentFit> {
    let grid = PointGrid::for_surface(&template.vertices);
    let mut around = vec![Vec::new(); template.vertices.len()];
    for (k, t) in template.triangles.iter().enumerate() {
        for &i in t {
            around[i as usize].push(k as u32);
        }
    }
    let anchor_grid = PointGrid::for_surface(&anchors.positions);
    library
        .garments
        .iter()
        .map(|g| {
            let mut d: Vec<f32> = g
                .vertices
                .iter()
                .map(|p| skin_distance(*p, template, &grid, &around))
                .collect();
            d.sort_by(f32::total_cmp);
            let points = surface_samples(g, samples, 1);
            let reach_d: Vec<f32> = points
                .iter()
                .filter_map(|p| {
                    anchor_grid
                        .nearest(*p)
                        .map(|a| anchors.positions[a].distance(*p))
                })
                .collect();
            let share = |x: f32| {
                reach_d.iter().filter(|d| **d <= x).count() as f32 / reach_d.len().max(1) as f32
            };
            GarmentFit {
                name: g.name.clone(),
                vertices: g.vertices.len(),
                triangles: g.triangles.len(),
                skin_median: percentile(&d, 0.5),
                skin_p95: percentile(&d, 0.95),
                reach: REACH_THRESHOLDS.map(share),
                covered: g.covers.iter().filter(|c| **c).count() as f32
                    / g.covers.len().max(1) as f32,
            }
        })
        .collect()
}
