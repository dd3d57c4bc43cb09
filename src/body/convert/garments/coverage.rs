//! What each garment covers and how enclosed each of its vertices is, in the rest pose on the
//! template: skin coverage by rays along the skin's normals, ambient occlusion by hemisphere
//! sampling against the garment and the body.

use super::Piece;
use crate::body::garment::{covered, shading_normals, Garment};
use crate::body::raycast::{ambient_occlusion, TriangleBvh};
use crate::body::{vertex_normals, BodyTemplate, PointGrid};
use glam::Vec3;
use rayon::prelude::*;

/// Hemisphere rays per vertex for ambient occlusion.
pub const OCCLUSION_RAYS: usize = 24;

/// Reach of the occlusion rays (metres).
pub const OCCLUSION_RANGE: f32 = 0.25;

/// The naked template prepared for ray casting and nearest-vertex queries.
pub struct BodyScene<'a> {
    /// The template.
    pub template: &'a BodyTemplate,
    /// Its unit vertex normals.
    pub normals: Vec<Vec3>,
    /// Its triangles.
    pub bvh: TriangleBvh,
    /// Its vertices.
    pub grid: PointGrid,
    /// Mean of the head's vertices (hair normals point away from it).
    pub head_centre: Vec3,
}

impl<'a> BodyScene<'a> {
    /// Prepares `template`.
    pub fn new(template: &'a BodyTemplate) -> Self {
        let head = template.part_names.iter().position(|n| n == "head");
        let on_head: Vec<Vec3> = template
            .vertices
            .iter()
            .zip(&template.part_labels)
            .filter(|(_, l)| Some(**l as usize) == head)
            .map(|(v, _)| *v)
            .collect();
        let head_centre = if on_head.is_empty() {
            Vec3::new(0.0, 0.93 * template.height(), 0.0)
        } else {
            on_head.iter().sum::<Vec3>() / on_head.len() as f32
        };
        Self {
            template,
            normals: vertex_normals(&template.vertices, &template.triangles),
            bvh: TriangleBvh::new(&template.vertices, &template.triangles),
            grid: PointGrid::for_surface(&template.vertices),
            head_centre,
        }
    }

    /// Ambient occlusion of the naked template per vertex.
    pub fn occlusion(&self) -> Vec<f32> {
        ambient_occlusion(
            &self.bvh,
            &self.template.vertices,
            &self.normals,
            OCCLUSION_RAYS,
            OCCLUSION_RANGE,
        )
    }
}

/// The library garment of `piece`: the skin it covers and its vertices' ambient occlusion.
pub fn finish(piece: Piece, body: &BodyScene) -> Garment {
    let own = TriangleBvh::new(&piece.vertices, &piece.triangles);
    let two_sided = piece.kind.two_sided();
    let covers = body
        .template
        .vertices
        .par_iter()
        .zip(&body.normals)
        .map(|(v, n)| covered(&own, two_sided, &body.bvh, *v, *n))
        .collect();
    let b = body.template.vertices.len() as u32;
    let mut scene_vertices = body.template.vertices.clone();
    scene_vertices.extend(&piece.vertices);
    let mut scene_triangles = body.template.triangles.clone();
    scene_triangles.extend(piece.triangles.iter().map(|t| t.map(|i| i + b)));
    let scene = TriangleBvh::new(&scene_vertices, &scene_triangles);
    let normals = shading_normals(
        piece.kind,
        &piece.vertices,
        &piece.triangles,
        body.head_centre,
    );
    let occlusion = ambient_occlusion(
        &scene,
        &piece.vertices,
        &normals,
        OCCLUSION_RAYS,
        OCCLUSION_RANGE,
    );
    Garment {
        name: piece.name,
        kind: piece.kind,
        source: piece.source,
        vertices: piece.vertices,
        triangles: piece.triangles,
        skin: piece.skin,
        binding: piece.binding,
        regions: piece.regions,
        occlusion,
        covers,
    }
}
