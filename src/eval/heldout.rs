//! Held-out-view evaluation of a synthetic bag (`lhmpp eval`): reconstruct from the input views,
//! pose the avatar with the ground-truth body pose, render the held-out cameras and score the
//! renders against the held-out images and masks.

use super::metrics::{mask_iou, psnr, ssim, ImageRef};
use crate::bag::{BagError, BagReader};
use crate::body::Pose;
use crate::config::{Delight, ModelConfig};
use crate::msgs::{BodyPose, BodyShape, CameraInfo, Image, TFMessage};
use crate::reconstruct::image_decode::{decode_raw, RawImage};
use crate::reconstruct::photo_colours::{colour_from_evidence, ViewEvidence};
use crate::reconstruct::preprocess::{preprocess, PreprocessConfig, Subject};
use crate::reconstruct::shape::check_shape;
use crate::reconstruct::{ReconstructError, Reconstructor};
use crate::splat::{render, Camera, RenderOptions};
use crate::synth::capture::{
    image_topic, info_topic, mask_topic, POSE_TOPIC, SHAPE_TOPIC, TF_STATIC_TOPIC,
};
use glam::{Affine3A, Quat, Vec3};
use std::collections::BTreeMap;
use std::path::Path;

/// An evaluation problem, naming the bag and what is missing.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// The bag could not be read.
    #[error(transparent)]
    Bag(#[from] BagError),
    /// The bag lacks ground truth the evaluation needs.
    #[error("{path}: {message}")]
    MissingGroundTruth {
        /// The bag.
        path: String,
        /// What is missing.
        message: String,
    },
    /// The reconstruction failed.
    #[error(transparent)]
    Reconstruct(#[from] ReconstructError),
    /// The refinement could not run.
    #[error(transparent)]
    Refine(#[from] crate::refine::RefineError),
}

/// Scores of one held-out view.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewScore {
    /// Held-out camera name.
    pub camera: String,
    /// PSNR (dB).
    pub psnr: f64,
    /// SSIM.
    pub ssim: f64,
    /// Mask IoU (render alpha ≥ 0.5 against the ground-truth mask).
    pub iou: f64,
}

/// The stages an evaluation runs between the bag and the scores, each as the node runs it or
/// switched off.
#[derive(Debug, Clone, Default)]
pub struct EvalStages {
    /// How the input views are located before the encoder.
    pub crop: InputCrop,
    /// The body shape reconstructed on.
    pub shape: ShapeSource,
    /// Where the avatar's colours come from.
    pub colours: ColourSource,
    /// Refinement against the input views (calibrated ones with a mask), when set.
    pub refine: Option<crate::refine::RefineConfig>,
}

/// Scores of one reconstruction (a number of input views) over all held-out views.
#[derive(Debug, Clone, PartialEq)]
pub struct EvalRow {
    /// What refinement did, when it ran.
    pub refine: Option<crate::refine::RefineReport>,
    /// Input views used.
    pub views: usize,
    /// Per held-out view.
    pub per_view: Vec<ViewScore>,
    /// A strip for people: up to four of the input views used | the first held-out view's
    /// ground truth | our render from that camera (all at the held-out height).
    pub picture: image::RgbImage,
}

impl EvalRow {
    /// Mean PSNR, SSIM and IoU over the held-out views.
    pub fn means(&self) -> (f64, f64, f64) {
        let n = self.per_view.len().max(1) as f64;
        let s = self.per_view.iter().fold((0.0, 0.0, 0.0), |a, v| {
            (a.0 + v.psnr, a.1 + v.ssim, a.2 + v.iou)
        });
        (s.0 / n, s.1 / n, s.2 / n)
    }
}

struct HeldoutView {
    name: String,
    camera: Camera,
    rgb: Vec<f32>,
    mask: Vec<f32>,
}

/// Ground truth read from a synthetic bag.
/// How the evaluation crops its input views before the encoder.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum InputCrop {
    /// Each view is cropped to the person by its `/camN/mask` in the bag, as the node does when
    /// `inputs.mask_topics` are set (a view without a mask falls back to the whole frame).
    #[default]
    Mask,
    /// Whole frames, as the node does without mask topics.
    FullFrame,
}

