//! Training samples for the default model (`lhmpp synth-dataset`): one seeded synthetic person
//! per sample, its input views preprocessed exactly as the node does, the anchor points the
//! node samples on that person's (shaped) template, per-anchor ground truth (canonical colour)
//! and low-resolution target views (cameras, images, alpha) for render losses.
//!
//! Seeds below [`TRAIN_SEED_START`] are reserved for evaluation and are refused here, so an
//! evaluation person is never trained on.

mod dressed;

use super::outfit::Rgb;
use super::person::{SynthError, SyntheticPerson};
use super::random_pose::grounded_random_pose;
use super::scene::{Rig, RigCamera};
use crate::avatar::Avatar;
use crate::body::{motion, BodyTemplate, Pose, MAKEHUMAN_MODEL_ID};
use crate::reconstruct::preprocess::{preprocess, PreprocessConfig, Subject};
use crate::splat::{render, Camera, Gaussians, RenderOptions};
use glam::{Affine3A, Quat, Vec3};
use image::{GrayImage, RgbImage};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::path::Path;

/// First seed that may be trained on; seeds below it are evaluation people.
pub const TRAIN_SEED_START: u64 = 1_000_000;

/// What the samples look like.
#[derive(Debug, Clone, PartialEq)]
pub struct DatasetOptions {
    /// Anchor points per person (the node's `model.num_points`).
    pub points: usize,
    /// Anchor sampling seed (the node's `model.seed`).
    pub anchor_seed: u64,
    /// Encoder input height (the network's `image_height`).
    pub input_height: u32,
    /// Encoder input width (the network's `image_width`).
    pub input_width: u32,
    /// Side of the target views.
    pub target_size: u32,
    /// Most input views of one sample (at least 1).
    pub max_views: usize,
    /// Held-out target cameras per sample (besides one input camera).
    pub heldout_targets: usize,
    /// Gaussians of the ground-truth person.
    pub person_points: usize,
    /// Fraction of input views cropped to the person by its mask (`Subject::Mask`, as the node
    /// does with `inputs.mask_topics`); the others are whole frames.
    pub mask_fraction: f64,
    /// The people: plain (the template painted by body part, flat colours) or dressed and lit
    /// ([`Realism::Dressed`]).
    pub realism: Realism,
    /// With [`Realism::Dressed`], the fraction of samples (by seed) that are dressed; the others
    /// are plain.
    pub dressed_fraction: f64,
    /// Fraction of samples (by seed) whose anchors sit where the node puts them without
    /// knowing the person's girth: on the template of the person's height with girth 1
    /// (calibrated views read the height only; [`crate::perception::shape`]), posed with that
    /// template's skeleton. The targets stay the true person, so the network learns to reach
    /// the true surface from there.
    pub girth_one_fraction: f64,
}

impl Default for DatasetOptions {
    fn default() -> Self {
        Self {
            points: 4096,
            anchor_seed: 1,
            input_height: 112,
            input_width: 112,
            target_size: 96,
            max_views: 8,
            heldout_targets: 2,
            person_points: 20_000,
            mask_fraction: 0.25,
            realism: Realism::Plain,
            dressed_fraction: 1.0,
            girth_one_fraction: 0.0,
        }
    }
}

/// Synthetic people of a dataset or bag.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Realism {
    /// The naked template painted by body part with flat colours, rendered unlit.
    #[default]
    Plain,
    /// Dressed people (garments, hair, shoes, procedural materials) whose input views are lit
    /// and pass through camera effects over textured backgrounds; targets and ground truth
    /// are the albedo (see `dataset/dressed.rs`).
    Dressed,
}

/// Whether sample `seed` of a dataset with `options` is dressed.
pub fn is_dressed(seed: u64, options: &DatasetOptions) -> bool {
    if options.realism != Realism::Dressed {
        return false;
    }
    let draw = crate::synth::material::hash3(seed, [0x64, 0x72, 0x73]) as f64;
    draw < options.dressed_fraction
}

/// Whether `seed`'s anchors sit on the girth-1 template ([`DatasetOptions::girth_one_fraction`]).
pub fn anchors_at_girth_one(seed: u64, options: &DatasetOptions) -> bool {
    let draw = crate::synth::material::hash3(seed, [0x67, 0x69, 0x31]) as f64;
    draw < options.girth_one_fraction
}

