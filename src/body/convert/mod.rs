//! Converter from the MakeHuman / MPFB2 source folder (`base.obj`, `rig.default.json`,
//! `weights.default.json`, `body_parts_segmentation.{png,yaml}`, `walkcycle_female.json`,
//! `poses/t-pose.json`) into the project's committed assets: `makehuman.safetensors`,
//! `walk.json` and `tpose.json` (run by `lhmpp body convert`).
//!
//! Steps: keep the faces of OBJ group `body` (quads split into two triangles, vertices
//! re-indexed in source order, one UV per vertex: the last face corner that names it); place
//! every bone head and tail on the full source mesh by the rig's CUBE (centre of a `joint-*`
//! helper group), VERTEX or MEAN strategy; scale decimetres to metres and move the origin to
//! the soles, centred between the feet; orient bones from head, tail and roll as Blender does;
//! reduce weights to the top 4; label vertices by sampling the segmentation image at their UV.

pub mod garments;
mod obj;
mod parts;
mod rig;
mod walk;
mod weights;

pub use obj::{ObjFace, ObjMesh};
pub use rig::{blender_to_canonical, canonical_to_blender, rest_orientation, vec_roll_to_mat3};
pub use walk::{convert_tpose, convert_walk};
pub use weights::top_k;

use super::{BodyError, BodyTemplate, Skeleton};
use glam::{Vec2, Vec3};
use std::path::Path;

/// Name of the canonical pose written into converted templates.
pub const CANONICAL_POSE: &str = "makehuman-a-pose";

/// OBJ group that holds the skin.
const BODY_GROUP: &str = "body";

/// Source units per metre (base.obj is in decimetres).
const SOURCE_UNITS_PER_METRE: f32 = 10.0;

/// Everything the converter writes.
#[derive(Debug, Clone)]
pub struct ConvertedAssets {
    /// The body template (`makehuman.safetensors`).
    pub template: BodyTemplate,
    /// The walk cycle's FK channels (`walk.json`).
    pub walk_json: String,
    /// The T-pose rotations (`tpose.json`).
    pub tpose_json: String,
}

fn read_text(dir: &Path, name: &str) -> Result<String, BodyError> {
    let path = dir.join(name);
    std::fs::read_to_string(&path).map_err(|e| BodyError::io(path, e))
}

/// Converts the MakeHuman source folder `dir` into the project's assets.
pub fn convert_makehuman(dir: &Path) -> Result<ConvertedAssets, BodyError> {
    let template = convert_template(dir)?;
    let walk_json = convert_walk(
        &read_text(dir, "walkcycle_female.json")?,
        &template.skeleton,
    )?;
    let tpose_json = convert_tpose(&read_text(dir, "poses/t-pose.json")?, &template.skeleton)?;
    Ok(ConvertedAssets {
        template,
        walk_json,
        tpose_json,
    })
}

/// Writes the converted assets: the template at `out` and `walk.json`, `tpose.json` beside it.
pub fn write_assets(assets: &ConvertedAssets, out: &Path) -> Result<(), BodyError> {
    assets.template.save(out)?;
    let dir = out.parent().unwrap_or(Path::new("."));
    for (name, text) in [
        ("walk.json", &assets.walk_json),
        ("tpose.json", &assets.tpose_json),
    ] {
        let path = dir.join(name);
        std::fs::write(&path, text).map_err(|e| BodyError::io(path, e))?;
    }
    Ok(())
}