/// Which body shape the evaluation reconstructs on.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum ShapeSource {
    /// The bag's `BodyShape` when it carries one (the node with a shape topic), else the
    /// template's own shape.
    #[default]
    Bag,
    /// The template's own shape, whatever the bag carries (the node without a shape topic).
    Template,
    /// This MakeHuman shape.
    Fixed(crate::body::MakeHumanShape),
    /// The shape camera-only perception reads from the calibrated input views
    /// ([`crate::perception::shape`]; the template's own shape when it cannot).
    Estimate,
}

/// The body shape perception reads from the bag's calibrated input views: each view's image
/// landmarks (a fresh tracker per view, the `full` landmark model) triangulated with the
/// views' cameras; `None` when too few segments were seen.
pub fn estimate_bag_shape(
    path: &Path,
    template: &crate::body::BodyTemplate,
) -> Result<Option<crate::perception::shape::ShapeEstimate>, EvalError> {
    use crate::perception::shape::{estimate_shape, CalibratedView};
    use crate::perception::{LandmarkModel, PersonTracker, PoseNetworks, TrackerConfig};
    let failed = |message: String| EvalError::MissingGroundTruth {
        path: path.display().to_string(),
        message,
    };
    let scene = super::perception::read_scene(path).map_err(|e| failed(e.to_string()))?;
    let networks = std::sync::Arc::new(
        PoseNetworks::load(LandmarkModel::Full, None).map_err(|e| failed(e.to_string()))?,
    );
    let config = TrackerConfig {
        smooth_masks: false,
        ..TrackerConfig::default()
    };
    let mut views = Vec::new();
    for view in scene.views.iter().filter(|v| !v.heldout) {
        let mut tracker = PersonTracker::new(networks.clone(), config);
        let Some(seen) = tracker
            .perceive(&view.image)
            .map_err(|e| failed(e.to_string()))?
        else {
            continue;
        };
        let k = &view.camera.intrinsics;
        views.push(CalibratedView {
            fx: k.fx,
            fy: k.fy,
            cx: k.cx,
            cy: k.cy,
            world_from_camera: view.camera.world_from_camera,
            landmarks: seen.landmarks.image,
        });
    }
    estimate_shape(template, &views, 0.5).map_err(|e| failed(e.to_string()))
}

/// Where the avatar's colours come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ColourSource {
    /// The network's colours.
    #[default]
    Network,
    /// The input views perception reads the person in, as `perception.colours_from_views`
    /// in the node ([`crate::reconstruct::photo_colours`]), with the node's
    /// `perception.delight`.
    Views(Delight),
}

/// What perception sees of the person in each input view (a fresh tracker per view, the
/// `full` landmark model; the bag's mask where it has one, else perception's); `None` where
/// it finds nobody. A view whose camera the bag calibrates carries that camera and `pose`
/// (the bag's pose topic), as the node's views do when it has CameraInfo, TF and a pose topic.
fn perceive_inputs(
    path: &Path,
    inputs: &[InputView],
    pose: &Pose,
) -> Result<Vec<Option<ViewEvidence>>, EvalError> {
    use crate::perception::{LandmarkModel, PersonTracker, PoseNetworks, TrackerConfig};
    let failed = |message: String| EvalError::MissingGroundTruth {
        path: path.display().to_string(),
        message,
    };
    let networks = std::sync::Arc::new(
        PoseNetworks::load(LandmarkModel::Full, None).map_err(|e| failed(e.to_string()))?,
    );
    let config = TrackerConfig {
        smooth_masks: false,
        ..TrackerConfig::default()
    };
    inputs
        .iter()
        .map(|v| {
            let mut tracker = PersonTracker::new(networks.clone(), config);
            let seen = tracker
                .perceive(&v.rgb)
                .map_err(|e| failed(e.to_string()))?;
            Ok(seen.map(|p| {
                let mask = v.mask.clone().unwrap_or_else(|| p.mask.to_mask(0.5, 0.1));
                let evidence =
                    ViewEvidence::new(&v.rgb, &mask, &p.landmarks.image, &p.landmarks.world);
                match v.camera {
                    Some(camera) => evidence.with_calibration(camera, pose.clone()),
                    None => evidence,
                }
            }))
        })
        .collect()
}

