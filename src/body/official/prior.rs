//! The LHM++ body prior assembled from the user's `LHMPP-Prior` download: SMPL-X template,
//! 160K canonical query points, their neutral-pose positions and normals (the network input),
//! and diffused-volume skinning weights.

use std::path::{Path, PathBuf};

use candle_core::{npy::NpzTensors, DType};
use glam::{Mat4, Quat, Vec3};
use rayon::prelude::*;

use super::nearest::nearest_indices;
use super::ply_points::read_ply_points;
use super::volume::BlendWeightVolume;
use crate::body::{load_smplx, vertex_normals, BodyError, BodyTemplate, Pose, SkinWeights};

/// Query points, relative to the prior folder (`cano_pose_type` 1, 160000 points).
pub const POINTS_FILE: &str = "dense_sample_points/1_160000.ply";
/// Diffused skinning volume, relative to the prior folder.
pub const VOLUME_FILE: &str = "voxel_grid/cano_1_volume.npz";
/// SMPL-X neutral model, relative to the prior folder.
pub const SMPLX_FILE: &str = "human_model_files/smplx/SMPLX_NEUTRAL.npz";
/// Body-model id of avatars bound to the SMPL-X prior (PLY comments, messages).
pub const SMPLX_MODEL_ID: &str = "smplx-lhmpp-prior";
/// Hip rotation of the official canonical pose (`cano_pose_type` 1): ±π/9 about z.
pub const NEUTRAL_HIP_ANGLE: f32 = std::f32::consts::PI / 9.0;
/// Body points per head point in the query-point file (`body_face_ratio`): the first 3/4
/// of the points are body, the rest head.
pub const BODY_FACE_RATIO: usize = 3;

/// Paths of the prior files.
#[derive(Debug, Clone, PartialEq)]
pub struct PriorPaths {
    /// Canonical query points (PLY).
    pub points: PathBuf,
    /// Diffused skinning volume (npz).
    pub volume: PathBuf,
    /// SMPL-X model (npz).
    pub smplx: PathBuf,
}

impl PriorPaths {
    /// The official layout under `dir` (the `pretrained_models` folder of the download).
    pub fn in_dir(dir: &Path) -> Self {
        Self {
            points: dir.join(POINTS_FILE),
            volume: dir.join(VOLUME_FILE),
            smplx: dir.join(SMPLX_FILE),
        }
    }

    /// Errors naming the first missing file.
    pub fn check(&self) -> Result<(), BodyError> {
        for p in [&self.points, &self.volume, &self.smplx] {
            if !p.is_file() {
                return Err(BodyError::format(
                    p.display(),
                    "file not found (part of the LHMPP-Prior / SMPL-X download; see the README \
                     section \"Official LHM++ weights\")",
                ));
            }
        }
        Ok(())
    }
}

/// The official canonical pose (legs apart): hips rotated ±π/9 about z.
pub fn neutral_pose() -> Pose {
    let mut pose = Pose::identity();
    pose.rotations
        .insert("left_hip".into(), Quat::from_rotation_z(NEUTRAL_HIP_ANGLE));
    pose.rotations.insert(
        "right_hip".into(),
        Quat::from_rotation_z(-NEUTRAL_HIP_ANGLE),
    );
    pose
}

/// The prior in our canonical frame (the SMPL-X model frame shifted by `model_offset`).
#[derive(Debug, Clone)]
pub struct OfficialPrior {
    /// SMPL-X template (zero betas, zero pose), canonical frame.
    pub template: BodyTemplate,
    /// SMPL-X model-frame position of the canonical origin (model = canonical + offset).
    pub model_offset: Vec3,
    /// Query points in the zero pose (as stored in the PLY), canonical frame.
    pub rest_points: Vec<Vec3>,
    /// Query points in the neutral pose: the network input.
    pub query_points: Vec<Vec3>,
    /// Unit normals at the query points (nearest template vertex, posed).
    pub query_normals: Vec<Vec3>,
    /// Skinning weights per point: the volume at the neutral-pose point; hand and head points
    /// keep their nearest vertex's weights.
    pub skin: SkinWeights,
    /// True for body points (the first 3/4 of the file), false for head points.
    pub is_body: Vec<bool>,
    /// Per point: maps neutral-pose positions back to the zero (rest) pose.
    rest_from_neutral: Vec<Mat4>,
}

impl OfficialPrior {
    /// Loads the prior files named by `paths`.
    pub fn load(paths: &PriorPaths) -> Result<Self, BodyError> {
        paths.check()?;
        let template = load_smplx(&paths.smplx, &[])?;
        let model_offset = model_offset(&paths.smplx, &template)?;
        let points = read_ply_points(&paths.points)?;
        let volume = BlendWeightVolume::load(&paths.volume)?;
        if volume.joints != template.skeleton.len() {
            return Err(BodyError::format(
                paths.volume.display(),
                format!(
                    "volume has {} joints, the SMPL-X model {} ({})",
                    volume.joints,
                    template.skeleton.len(),
                    paths.smplx.display()
                ),
            ));
        }
        let rest: Vec<Vec3> = points.iter().map(|p| *p - model_offset).collect();
        Ok(Self::from_parts(template, model_offset, rest, &volume))
    }

