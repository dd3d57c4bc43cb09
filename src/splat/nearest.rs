//! Binds Gaussians to the skinning weights of the closest template vertex.

use crate::body::{PointGrid, SkinWeights};
use glam::Vec3;
use rayon::prelude::*;

/// Skinning weights for `points`, each copied from the nearest of `vertices` (whose weights
/// are `vertex_skin`), as LHM++ does for its query points. Points that are not finite get the
/// weights of vertex 0.
pub fn nearest_vertex_skin(
    points: &[Vec3],
    vertices: &[Vec3],
    vertex_skin: &SkinWeights,
) -> SkinWeights {
    let _span = tracing::debug_span!("nearest_vertex_skin", points = points.len()).entered();
    let grid = PointGrid::new(vertices, 0.02);
    let rows: Vec<usize> = points
        .par_iter()
        .map(|p| grid.nearest(*p).unwrap_or(0))
        .collect();
    SkinWeights {
        bones: rows.iter().map(|&v| vertex_skin.bones[v]).collect(),
        weights: rows.iter().map(|&v| vertex_skin.weights[v]).collect(),
    }
}