/// `anchors` (on `template`, the person's shaped template) moved to where they are on the
/// template of the same height with girth 1 (x and z divided by the girth scale; normals
/// transformed by the inverse transpose), and posed by `pose` with that template's skeleton.
/// Returns the moved anchors and their posed frame.
pub(crate) fn girth_one_anchors(
    template: &crate::body::BodyTemplate,
    girth: f32,
    anchors: &crate::body::AnchorPoints,
    pose: &Pose,
) -> Result<(crate::body::AnchorPoints, Gaussians), SynthError> {
    let scale = Vec3::new(1.0 / girth, 1.0, 1.0 / girth);
    let mut moved = anchors.clone();
    for (p, n) in moved.positions.iter_mut().zip(&mut moved.normals) {
        *p *= scale;
        *n = (*n / scale).normalize_or_zero();
    }
    let mut skeleton = template.skeleton.clone();
    for j in &mut skeleton.joints {
        *j *= scale;
    }
    let matrices = skeleton
        .try_skinning_matrices(pose)
        .map_err(|e| SynthError::Pose(e.to_string()))?;
    let n = moved.positions.len();
    let frame = Gaussians::from_rgb(
        moved.positions.clone(),
        vec![Vec3::splat(0.01); n],
        vec![Quat::IDENTITY; n],
        vec![1.0; n],
        &vec![Vec3::ZERO; n],
    )?;
    let posed = Avatar::new(frame, moved.skin.clone(), MAKEHUMAN_MODEL_ID)?.animate(&matrices);
    Ok((moved, posed))
}

/// One training sample (flat row-major arrays; shapes in the field docs).
#[derive(Debug, Clone)]
pub struct TrainingSample {
    /// The person's seed.
    pub seed: u64,
    /// Input views `V`.
    pub views: usize,
    /// Preprocessed input views `[V, 3, H, W]`, 8-bit (the node's f32 input is `v / 255`).
    pub images: Vec<u8>,
    /// `(H, W)` of the input views.
    pub image_size: (usize, usize),
    /// Anchor positions `[N, 3]` on the shaped template (canonical frame).
    pub anchors: Vec<f32>,
    /// Anchor normals `[N, 3]`.
    pub normals: Vec<f32>,
    /// Ground-truth canonical colour per anchor `[N, 3]`.
    pub colors: Vec<f32>,
    /// Anchors posed by the sample's body pose `[N, 3]` (world frame).
    pub posed_anchors: Vec<f32>,
    /// Per-anchor skinning rotation of that pose, `[N, 4]` as (w, x, y, z).
    pub posed_rotations: Vec<f32>,
    /// Target images `[T, 3, R, R]` on white, 8-bit.
    pub target_rgb: Vec<u8>,
    /// Target alpha `[T, R, R]`, 8-bit.
    pub target_alpha: Vec<u8>,
    /// Target intrinsics `[T, 4]`: fx, fy, cx, cy (pixels of the R×R target).
    pub target_intrinsics: Vec<f32>,
    /// Target extrinsics `[T, 3, 4]`: camera_from_world (optical frame, +Z forward).
    pub target_camera_from_world: Vec<f32>,
    /// Height scale and girth scale of the person (the BodyShape the node would receive).
    pub shape: [f32; 2],
    /// Where each anchor shows in each preprocessed input view, `[V, N, 2]` as (column, row)
    /// pixel of the `W × H` encoder input, [`HIDDEN_ANCHOR`] for both where the anchor is
    /// hidden (behind the body, outside the view): for trainer-only losses that need to know
    /// which image patch shows which anchor. The network never receives it.
    pub anchor_pixels: Vec<u16>,
    /// Dressed samples: what each anchor's colour comes from, `[N]`: 0 the skin, `1 + i`
    /// garment `i` of the garment library.
    pub anchor_garment: Option<Vec<u8>>,
    /// Dressed samples: where the outermost surface over each anchor is, `[N, 3]` (canonical
    /// frame, shaped): the anchor plus the offset a Gaussian needs to sit on the garment.
    pub anchor_surface: Option<Vec<f32>>,
}

/// [`TrainingSample::anchor_pixels`] of an anchor a view does not show.
pub const HIDDEN_ANCHOR: u16 = u16::MAX;

/// An input view as rendered before preprocessing, kept to locate the anchors in it.
struct RenderedInput {
    camera: Camera,
    region: crate::reconstruct::preprocess::BBox,
    width: u32,
    height: u32,
    alpha: Vec<f32>,
    depth: Vec<f32>,
}

