//! Loader for a user-supplied SMPL-X model (`SMPLX_NEUTRAL.npz`), giving the same
//! [`BodyTemplate`] as the free MakeHuman asset.
//!
//! Keys read: `v_template` (V×3), `f` (F×3), `J_regressor` (J×V), `weights` (V×J),
//! `kintree_table` (2×J, row 0 = parents, root marked by a negative or out-of-range value) and,
//! when betas are given, `shapedirs` (V×3×B). The shaped mesh is moved into the canonical
//! frame (soles at y = 0, centred between the feet; SMPL-X is already metres, +Y up, facing
//! +Z). Bone orientations are identity (SMPL's convention is the [`Pose`] convention). Part
//! labels come from each vertex's dominant joint (head, hands, feet, body).
//!
//! [`Pose`]: super::Pose

use super::convert::top_k;
use super::{BodyError, BodyTemplate, Skeleton, SkinWeights};
use candle_core::{npy::NpzTensors, DType, Tensor};
use glam::{Mat3, Vec3};
use std::path::Path;

/// The 55 SMPL-X joint names in model order.
#[rustfmt::skip]
pub const SMPLX_JOINT_NAMES: [&str; 55] = [
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2", "left_ankle",
    "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar", "right_collar",
    "head", "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist",
    "right_wrist", "jaw", "left_eye_smplhf", "right_eye_smplhf", "left_index1", "left_index2",
    "left_index3", "left_middle1", "left_middle2", "left_middle3", "left_pinky1", "left_pinky2",
    "left_pinky3", "left_ring1", "left_ring2", "left_ring3", "left_thumb1", "left_thumb2",
    "left_thumb3", "right_index1", "right_index2", "right_index3", "right_middle1",
    "right_middle2", "right_middle3", "right_pinky1", "right_pinky2", "right_pinky3",
    "right_ring1", "right_ring2", "right_ring3", "right_thumb1", "right_thumb2", "right_thumb3",
];

/// Part names of SMPL-X templates (labels index into this).
const PART_NAMES: [&str; 6] = ["body", "head", "hand.L", "hand.R", "foot.L", "foot.R"];

