//! The MakeHuman/MPFB2 rig (`rig.default.json`): bone ends placed on the mesh by their
//! CUBE / VERTEX / MEAN strategies, bone order, and Blender rest orientations from roll.

use crate::body::BodyError;
use glam::{Mat3, Quat, Vec3};
use serde::Deserialize;
use std::collections::BTreeMap;

/// How one bone end (head or tail) is placed on the mesh.
#[derive(Debug, Clone, Deserialize)]
pub struct BoneEnd {
    /// `CUBE`, `VERTEX` or `MEAN`.
    pub strategy: String,
    /// Helper group whose vertex centre is the end (CUBE).
    #[serde(default)]
    pub cube_name: Option<String>,
    /// Vertex that is the end (VERTEX).
    #[serde(default)]
    pub vertex_index: Option<usize>,
    /// Vertices whose mean is the end (MEAN).
    #[serde(default)]
    pub vertex_indices: Option<Vec<usize>>,
    /// Blender (Z-up metres) position for the rig's own body shape; a cross-check only.
    pub default_position: [f32; 3],
}

/// One bone of the rig file.
#[derive(Debug, Clone, Deserialize)]
pub struct RigBone {
    /// Parent bone name, empty for the root.
    pub parent: String,
    /// Where the bone starts (its joint).
    pub head: BoneEnd,
    /// Where the bone points to.
    pub tail: BoneEnd,
    /// Blender roll about the head → tail axis (radians).
    pub roll: f32,
}

/// Parses `rig.default.json` text into bones by name.
pub fn parse_rig(text: &str, origin: &str) -> Result<BTreeMap<String, RigBone>, BodyError> {
    serde_json::from_str(text).map_err(|e| BodyError::format(origin, e.to_string()))
}

/// Bone names ordered parents first: depth-first from each root, children by name.
pub fn bone_order(rig: &BTreeMap<String, RigBone>, origin: &str) -> Result<Vec<String>, BodyError> {
    let mut children: BTreeMap<&str, Vec<&str>> = BTreeMap::new();
    for (name, bone) in rig {
        if !bone.parent.is_empty() && !rig.contains_key(&bone.parent) {
            return Err(BodyError::format(
                origin,
                format!("bone `{name}` has unknown parent `{}`", bone.parent),
            ));
        }
        children.entry(bone.parent.as_str()).or_default().push(name);
    }
    let mut order = Vec::with_capacity(rig.len());
    let mut stack: Vec<&str> = children.get("").cloned().unwrap_or_default();
    stack.reverse();
    while let Some(name) = stack.pop() {
        order.push(name.to_string());
        if let Some(kids) = children.get(name) {
            stack.extend(kids.iter().rev());
        }
    }
    if order.len() != rig.len() {
        return Err(BodyError::format(
            origin,
            "the rig's parent links form a cycle",
        ));
    }
    Ok(order)
}

/// Places a bone end on the (unnormalised, source-frame) mesh positions.
pub fn place_end(
    end: &BoneEnd,
    positions: &[Vec3],
    cube_centre: &dyn Fn(&str) -> Option<Vec3>,
    what: &str,
) -> Result<Vec3, BodyError> {
    let bad = |m: String| BodyError::format("rig", format!("{what}: {m}"));
    let vertex = |i: usize| {
        positions.get(i).copied().ok_or_else(|| {
            bad(format!(
                "vertex index {i} past {} vertices",
                positions.len()
            ))
        })
    };
    match end.strategy.as_str() {
        "CUBE" => {
            let name = end
                .cube_name
                .as_deref()
                .ok_or_else(|| bad("CUBE without cube_name".into()))?;
            cube_centre(name).ok_or_else(|| bad(format!("no helper group `{name}` in the mesh")))
        }
        "VERTEX" => vertex(
            end.vertex_index
                .ok_or_else(|| bad("VERTEX without vertex_index".into()))?,
        ),
        "MEAN" => {
            let idx = end
                .vertex_indices
                .as_ref()
                .filter(|v| !v.is_empty())
                .ok_or_else(|| bad("MEAN without vertex_indices".into()))?;
            let mut sum = Vec3::ZERO;
            for &i in idx {
                sum += vertex(i)?;
            }
            Ok(sum / idx.len() as f32)
        }
        other => Err(bad(format!("unknown strategy `{other}`"))),
    }
}

/// Converts a canonical-frame vector (Y up, facing +Z) into Blender axes (Z up, facing −Y).
pub fn canonical_to_blender(v: Vec3) -> Vec3 {
    Vec3::new(v.x, -v.z, v.y)
}