/// One input view of the bag: its name, image, person mask (when the bag has one) and
/// calibrated camera (when the bag has its CameraInfo and a `/tf_static` pose).
struct InputView {
    name: String,
    rgb: image::RgbImage,
    mask: Option<image::GrayImage>,
    camera: Option<Camera>,
}

struct GroundTruth {
    inputs: Vec<InputView>,
    heldout: Vec<HeldoutView>,
    pose: Pose,
    /// The person's body shape, when the bag carries one (`lhmpp synth --publish-shape`).
    shape: Option<BodyShape>,
}

fn first<'a>(bag: &'a BagReader, topic: &str) -> Option<&'a crate::bag::BagMessage> {
    bag.messages().iter().find(|m| &*m.topic == topic)
}

/// Decodes one Image message of `topic`.
fn decode_message(
    bag: &BagReader,
    topic: &str,
    m: &crate::bag::BagMessage,
) -> Result<image::RgbImage, EvalError> {
    let msg: Image = bag.decode(m)?;
    decode_raw(topic, &RawImage::from(&msg), 1 << 14).map_err(|e| EvalError::MissingGroundTruth {
        path: bag.path().display().to_string(),
        message: e.to_string(),
    })
}

/// The first frame of `topic`, if any.
fn decode_image(bag: &BagReader, topic: &str) -> Result<Option<image::RgbImage>, EvalError> {
    first(bag, topic)
        .map(|m| decode_message(bag, topic, m))
        .transpose()
}

/// Every frame of `topic` in bag order (one per view: a moving camera gives several).
fn decode_all_images(bag: &BagReader, topic: &str) -> Result<Vec<image::RgbImage>, EvalError> {
    bag.messages()
        .iter()
        .filter(|m| &*m.topic == topic)
        .map(|m| decode_message(bag, topic, m))
        .collect()
}

/// Every mono8 mask on `topic`, in bag order.
fn decode_all_masks(bag: &BagReader, topic: &str) -> Result<Vec<image::GrayImage>, EvalError> {
    bag.messages()
        .iter()
        .filter(|m| &*m.topic == topic)
        .map(|m| {
            let msg: Image = bag.decode(m)?;
            let bad = || EvalError::MissingGroundTruth {
                path: bag.path().display().to_string(),
                message: format!("{topic}: expected a mono8 mask"),
            };
            if msg.encoding != "mono8" || msg.step != msg.width {
                return Err(bad());
            }
            image::GrayImage::from_raw(msg.width, msg.height, msg.data).ok_or_else(bad)
        })
        .collect()
}