    /// Builds the prior from a template, its model offset, zero-pose points (canonical
    /// frame) and the skinning volume (model frame).
    pub fn from_parts(
        template: BodyTemplate,
        model_offset: Vec3,
        rest_points: Vec<Vec3>,
        volume: &BlendWeightVolume,
    ) -> Self {
        let n = rest_points.len();
        let nearest = nearest_indices(&rest_points, &template.vertices);
        let normals = vertex_normals(&template.vertices, &template.triangles);
        let mats = template.skeleton.skinning_matrices(&neutral_pose());
        let head = template.part_names.iter().position(|p| p == "head");
        let is_hand_or_head = |label: u8| {
            let name = template.part_names.get(label as usize).map(String::as_str);
            Some(label as usize) == head || name.is_some_and(|n| n.starts_with("hand"))
        };
        let rows: Vec<_> = (0..n)
            .into_par_iter()
            .map(|i| {
                let v = nearest[i] as usize;
                let m_nn = template.skin.blended(v, &mats);
                let q = m_nn.transform_point3(rest_points[i]);
                let normal = m_nn.transform_vector3(normals[v]).normalize_or_zero();
                let nn_row = (template.skin.bones[v], template.skin.weights[v]);
                let row = if is_hand_or_head(template.part_labels[v]) {
                    nn_row
                } else {
                    volume.top_weights(q + model_offset).unwrap_or(nn_row)
                };
                (q, normal, row)
            })
            .collect();
        let mut skin = SkinWeights::default();
        let mut query_points = Vec::with_capacity(n);
        let mut query_normals = Vec::with_capacity(n);
        for (q, normal, (b, w)) in rows {
            query_points.push(q);
            query_normals.push(normal);
            skin.bones.push(b);
            skin.weights.push(w);
        }
        let rest_from_neutral = (0..n)
            .into_par_iter()
            .map(|i| skin.blended(i, &mats).inverse())
            .collect();
        let body_points = n / (BODY_FACE_RATIO + 1) * BODY_FACE_RATIO;
        Self {
            template,
            model_offset,
            rest_points,
            query_points,
            query_normals,
            skin,
            is_body: (0..n).map(|i| i < body_points).collect(),
            rest_from_neutral,
        }
    }

    /// Number of query points.
    pub fn len(&self) -> usize {
        self.rest_points.len()
    }

    /// True when there is no point.
    pub fn is_empty(&self) -> bool {
        self.rest_points.is_empty()
    }

    /// Keeps `n` points evenly spread over the file order (body/head ratio kept); all when
    /// `n` is 0 or not smaller than [`OfficialPrior::len`].
    pub fn subsample(&self, n: usize) -> Self {
        let len = self.len();
        if n == 0 || n >= len {
            return self.clone();
        }
        let idx: Vec<usize> = (0..n).map(|k| k * len / n).collect();
        let pick = |v: &[Vec3]| idx.iter().map(|&i| v[i]).collect::<Vec<_>>();
        Self {
            template: self.template.clone(),
            model_offset: self.model_offset,
            rest_points: pick(&self.rest_points),
            query_points: pick(&self.query_points),
            query_normals: pick(&self.query_normals),
            skin: SkinWeights {
                bones: idx.iter().map(|&i| self.skin.bones[i]).collect(),
                weights: idx.iter().map(|&i| self.skin.weights[i]).collect(),
            },
            is_body: idx.iter().map(|&i| self.is_body[i]).collect(),
            rest_from_neutral: idx.iter().map(|&i| self.rest_from_neutral[i]).collect(),
        }
    }

    /// Moves a Gaussian of point `i` from the neutral pose (where the network predicts it) to
    /// the template's rest pose: position and rotation.
    pub fn to_rest(&self, i: usize, position: Vec3, rotation: Quat) -> (Vec3, Quat) {
        let m = self.rest_from_neutral[i];
        let (_, r, _) = m.to_scale_rotation_translation();
        (m.transform_point3(position), (r * rotation).normalize())
    }
}

/// `v_template[0]` in the model frame minus the same vertex in the canonical template.
fn model_offset(path: &Path, template: &BodyTemplate) -> Result<Vec3, BodyError> {
    let origin = path.display().to_string();
    let npz = NpzTensors::new(path).map_err(|e| BodyError::format(&origin, e.to_string()))?;
    let v = npz
        .get("v_template")
        .map_err(|e| BodyError::format(&origin, format!("`v_template`: {e}")))?
        .ok_or_else(|| BodyError::missing(&origin, "v_template"))?;
    let first = v
        .narrow(0, 0, 1)
        .and_then(|t| t.to_dtype(DType::F32))
        .and_then(|t| t.flatten_all())
        .and_then(|t| t.to_vec1::<f32>())
        .map_err(|e| BodyError::format(&origin, format!("`v_template`: {e}")))?;
    let model = Vec3::from_slice(&first[..3]);
    Ok(model - template.vertices[0])
}