/// Builds the body template from the source folder `dir`.
pub fn convert_template(dir: &Path) -> Result<BodyTemplate, BodyError> {
    let obj_path = dir.join("base.obj");
    let obj = ObjMesh::parse(
        &read_text(dir, "base.obj")?,
        &obj_path.display().to_string(),
    )?;

    // Skin faces, re-indexed in source vertex order.
    let body_faces: Vec<&ObjFace> = obj.faces.iter().filter(|f| f.group == BODY_GROUP).collect();
    if body_faces.is_empty() {
        return Err(BodyError::format(
            obj_path.display(),
            "no faces in group `body`",
        ));
    }
    let kept: Vec<usize> = obj.group_vertices(BODY_GROUP).into_iter().collect();
    let mut new_index = vec![u32::MAX; obj.positions.len()];
    for (i, &s) in kept.iter().enumerate() {
        new_index[s] = i as u32;
    }
    let mut uvs = vec![None; kept.len()];
    let mut triangles = Vec::new();
    for f in &body_faces {
        for &(v, t) in &f.corners {
            // The last face corner naming a vertex wins (vertices on UV seams have several);
            // this reproduces the part counts documented with the source assets.
            if let Some(t) = t {
                uvs[new_index[v] as usize] = Some(obj.texcoords[t]);
            }
        }
        let c: Vec<u32> = f.corners.iter().map(|c| new_index[c.0]).collect();
        for k in 1..c.len() - 1 {
            triangles.push([c[0], c[k], c[k + 1]]);
        }
    }
    let uvs: Vec<Vec2> = uvs
        .into_iter()
        .enumerate()
        .map(|(i, uv)| {
            uv.ok_or_else(|| {
                BodyError::format(
                    obj_path.display(),
                    format!("vertex {} has no UV", kept[i] + 1),
                )
            })
        })
        .collect::<Result<_, _>>()?;

    // Part labels from the segmentation image.
    let palette_path = dir.join("body_parts_segmentation.yaml");
    let palette = parts::parse_palette(
        &read_text(dir, "body_parts_segmentation.yaml")?,
        &palette_path.display().to_string(),
    )?;
    if palette.is_empty() || palette.len() > 256 {
        return Err(BodyError::format(
            palette_path.display(),
            "expected 1 to 256 part colours",
        ));
    }
    let png_path = dir.join("body_parts_segmentation.png");
    let image = image::open(&png_path)
        .map_err(|e| BodyError::format(png_path.display(), e.to_string()))?
        .to_rgb8();
    let (part_labels, inexact) = parts::label_uvs(&image, &palette, &uvs);
    if inexact > 0 {
        tracing::warn!(
            "{inexact} vertices hit no exact palette colour in {}",
            png_path.display()
        );
    }
    let part_names: Vec<String> = palette.into_iter().map(|(n, _)| n).collect();

    // Frame: decimetres → metres, soles at y = 0, centred between the feet.
    let source_vertices: Vec<Vec3> = kept.iter().map(|&s| obj.positions[s]).collect();
    let offset = canonical_offset(&source_vertices, &part_labels, &part_names);
    let to_canonical = |p: Vec3| p / SOURCE_UNITS_PER_METRE - offset;
    let vertices: Vec<Vec3> = source_vertices.iter().map(|&p| to_canonical(p)).collect();

    // Skeleton.
    let rig_path = dir.join("rig.default.json").display().to_string();
    let rig = rig::parse_rig(&read_text(dir, "rig.default.json")?, &rig_path)?;
    let order = rig::bone_order(&rig, &rig_path)?;
    let cube_centre = |name: &str| -> Option<Vec3> {
        let vs = obj.group_vertices(name);
        (!vs.is_empty())
            .then(|| vs.iter().map(|&i| obj.positions[i]).sum::<Vec3>() / vs.len() as f32)
    };
    let mut skeleton = Skeleton::default();
    let mut max_dev = 0.0f32;
    for name in &order {
        let bone = &rig[name];
        let head = rig::place_end(
            &bone.head,
            &obj.positions,
            &cube_centre,
            &format!("{name}.head"),
        )?;
        let tail = rig::place_end(
            &bone.tail,
            &obj.positions,
            &cube_centre,
            &format!("{name}.tail"),
        )?;
        let (head, tail) = (to_canonical(head), to_canonical(tail));
        let default_head =
            rig::blender_to_canonical(Vec3::from(bone.head.default_position)) - offset;
        max_dev = max_dev.max(head.distance(default_head));
        skeleton.bone_names.push(name.clone());
        skeleton
            .parents
            .push(order.iter().position(|b| *b == bone.parent));
        skeleton.joints.push(head);
        skeleton
            .rest_orientations
            .push(rig::rest_orientation(head, tail, bone.roll));
    }
    tracing::info!("joints differ from the rig's default positions by at most {max_dev:.3} m");

    let weights_path = dir.join("weights.default.json").display().to_string();
    let skin = weights::skin_weights(
        &read_text(dir, "weights.default.json")?,
        &weights_path,
        &order,
        &kept,
    )?;
    let template = BodyTemplate {
        vertices,
        triangles,
        uvs,
        part_labels,
        part_names,
        skeleton,
        skin,
        canonical_pose: CANONICAL_POSE.to_string(),
    };
    template.validate(&obj_path.display().to_string())?;
    Ok(template)
}

/// Offset (metres) that moves the lowest vertex to y = 0 and the centre of the feet's
/// bounding box (vertices labelled `foot.*`, else all vertices) to x = z = 0.
fn canonical_offset(source: &[Vec3], labels: &[u8], part_names: &[String]) -> Vec3 {
    let metres: Vec<Vec3> = source.iter().map(|p| *p / SOURCE_UNITS_PER_METRE).collect();
    let is_foot: Vec<bool> = part_names.iter().map(|n| n.starts_with("foot")).collect();
    let feet: Vec<Vec3> = metres
        .iter()
        .zip(labels)
        .filter(|(_, &l)| is_foot[l as usize])
        .map(|(p, _)| *p)
        .collect();
    let centre_set = if feet.is_empty() { &metres } else { &feet };
    let (lo, hi) = bounds(centre_set);
    let (all_lo, _) = bounds(&metres);
    Vec3::new((lo.x + hi.x) * 0.5, all_lo.y, (lo.z + hi.z) * 0.5)
}

fn bounds(points: &[Vec3]) -> (Vec3, Vec3) {
    points.iter().fold(
        (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
        |(lo, hi), p| (lo.min(*p), hi.max(*p)),
    )
}