fn read_ground_truth(bag: &BagReader) -> Result<GroundTruth, EvalError> {
    let missing = |message: String| EvalError::MissingGroundTruth {
        path: bag.path().display().to_string(),
        message,
    };
    let mut names: Vec<String> = bag
        .topics()
        .iter()
        .filter_map(|t| t.name.strip_suffix("/image_raw"))
        .map(|n| n.trim_start_matches('/').to_owned())
        .collect();
    names.sort_by_key(|n| {
        let digits: String = n.chars().filter(|c| c.is_ascii_digit()).collect();
        (n.starts_with("heldout"), digits.parse::<u32>().unwrap_or(0))
    });
    let tf: TFMessage = bag.decode(
        first(bag, TF_STATIC_TOPIC).ok_or_else(|| missing(format!("no {TF_STATIC_TOPIC}")))?,
    )?;
    let poses: BTreeMap<String, Affine3A> = tf
        .transforms
        .iter()
        .map(|t| {
            let q: Quat = t.transform.rotation.into();
            let p: Vec3 = t.transform.translation.into();
            (
                t.child_frame_id.clone(),
                Affine3A::from_rotation_translation(q, p),
            )
        })
        .collect();
    let body: BodyPose =
        bag.decode(first(bag, POSE_TOPIC).ok_or_else(|| missing(format!("no {POSE_TOPIC}")))?)?;
    let pose = body
        .to_pose()
        .map_err(|e| missing(format!("{POSE_TOPIC}: {e}")))?;
    let mut inputs = Vec::new();
    let mut heldout = Vec::new();
    for name in names {
        if !name.starts_with("heldout") {
            let frames = decode_all_images(bag, &image_topic(&name))?;
            let mut masks = decode_all_masks(bag, &mask_topic(&name))?.into_iter();
            let several = frames.len() > 1;
            // A fixed camera's calibration (a moving camera's poses are on /tf, not read here).
            let camera = if several {
                None
            } else {
                let info = first(bag, &info_topic(&name))
                    .map(|m| bag.decode::<CameraInfo>(m))
                    .transpose()?;
                let pose = poses.get(&crate::synth::capture::optical_frame(&name));
                info.zip(pose).map(|(info, pose)| {
                    Camera::from_camera_info(info.k, info.width, info.height, *pose)
                })
            };
            for (i, rgb) in frames.into_iter().enumerate() {
                let view = if several {
                    format!("{name}#{i}")
                } else {
                    name.clone()
                };
                let mask = masks.next().filter(|m| m.dimensions() == rgb.dimensions());
                inputs.push(InputView {
                    name: view,
                    rgb,
                    mask,
                    camera,
                });
            }
            continue;
        }
        let rgb = decode_image(bag, &image_topic(&name))?
            .ok_or_else(|| missing(format!("no {}", image_topic(&name))))?;
        let info: CameraInfo = bag.decode(
            first(bag, &info_topic(&name))
                .ok_or_else(|| missing(format!("no {}", info_topic(&name))))?,
        )?;
        let frame = crate::synth::capture::optical_frame(&name);
        let world_from_camera = *poses
            .get(&frame)
            .ok_or_else(|| missing(format!("no transform to {frame} in {TF_STATIC_TOPIC}")))?;
        let mask_msg: Image = bag.decode(
            first(bag, &mask_topic(&name))
                .ok_or_else(|| missing(format!("no {}", mask_topic(&name))))?,
        )?;
        if mask_msg.encoding != "mono8" || mask_msg.data.len() != rgb.as_raw().len() / 3 {
            return Err(missing(format!(
                "{}: expected a mono8 mask of the image size",
                mask_topic(&name)
            )));
        }
        let mask: Vec<f32> = mask_msg.data.iter().map(|v| *v as f32 / 255.0).collect();
        heldout.push(HeldoutView {
            camera: Camera::from_camera_info(info.k, info.width, info.height, world_from_camera),
            rgb: rgb.as_raw().iter().map(|v| *v as f32 / 255.0).collect(),
            mask,
            name,
        });
    }
    if inputs.is_empty() || heldout.is_empty() {
        return Err(missing(
            "needs input views (/camN/image_raw) and held-out views (/heldoutN/...), as made by `lhmpp synth`".into(),
        ));
    }
    let shape = first(bag, SHAPE_TOPIC).map(|m| bag.decode(m)).transpose()?;
    Ok(GroundTruth {
        inputs,
        heldout,
        pose,
        shape,
    })
}

/// `k` of `n` view indices spread evenly over `0..n` (all of them when `k >= n`).
fn spread(n: usize, k: usize) -> Vec<usize> {
    let k = k.clamp(1, n.max(1));
    (0..k).map(|i| i * n / k).collect()
}

