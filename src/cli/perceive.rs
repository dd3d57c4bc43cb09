//! `lhmpp perceive IMAGE... -o DIR`: what camera-only perception sees in photos, for
//! debugging. Per image: `<stem>_mask.png` (the feathered person mask), `<stem>_overlay.png`
//! (the mask tinted and the landmark skeleton) and `<stem>.json` (detection, crop, image and
//! world landmarks, and the BodyPose the solver derives from them). With `--people`, every
//! person of each photo instead (`super::perceive_people`).

use anyhow::{Context, Result};
use clap::Args;
use lhmpp::body::{BodyTemplate, Pose};
use lhmpp::perception::overlay::draw_overlay;
use lhmpp::perception::pose::{PoseEstimator, PoseEstimatorConfig};
use lhmpp::perception::{
    Detected, Landmark, LandmarkId, LandmarkModel, PeopleConfig, Perceived, PersonDetector,
    PersonTracker, PoseNetworks, TrackerConfig,
};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Options of `lhmpp perceive`.
#[derive(Args, Debug)]
pub struct PerceiveArgs {
    /// Photos (JPEG or PNG), each perceived on its own.
    #[arg(required = true)]
    pub(super) images: Vec<PathBuf>,
    /// Output directory (created if missing).
    #[arg(short, long)]
    pub(super) out: PathBuf,
    /// Landmark model: `lite`, `full` or `heavy`.
    #[arg(long, default_value = "full")]
    model: String,
    /// The converted heavy model (with `--model heavy`).
    #[arg(long)]
    heavy_weights: Option<PathBuf>,
    /// Person probability at the mask's edge.
    #[arg(long, default_value_t = 0.5)]
    pub(super) mask_threshold: f32,
    /// Half-width of the mask's soft edge, in probability.
    #[arg(long, default_value_t = 0.1)]
    pub(super) mask_feather: f32,
    /// Landmarks less visible than this are left out of the overlay and the pose.
    #[arg(long, default_value_t = 0.5)]
    pub(super) min_visibility: f32,
    /// Every person of each photo (MoveNet MultiPose, then the landmark model per person);
    /// photos given in order are frames of one camera, so persons keep their ids across them.
    #[arg(long)]
    people: bool,
    /// MoveNet person score a person needs.
    #[arg(long, default_value_t = 0.2)]
    pub(super) min_score: f32,
    /// Short side of MoveNet's input (a multiple of 32): larger finds people who fill less of
    /// the photo, at a higher cost.
    #[arg(long, default_value_t = lhmpp::perception::multipose::NATIVE_SIDE)]
    pub(super) detector_side: usize,
    /// Without `--people`, which detector finds the person: `movenet` (MoveNet MultiPose, the
    /// most prominent person) or `blazepose` (BlazePose's own, for a person filling much of
    /// the photo).
    #[arg(long, value_enum, default_value_t = DetectorArg::Movenet)]
    pub(super) person_detector: DetectorArg,
}

/// `--person-detector` values (`lhmpp perceive`, `lhmpp eval-tracking --one-person`).
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum DetectorArg {
    /// MoveNet MultiPose, then the most prominent person.
    Movenet,
    /// BlazePose's own detector.
    Blazepose,
}

impl DetectorArg {
    /// The value as written.
    pub fn name(self) -> &'static str {
        PersonDetector::from(self).name()
    }
}

impl From<DetectorArg> for PersonDetector {
    fn from(d: DetectorArg) -> Self {
        match d {
            DetectorArg::Movenet => PersonDetector::MultiPose,
            DetectorArg::Blazepose => PersonDetector::BlazePose,
        }
    }
}

/// Perceives every image; an image that cannot be read or shows nobody is reported and the
/// others go on (exit status 1 when none showed a person).
pub fn run(args: PerceiveArgs) -> Result<()> {
    let model = LandmarkModel::from_name(&args.model)
        .with_context(|| format!("--model `{}`: expected lite, full or heavy", args.model))?;
    let networks = Arc::new(PoseNetworks::load(model, args.heavy_weights.as_deref())?);
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    if args.people {
        return super::perceive_people::run(&args, networks);
    }
    let template = BodyTemplate::load_default().context("loading the embedded body template")?;
    let mut found = 0;
    for path in &args.images {
        match perceive_one(&args, &networks, &template, path) {
            Ok(true) => found += 1,
            Ok(false) => tracing::warn!(image = %path.display(), "no person found"),
            Err(e) => tracing::error!(image = %path.display(), "{}", super::error_line(&e)),
        }
    }
    if found == 0 {
        anyhow::bail!(
            "no person found in any of the {} image(s)",
            args.images.len()
        );
    }
    tracing::info!(found, images = args.images.len(), out = %args.out.display(), "perceived");
    Ok(())
}

