//! Camera-only perception measured on synthetic bags (`lhmpp eval-perception`): every camera
//! image of a bag made by `lhmpp synth` (input and held-out views alike) goes through
//! perception on its own (a fresh [`PersonTracker`] per image, mask smoothing off) and is
//! scored against the bag's ground truth.
//!
//! * **Mask IoU**: the perceived person probability > 0.5 against the bag's mask (≥ 128); a
//!   view where nobody is found scores 0.
//! * **2D landmarks**: the 33 landmarks of the posed, shaped template ([`template_landmarks`]
//!   of the bag's true pose on the template shaped by its `BodyShape`, as `lhmpp synth` shapes
//!   the person) projected with the view's camera, against perception's image landmarks, over
//!   the 12 limb joints (shoulders, elbows, wrists, hips, knees, ankles): mean error in pixels,
//!   the same divided by the height of the true mask's bounding box, and PCK@0.1 (the share of
//!   those joints within 10 % of that height).
//! * **3D joints after IK**: the world landmarks solved by a [`PoseEstimator`] (no filter, the
//!   shaped template) into a pose, against the true pose, on the 14 major joints (shoulders,
//!   elbows, wrists, hips, knees, ankles, neck, head), both root-aligned (the hip joints'
//!   midpoint at the origin). World landmarks come in the camera's axes, so the truth is
//!   expressed in that camera's axes the same way the solver maps them: the canonical frame's
//!   rotation from the camera ([`SolverConfig::canonical_from_camera`] of the default solver,
//!   fixed here so a misconfigured solver under test cannot move the truth with it) after the
//!   camera's rotation from the world. That error (`camera`) counts every mistake, including
//!   the body's orientation relative to the camera. The `aligned` error first turns the solved
//!   joints by the rotation (about the hip midpoint) that best fits them onto the truth
//!   (Horn's quaternion solution of orthogonal Procrustes): what is left is the articulation
//!   alone. Both poses are on the same shaped template, so bone lengths cannot differ and no
//!   scale is fitted.

use crate::bag::{BagError, BagReader};
use crate::body::{BodyError, BodyTemplate, MakeHumanShape, Pose, MAKEHUMAN_MODEL_ID};
use crate::msgs::{BodyPose, BodyShape, CameraInfo, Image, TFMessage, Time};
use crate::perception::overlay::draw_overlay;
use crate::perception::pose::{
    template_landmarks, LandmarkRig, PoseEstimator, PoseEstimatorConfig, PoseSolveError,
    SolverConfig,
};
use crate::perception::{
    Landmark, LandmarkId, PerceptionError, PersonDetector, PersonTracker, PoseNetworks,
    TrackerConfig, BODY_LANDMARKS,
};
use crate::reconstruct::image_decode::{decode_raw, RawImage};
use crate::splat::Camera;
use crate::synth::capture::{
    image_topic, info_topic, mask_topic, optical_frame, POSE_TOPIC, SHAPE_TOPIC, TF_STATIC_TOPIC,
    TF_TOPIC,
};
use glam::{Affine3A, DMat4, DVec4, Quat, Vec2, Vec3};
use image::{GrayImage, RgbImage};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

