//! What the avatar's Gaussians are on the body's surface: each one's canonical normal and body
//! part (those of the nearest template vertex), and which of them a light cannot reach past
//! the others (cast shadows). Shared by colouring from photos and by refinement.

use crate::avatar::Avatar;
use crate::body::BodyTemplate;
use glam::{IVec3, Vec3};
use std::collections::HashSet;

/// Each Gaussian's canonical surface normal and body part: those of the template's vertex
/// nearest to it.
pub fn canonical_normals(avatar: &Avatar, template: &BodyTemplate) -> (Vec<Vec3>, Vec<u8>) {
    let normals = crate::body::vertex_normals(&template.vertices, &template.triangles);
    let grid = crate::body::PointGrid::for_surface(&template.vertices);
    avatar
        .canonical
        .positions
        .iter()
        .map(|p| {
            grid.nearest(*p).map_or((Vec3::ZERO, 0), |v| {
                (
                    normals[v],
                    template.part_labels.get(v).copied().unwrap_or(0),
                )
            })
        })
        .unzip()
}

/// Side (metres) of the cells that block the key light.
pub const SHADOW_CELL: f32 = 0.03;

/// Cells holding a posed Gaussian.
pub fn occupied_cells(positions: &[Vec3]) -> HashSet<IVec3> {
    positions
        .iter()
        .filter(|p| p.is_finite())
        .map(|p| (*p / SHADOW_CELL).floor().as_ivec3())
        .collect()
}

/// Whether the ray from `from` towards unit `dir` meets an occupied cell: stepped every 2 cm
/// from 6 cm (clear of the surface the point lies on) to 1.2 m.
pub fn in_shadow(cells: &HashSet<IVec3>, from: Vec3, dir: Vec3) -> bool {
    let start = (from / SHADOW_CELL).floor().as_ivec3();
    (3..60).any(|k| {
        let q = ((from + dir * (k as f32 * 0.02)) / SHADOW_CELL)
            .floor()
            .as_ivec3();
        q != start && cells.contains(&q)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_point_behind_a_blocker_is_in_the_key_lights_shadow() {
        // A slab of points 30 cm above the origin.
        let slab: Vec<Vec3> = (-5..=5)
            .flat_map(|x| (-5..=5).map(move |z| Vec3::new(x as f32 * 0.02, 0.3, z as f32 * 0.02)))
            .collect();
        let cells = occupied_cells(&slab);
        assert!(in_shadow(&cells, Vec3::ZERO, Vec3::Y));
        assert!(!in_shadow(&cells, Vec3::ZERO, Vec3::X));
        assert!(!in_shadow(&cells, Vec3::new(0.5, 0.0, 0.0), Vec3::Y));
        // The point's own surface does not shadow it.
        assert!(!in_shadow(
            &occupied_cells(&[Vec3::ZERO]),
            Vec3::ZERO,
            Vec3::Y
        ));
    }
}