/// Writes one image's outputs; whether a person was found.
fn perceive_one(
    args: &PerceiveArgs,
    networks: &Arc<PoseNetworks>,
    template: &BodyTemplate,
    path: &Path,
) -> Result<bool> {
    let image = image::open(path)
        .with_context(|| format!("reading {}", path.display()))?
        .to_rgb8();
    let config = TrackerConfig {
        smooth_masks: false,
        detector: args.person_detector.into(),
        people: PeopleConfig {
            min_score: args.min_score,
            detector_side: args.detector_side,
            ..PeopleConfig::default()
        },
        ..TrackerConfig::default()
    };
    let mut tracker = PersonTracker::new(networks.clone(), config);
    let started = std::time::Instant::now();
    let perceived = tracker.perceive(&image)?;
    let ms = started.elapsed().as_secs_f64() * 1e3;
    let stem = path
        .file_stem()
        .map_or_else(|| "image".into(), |s| s.to_string_lossy().into_owned());
    let write = |name: String, img: &dyn Fn(&Path) -> image::ImageResult<()>| {
        let target = args.out.join(name);
        img(&target).with_context(|| format!("writing {}", target.display()))
    };
    let Some(p) = perceived else {
        let json = json!({ "image": path, "person_found": false, "ms": ms });
        write_json(&args.out.join(format!("{stem}.json")), &json)?;
        return Ok(false);
    };
    let mask = p.mask.to_mask(args.mask_threshold, args.mask_feather);
    write(format!("{stem}_mask.png"), &|t| mask.save(t))?;
    let overlay = draw_overlay(
        &image,
        Some(&mask),
        Some(&p.landmarks.image),
        args.min_visibility,
    );
    write(format!("{stem}_overlay.png"), &|t| overlay.save(t))?;
    let mut estimator_config = PoseEstimatorConfig {
        filter: None,
        ..PoseEstimatorConfig::default()
    };
    estimator_config.solver.min_visibility = args.min_visibility;
    let pose = PoseEstimator::new(template, estimator_config)?.update(0.0, &p.landmarks.world);
    let json = perception_json(path, &image, &p, &pose, ms);
    write_json(&args.out.join(format!("{stem}.json")), &json)?;
    Ok(true)
}

pub(super) fn write_json(path: &Path, value: &Value) -> Result<()> {
    let text = serde_json::to_string_pretty(value).expect("JSON values serialise");
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}

/// The JSON record of one perceived image.
fn perception_json(
    path: &Path,
    image: &image::RgbImage,
    p: &Perceived,
    pose: &Pose,
    ms: f64,
) -> Value {
    let landmarks = |list: &[Landmark]| -> Vec<Value> {
        LandmarkId::ALL
            .iter()
            .zip(list)
            .map(|(id, l)| {
                json!({
                    "name": id.name(),
                    "position": l.position.to_array(),
                    "visibility": l.visibility,
                    "presence": l.presence,
                })
            })
            .collect()
    };
    let mut bones: Vec<(&String, &glam::Quat)> = pose.rotations.iter().collect();
    bones.sort_by(|a, b| a.0.cmp(b.0));
    let quat = |q: &glam::Quat| [q.w, q.x, q.y, q.z];
    let roi = p.landmarks.roi;
    json!({
        "image": path,
        "width": image.width(),
        "height": image.height(),
        "person_found": true,
        "ms": ms,
        "detection": p.detection.as_ref().map(|d| json!({
            "detector": match d {
                Detected::BlazePose(_) => "blazepose",
                Detected::MultiPose(_) => "movenet",
            },
            "score": d.score(),
            "box_min": d.bounds().min.to_array(),
            "box_max": d.bounds().max.to_array(),
            "keypoints": match d {
                Detected::BlazePose(b) => b.keypoints.iter().map(|k| k.to_array()).collect::<Vec<_>>(),
                Detected::MultiPose(m) => m.keypoints.iter().map(|k| k.position.to_array()).collect(),
            },
        })),
        "presence": p.landmarks.presence,
        "roi": {
            "center": roi.center.to_array(),
            "size": roi.size.to_array(),
            "rotation": roi.rotation,
        },
        "landmarks_px": landmarks(&p.landmarks.image),
        "world_landmarks_m": landmarks(&p.landmarks.world),
        "body_pose": {
            "convention": "quaternions [w, x, y, z]; local rotations about each joint in \
                           canonical axes, relative to the rest pose (lhmpp_msgs/BodyPose)",
            "root_rotation": quat(&pose.root_rotation),
            "root_translation": pose.root_translation.to_array(),
            "rotations": bones
                .into_iter()
                .map(|(name, q)| (name.clone(), json!(quat(q))))
                .collect::<serde_json::Map<_, _>>(),
        },
    })
}