/// Loads an SMPL-X npz and applies the first `betas.len()` shape blend shapes.
pub fn load_smplx(path: &Path, betas: &[f32]) -> Result<BodyTemplate, BodyError> {
    let origin = path.display().to_string();
    let npz = NpzTensors::new(path).map_err(|e| BodyError::format(&origin, e.to_string()))?;
    let get = |key: &str| -> Result<Tensor, BodyError> {
        npz.get(key)
            .map_err(|e| BodyError::format(&origin, format!("`{key}`: {e}")))?
            .ok_or_else(|| BodyError::missing(&origin, key))
    };
    let bad =
        |key: &str, e: candle_core::Error| BodyError::format(&origin, format!("`{key}`: {e}"));
    let matrix_f32 = |key: &str| -> Result<Vec<Vec<f32>>, BodyError> {
        get(key)?
            .to_dtype(DType::F32)
            .and_then(|t| t.to_vec2::<f32>())
            .map_err(|e| bad(key, e))
    };
    let matrix_i64 = |key: &str| -> Result<Vec<Vec<i64>>, BodyError> {
        get(key)?
            .to_dtype(DType::I64)
            .and_then(|t| t.to_vec2::<i64>())
            .map_err(|e| bad(key, e))
    };

    let mut vertices: Vec<Vec3> = rows3(matrix_f32("v_template")?, "v_template", &origin)?;
    let nv = vertices.len();
    if !betas.is_empty() {
        let dirs = get("shapedirs")?;
        let dims = dirs.dims().to_vec();
        if dims.len() != 3 || dims[0] != nv || dims[1] != 3 {
            return Err(BodyError::format(
                &origin,
                format!("`shapedirs` is {dims:?}, expected [{nv}, 3, B]"),
            ));
        }
        if betas.len() > dims[2] {
            return Err(BodyError::format(
                &origin,
                format!(
                    "{} betas given but `shapedirs` has {} shape components",
                    betas.len(),
                    dims[2]
                ),
            ));
        }
        // Only the components the betas use are converted (SMPL-X ships 400).
        let dirs = dirs
            .narrow(2, 0, betas.len())
            .and_then(|t| t.to_dtype(DType::F32))
            .and_then(|t| t.to_vec3::<f32>())
            .map_err(|e| bad("shapedirs", e))?;
        for (v, d) in vertices.iter_mut().zip(&dirs) {
            for (k, beta) in betas.iter().enumerate() {
                *v += Vec3::new(d[0][k], d[1][k], d[2][k]) * *beta;
            }
        }
    }
    let triangles: Vec<[u32; 3]> = matrix_i64("f")?
        .into_iter()
        .map(|r| match r[..] {
            [a, b, c] if [a, b, c].iter().all(|&i| i >= 0 && (i as usize) < nv) => {
                Ok([a as u32, b as u32, c as u32])
            }
            _ => Err(BodyError::format(
                &origin,
                format!("`f` row {r:?} is not 3 vertex indices"),
            )),
        })
        .collect::<Result<_, _>>()?;
    let regressor = matrix_f32("J_regressor")?;
    let nj = regressor.len();
    if regressor.iter().any(|r| r.len() != nv) {
        return Err(BodyError::format(&origin, "`J_regressor` is not J×V"));
    }
    let joints: Vec<Vec3> = regressor
        .iter()
        .map(|r| r.iter().zip(&vertices).map(|(w, v)| *v * *w).sum())
        .collect();
    let kintree = matrix_i64("kintree_table")?;
    if kintree.len() != 2 || kintree[0].len() != nj {
        return Err(BodyError::format(
            &origin,
            format!("`kintree_table` is not 2×{nj}"),
        ));
    }
    let parents: Vec<Option<usize>> = kintree[0]
        .iter()
        .map(|&p| usize::try_from(p).ok().filter(|&p| p < nj))
        .collect();
    let weights = matrix_f32("weights")?;
    if weights.len() != nv || weights.iter().any(|r| r.len() != nj) {
        return Err(BodyError::format(&origin, "`weights` is not V×J"));
    }
    let bone_names: Vec<String> = if nj == SMPLX_JOINT_NAMES.len() {
        SMPLX_JOINT_NAMES.iter().map(|s| s.to_string()).collect()
    } else {
        (0..nj).map(|i| format!("joint{i}")).collect()
    };
    let mut skin = SkinWeights::default();
    let mut part_labels = Vec::with_capacity(nv);
    for (i, row) in weights.iter().enumerate() {
        let infl: Vec<(u16, f32)> = row
            .iter()
            .enumerate()
            .map(|(j, w)| (j as u16, *w))
            .collect();
        let (b, w) = top_k(&infl).ok_or_else(|| {
            BodyError::format(&origin, format!("vertex {i} has no positive weight"))
        })?;
        part_labels.push(part_of(&bone_names[b[0] as usize]));
        skin.bones.push(b);
        skin.weights.push(w);
    }
    let offset = canonical_offset(&vertices, &part_labels);
    for v in &mut vertices {
        *v -= offset;
    }
    let template = BodyTemplate {
        vertices,
        triangles,
        uvs: Vec::new(),
        part_labels,
        part_names: PART_NAMES.iter().map(|s| s.to_string()).collect(),
        skeleton: Skeleton {
            bone_names,
            parents,
            joints: joints.iter().map(|j| *j - offset).collect(),
            rest_orientations: vec![Mat3::IDENTITY; nj],
        },
        skin,
        canonical_pose: "smplx-rest".to_string(),
    };
    template.validate(&origin)?;
    Ok(template)
}

fn rows3(rows: Vec<Vec<f32>>, key: &str, origin: &str) -> Result<Vec<Vec3>, BodyError> {
    rows.into_iter()
        .map(|r| match r[..] {
            [x, y, z] => Ok(Vec3::new(x, y, z)),
            _ => Err(BodyError::format(origin, format!("`{key}` is not N×3"))),
        })
        .collect()
}

/// Part label of a vertex whose dominant joint is `joint`.
fn part_of(joint: &str) -> u8 {
    let hand = ["wrist", "index", "middle", "pinky", "ring", "thumb"];
    let is_hand = hand.iter().any(|h| joint.contains(h));
    let is_foot = joint.contains("ankle") || joint.contains("foot");
    let left = joint.starts_with("left_");
    match () {
        _ if joint == "head" || joint == "jaw" || joint.contains("eye") => 1,
        _ if is_hand => {
            if left {
                2
            } else {
                3
            }
        }
        _ if is_foot => {
            if left {
                4
            } else {
                5
            }
        }
        _ => 0,
    }
}

/// Offset moving the lowest vertex to y = 0 and the feet's bounding-box centre (all vertices
/// when no foot is labelled) to x = z = 0.
fn canonical_offset(vertices: &[Vec3], labels: &[u8]) -> Vec3 {
    let feet: Vec<Vec3> = vertices
        .iter()
        .zip(labels)
        .filter(|(_, &l)| l == 4 || l == 5)
        .map(|(v, _)| *v)
        .collect();
    let set = if feet.is_empty() { vertices } else { &feet };
    let lo = set.iter().fold(Vec3::splat(f32::MAX), |a, v| a.min(*v));
    let hi = set.iter().fold(Vec3::splat(f32::MIN), |a, v| a.max(*v));
    let floor = vertices.iter().fold(f32::MAX, |a, v| a.min(v.y));
    Vec3::new((lo.x + hi.x) * 0.5, floor, (lo.z + hi.z) * 0.5)
}