/// Reconstructs from `k` input views spread evenly over the bag's views (every `n/k`-th: on a
/// camera ring, cameras all around the person) for each `k` in `view_counts` (clamped to the
/// views in the bag) and scores the held-out views. `crop` says how the input views are
/// located (by their masks, or whole frames). Every frame of an input camera topic is a
/// view (a moving-camera bag has one topic with several frames).
pub fn evaluate_bag(
    path: &Path,
    model: &ModelConfig,
    view_counts: &[usize],
    stages: &EvalStages,
) -> Result<Vec<EvalRow>, EvalError> {
    let EvalStages {
        crop,
        shape,
        colours,
        ref refine,
    } = *stages;
    let bag = BagReader::open(path)?;
    let gt = read_ground_truth(&bag)?;
    let evidence = match colours {
        ColourSource::Network => Vec::new(),
        ColourSource::Views(_) => perceive_inputs(path, &gt.inputs, &gt.pose)?,
    };
    let mut recon = Reconstructor::new(model, gt.inputs.len())?;
    // Reconstruct on the person's body shape, as the node does when a shape topic is set.
    let makehuman = |s: crate::body::MakeHumanShape| BodyShape {
        body_model: crate::body::MAKEHUMAN_MODEL_ID.into(),
        shape_params: s.params().to_vec(),
        ..BodyShape::default()
    };
    let given = match shape {
        ShapeSource::Bag => gt.shape.clone(),
        ShapeSource::Template => None,
        ShapeSource::Fixed(s) => Some(makehuman(s)),
        ShapeSource::Estimate => {
            let estimate = estimate_bag_shape(path, recon.template())?;
            tracing::info!(bag = %path.display(), ?estimate, "body shape read from the views");
            estimate.map(|e| makehuman(e.shape))
        }
    };
    if let Some(shape) = &given {
        let accepted = check_shape(SHAPE_TOPIC, shape, recon.body_model()).map_err(|e| {
            EvalError::MissingGroundTruth {
                path: path.display().to_string(),
                message: e.to_string(),
            }
        })?;
        recon.set_shape(accepted)?;
    }
    let (h, w) = recon.input_size();
    let pre = PreprocessConfig {
        out_height: h,
        out_width: w,
        ..PreprocessConfig::default()
    };
    let images = gt
        .inputs
        .iter()
        .map(|v| {
            let subject = match (&v.mask, crop) {
                (Some(mask), InputCrop::Mask) => Subject::Mask(mask),
                _ => Subject::FullFrame,
            };
            preprocess(&v.rgb, subject, &pre).map_err(|e| EvalError::MissingGroundTruth {
                path: path.display().to_string(),
                message: format!("{}: {e}", v.name),
            })
        })
        .collect::<Result<Vec<_>, _>>()?;
    let matrices = recon.template().skeleton.skinning_matrices(&gt.pose);
    let options = RenderOptions {
        background: Vec3::ONE,
        ..RenderOptions::default()
    };
    let mut rows = Vec::new();
    let mut counts: Vec<usize> = view_counts
        .iter()
        .map(|k| (*k).clamp(1, images.len()))
        .collect();
    counts.dedup();
    for k in counts {
        let views: Vec<_> = spread(images.len(), k)
            .into_iter()
            .map(|i| (i as u64 + 1, &images[i]))
            .collect();
        let mut avatar = recon.reconstruct(&views)?;
        // The key light divided out of the views' colours, and each view's exposure in it.
        let mut light: Option<(crate::reconstruct::delight::KeyLight, BTreeMap<usize, f32>)> = None;
        if let ColourSource::Views(delight) = colours {
            let chosen: Vec<(usize, &ViewEvidence)> = spread(images.len(), k)
                .into_iter()
                .filter_map(|i| Some((i, evidence[i].as_ref()?)))
                .collect();
            let seen: Vec<&ViewEvidence> = chosen.iter().map(|(_, e)| *e).collect();
            let report = colour_from_evidence(&mut avatar, recon.template(), &seen, delight);
            let modelled = delight != crate::config::Delight::Never;
            light = modelled.then(|| {
                let l = report.lights.into_iter().next().unwrap_or_default();
                let exposure = chosen
                    .iter()
                    .enumerate()
                    .map(|(photo, (i, _))| (*i, l.exposure.get(photo).copied().unwrap_or(0.0)))
                    .collect();
                (l, exposure)
            });
        }
        let refined = match refine {
            Some(cfg) => {
                let views = spread(images.len(), k)
                    .into_iter()
                    .filter_map(|i| {
                        let v = &gt.inputs[i];
                        let (mask, camera) = (v.mask.as_ref()?, v.camera?);
                        let mut view = crate::refine::RefineView::new(
                            &v.name,
                            &v.rgb,
                            mask,
                            camera,
                            matrices.clone(),
                            cfg.max_side,
                        )
                        .ok()?;
                        if let Some((_, exposure)) = &light {
                            view.exposure = exposure.get(&i).copied().unwrap_or(0.0);
                        }
                        Some(view)
                    })
                    .collect();
                let start = light.as_ref().map(|(key, _)| crate::refine::LightStart {
                    key: key.clone(),
                    normals: crate::reconstruct::surface::canonical_normals(
                        &avatar,
                        recon.template(),
                    )
                    .0,
                });
                let out = crate::refine::refine(&avatar, views, start, cfg, |p| {
                    tracing::debug!(?p, "refine");
                    true
                })?;
                avatar = out.avatar;
                Some(out.report)
            }
            None => None,
        };
        let posed = avatar.animate(&matrices);
        let mut first_render = None;
        let per_view = gt
            .heldout
            .iter()
            .map(|v| {
                let out = render(&posed, &v.camera, &options);
                if first_render.is_none() {
                    first_render = Some(out.to_rgb8());
                }
                let rgb: Vec<f32> = out.rgb.iter().map(|x| x.clamp(0.0, 1.0)).collect();
                let (w, h) = (out.width as usize, out.height as usize);
                ViewScore {
                    camera: v.name.clone(),
                    psnr: psnr(ImageRef::new(&rgb, w, h, 3), ImageRef::new(&v.rgb, w, h, 3)),
                    ssim: ssim(ImageRef::new(&rgb, w, h, 3), ImageRef::new(&v.rgb, w, h, 3)),
                    iou: mask_iou(&out.alpha, &v.mask),
                }
            })
            .collect();
        let shown: Vec<&image::RgbImage> = spread(gt.inputs.len(), k.min(4))
            .into_iter()
            .map(|i| &gt.inputs[i].rgb)
            .collect();
        let picture = comparison_strip(&shown, &gt.heldout[0], first_render.as_ref(), k);
        rows.push(EvalRow {
            refine: refined,
            views: k,
            per_view,
            picture,
        });
    }
    Ok(rows)
}