/// Depth slack of the visibility test: an anchor this far behind the rendered surface still
/// counts as seen (metres; the surface's expected depth blends a few Gaussians).
const VISIBLE_DEPTH_SLACK: f32 = 0.04;

impl RenderedInput {
    /// The (column, row) pixel of world point `p` in the preprocessed `width × height` input, or
    /// `None` when the view does not show it (outside the frame, on the background, or behind
    /// the rendered surface).
    fn locate(&self, p: Vec3, width: u32, height: u32) -> Option<[u16; 2]> {
        let q = self.camera.camera_from_world().transform_point3(p);
        if q.z <= 1e-3 {
            return None;
        }
        let uv = self.camera.project_camera_point(q);
        let (x, y) = (uv.x.round(), uv.y.round());
        if x < 0.0 || y < 0.0 || x >= self.width as f32 || y >= self.height as f32 {
            return None;
        }
        let i = (y as u32 * self.width + x as u32) as usize;
        if self.alpha[i] < 0.5 || q.z > self.depth[i] + VISIBLE_DEPTH_SLACK {
            return None;
        }
        let r = self.region;
        let u = (uv.x - r.x0 as f32 + 0.5) * width as f32 / r.width() as f32 - 0.5;
        let v = (uv.y - r.y0 as f32 + 0.5) * height as f32 / r.height() as f32 - 0.5;
        let (u, v) = (u.round(), v.round());
        (u >= 0.0 && v >= 0.0 && u < width as f32 && v < height as f32)
            .then_some([u as u16, v as u16])
    }
}

/// Background behind an input view.
#[derive(Debug, Clone, Copy)]
enum Background {
    Solid(Rgb),
    Gradient(Rgb, Rgb),
    Noise(u64),
}

impl Background {
    fn random(rng: &mut ChaCha8Rng) -> Self {
        let color = |rng: &mut ChaCha8Rng| [rng.gen(), rng.gen(), rng.gen()];
        match rng.gen_range(0..100) {
            0..=49 => Background::Solid([1.0; 3]),
            50..=69 => Background::Solid(color(rng)),
            70..=88 => Background::Gradient(color(rng), color(rng)),
            _ => Background::Noise(rng.gen()),
        }
    }

    fn at(&self, x: u32, y: u32, h: u32) -> Vec3 {
        match *self {
            Background::Solid(c) => Vec3::from(c),
            Background::Gradient(a, b) => {
                let t = y as f32 / h.max(1) as f32;
                Vec3::from(a).lerp(Vec3::from(b), t)
            }
            Background::Noise(seed) => {
                // Blocky value noise: 8 px cells, hashed per cell and channel.
                let (cx, cy) = (x / 8, y / 8);
                let mut c = [0f32; 3];
                for (k, v) in c.iter_mut().enumerate() {
                    let mut hsh = seed ^ (u64::from(cx) << 32) ^ u64::from(cy);
                    hsh = (hsh ^ (k as u64 + 1).wrapping_mul(0xD6E8_FEB8_6659_FD93))
                        .wrapping_mul(0x9E37_79B9_7F4A_7C15);
                    hsh ^= hsh >> 29;
                    *v = (hsh & 0xFFFF) as f32 / 65535.0;
                }
                Vec3::from(c)
            }
        }
    }
}

/// A random body pose for a sample: walk cycle, random within joint limits, or rest.
fn sample_pose(template: &BodyTemplate, seed: u64, rng: &mut ChaCha8Rng) -> Pose {
    match rng.gen_range(0..10) {
        0..=3 => motion::walk_pose(rng.gen_range(0.0..48.0)),
        4..=7 => grounded_random_pose(template, seed, 0),
        _ => Pose::identity(),
    }
}

/// Rolls a camera about its optical axis by `angle` radians.
fn rolled(camera: &Camera, angle: f32) -> Camera {
    Camera {
        world_from_camera: camera.world_from_camera
            * Affine3A::from_quat(Quat::from_rotation_z(angle)),
        ..*camera
    }
}

