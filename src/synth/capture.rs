//! Renders a synthetic person from a rig and writes everything a test or the demo needs into a
//! rosbag2-layout MCAP bag: input images, camera calibration, camera poses (`/tf_static` for
//! fixed cameras, `/tf` per frame for a moving one), the body pose, and held-out views with
//! masks for scoring.

use super::camera_fx::CameraEffects;
use super::dataset::Realism;
use super::dressed::DressedPerson;
use super::lighting::Lighting;
use super::outfit::Outfit;
use super::person::{SynthError, SyntheticPerson};
use super::random_pose::grounded_random_pose;
use super::scene::{Rig, RigCamera};
use crate::bag::{BagWriter, BagWriterOptions};
use crate::body::{motion, Pose};
use crate::msgs::{
    BodyPose, BodyShape, CameraInfo, Header, Image, TFMessage, Time, Transform, TransformStamped,
};
use crate::splat::{render, RenderOptions, RenderOutput};
use glam::Vec3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::path::Path;

/// World frame of synthetic bags: the body's canonical frame (+Y up, person facing +Z).
pub const WORLD_FRAME: &str = "world";
/// Topic of the ground-truth body pose.
pub const POSE_TOPIC: &str = "/lhmpp/body_pose";
/// Topic of the ground-truth body shape (written only with [`SynthOptions::publish_shape`]).
pub const SHAPE_TOPIC: &str = "/lhmpp/body_shape";
/// Topic of the static camera poses.
pub const TF_STATIC_TOPIC: &str = "/tf_static";
/// Topic of the moving camera's pose, one message per frame.
pub const TF_TOPIC: &str = "/tf";
/// First stamp written (nanoseconds since the epoch): 2023-11-14T22:13:20Z.
pub const START_NS: u64 = 1_700_000_000_000_000_000;

/// Image topic of camera `name`.
pub fn image_topic(name: &str) -> String {
    format!("/{name}/image_raw")
}
/// CameraInfo topic of camera `name`.
pub fn info_topic(name: &str) -> String {
    format!("/{name}/camera_info")
}
/// Mask topic of camera `name` (mono8, 255 = person).
pub fn mask_topic(name: &str) -> String {
    format!("/{name}/mask")
}
/// Optical frame id of camera `name`.
pub fn optical_frame(name: &str) -> String {
    format!("{name}_optical_frame")
}

/// What `lhmpp synth` makes.
#[derive(Debug, Clone, PartialEq)]
pub struct SynthOptions {
    /// Seed of the person, outfit, pose and cameras.
    pub seed: u64,
    /// Input views.
    pub views: usize,
    /// Held-out views for scoring.
    pub heldout: usize,
    /// Image side in pixels.
    pub size: u32,
    /// Gaussians on the ground-truth body.
    pub points: usize,
    /// The person's pose.
    pub pose: SynthPose,
    /// How the input views are taken.
    pub camera: CameraMode,
    /// Also write the ground-truth `BodyShape` (`makehuman-cc0` [height_scale, girth_scale])
    /// on [`SHAPE_TOPIC`]; off by default so existing fixtures keep their bytes.
    pub publish_shape: bool,
    /// Give the person's upper garments a back of another colour (a shirt back for plain
    /// people, a back panel on dressed people's tops, one-pieces and coats): people whose
    /// back differs from their front, for measuring what more views add.
    pub contrasting_back: bool,
}

/// The pose of the synthetic person.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SynthPose {
    /// The canonical rest pose.
    Rest,
    /// A frame of the built-in walk cycle.
    Walk(f32),
    /// Seeded random joint rotations within [`super::random_pose::JOINT_LIMITS`].
    Random,
}

/// Where the input views come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CameraMode {
    /// `views` fixed cameras `cam0..` on a ring (poses on `/tf_static`).
    Ring,
    /// One camera `cam0` moving around the person, `views` frames (pose on `/tf` per frame).
    Moving,
}