/// Why a bag could not be evaluated.
#[derive(Debug, thiserror::Error)]
pub enum PerceptionEvalError {
    /// The bag could not be read.
    #[error(transparent)]
    Bag(#[from] BagError),
    /// The bag lacks ground truth the evaluation needs, or carries it malformed.
    #[error("{path}: {message}")]
    GroundTruth {
        /// The bag.
        path: PathBuf,
        /// What is missing or wrong.
        message: String,
    },
    /// The body template could not be loaded.
    #[error(transparent)]
    Body(#[from] BodyError),
    /// The pose solver or the template's landmarks could not be set up.
    #[error(transparent)]
    Pose(#[from] PoseSolveError),
    /// A perception network failed.
    #[error(transparent)]
    Perception(#[from] PerceptionError),
}

/// The 12 limb joints the 2D landmark error is taken over.
pub const LIMB_LANDMARKS: [LandmarkId; 12] = [
    LandmarkId::LeftShoulder,
    LandmarkId::RightShoulder,
    LandmarkId::LeftElbow,
    LandmarkId::RightElbow,
    LandmarkId::LeftWrist,
    LandmarkId::RightWrist,
    LandmarkId::LeftHip,
    LandmarkId::RightHip,
    LandmarkId::LeftKnee,
    LandmarkId::RightKnee,
    LandmarkId::LeftAnkle,
    LandmarkId::RightAnkle,
];

/// The 14 major joints of the MakeHuman rig the 3D error is taken over: shoulders, elbows,
/// wrists, hips, knees, ankles, neck and head.
pub const MAJOR_JOINTS: [&str; 14] = [
    "upperarm01.L",
    "upperarm01.R",
    "lowerarm01.L",
    "lowerarm01.R",
    "wrist.L",
    "wrist.R",
    "upperleg01.L",
    "upperleg01.R",
    "lowerleg01.L",
    "lowerleg01.R",
    "foot.L",
    "foot.R",
    "neck01",
    "head",
];

/// The joints whose midpoint is the root the 3D joints are aligned at (the femoral heads).
const HIP_JOINTS: [&str; 2] = ["upperleg01.L", "upperleg01.R"];

/// PCK threshold, as a fraction of the person's box height.
pub const PCK_FRACTION: f64 = 0.1;

/// One camera image of a synthetic bag with its ground truth.
#[derive(Debug, Clone)]
pub struct SyntheticView {
    /// Camera name, with `#k` for frame `k` of a camera that has several (a moving camera).
    pub name: String,
    /// Whether the camera is a held-out one (`/heldoutN/...`).
    pub heldout: bool,
    /// The image.
    pub image: RgbImage,
    /// The true person mask (mono8, 255 = person).
    pub mask: GrayImage,
    /// The camera that took the image (intrinsics from CameraInfo, pose from `/tf_static` or
    /// the frame's `/tf`).
    pub camera: Camera,
}

/// A synthetic bag's person and views.
#[derive(Debug, Clone)]
pub struct SyntheticScene {
    /// The bag.
    pub path: PathBuf,
    /// Every camera image, input cameras first (in camera and frame order), then held-out.
    pub views: Vec<SyntheticView>,
    /// The true body pose.
    pub pose: Pose,
    /// The body shape the bag carries (`None`: the bag has no `BodyShape`, and the truth uses
    /// the unshaped template, which is not what `lhmpp synth` rendered).
    pub shape: Option<MakeHumanShape>,
    /// The MakeHuman template with that shape applied.
    pub template: BodyTemplate,
    /// The 33 landmarks of the template in the true pose (world frame, metres).
    pub truth_landmarks: [Vec3; BODY_LANDMARKS],
}

/// 2D landmark errors of one view over [`LIMB_LANDMARKS`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LandmarkError2d {
    /// Mean distance, pixels.
    pub mean_px: f64,
    /// Mean distance divided by the height of the true mask's bounding box.
    pub mean_box_fraction: f64,
    /// Share of the joints within [`PCK_FRACTION`] of the box height.
    pub pck: f64,
}

/// 3D joint errors of one view over [`MAJOR_JOINTS`], root-aligned (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointError3d {
    /// Mean distance with the truth in the camera's axes, millimetres.
    pub camera_mm: f64,
    /// Mean distance after the best-fitting rotation, millimetres.
    pub aligned_mm: f64,
}

/// What perception made of one view, and its scores.
#[derive(Debug, Clone)]
pub struct ViewResult {
    /// The view's name ([`SyntheticView::name`]).
    pub name: String,
    /// Whether it is a held-out view.
    pub heldout: bool,
    /// Height of the true mask's bounding box, pixels (0 for an empty mask).
    pub box_height: f64,
    /// Angle between the way the person's pelvis faces and the direction from the hips to
    /// the camera, degrees: 0 when they face the camera, 180 with their back to it.
    pub facing_deg: f64,
    /// The true landmarks projected into the image, pixels.
    pub truth_px: [Vec2; BODY_LANDMARKS],
    /// Perception's landmarks (`None`: nobody found).
    pub landmarks: Option<crate::perception::landmarks::PoseLandmarks>,
    /// Perception's mask thresholded at 0.5 (mono8), when somebody was found.
    pub mask: Option<GrayImage>,
    /// Mask IoU against the true mask (0 when nobody was found).
    pub mask_iou: f64,
    /// 2D landmark errors, when somebody was found.
    pub landmarks_2d: Option<LandmarkError2d>,
    /// 3D joint errors after IK, when somebody was found.
    pub joints_3d: Option<JointError3d>,
    /// Time perception took on the image, milliseconds.
    pub perception_ms: f64,
}

/// Means over a set of views.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Summary {
    /// Views.
    pub views: usize,
    /// Views where a person was found.
    pub found: usize,
    /// Mean mask IoU over all views (a miss scores 0).
    pub mask_iou_all: f64,
    /// Mean mask IoU over the views where a person was found (NaN when none was).
    pub mask_iou_found: f64,
    /// Mean 2D limb-joint error, pixels, over found views.
    pub mean_px: f64,
    /// Mean 2D limb-joint error over the box height, over found views.
    pub mean_box_fraction: f64,
    /// PCK@0.1 over found views.
    pub pck: f64,
    /// Mean 3D joint error, camera axes, millimetres, over found views.
    pub camera_mm: f64,
    /// Mean 3D joint error after the best-fitting rotation, millimetres, over found views.
    pub aligned_mm: f64,
    /// Mean perception time per image, milliseconds.
    pub perception_ms: f64,
}

impl Summary {
    /// Means of `views` (NaN for a mean over no found view).
    pub fn of<'a>(views: impl IntoIterator<Item = &'a ViewResult>) -> Self {
        let views: Vec<&ViewResult> = views.into_iter().collect();
        let mean = |values: Vec<f64>| {
            if values.is_empty() {
                f64::NAN
            } else {
                values.iter().sum::<f64>() / values.len() as f64
            }
        };
        let found: Vec<&&ViewResult> = views.iter().filter(|v| v.landmarks.is_some()).collect();
        let l2 = |f: fn(&LandmarkError2d) -> f64| {
            mean(
                found
                    .iter()
                    .filter_map(|v| v.landmarks_2d.as_ref().map(f))
                    .collect(),
            )
        };
        let j3 = |f: fn(&JointError3d) -> f64| {
            mean(
                found
                    .iter()
                    .filter_map(|v| v.joints_3d.as_ref().map(f))
                    .collect(),
            )
        };
        Self {
            views: views.len(),
            found: found.len(),
            mask_iou_all: mean(views.iter().map(|v| v.mask_iou).collect()),
            mask_iou_found: mean(found.iter().map(|v| v.mask_iou).collect()),
            mean_px: l2(|e| e.mean_px),
            mean_box_fraction: l2(|e| e.mean_box_fraction),
            pck: l2(|e| e.pck),
            camera_mm: j3(|e| e.camera_mm),
            aligned_mm: j3(|e| e.aligned_mm),
            perception_ms: mean(views.iter().map(|v| v.perception_ms).collect()),
        }
    }
}