/// The same camera seen at another image size (intrinsics scaled).
fn resized(camera: &Camera, size: u32) -> Camera {
    let i = camera.intrinsics;
    let s = size as f32 / i.width as f32;
    let mut intrinsics = i;
    intrinsics.fx *= s;
    intrinsics.fy *= s;
    intrinsics.cx = (i.cx + 0.5) * s - 0.5;
    intrinsics.cy = (i.cy + 0.5) * s - 0.5;
    intrinsics.width = size;
    intrinsics.height = (i.height as f32 * s).round() as u32;
    Camera {
        intrinsics,
        ..*camera
    }
}

/// Makes the training sample of `seed` (≥ [`TRAIN_SEED_START`]).
pub fn make_sample(seed: u64, options: &DatasetOptions) -> Result<TrainingSample, SynthError> {
    if seed < TRAIN_SEED_START {
        return Err(SynthError::Dataset(format!(
            "seed {seed} is reserved for evaluation (training seeds start at {TRAIN_SEED_START})"
        )));
    }
    if is_dressed(seed, options) {
        return dressed::make_dressed_sample(seed, options);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x6461_7461);
    let person = SyntheticPerson::new(seed, options.person_points)?;
    let height = person.template.height();
    let views = rng.gen_range(1..=options.max_views.max(1));
    let size = [128u32, 192, 256][rng.gen_range(0..3)];
    let rig = if rng.gen_bool(0.7) {
        Rig::ring(seed, views, options.heldout_targets, size, height)
    } else {
        Rig::moving(seed, views, options.heldout_targets, size, height)
    };
    let pose = sample_pose(&person.template, seed, &mut rng);
    let matrices = person
        .template
        .skeleton
        .try_skinning_matrices(&pose)
        .map_err(|e| SynthError::Pose(e.to_string()))?;
    let posed_person = person.avatar.animate(&matrices);

    // Input views: rendered over a random background, preprocessed like the node.
    let pre = PreprocessConfig {
        out_height: options.input_height,
        out_width: options.input_width,
        ..PreprocessConfig::default()
    };
    let black = RenderOptions::default();
    let input_pixels = (options.input_height * options.input_width) as usize;
    let mut images = Vec::with_capacity(views * 3 * input_pixels);
    let mut rendered_inputs = Vec::with_capacity(views);
    for rig_camera in &rig.inputs {
        let camera = rolled(&rig_camera.camera, rng.gen_range(-0.12..0.12));
        let out = render(&posed_person, &camera, &black);
        let bg = Background::random(&mut rng);
        let (w, h) = (out.width, out.height);
        let rgb = RgbImage::from_fn(w, h, |x, y| {
            let i = (y * w + x) as usize;
            let a = out.alpha[i];
            let c = Vec3::from_slice(&out.rgb[3 * i..3 * i + 3]) + (1.0 - a) * bg.at(x, y, h);
            let c = (c.clamp(Vec3::ZERO, Vec3::ONE) * 255.0).round();
            image::Rgb([c.x as u8, c.y as u8, c.z as u8])
        });
        let masked = rng.gen_bool(options.mask_fraction.clamp(0.0, 1.0));
        let mask = GrayImage::from_fn(w, h, |x, y| {
            image::Luma([if out.alpha[(y * w + x) as usize] >= 0.5 {
                255
            } else {
                0
            }])
        });
        let subject = if masked {
            Subject::Mask(&mask)
        } else {
            Subject::FullFrame
        };
        let view = preprocess(&rgb, subject, &pre)
            .or_else(|_| preprocess(&rgb, Subject::FullFrame, &pre))
            .map_err(|e| SynthError::Dataset(format!("preprocess: {e}")))?;
        images.extend(view.chw.iter().map(|v| (v * 255.0).round() as u8));
        rendered_inputs.push(RenderedInput {
            camera,
            region: view.region,
            width: w,
            height: h,
            alpha: out.alpha,
            depth: out.depth,
        });
    }

    // Anchors as the node samples them on the shaped template, their ground truth and pose.
    let anchors = person
        .template
        .sample_anchors(options.points, options.anchor_seed);
    let n = anchors.len();
    let colors: Vec<f32> = anchors
        .positions
        .iter()
        .zip(&anchors.part_labels)
        .flat_map(|(p, label)| {
            let part = person.template.part_names[*label as usize].as_str();
            person.outfit.color(part, *p, height)
        })
        .collect();
    let frame = Gaussians::from_rgb(
        anchors.positions.clone(),
        vec![Vec3::splat(0.01); n],
        vec![Quat::IDENTITY; n],
        vec![1.0; n],
        &vec![Vec3::ZERO; n],
    )?;
    let posed_frame =
        Avatar::new(frame, anchors.skin.clone(), MAKEHUMAN_MODEL_ID)?.animate(&matrices);
    let flat = |v: &[Vec3]| v.iter().flat_map(|p| p.to_array()).collect::<Vec<f32>>();
    let anchor_pixels = rendered_inputs
        .iter()
        .flat_map(|view| {
            posed_frame.positions.iter().flat_map(|p| {
                view.locate(*p, options.input_width, options.input_height)
                    .unwrap_or([HIDDEN_ANCHOR; 2])
            })
        })
        .collect();

    // Targets: the held-out cameras and one input camera, at the target size, on white.
    let mut targets: Vec<&RigCamera> = rig.heldout.iter().collect();
    targets.push(&rig.inputs[rng.gen_range(0..rig.inputs.len())]);
    let white = RenderOptions {
        background: Vec3::ONE,
        ..RenderOptions::default()
    };
    let r = options.target_size;
    let mut target_rgb = Vec::new();
    let mut target_alpha = Vec::new();
    let mut target_intrinsics = Vec::new();
    let mut target_camera_from_world = Vec::new();
    for t in targets.iter() {
        let camera = resized(&t.camera, r);
        let out = render(&posed_person, &camera, &white);
        for c in 0..3 {
            target_rgb.extend(
                out.rgb
                    .chunks_exact(3)
                    .map(|p| (p[c].clamp(0.0, 1.0) * 255.0).round() as u8),
            );
        }
        target_alpha.extend(
            out.alpha
                .iter()
                .map(|a| (a.clamp(0.0, 1.0) * 255.0).round() as u8),
        );
        let i = camera.intrinsics;
        target_intrinsics.extend([i.fx, i.fy, i.cx, i.cy]);
        let m = glam::Mat4::from(camera.camera_from_world());
        for row in 0..3 {
            target_camera_from_world.extend((0..4).map(|col| m.col(col)[row]));
        }
    }
    // Where the node puts the anchors without knowing the girth (for some samples).
    let (anchors, posed_frame) = if anchors_at_girth_one(seed, options) {
        girth_one_anchors(&person.template, person.girth_scale, &anchors, &pose)?
    } else {
        (anchors, posed_frame)
    };
    Ok(TrainingSample {
        seed,
        views,
        images,
        image_size: (options.input_height as usize, options.input_width as usize),
        anchors: flat(&anchors.positions),
        normals: flat(&anchors.normals),
        colors,
        posed_anchors: flat(&posed_frame.positions),
        posed_rotations: posed_frame
            .rotations
            .iter()
            .flat_map(|q| [q.w, q.x, q.y, q.z])
            .collect(),
        target_rgb,
        target_alpha,
        target_intrinsics,
        target_camera_from_world,
        shape: [person.height_scale, person.girth_scale],
        anchor_pixels,
        anchor_garment: None,
        anchor_surface: None,
    })
}