/// Converts a Blender-axes vector into the canonical frame.
pub fn blender_to_canonical(v: Vec3) -> Vec3 {
    Vec3::new(v.x, v.z, -v.y)
}

/// Blender's `vec_roll_to_mat3_normalized`: the bone matrix whose Y axis is `nor` (unit) with
/// the given roll, columns = bone X, Y, Z axes in the same (Blender) coordinates.
pub fn vec_roll_to_mat3(nor: Vec3, roll: f32) -> Mat3 {
    let (x, y, z) = (nor.x, nor.y, nor.z);
    let theta = 1.0 + y;
    let theta_alt = x * x + z * z;
    // Same thresholds as Blender: away from −Y use the closed form, else a flip about Z.
    let b = if theta > 1.0e-5 || ((x != 0.0 || z != 0.0) && theta > 1.0e-9) {
        let theta = if theta <= 1.0e-5 {
            theta_alt * 0.5 + theta_alt * theta_alt * 0.125
        } else {
            theta
        };
        Mat3::from_cols(
            Vec3::new(1.0 - x * x / theta, -x, -x * z / theta),
            Vec3::new(x, y, z),
            Vec3::new(-x * z / theta, -z, 1.0 - z * z / theta),
        )
    } else {
        Mat3::from_cols(
            Vec3::new(-1.0, 0.0, 0.0),
            Vec3::new(0.0, -1.0, 0.0),
            Vec3::Z,
        )
    };
    Mat3::from_quat(Quat::from_axis_angle(nor, roll)) * b
}

/// The rest orientation of a bone in canonical coordinates from its canonical head and tail
/// and its Blender roll.
pub fn rest_orientation(head: Vec3, tail: Vec3, roll: f32) -> Mat3 {
    let nor = canonical_to_blender(tail - head).normalize_or(Vec3::Z);
    let m = vec_roll_to_mat3(nor, roll);
    Mat3::from_cols(
        blender_to_canonical(m.x_axis),
        blender_to_canonical(m.y_axis),
        blender_to_canonical(m.z_axis),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bone_matrix_y_axis_points_head_to_tail_and_is_orthonormal() {
        for (nor, roll) in [
            (Vec3::new(0.3, 0.5, -0.8), 0.7),
            (Vec3::Y, 0.0),
            (Vec3::NEG_Y, 0.3),
            (Vec3::new(1e-4, -1.0, 0.0), -1.0),
        ] {
            let nor = nor.normalize();
            let m = vec_roll_to_mat3(nor, roll);
            assert!(m.y_axis.abs_diff_eq(nor, 1e-4), "{m:?}");
            assert!((m.determinant() - 1.0).abs() < 1e-4);
            assert!((m * m.transpose()).abs_diff_eq(Mat3::IDENTITY, 1e-4));
        }
    }

    #[test]
    fn zero_roll_along_y_is_identity_and_roll_turns_x_about_y() {
        assert!(vec_roll_to_mat3(Vec3::Y, 0.0).abs_diff_eq(Mat3::IDENTITY, 1e-6));
        let m = vec_roll_to_mat3(Vec3::Y, std::f32::consts::FRAC_PI_2);
        // Blender: positive roll rotates the X axis towards −Z about +Y.
        assert!(m.x_axis.abs_diff_eq(Vec3::NEG_Z, 1e-6), "{m:?}");
    }

    #[test]
    fn parents_come_before_children() {
        let text = r#"{
          "b": {"parent": "a", "roll": 0, "head": {"strategy": "VERTEX", "vertex_index": 0, "default_position": [0,0,0]}, "tail": {"strategy": "VERTEX", "vertex_index": 1, "default_position": [0,0,0]}},
          "a": {"parent": "", "roll": 0, "head": {"strategy": "VERTEX", "vertex_index": 0, "default_position": [0,0,0]}, "tail": {"strategy": "VERTEX", "vertex_index": 1, "default_position": [0,0,0]}},
          "c": {"parent": "b", "roll": 0, "head": {"strategy": "VERTEX", "vertex_index": 0, "default_position": [0,0,0]}, "tail": {"strategy": "VERTEX", "vertex_index": 1, "default_position": [0,0,0]}}
        }"#;
        let rig = parse_rig(text, "rig.json").unwrap();
        assert_eq!(bone_order(&rig, "rig.json").unwrap(), ["a", "b", "c"]);
    }
}