impl Default for SynthOptions {
    fn default() -> Self {
        Self {
            seed: 0,
            views: 4,
            heldout: 2,
            size: 256,
            points: 30_000,
            pose: SynthPose::Walk(8.0),
            camera: CameraMode::Ring,
            publish_shape: false,
            contrasting_back: false,
        }
    }
}

/// What was written.
#[derive(Debug, Clone, PartialEq)]
pub struct SynthSummary {
    /// Messages written.
    pub messages: u64,
    /// Bag size in bytes.
    pub bytes: u64,
}

/// A rendered view with its camera.
pub struct RenderedView<'a> {
    /// The camera.
    pub rig: &'a RigCamera,
    /// Its render of the posed person.
    pub output: RenderOutput,
}

/// The pose of `person` (person 0 of the bag) for `options`.
pub fn synth_pose(options: &SynthOptions, person: &SyntheticPerson) -> Pose {
    match options.pose {
        SynthPose::Rest => Pose::identity(),
        SynthPose::Walk(frame) => motion::walk_pose(frame),
        SynthPose::Random => grounded_random_pose(&person.template, options.seed, 0),
    }
}

/// Renders the person posed by `pose` from `cameras` on a white background.
pub fn render_views<'a>(
    person: &SyntheticPerson,
    pose: &Pose,
    cameras: &'a [RigCamera],
) -> Result<Vec<RenderedView<'a>>, SynthError> {
    let matrices = person
        .template
        .skeleton
        .try_skinning_matrices(pose)
        .map_err(|e| SynthError::Pose(e.to_string()))?;
    let posed = person.avatar.animate(&matrices);
    let options = RenderOptions {
        background: Vec3::ONE,
        ..RenderOptions::default()
    };
    Ok(cameras
        .iter()
        .map(|rig| RenderedView {
            rig,
            output: render(&posed, &rig.camera, &options),
        })
        .collect())
}

/// The person a bag shows.
enum Subject {
    Plain(Box<SyntheticPerson>),
    Dressed(Box<DressedPerson>),
}

impl Subject {
    fn template(&self) -> &crate::body::BodyTemplate {
        match self {
            Subject::Plain(p) => &p.template,
            Subject::Dressed(p) => &p.template,
        }
    }

    fn shape(&self) -> crate::body::MakeHumanShape {
        match self {
            Subject::Plain(p) => p.shape(),
            Subject::Dressed(p) => p.shape(),
        }
    }

    /// The views from `cameras`; a dressed person's input views lit (lighting and effects
    /// seeded by `seed`), its held-out views unlit.
    fn render<'a>(
        &self,
        pose: &Pose,
        cameras: &'a [RigCamera],
        input: bool,
        seed: u64,
    ) -> Result<Vec<RenderedView<'a>>, SynthError> {
        match self {
            Subject::Plain(p) => render_views(p, pose, cameras),
            Subject::Dressed(p) => render_dressed_views(p, pose, cameras, input, seed),
        }
    }
}

/// Renders a dressed person posed by `pose` from `cameras` on white: `lit` views under the
/// seeded lighting of `seed`, each through its seeded camera effects (the background stays
/// white); unlit views show the albedo.
pub fn render_dressed_views<'a>(
    person: &DressedPerson,
    pose: &Pose,
    cameras: &'a [RigCamera],
    lit: bool,
    seed: u64,
) -> Result<Vec<RenderedView<'a>>, SynthError> {
    let matrices = person
        .template
        .skeleton
        .try_skinning_matrices(pose)
        .map_err(|e| SynthError::Pose(e.to_string()))?;
    let posed = person.avatar.animate(&matrices);
    let options = RenderOptions {
        background: Vec3::ONE,
        ..RenderOptions::default()
    };
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x6c69_6768_7473);
    let lighting = Lighting::random(&mut rng);
    tracing::debug!(?lighting, "lighting of the lit views");
    let shadow = match lighting.lights.first() {
        Some(key) if lit => Some(person.light_visibility(&matrices, &posed, key.direction)?),
        _ => None,
    };
    Ok(cameras
        .iter()
        .map(|rig| {
            if !lit {
                let output = render(&posed, &rig.camera, &options);
                return RenderedView { rig, output };
            }
            let eye = Vec3::from(rig.camera.world_from_camera.translation);
            let mut output = render(
                &lighting.lit(person, &posed, eye, shadow.as_deref(), false),
                &rig.camera,
                &options,
            );
            let effects = CameraEffects::random(&mut rng);
            let image = effects.apply(&output.rgb, output.width, output.height);
            for (i, p) in image.pixels().enumerate() {
                let white = output.alpha[i] < 1.0 / 255.0;
                for c in 0..3 {
                    output.rgb[3 * i + c] = if white { 1.0 } else { p.0[c] as f32 / 255.0 };
                }
            }
            RenderedView { rig, output }
        })
        .collect())
}