/// Writes `samples` to one safetensors shard: tensors `{k}.images` (u8 `[V,3,H,W]`),
/// `{k}.anchors`, `{k}.normals`, `{k}.colors`, `{k}.posed_anchors` (f32 `[N,3]`),
/// `{k}.posed_rotations` (f32 `[N,4]`), `{k}.target_rgb` (u8 `[T,3,R,R]`), `{k}.target_alpha`
/// (u8 `[T,R,R]`), `{k}.target_intrinsics` (f32 `[T,4]`), `{k}.target_camera_from_world`
/// (f32 `[T,3,4]`), `{k}.shape` (f32 `[2]`), `{k}.anchor_pixels` (u16 `[V,N,2]`) for sample
/// `k`, and the seeds in the metadata. Dressed samples add `{k}.anchor_garment` (u8 `[N]`) and
/// `{k}.anchor_surface` (f32 `[N,3]`); readers of the format that do not know them skip them,
/// and the metadata's `dressed` (only in shards that hold some) lists their indices.
pub fn write_shard(path: &Path, samples: &[TrainingSample]) -> Result<(), SynthError> {
    use safetensors::tensor::{Dtype, TensorView};
    let le = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let mut buffers: Vec<(String, Dtype, Vec<usize>, Vec<u8>)> = Vec::new();
    for (k, s) in samples.iter().enumerate() {
        let n = s.anchors.len() / 3;
        let t = s.target_intrinsics.len() / 4;
        let side = |len: usize, per: usize| ((len / per) as f64).sqrt().round() as usize;
        let (ih, iw) = s.image_size;
        let r = side(s.target_alpha.len(), t);
        let (u8s, f32s) = (Dtype::U8, Dtype::F32);
        let u16le = |v: &[u16]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
        let entries: [(&str, Dtype, Vec<usize>, Vec<u8>); 12] = [
            ("images", u8s, vec![s.views, 3, ih, iw], s.images.clone()),
            ("anchors", f32s, vec![n, 3], le(&s.anchors)),
            ("normals", f32s, vec![n, 3], le(&s.normals)),
            ("colors", f32s, vec![n, 3], le(&s.colors)),
            ("posed_anchors", f32s, vec![n, 3], le(&s.posed_anchors)),
            ("posed_rotations", f32s, vec![n, 4], le(&s.posed_rotations)),
            ("target_rgb", u8s, vec![t, 3, r, r], s.target_rgb.clone()),
            ("target_alpha", u8s, vec![t, r, r], s.target_alpha.clone()),
            (
                "target_intrinsics",
                f32s,
                vec![t, 4],
                le(&s.target_intrinsics),
            ),
            (
                "target_camera_from_world",
                f32s,
                vec![t, 3, 4],
                le(&s.target_camera_from_world),
            ),
            ("shape", f32s, vec![2], le(&s.shape)),
            (
                "anchor_pixels",
                Dtype::U16,
                vec![s.views, n, 2],
                u16le(&s.anchor_pixels),
            ),
        ];
        for (name, dtype, shape, bytes) in entries {
            buffers.push((format!("{k}.{name}"), dtype, shape, bytes));
        }
        if let Some(garment) = &s.anchor_garment {
            buffers.push((format!("{k}.anchor_garment"), u8s, vec![n], garment.clone()));
        }
        if let Some(surface) = &s.anchor_surface {
            buffers.push((format!("{k}.anchor_surface"), f32s, vec![n, 3], le(surface)));
        }
    }
    let views = buffers
        .iter()
        .map(|(name, dtype, shape, bytes)| {
            TensorView::new(*dtype, shape.clone(), bytes)
                .map(|v| (name.clone(), v))
                .map_err(|e| SynthError::Dataset(format!("{name}: {e}")))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let seeds = samples
        .iter()
        .map(|s| s.seed.to_string())
        .collect::<Vec<_>>()
        .join(",");
    let dressed = samples
        .iter()
        .enumerate()
        .filter(|(_, s)| s.anchor_garment.is_some())
        .map(|(k, _)| k.to_string())
        .collect::<Vec<_>>()
        .join(",");
    let mut metadata = std::collections::HashMap::from([
        ("format".to_string(), "lhmpp-training-shard-v1".to_string()),
        ("samples".to_string(), samples.len().to_string()),
        ("seeds".to_string(), seeds),
    ]);
    if !dressed.is_empty() {
        metadata.insert("dressed".to_string(), dressed);
    }
    safetensors::tensor::serialize_to_file(views, Some(metadata), path)
        .map_err(|e| SynthError::Dataset(format!("{}: {e}", path.display())))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn evaluation_seeds_are_refused() {
        assert!(make_sample(5, &DatasetOptions::default()).is_err());
    }

    #[test]
    fn sample_shapes_agree_and_repeat_per_seed() {
        let o = DatasetOptions {
            points: 512,
            person_points: 3000,
            max_views: 3,
            ..DatasetOptions::default()
        };
        let a = make_sample(TRAIN_SEED_START + 7, &o).unwrap();
        let b = make_sample(TRAIN_SEED_START + 7, &o).unwrap();
        assert_eq!(a.images, b.images);
        assert_eq!(a.images.len(), a.views * 3 * 112 * 112);
        assert_eq!(a.anchors.len(), 512 * 3);
        assert_eq!(a.colors.len(), 512 * 3);
        assert_eq!(a.posed_rotations.len(), 512 * 4);
        let t = o.heldout_targets + 1;
        assert_eq!(a.target_rgb.len(), t * 3 * 96 * 96);
        assert_eq!(a.target_alpha.len(), t * 96 * 96);
        assert_eq!(a.target_camera_from_world.len(), t * 12);
        // The person covers part of each target, not all of it.
        let covered = a.target_alpha.iter().filter(|v| **v > 128).count();
        assert!(covered > t * 400 && covered < t * 96 * 96 / 2, "{covered}");
        assert_eq!(a.anchor_pixels.len(), a.views * 512 * 2);
    }

    #[test]
    fn girth_one_anchors_keep_the_height_and_undo_the_girth() {
        let base = DatasetOptions {
            points: 256,
            person_points: 2000,
            max_views: 2,
            ..DatasetOptions::default()
        };
        let moved = DatasetOptions {
            girth_one_fraction: 1.0,
            ..base.clone()
        };
        let seed = TRAIN_SEED_START + 11;
        let (a, b) = (
            make_sample(seed, &base).unwrap(),
            make_sample(seed, &moved).unwrap(),
        );
        let girth = a.shape[1];
        assert!(
            (girth - 1.0).abs() > 0.01,
            "seed with a girth other than 1: {girth}"
        );
        for (p, q) in a.anchors.chunks(3).zip(b.anchors.chunks(3)) {
            assert!((q[0] - p[0] / girth).abs() < 1e-5 && (q[1] - p[1]).abs() < 1e-6);
            assert!((q[2] - p[2] / girth).abs() < 1e-5);
        }
        // The targets, colours and views are the true person's, unchanged.
        assert_eq!(a.images, b.images);
        assert_eq!(a.target_rgb, b.target_rgb);
        assert_eq!(a.colors, b.colors);
        assert_ne!(a.posed_anchors, b.posed_anchors);
        // The fraction picks samples by seed.
        let half = DatasetOptions {
            girth_one_fraction: 0.5,
            ..base
        };
        let picked = (0..200)
            .filter(|k| anchors_at_girth_one(TRAIN_SEED_START + k, &half))
            .count();
        assert!((70..130).contains(&picked), "{picked}");
    }

    #[test]
    fn anchor_pixels_show_the_anchor_colour() {
        let o = DatasetOptions {
            points: 1024,
            person_points: 8000,
            max_views: 4,
            input_height: 224,
            input_width: 140,
            ..DatasetOptions::default()
        };
        let s = make_sample(TRAIN_SEED_START + 11, &o).unwrap();
        let (n, h, w) = (1024, 224usize, 140usize);
        assert_eq!(s.images.len(), s.views * 3 * h * w);
        let pixel = |view: usize, x: usize, y: usize| -> [f32; 3] {
            let at = |c: usize| s.images[((view * 3 + c) * h + y) * w + x] as f32 / 255.0;
            [at(0), at(1), at(2)]
        };
        // Mean colour error over the seen anchor-views, reading each anchor's pixel moved by
        // (dx, dy), and against another anchor's colour.
        let score = |dx: i32, dy: i32, other: bool| -> (usize, f32) {
            let (mut seen, mut err) = (0usize, 0f32);
            for view in 0..s.views {
                for i in 0..n {
                    let px = &s.anchor_pixels[(view * n + i) * 2..(view * n + i) * 2 + 2];
                    if px[0] == HIDDEN_ANCHOR {
                        continue;
                    }
                    let x = (px[0] as i32 + dx).clamp(0, w as i32 - 1) as usize;
                    let y = (px[1] as i32 + dy).clamp(0, h as i32 - 1) as usize;
                    let got = pixel(view, x, y);
                    let j = if other { (i * 7 + 313) % n } else { i };
                    seen += 1;
                    err += (0..3)
                        .map(|c| (got[c] - s.colors[3 * j + c]).abs())
                        .sum::<f32>()
                        / 3.0;
                }
            }
            (seen, err / seen.max(1) as f32)
        };
        let (seen, err) = score(0, 0, false);
        let (_, shuffled) = score(0, 0, true);
        // Every view shows a good part of the body; the pixel an anchor lands on has that
        // anchor's colour (up to the resampling) far more than another anchor's, and
        // better than the pixels 2 px beside it.
        assert!(
            seen > s.views * n / 5,
            "{seen} of {} anchor-views seen",
            s.views * n
        );
        for (dx, dy) in [(2, 0), (-2, 0), (0, 2), (0, -2)] {
            let (_, moved) = score(dx, dy, false);
            assert!(
                err < moved,
                "error {err} at the pixel, {moved} moved by ({dx}, {dy})"
            );
        }
        assert!(
            err < 0.75 * shuffled,
            "colour error {err} vs shuffled {shuffled}"
        );
    }
}