fn ground_truth_error(path: &Path, message: impl Into<String>) -> PerceptionEvalError {
    PerceptionEvalError::GroundTruth {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

fn pose_of(t: &crate::msgs::TransformStamped) -> Affine3A {
    let q: Quat = t.transform.rotation.into();
    let p: Vec3 = t.transform.translation.into();
    Affine3A::from_rotation_translation(q.normalize(), p)
}

/// Reads every camera image of a bag made by `lhmpp synth` with its camera and true mask,
/// and the true pose and shape.
pub fn read_scene(path: &Path) -> Result<SyntheticScene, PerceptionEvalError> {
    let bag = BagReader::open(path)?;
    let bad = |message: String| ground_truth_error(path, message);
    let of_topic = |topic: &str| -> Vec<&crate::bag::BagMessage> {
        bag.messages()
            .iter()
            .filter(|m| &*m.topic == topic)
            .collect()
    };
    let mut fixed: BTreeMap<String, Affine3A> = BTreeMap::new();
    for m in of_topic(TF_STATIC_TOPIC) {
        let tf: TFMessage = bag.decode(m)?;
        for t in &tf.transforms {
            fixed.insert(t.child_frame_id.clone(), pose_of(t));
        }
    }
    let mut moving: BTreeMap<(String, Time), Affine3A> = BTreeMap::new();
    for m in of_topic(TF_TOPIC) {
        let tf: TFMessage = bag.decode(m)?;
        for t in &tf.transforms {
            moving.insert((t.child_frame_id.clone(), t.header.stamp), pose_of(t));
        }
    }
    let pose_msg: BodyPose = bag.decode(
        of_topic(POSE_TOPIC)
            .first()
            .ok_or_else(|| bad(format!("no {POSE_TOPIC}")))?,
    )?;
    let pose = pose_msg
        .to_pose()
        .map_err(|e| bad(format!("{POSE_TOPIC}: {e}")))?;
    let shape = match of_topic(SHAPE_TOPIC).first() {
        None => None,
        Some(m) => {
            let msg: BodyShape = bag.decode(m)?;
            if msg.body_model != MAKEHUMAN_MODEL_ID {
                return Err(bad(format!(
                    "{SHAPE_TOPIC}: body model `{}`, expected `{MAKEHUMAN_MODEL_ID}`",
                    msg.body_model
                )));
            }
            Some(
                MakeHumanShape::from_params(&msg.shape_params).ok_or_else(|| {
                    bad(format!(
                        "{SHAPE_TOPIC}: shape {:?} is not [height_scale, girth_scale] in range",
                        msg.shape_params
                    ))
                })?,
            )
        }
    };
    let mut template = BodyTemplate::load_default()?;
    if let Some(shape) = shape {
        shape.apply(&mut template);
    }
    let truth_landmarks = template_landmarks(&template, &pose)?;

    let mut names: Vec<String> = bag
        .topics()
        .iter()
        .filter_map(|t| t.name.strip_suffix("/image_raw"))
        .map(|n| n.trim_start_matches('/').to_owned())
        .collect();
    names.sort_by_key(|n| {
        let digits: String = n.chars().filter(|c| c.is_ascii_digit()).collect();
        (
            n.starts_with("heldout"),
            digits.parse::<u32>().unwrap_or(0),
            n.clone(),
        )
    });
    let mut views = Vec::new();
    for name in names {
        let frame = optical_frame(&name);
        let images = of_topic(&image_topic(&name));
        let masks = of_topic(&mask_topic(&name));
        let infos: Vec<CameraInfo> = of_topic(&info_topic(&name))
            .into_iter()
            .map(|m| bag.decode(m))
            .collect::<Result<_, _>>()?;
        if masks.len() != images.len() {
            return Err(bad(format!(
                "{}: {} images but {} masks on {}",
                name,
                images.len(),
                masks.len(),
                mask_topic(&name)
            )));
        }
        let several = images.len() > 1;
        for (k, (image_msg, mask_msg)) in images.into_iter().zip(masks).enumerate() {
            let msg: Image = bag.decode(image_msg)?;
            let topic = image_topic(&name);
            let image = decode_raw(&topic, &RawImage::from(&msg), 1 << 14)
                .map_err(|e| bad(e.to_string()))?;
            let mask_msg: Image = bag.decode(mask_msg)?;
            if mask_msg.encoding != "mono8"
                || mask_msg.step != mask_msg.width
                || (mask_msg.width, mask_msg.height) != image.dimensions()
            {
                return Err(bad(format!(
                    "{}: expected a mono8 mask of the image size",
                    mask_topic(&name)
                )));
            }
            let mask = GrayImage::from_raw(mask_msg.width, mask_msg.height, mask_msg.data)
                .ok_or_else(|| bad(format!("{}: short mask", mask_topic(&name))))?;
            let stamp = msg.header.stamp;
            let info = infos
                .iter()
                .find(|i| i.header.stamp == stamp)
                .or(infos.first())
                .ok_or_else(|| bad(format!("no {}", info_topic(&name))))?;
            let world_from_camera = moving
                .get(&(frame.clone(), stamp))
                .or_else(|| fixed.get(&frame))
                .copied()
                .ok_or_else(|| {
                    bad(format!(
                        "no pose of {frame} on {TF_STATIC_TOPIC} or at the image's stamp on {TF_TOPIC}"
                    ))
                })?;
            views.push(SyntheticView {
                name: if several {
                    format!("{name}#{k}")
                } else {
                    name.clone()
                },
                heldout: name.starts_with("heldout"),
                camera: Camera::from_camera_info(
                    info.k,
                    image.width(),
                    image.height(),
                    world_from_camera,
                ),
                image,
                mask,
            });
        }
    }
    if views.is_empty() {
        return Err(bad(
            "no camera images (/NAME/image_raw), as made by `lhmpp synth`".into(),
        ));
    }
    Ok(SyntheticScene {
        path: path.to_path_buf(),
        views,
        pose,
        shape,
        template,
        truth_landmarks,
    })
}

/// IoU of two mono8 masks, pixels ≥ 128 counting as person (`perceived`: perception's map
/// through [`ProbabilityMap::to_mask`](crate::perception::segmentation::ProbabilityMap::to_mask)
/// at threshold 0.5 without feather, i.e. probability above 0.5); 1 when both are empty, 0
/// when the sizes differ.
pub fn mask_iou(perceived: &GrayImage, truth: &GrayImage) -> f64 {
    if perceived.dimensions() != truth.dimensions() {
        return 0.0;
    }
    let (mut inter, mut union) = (0u64, 0u64);
    for (p, t) in perceived.as_raw().iter().zip(truth.as_raw()) {
        let (a, b) = (*p >= 128, *t >= 128);
        inter += u64::from(a && b);
        union += u64::from(a || b);
    }
    if union == 0 {
        1.0
    } else {
        inter as f64 / union as f64
    }
}

/// Height of the bounding box of the mask's pixels ≥ 128 (rows spanned), 0 for an empty mask.
pub fn box_height(mask: &GrayImage) -> f64 {
    let rows: Vec<u32> = mask
        .rows()
        .enumerate()
        .filter(|(_, row)| row.clone().any(|p| p.0[0] >= 128))
        .map(|(y, _)| y as u32)
        .collect();
    match (rows.first(), rows.last()) {
        (Some(a), Some(b)) => f64::from(b - a + 1),
        _ => 0.0,
    }
}

/// World points projected into `camera`'s image, pixels (centres at integers, as the
/// landmarks are).
pub fn project(camera: &Camera, points: &[Vec3; BODY_LANDMARKS]) -> [Vec2; BODY_LANDMARKS] {
    let from_world = camera.camera_from_world();
    std::array::from_fn(|i| camera.project_camera_point(from_world.transform_point3(points[i])))
}

/// [`ViewResult::facing_deg`] of a person whose landmarks (world frame) are `truth`, seen by
/// `camera`: the pelvis faces along (right hip → left hip) × (hips → shoulders), as the
/// canonical frame's +X × +Y = +Z.
pub fn facing_deg(camera: &Camera, truth: &[Vec3; BODY_LANDMARKS]) -> f64 {
    let at = |id: LandmarkId| truth[id.index()];
    let hips = 0.5 * (at(LandmarkId::LeftHip) + at(LandmarkId::RightHip));
    let shoulders = 0.5 * (at(LandmarkId::LeftShoulder) + at(LandmarkId::RightShoulder));
    let forward = (at(LandmarkId::LeftHip) - at(LandmarkId::RightHip)).cross(shoulders - hips);
    f64::from(forward.angle_between(camera.center() - hips).to_degrees())
}

/// 2D errors of perceived image landmarks against the true pixels, over [`LIMB_LANDMARKS`],
/// normalised by `box_height` pixels.
pub fn landmark_error_2d(
    truth_px: &[Vec2; BODY_LANDMARKS],
    perceived: &[Landmark; BODY_LANDMARKS],
    box_height: f64,
) -> LandmarkError2d {
    let d: Vec<f64> = LIMB_LANDMARKS
        .iter()
        .map(|id| {
            let i = id.index();
            f64::from(perceived[i].position.truncate().distance(truth_px[i]))
        })
        .collect();
    let n = d.len() as f64;
    let mean_px = d.iter().sum::<f64>() / n;
    let h = box_height.max(1.0);
    LandmarkError2d {
        mean_px,
        mean_box_fraction: mean_px / h,
        pck: d.iter().filter(|e| **e <= PCK_FRACTION * h).count() as f64 / n,
    }
}

/// Poses world landmarks with a solver and compares the major joints with a scene's truth.
#[derive(Debug, Clone)]
pub struct JointScorer {
    estimator: PoseEstimator,
    template: BodyTemplate,
    bones: Vec<usize>,
    hips: [usize; 2],
    /// Root-aligned true joints, world axes.
    truth: Vec<Vec3>,
}

impl JointScorer {
    /// A scorer for `scene`'s person, solving with `solver` on the scene's shaped template
    /// (the estimator unfiltered, reset before every view so views do not share state).
    pub fn new(scene: &SyntheticScene, solver: SolverConfig) -> Result<Self, PerceptionEvalError> {
        let template = scene.template.clone();
        let estimator = PoseEstimator::new(
            &template,
            PoseEstimatorConfig {
                solver,
                filter: None,
                ..PoseEstimatorConfig::default()
            },
        )?;
        let index = |name: &str| {
            template.skeleton.bone_index(name).ok_or_else(|| {
                PerceptionEvalError::Pose(PoseSolveError::MissingBone {
                    skeleton: "MakeHuman",
                    bone: name.to_owned(),
                })
            })
        };
        let bones = MAJOR_JOINTS
            .iter()
            .map(|b| index(b))
            .collect::<Result<Vec<_>, _>>()?;
        let hips = [index(HIP_JOINTS[0])?, index(HIP_JOINTS[1])?];
        let mut scorer = Self {
            estimator,
            template,
            bones,
            hips,
            truth: Vec::new(),
        };
        scorer.truth = scorer.root_aligned(&scene.pose);
        Ok(scorer)
    }

    fn root_aligned(&self, pose: &Pose) -> Vec<Vec3> {
        let s = &self.template.skeleton;
        let posed = s.posed_joints(&s.skinning_matrices(pose));
        let centre = 0.5 * (posed[self.hips[0]] + posed[self.hips[1]]);
        self.bones.iter().map(|&b| posed[b] - centre).collect()
    }

    /// The pose the solver gives for `world` (camera axes, hip-centred, metres).
    pub fn solve(&mut self, world: &[Landmark; BODY_LANDMARKS]) -> Pose {
        self.estimator.reset();
        self.estimator.update(0.0, world)
    }

    /// 3D joint errors of the pose solved from `world` landmarks seen by `camera`.
    pub fn score(&mut self, camera: &Camera, world: &[Landmark; BODY_LANDMARKS]) -> JointError3d {
        let solved = self.solve(world);
        let got = self.root_aligned(&solved);
        let (_, camera_from_world, _) = camera.camera_from_world().to_scale_rotation_translation();
        let to_camera = SolverConfig::default().canonical_from_camera * camera_from_world;
        let truth: Vec<Vec3> = self.truth.iter().map(|p| to_camera * *p).collect();
        let mean_mm = |a: &[Vec3]| {
            1000.0
                * a.iter()
                    .zip(&truth)
                    .map(|(a, b)| f64::from(a.distance(*b)))
                    .sum::<f64>()
                / truth.len() as f64
        };
        let fit = best_rotation(&got, &truth);
        let turned: Vec<Vec3> = got.iter().map(|p| fit * *p).collect();
        JointError3d {
            camera_mm: mean_mm(&got),
            aligned_mm: mean_mm(&turned),
        }
    }
}

/// The rotation `R` minimising `Σ |R·from_i − to_i|²` (Horn 1987: the eigenvector of the
/// largest eigenvalue of a 4×4 symmetric matrix, found by Jacobi rotations).
pub fn best_rotation(from: &[Vec3], to: &[Vec3]) -> Quat {
    let mut s = [[0f64; 3]; 3];
    for (a, b) in from.iter().zip(to) {
        let (a, b) = (a.as_dvec3().to_array(), b.as_dvec3().to_array());
        for (r, row) in s.iter_mut().enumerate() {
            for (c, v) in row.iter_mut().enumerate() {
                *v += a[r] * b[c];
            }
        }
    }
    let [[xx, xy, xz], [yx, yy, yz], [zx, zy, zz]] = s;
    let mut n = [
        [xx + yy + zz, yz - zy, zx - xz, xy - yx],
        [yz - zy, xx - yy - zz, xy + yx, zx + xz],
        [zx - xz, xy + yx, -xx + yy - zz, yz + zy],
        [xy - yx, zx + xz, yz + zy, -xx - yy + zz],
    ];
    let mut v = DMat4::IDENTITY.to_cols_array_2d();
    for _sweep in 0..50 {
        let off: f64 = (0..4)
            .flat_map(|i| (0..4).filter(move |j| *j != i).map(move |j| (i, j)))
            .map(|(i, j)| n[i][j] * n[i][j])
            .sum();
        if off < 1e-24 {
            break;
        }
        for p in 0..4 {
            for q in p + 1..4 {
                if n[p][q].abs() < 1e-300 {
                    continue;
                }
                let theta = (n[q][q] - n[p][p]) / (2.0 * n[p][q]);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let c = 1.0 / (t * t + 1.0).sqrt();
                let sn = t * c;
                // N ← Jᵀ N J and V ← V J, J the rotation in the (p, q) plane.
                let turn_columns = |row: &mut [f64; 4]| {
                    let (kp, kq) = (row[p], row[q]);
                    row[p] = c * kp - sn * kq;
                    row[q] = sn * kp + c * kq;
                };
                n.iter_mut().for_each(turn_columns);
                let (rp, rq) = (n[p], n[q]);
                n[p] = std::array::from_fn(|k| c * rp[k] - sn * rq[k]);
                n[q] = std::array::from_fn(|k| sn * rp[k] + c * rq[k]);
                v.iter_mut().for_each(turn_columns);
            }
        }
    }
    let best = (0..4)
        .max_by(|a, b| n[*a][*a].total_cmp(&n[*b][*b]))
        .unwrap_or(0);
    let e = DVec4::new(v[0][best], v[1][best], v[2][best], v[3][best]);
    // The eigenvector is (w, x, y, z).
    Quat::from_xyzw(e.y as f32, e.z as f32, e.w as f32, e.x as f32).normalize()
}

/// Runs perception on every view of `scene` (a fresh tracker per image, mask smoothing off,
/// `detector` finding the person) and scores it; 3D joints are solved with `solver`.
pub fn evaluate_scene(
    scene: &SyntheticScene,
    networks: &Arc<PoseNetworks>,
    solver: SolverConfig,
    detector: PersonDetector,
) -> Result<Vec<ViewResult>, PerceptionEvalError> {
    let mut scorer = JointScorer::new(scene, solver)?;
    let tracker_config = TrackerConfig {
        smooth_masks: false,
        detector,
        ..TrackerConfig::default()
    };
    let mut results = Vec::with_capacity(scene.views.len());
    for view in &scene.views {
        let mut tracker = PersonTracker::new(networks.clone(), tracker_config);
        let started = Instant::now();
        let perceived = tracker.perceive(&view.image)?;
        let perception_ms = started.elapsed().as_secs_f64() * 1e3;
        let truth_px = project(&view.camera, &scene.truth_landmarks);
        let box_height = box_height(&view.mask);
        let facing_deg = facing_deg(&view.camera, &scene.truth_landmarks);
        let result = match perceived {
            None => ViewResult {
                name: view.name.clone(),
                heldout: view.heldout,
                box_height,
                facing_deg,
                truth_px,
                landmarks: None,
                mask: None,
                mask_iou: 0.0,
                landmarks_2d: None,
                joints_3d: None,
                perception_ms,
            },
            Some(p) => {
                let perceived_mask = p.mask.to_mask(0.5, 0.0);
                ViewResult {
                    name: view.name.clone(),
                    heldout: view.heldout,
                    box_height,
                    facing_deg,
                    truth_px,
                    mask_iou: mask_iou(&perceived_mask, &view.mask),
                    mask: Some(perceived_mask),
                    landmarks_2d: Some(landmark_error_2d(
                        &truth_px,
                        &p.landmarks.image,
                        box_height,
                    )),
                    joints_3d: Some(scorer.score(&view.camera, &p.landmarks.world)),
                    landmarks: Some(p.landmarks),
                    perception_ms,
                }
            }
        };
        results.push(result);
    }
    Ok(results)
}

/// The body shape read from a scene's calibrated input views ([`crate::perception::shape`]),
/// against the truth.
#[derive(Debug, Clone, PartialEq)]
pub struct ShapeResult {
    /// The estimate (`None`: too few segments seen).
    pub estimate: Option<crate::perception::shape::ShapeEstimate>,
    /// Per segment of [`crate::perception::shape::SEGMENTS`]: measured length over the true
    /// person's (the shaped template's rest landmarks), where measured.
    pub ratios: [Option<f32>; 12],
}

/// Triangulates the input views' perceived landmarks with their cameras and reads the body
/// shape; `results` are [`evaluate_scene`]'s for `scene`.
pub fn scene_shape(
    scene: &SyntheticScene,
    results: &[ViewResult],
    min_visibility: f32,
) -> Result<ShapeResult, PerceptionEvalError> {
    use crate::perception::shape::{
        estimate_shape, segment_lengths, template_segment_lengths, CalibratedView,
    };
    let views: Vec<CalibratedView> = scene
        .views
        .iter()
        .zip(results)
        .filter(|(v, _)| !v.heldout)
        .filter_map(|(v, r)| {
            let k = &v.camera.intrinsics;
            Some(CalibratedView {
                fx: k.fx,
                fy: k.fy,
                cx: k.cx,
                cy: k.cy,
                world_from_camera: v.camera.world_from_camera,
                landmarks: r.landmarks.as_ref()?.image,
            })
        })
        .collect();
    let base = BodyTemplate::load_default()?;
    let truth = template_segment_lengths(&LandmarkRig::new(&scene.template)?.rest());
    let measured = segment_lengths(&views, min_visibility);
    let ratios = std::array::from_fn(|i| measured[i].map(|m| m / truth[i]));
    Ok(ShapeResult {
        estimate: estimate_shape(&base, &views, min_visibility)?,
        ratios,
    })
}

/// Side of a tile of [`contact_sheet`], pixels.
const TILE: u32 = 256;

/// A picture of views: per view, the image with the perceived mask tinted and the perceived
/// skeleton (or "nobody found": the bare image with a red border) beside the true mask with
/// the true landmarks' skeleton; two views per row, tiles 256 pixels high.
pub fn contact_sheet(views: &[(&SyntheticView, &ViewResult)]) -> RgbImage {
    use image::imageops::{resize, FilterType};
    let gap = 6;
    let pair = 2 * TILE + gap;
    let per_row = 2u32;
    let rows = (views.len() as u32).div_ceil(per_row).max(1);
    let cols = (views.len() as u32).clamp(1, per_row);
    let mut sheet = RgbImage::from_pixel(
        cols * pair + (cols - 1) * 3 * gap,
        rows * TILE + (rows - 1) * gap,
        image::Rgb([90, 90, 90]),
    );
    for (i, (view, result)) in views.iter().enumerate() {
        let overlay = match &result.landmarks {
            Some(l) => draw_overlay(&view.image, result.mask.as_ref(), Some(&l.image), 0.5),
            None => {
                let mut img = view.image.clone();
                let (w, h) = img.dimensions();
                let border = (w.max(h) / 64).max(2);
                for (x, y, p) in img.enumerate_pixels_mut() {
                    if x < border || y < border || x + border >= w || y + border >= h {
                        *p = image::Rgb([220, 30, 30]);
                    }
                }
                img
            }
        };
        let truth_rgb = RgbImage::from_fn(view.mask.width(), view.mask.height(), |x, y| {
            let v = view.mask.get_pixel(x, y).0[0] / 2;
            image::Rgb([v, v, v])
        });
        let truth_landmarks: [Landmark; BODY_LANDMARKS] = std::array::from_fn(|k| Landmark {
            position: result.truth_px[k].extend(0.0),
            visibility: 1.0,
            presence: 1.0,
        });
        let truth = draw_overlay(&truth_rgb, None, Some(&truth_landmarks), 0.5);
        let fit = |img: &RgbImage| {
            let w = (img.width() as u64 * TILE as u64 / img.height().max(1) as u64).max(1) as u32;
            resize(img, w.min(TILE), TILE, FilterType::Triangle)
        };
        let (r, c) = (i as u32 / per_row, i as u32 % per_row);
        let (x, y) = (c * (pair + 3 * gap), r * (TILE + gap));
        image::imageops::replace(&mut sheet, &fit(&overlay), i64::from(x), i64::from(y));
        image::imageops::replace(
            &mut sheet,
            &fit(&truth),
            i64::from(x + TILE + gap),
            i64::from(y),
        );
    }
    sheet
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn best_rotation_recovers_a_known_rotation() {
        let from: Vec<Vec3> = (0..14)
            .map(|i| {
                let t = i as f32;
                Vec3::new((0.7 * t).sin(), (1.3 * t).cos() * 0.8, 0.1 * t - 0.6)
            })
            .collect();
        for q in [
            Quat::IDENTITY,
            Quat::from_rotation_y(2.5),
            Quat::from_rotation_x(std::f32::consts::PI),
            Quat::from_axis_angle(Vec3::new(1.0, -2.0, 0.5).normalize(), 1.1),
        ] {
            let to: Vec<Vec3> = from.iter().map(|p| q * *p).collect();
            let got = best_rotation(&from, &to);
            assert!(got.angle_between(q) < 1e-4, "{q} → {got}");
        }
    }

    #[test]
    fn box_height_and_iou_count_pixels() {
        let mut mask = GrayImage::new(8, 8);
        for y in 2..6 {
            for x in 1..3 {
                mask.put_pixel(x, y, image::Luma([255]));
            }
        }
        assert_eq!(box_height(&mask), 4.0);
        assert_eq!(box_height(&GrayImage::new(4, 4)), 0.0);
        let mut seen = GrayImage::new(8, 8);
        for y in 2..6 {
            seen.put_pixel(1, y, image::Luma([200]));
            seen.put_pixel(5, y, image::Luma([127]));
        }
        assert!((mask_iou(&seen, &mask) - 0.5).abs() < 1e-12);
        assert_eq!(mask_iou(&GrayImage::new(8, 8), &GrayImage::new(8, 8)), 1.0);
        assert_eq!(mask_iou(&seen, &GrayImage::new(4, 8)), 0.0);
    }

    #[test]
    fn landmark_error_counts_pck_against_the_box_height() {
        let truth = [Vec2::new(10.0, 10.0); BODY_LANDMARKS];
        let mut seen = [Landmark::default(); BODY_LANDMARKS];
        for (k, id) in LIMB_LANDMARKS.iter().enumerate() {
            // Half the limb joints 5 px off, half 20 px off.
            let off = if k % 2 == 0 { 5.0 } else { 20.0 };
            seen[id.index()].position = Vec3::new(10.0 + off, 10.0, 0.0);
        }
        let e = landmark_error_2d(&truth, &seen, 100.0);
        assert!((e.mean_px - 12.5).abs() < 1e-9);
        assert!((e.mean_box_fraction - 0.125).abs() < 1e-9);
        assert!((e.pck - 0.5).abs() < 1e-9);
    }
}