fn header(ns: u64, frame: &str) -> Header {
    Header::new(Time::from_nanos(ns as i64), frame)
}

/// The rgb8 image message of a rendered view, stamped `ns`.
pub(crate) fn rgb_image(view: &RenderedView, ns: u64) -> Image {
    let rgb = view.output.to_rgb8();
    Image {
        header: header(ns, &optical_frame(&view.rig.name)),
        height: rgb.height(),
        width: rgb.width(),
        encoding: "rgb8".into(),
        is_bigendian: 0,
        step: 3 * rgb.width(),
        data: rgb.into_raw(),
    }
}

/// The true mono8 mask of a rendered view (255 where its alpha is at least ½), stamped `ns`.
pub(crate) fn mask_image(view: &RenderedView, ns: u64) -> Image {
    let data: Vec<u8> = view
        .output
        .alpha
        .iter()
        .map(|a| if *a >= 0.5 { 255 } else { 0 })
        .collect();
    Image {
        header: header(ns, &optical_frame(&view.rig.name)),
        height: view.output.height,
        width: view.output.width,
        encoding: "mono8".into(),
        is_bigendian: 0,
        step: view.output.width,
        data,
    }
}

/// The calibration message of `rig` (no distortion), stamped `ns`.
pub fn camera_info(rig: &RigCamera, ns: u64) -> CameraInfo {
    let i = &rig.camera.intrinsics;
    let k = i.k();
    CameraInfo {
        header: header(ns, &optical_frame(&rig.name)),
        height: i.height,
        width: i.width,
        distortion_model: "plumb_bob".into(),
        d: vec![0.0; 5],
        k,
        r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: [
            k[0], 0.0, k[2], 0.0, 0.0, k[4], k[5], 0.0, 0.0, 0.0, 1.0, 0.0,
        ],
        ..CameraInfo::default()
    }
}

/// The world pose of `rig`'s optical frame, stamped `ns`.
pub(crate) fn camera_transform(rig: &RigCamera, ns: u64) -> TransformStamped {
    let (_, rotation, translation) = rig.camera.world_from_camera.to_scale_rotation_translation();
    TransformStamped {
        header: header(ns, WORLD_FRAME),
        child_frame_id: optical_frame(&rig.name),
        transform: Transform {
            translation: translation.into(),
            rotation: rotation.normalize().into(),
        },
    }
}

/// Renders the person of `options.seed` and writes the bag at `path`.
pub fn write_synthetic_bag(
    path: &Path,
    options: &SynthOptions,
) -> Result<SynthSummary, SynthError> {
    write_bag(path, options, Realism::Plain)
}