/// Input views | held-out ground truth | render, side by side at the held-out height, each
/// captioned ("input 1", ..., "truth, held out", "ours, K views").
fn comparison_strip(
    inputs: &[&image::RgbImage],
    heldout: &HeldoutView,
    render: Option<&image::RgbImage>,
    views: usize,
) -> image::RgbImage {
    use image::imageops::{resize, FilterType};
    let (w, h) = (
        heldout.camera.intrinsics.width,
        heldout.camera.intrinsics.height,
    );
    let truth = image::RgbImage::from_fn(w, h, |x, y| {
        let i = 3 * (y * w + x) as usize;
        let c = |k: usize| (heldout.rgb[i + k].clamp(0.0, 1.0) * 255.0).round() as u8;
        image::Rgb([c(0), c(1), c(2)])
    });
    let mut tiles: Vec<(image::RgbImage, String)> = inputs
        .iter()
        .enumerate()
        .map(|(i, im)| {
            let tw = (im.width() as u64 * h as u64 / im.height().max(1) as u64).max(1) as u32;
            (
                resize(*im, tw, h, FilterType::Triangle),
                format!("input {}", i + 1),
            )
        })
        .collect();
    tiles.push((truth, "truth, held out".into()));
    if let Some(r) = render {
        let plural = if views == 1 { "" } else { "s" };
        tiles.push((r.clone(), format!("ours, {views} view{plural}")));
    }
    let refs: Vec<(&image::RgbImage, &str)> = tiles.iter().map(|(t, c)| (t, c.as_str())).collect();
    let scale = if h >= 160 { 2 } else { 1 };
    crate::picture::captioned_row(&refs, scale, 12, image::Rgb([255, 255, 255]))
}
