//! The LHM++ body prior assembled from the user's `LHMPP-Prior` download: SMPL-X template,
//! 160K canonical query points, their neutral-pose positions and normals (the network input),
//! and diffused-volume skinning weights.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use candle_core::{npy::NpzTensors, DType};
use glam::{Mat4, Quat, Vec3};
use rayon::prelude::*;

use super::ply_points::read_ply_points;
use super::volume::BlendWeightVolume;
use crate::body::motion::official::SmplxFrame;
use crate::body::{
    load_smplx, vertex_normals, BodyError, BodyTemplate, Pose, SkinWeights, MAX_INFLUENCES,
};

/// One sparse skinning row: bones and weights.
pub type SkinRow = ([u16; MAX_INFLUENCES], [f32; MAX_INFLUENCES]);

/// SMPL-X joints whose vertices form the official "upper body" (spine 1–3, collars,
/// shoulders, elbows, wrists; `base_skinning.py` `joint_part["upper_body"]`).
pub const UPPER_BODY_JOINTS: [usize; 11] = [3, 6, 9, 13, 14, 16, 17, 18, 19, 20, 21];

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
                return Err(BodyError::format(p.display(), missing_file_hint(p)));
            }
        }
        Ok(())
    }
}

/// What to do about a missing prior file: the download that brings it, into the folder the
/// node looks in (or, for a SMPL-X file outside the official layout, the setting that names it).
fn missing_file_hint(path: &Path) -> String {
    let dir = [POINTS_FILE, VOLUME_FILE, SMPLX_FILE]
        .iter()
        .find_map(|rel| {
            let rel = Path::new(rel);
            path.ends_with(rel).then(|| {
                path.ancestors()
                    .nth(rel.components().count())
                    .unwrap_or(Path::new("."))
                    .to_path_buf()
            })
        });
    match dir {
        Some(dir) => format!(
            "file not found: it is part of the LHMPP-Prior download (SMPL-X licence): \
             `huggingface-cli download 3DAIGC/LHMPP-Prior --local-dir {}` \
             (docs/model.md, \"Official LHM++ weights\")",
            dir.display()
        ),
        None => "file not found: point model.smplx_model at your SMPL-X .npz \
                 (docs/model.md, \"Official LHM++ weights\")"
            .to_owned(),
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
    /// Skinning weights at the query points: the volume; hand and head points keep their
    /// nearest vertex's weights.
    pub skin: SkinWeights,
    /// True for body points (the first 3/4 of the file), false for head points.
    pub is_body: Vec<bool>,
    /// Points on the hands (nearest vertex labelled `hand.*`): the official decoder fixes
    /// their opacity (`model::gs_head::HAND_OPACITY`).
    pub is_hand: Vec<bool>,
    /// Points whose nearest vertex is dominated by an [`UPPER_BODY_JOINTS`] joint: the
    /// official decoder clamps their scales (`model::gs_head::UPPER_BODY_MAX_SCALE`).
    pub is_upper_body: Vec<bool>,
    /// Points skinned by their nearest vertex instead of the volume (hands and head).
    fixed: Vec<bool>,
    /// Nearest-vertex skinning row per point.
    nearest_rows: Vec<SkinRow>,
    /// Per joint: rest (zero) pose → neutral pose.
    neutral_mats: Vec<Mat4>,
    volume: Arc<BlendWeightVolume>,
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
        Ok(Self::from_parts(template, model_offset, rest, volume))
    }

    /// Builds the prior from a template, its model offset, zero-pose points (canonical
    /// frame) and the skinning volume (model frame).
    pub fn from_parts(
        template: BodyTemplate,
        model_offset: Vec3,
        rest_points: Vec<Vec3>,
        volume: BlendWeightVolume,
    ) -> Self {
        let n = rest_points.len();
        let grid = crate::body::PointGrid::for_surface(&template.vertices);
        let nearest: Vec<u32> = rest_points
            .par_iter()
            .map(|q| grid.nearest(*q).unwrap_or(0) as u32)
            .collect();
        let normals = vertex_normals(&template.vertices, &template.triangles);
        let neutral_mats = template.skeleton.skinning_matrices(&neutral_pose());
        let part = |v: usize| {
            template
                .part_names
                .get(template.part_labels[v] as usize)
                .map_or("", String::as_str)
        };
        let mut prior = Self {
            model_offset,
            rest_points,
            query_points: Vec::with_capacity(n),
            query_normals: Vec::with_capacity(n),
            skin: SkinWeights::default(),
            is_body: Vec::with_capacity(n),
            is_hand: Vec::with_capacity(n),
            is_upper_body: Vec::with_capacity(n),
            fixed: Vec::with_capacity(n),
            nearest_rows: Vec::with_capacity(n),
            neutral_mats,
            volume: Arc::new(volume),
            template: BodyTemplate::default(),
        };
        let body_points = n / (BODY_FACE_RATIO + 1) * BODY_FACE_RATIO;
        for (i, &v) in nearest.iter().enumerate() {
            let v = v as usize;
            let m = template.skin.blended(v, &prior.neutral_mats);
            prior
                .query_points
                .push(m.transform_point3(prior.rest_points[i]));
            prior
                .query_normals
                .push(m.transform_vector3(normals[v]).normalize_or_zero());
            let row = (template.skin.bones[v], template.skin.weights[v]);
            let hand = part(v).starts_with("hand");
            prior.is_body.push(i < body_points);
            prior.is_hand.push(hand);
            prior
                .is_upper_body
                .push(UPPER_BODY_JOINTS.contains(&(row.0[0] as usize)));
            prior.fixed.push(hand || part(v) == "head");
            prior.nearest_rows.push(row);
        }
        prior.template = template;
        let rows: Vec<SkinRow> = (0..n)
            .into_par_iter()
            .map(|i| prior.row_at(i, prior.query_points[i]))
            .collect();
        (prior.skin.bones, prior.skin.weights) = rows.into_iter().unzip();
        prior
    }

    /// Skinning row of a Gaussian of point `i` at neutral-pose position `p`: the volume there,
    /// or the nearest vertex's row for hand and head points.
    pub fn row_at(&self, i: usize, p: Vec3) -> SkinRow {
        if self.fixed[i] {
            return self.nearest_rows[i];
        }
        self.volume
            .top_weights(p + self.model_offset)
            .unwrap_or(self.nearest_rows[i])
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
        fn pick<T: Copy>(v: &[T], idx: &[usize]) -> Vec<T> {
            idx.iter().map(|&i| v[i]).collect()
        }
        Self {
            template: self.template.clone(),
            model_offset: self.model_offset,
            rest_points: pick(&self.rest_points, &idx),
            query_points: pick(&self.query_points, &idx),
            query_normals: pick(&self.query_normals, &idx),
            skin: SkinWeights {
                bones: pick(&self.skin.bones, &idx),
                weights: pick(&self.skin.weights, &idx),
            },
            is_body: pick(&self.is_body, &idx),
            is_hand: pick(&self.is_hand, &idx),
            is_upper_body: pick(&self.is_upper_body, &idx),
            fixed: pick(&self.fixed, &idx),
            nearest_rows: pick(&self.nearest_rows, &idx),
            neutral_mats: self.neutral_mats.clone(),
            volume: self.volume.clone(),
        }
    }

    /// Moves a Gaussian of point `i` predicted at neutral-pose `position` with `rotation` to
    /// the template's rest pose, as the official `transform_to_posed_verts_from_neutral_pose`
    /// does: the skinning row at its position ([`OfficialPrior::row_at`]) blends the inverse
    /// neutral-pose joint transforms. Returns the rest position, rotation and that row (the
    /// Gaussian's skinning weights from then on).
    pub fn to_rest(&self, i: usize, position: Vec3, rotation: Quat) -> (Vec3, Quat, SkinRow) {
        let row = self.row_at(i, position);
        let mut m = Mat4::ZERO;
        for (b, w) in row.0.iter().zip(&row.1) {
            if *w > 0.0 {
                m += self.neutral_mats[*b as usize] * *w;
            }
        }
        let m = m.inverse();
        let (_, r, _) = m.to_scale_rotation_translation();
        (
            m.transform_point3(position),
            (r * rotation).normalize(),
            row,
        )
    }

    /// [`OfficialPrior::to_rest`] for every Gaussian (one per point), in place, in parallel;
    /// returns their skinning weights.
    pub fn all_to_rest(&self, positions: &mut [Vec3], rotations: &mut [Quat]) -> SkinWeights {
        let rows: Vec<SkinRow> = positions
            .par_iter_mut()
            .zip(rotations.par_iter_mut())
            .enumerate()
            .map(|(i, (p, q))| {
                let (np, nq, row) = self.to_rest(i, *p, *q);
                (*p, *q) = (np, nq);
                row
            })
            .collect();
        let (bones, weights) = rows.into_iter().unzip();
        SkinWeights { bones, weights }
    }

    /// The [`Pose`] of the SMPL-X template for one official motion frame: the frame's
    /// rotations, and its `trans` moved into our canonical frame, so that posed points land
    /// where SMPL-X puts them (the frame's camera space: x right, y down, z forward).
    /// Shape (`betas`) and expressions are not applied (zero-beta template).
    pub fn motion_pose(&self, frame: &SmplxFrame) -> Pose {
        let mut pose = frame.pose();
        pose.root_translation += self.model_offset;
        pose
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