/// Like [`write_synthetic_bag`], with plain or dressed people ([`Realism`]). A dressed
/// person's input views are lit by a seeded [`Lighting`] and pass through seeded
/// [`CameraEffects`] (on white); its held-out views are unlit (albedo), what a reconstructed
/// avatar should show.
pub fn write_bag(
    path: &Path,
    options: &SynthOptions,
    realism: Realism,
) -> Result<SynthSummary, SynthError> {
    let subject = match realism {
        Realism::Plain => {
            let mut outfit = Outfit::random(options.seed);
            if options.contrasting_back {
                outfit = outfit.with_contrasting_back(options.seed);
            }
            Subject::Plain(Box::new(SyntheticPerson::wearing(
                options.seed,
                options.points,
                outfit,
            )?))
        }
        Realism::Dressed => Subject::Dressed(Box::new(DressedPerson::new_with(
            options.seed,
            options.points,
            options.contrasting_back,
        )?)),
    };
    let template = subject.template();
    let (seed, views, heldout, size) = (options.seed, options.views, options.heldout, options.size);
    let height = template.height();
    let rig = match options.camera {
        CameraMode::Ring => Rig::ring(seed, views, heldout, size, height),
        CameraMode::Moving => Rig::moving(seed, views, heldout, size, height),
    };
    let pose = match options.pose {
        SynthPose::Rest => Pose::identity(),
        SynthPose::Walk(frame) => motion::walk_pose(frame),
        SynthPose::Random => grounded_random_pose(template, options.seed, 0),
    };
    // No time-based flushing: the same seed must give the same bytes.
    let options_bag = BagWriterOptions {
        flush_interval: None,
        ..BagWriterOptions::default()
    };
    let mut bag = BagWriter::create_with(path, options_bag)?;
    let ns = START_NS;
    let fixed: Vec<&RigCamera> = match options.camera {
        CameraMode::Ring => rig.inputs.iter().chain(&rig.heldout).collect(),
        CameraMode::Moving => rig.heldout.iter().collect(),
    };
    bag.write(
        TF_STATIC_TOPIC,
        ns,
        &TFMessage {
            transforms: fixed.iter().map(|c| camera_transform(c, ns)).collect(),
        },
    )?;
    bag.write(
        POSE_TOPIC,
        ns,
        &BodyPose::from_pose(header(ns, WORLD_FRAME), "person_0", &pose),
    )?;
    tracing::debug!(shape = ?subject.shape(), "the person's body shape");
    if let Subject::Dressed(p) = &subject {
        if let Ok(room) = super::dressing_room::DressingRoom::shared() {
            let worn: Vec<&str> = p
                .wardrobe
                .garments
                .iter()
                .filter_map(|g| room.library.garments.get(g.index).map(|g| g.name.as_str()))
                .collect();
            tracing::info!(?worn, scalp = ?p.wardrobe.scalp, "the person's outfit");
        }
    }
    if options.publish_shape {
        bag.write(
            SHAPE_TOPIC,
            ns,
            &BodyShape {
                header: header(ns, WORLD_FRAME),
                person_id: "person_0".into(),
                body_model: crate::body::MAKEHUMAN_MODEL_ID.into(),
                shape_params: subject.shape().params().to_vec(),
            },
        )?;
    }
    for (cameras, moving, input) in [
        (&rig.inputs, options.camera == CameraMode::Moving, true),
        (&rig.heldout, false, false),
    ] {
        for (i, view) in subject
            .render(&pose, cameras, input, seed)?
            .iter()
            .enumerate()
        {
            // Views arrive 50 ms apart, as from a camera ring triggered in sequence or one
            // camera at 20 fps.
            let t = ns + 50_000_000 * (i as u64 + 1);
            let name = &view.rig.name;
            bag.write(&info_topic(name), t, &camera_info(view.rig, t))?;
            if moving {
                let transforms = vec![camera_transform(view.rig, t)];
                bag.write(TF_TOPIC, t, &TFMessage { transforms })?;
            }
            bag.write(&image_topic(name), t, &rgb_image(view, t))?;
            bag.write(&mask_topic(name), t, &mask_image(view, t))?;
        }
    }
    let messages = bag.finish()?;
    let bytes = std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
    Ok(SynthSummary { messages, bytes })
}
