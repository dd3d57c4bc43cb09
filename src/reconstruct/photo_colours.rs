//! Colours from the photos: after the network has made the avatar from photos, each Gaussian
//! that a photo shows takes its colour from that photo (texture back-projection), and the rest
//! get the network's colour mapped by the colour transform that best turns the network's
//! colours into the photos' over the Gaussians seen.
//!
//! Per photo with a solved pose: the avatar is posed as the person stands; an affine camera
//! (`pixel = A · X + b`, 8 values) is fitted by least squares to perception's image landmarks
//! and the posed template's landmarks; its rows' cross product is the viewing direction. A
//! point z-buffer over the photo (cells of 1/64 of the person's height) keeps the Gaussians
//! within [`PhotoColourConfig::depth_tolerance`] of the front-most one in their cell; those
//! that land on the person's mask (eroded, away from its edge) sample the photo there. A
//! Gaussian seen in several photos takes their colours weighted by how squarely it faces each
//! camera (the weighted median of three or more, else the weighted mean). The landmark the fit
//! misses most is dropped while the fit misses by more than
//! [`PhotoColourConfig::max_fit_error`] of the person's height (down to two thirds of them); a
//! photo whose fit still misses is skipped.
//!
//! A calibrated view (its pinhole camera from CameraInfo and TF, the person's pose in the same
//! world frame from the pose topic) needs no fit: the avatar is projected through the real
//! camera, perspective included. Its projection is only checked against perception's
//! landmarks (a stale pose or a wrong TF would paint the wrong Gaussians).
//!
//! Before the colours are combined, a key light fitted to them can be divided out
//! ([`super::delight`], [`PhotoColourConfig::delight`]): by default over the calibrated views,
//! which share one world frame and see the person from several sides.

use super::delight::{fit_key_light, hue_bin, KeyLight, ShadedSample};
use super::head_fit::{fit_head_warp, head_weights, HeadEvidence, HeadWarp};
use super::landmark_warp::{landmark_misses, LandmarkTies};
use super::surface::{canonical_normals, in_shadow, occupied_cells};
use crate::avatar::Avatar;
use crate::body::{BodyTemplate, Pose};
use crate::config::Delight;
use crate::perception::pose::{template_landmarks, PoseEstimator, PoseEstimatorConfig};
use crate::perception::{Landmark, LandmarkId, BODY_LANDMARKS};
use crate::splat::{rgb_to_sh_dc, sh_dc_to_rgb, Camera};
use glam::{IVec3, Mat4, Vec2, Vec3, Vec4};
use image::{GrayImage, RgbImage};
use std::collections::{HashMap, HashSet};

/// Settings of [`colour_from_photos`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PhotoColourConfig {
    /// Landmark visibility from which a landmark places the camera.
    pub min_visibility: f32,
    /// Largest RMS landmark error of the camera fit, as a share of the person's height.
    pub max_fit_error: f32,
    /// Depth (metres) behind the front-most Gaussian of a cell within which a Gaussian counts as
    /// seen.
    pub depth_tolerance: f32,
    /// Mask value (0–255) a sampled pixel and its neighbours need.
    pub min_mask: u8,
    /// Pull of the colour transform towards the identity (ridge weight per Gaussian seen).
    pub ridge: f32,
    /// Which photos' colours have a fitted key light divided out ([`super::delight`]).
    pub delight: Delight,
}

impl Default for PhotoColourConfig {
    fn default() -> Self {
        Self {
            min_visibility: 0.5,
            max_fit_error: 0.06,
            depth_tolerance: 0.03,
            min_mask: 200,
            ridge: 0.05,
            delight: Delight::Calibrated,
        }
    }
}

/// A photo of the person with what the camera fit needs.
pub struct PhotoSample<'a> {
    /// The photo.
    pub image: &'a RgbImage,
    /// The person's mask on it (255 = person).
    pub mask: &'a GrayImage,
    /// Perception's image landmarks (pixels).
    pub landmarks: &'a [Landmark; BODY_LANDMARKS],
    /// The pose solved for the photo (with [`PhotoSample::camera`], the person's pose in that
    /// camera's world frame).
    pub pose: &'a Pose,
    /// The photo's calibrated camera (intrinsics in the photo's pixels, pose in the world
    /// frame of [`PhotoSample::pose`]), when known; else a camera is fitted to the landmarks.
    pub camera: Option<Camera>,
}

/// What [`colour_from_photos`] did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PhotoColourReport {
    /// Photos used (camera fit good enough).
    pub photos_used: usize,
    /// Photos skipped, with why.
    pub skipped: Vec<String>,
    /// Gaussians that took a photo's colour.
    pub seen: usize,
    /// Gaussians recoloured by the fitted transform.
    pub mapped: usize,
    /// RMS landmark error of each used photo's camera fit, as a share of the person's height.
    pub fit_errors: Vec<f32>,
    /// Key lights divided out (one per set of views sharing a frame), when de-lighting.
    pub lights: Vec<KeyLight>,
}

/// One photo's colour of one Gaussian.
#[derive(Debug, Clone, Copy)]
struct Seen {
    /// How squarely the Gaussian faces the camera (the combination's weight).
    weight: f32,
    /// The colour sampled (sRGB, 0–1).
    colour: Vec3,
    /// The Gaussian's posed normal in the photo's frame.
    normal: Vec3,
    /// The Gaussian's posed position in the photo's frame.
    position: Vec3,
    /// How much of the fitted key light reaches it there (0 in a cast shadow; 1 until a light
    /// is fitted).
    lit: f32,
    /// The photo.
    photo: u32,
}

/// Landmarks that place the camera: the body joints (shoulders to feet) and the nose.
const FIT_LANDMARKS: [LandmarkId; 15] = [
    LandmarkId::Nose,
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
    LandmarkId::LeftHeel,
    LandmarkId::RightHeel,
];

/// Fewest landmarks a camera is fitted to.
const MIN_FIT_LANDMARKS: usize = 6;

/// An affine camera: `pixel = rows · (X, 1)`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct AffineCamera {
    /// The row giving the pixel's x.
    pub u: Vec4,
    /// The row giving the pixel's y.
    pub v: Vec4,
}

impl AffineCamera {
    /// The pixel of `p`.
    pub fn project(&self, p: Vec3) -> Vec2 {
        let h = p.extend(1.0);
        Vec2::new(self.u.dot(h), self.v.dot(h))
    }

    /// The direction the camera looks along (depth grows along it).
    pub fn forward(&self) -> Vec3 {
        self.u
            .truncate()
            .cross(self.v.truncate())
            .normalize_or_zero()
    }
}

/// How a photo's pixels are reached from posed points: an affine camera fitted to the
/// landmarks, or the calibrated pinhole camera.
#[derive(Debug, Clone, Copy)]
enum Projection {
    Affine {
        camera: AffineCamera,
        /// [`AffineCamera::forward`], computed once.
        forward: Vec3,
    },
    Pinhole {
        camera_from_world: glam::Affine3A,
        camera: Camera,
    },
}

impl Projection {
    /// The unit direction from the camera towards `p`.
    fn direction(&self, p: Vec3) -> Vec3 {
        match self {
            Projection::Affine { forward, .. } => *forward,
            Projection::Pinhole { camera, .. } => (p - camera.center()).normalize_or_zero(),
        }
    }

    /// The pixel of `p` and its depth along the viewing direction (`None` behind a pinhole
    /// camera).
    fn project(&self, p: Vec3) -> Option<(Vec2, f32)> {
        match self {
            Projection::Affine { camera, forward } => Some((camera.project(p), forward.dot(p))),
            Projection::Pinhole {
                camera_from_world,
                camera,
            } => {
                let c = camera_from_world.transform_point3(p);
                (c.z > 1e-3).then(|| (camera.project_camera_point(c), c.z))
            }
        }
    }
}

/// The camera fit's correspondences: each of [`FIT_LANDMARKS`] seen at `min_visibility`, as
/// (the posed template's landmark, perception's pixel), and the person's height on the photo
/// (the pixels' vertical extent, at least 1).
pub(crate) fn landmark_pairs(
    posed_landmarks: &[Vec3; BODY_LANDMARKS],
    landmarks: &[Landmark; BODY_LANDMARKS],
    min_visibility: f32,
) -> (Vec<(Vec3, Vec2)>, f32) {
    let pairs: Vec<(Vec3, Vec2)> = FIT_LANDMARKS
        .iter()
        .map(|&id| id as usize)
        .filter(|&i| landmarks[i].visibility >= min_visibility)
        .map(|i| (posed_landmarks[i], landmarks[i].position.truncate()))
        .collect();
    let (lo, hi) = pairs.iter().fold((f32::MAX, f32::MIN), |(lo, hi), (_, p)| {
        (lo.min(p.y), hi.max(p.y))
    });
    (pairs, (hi - lo).max(1.0))
}

/// Least-squares affine camera through `(X, pixel)` pairs (at least 4, not coplanar).
pub(crate) fn fit_camera(pairs: &[(Vec3, Vec2)]) -> Option<AffineCamera> {
    if pairs.len() < 4 {
        return None;
    }
    let mut ata = Mat4::ZERO;
    let (mut atu, mut atv) = (Vec4::ZERO, Vec4::ZERO);
    for (x, px) in pairs {
        let h = x.extend(1.0);
        ata += Mat4::from_cols(h * h.x, h * h.y, h * h.z, h * h.w);
        atu += h * px.x;
        atv += h * px.y;
    }
    if ata.determinant().abs() < 1e-9 {
        return None;
    }
    let inv = ata.inverse();
    Some(AffineCamera {
        u: inv * atu,
        v: inv * atv,
    })
}

/// Whether the mask is at least `min` over the 3×3 pixels around `(x, y)`.
fn inside_mask(mask: &GrayImage, x: i64, y: i64, min: u8) -> bool {
    (-1..=1).all(|dy| {
        (-1..=1).all(|dx| {
            let (px, py) = (x + dx, y + dy);
            px >= 0
                && py >= 0
                && (px as u32) < mask.width()
                && (py as u32) < mask.height()
                && mask.get_pixel(px as u32, py as u32).0[0] >= min
        })
    })
}

/// Mean sRGB colour (0–1) of the 3×3 pixels around `(x, y)`.
fn sample(image: &RgbImage, x: i64, y: i64) -> Vec3 {
    let mut sum = Vec3::ZERO;
    for dy in -1..=1 {
        for dx in -1..=1 {
            let px = (x + dx).clamp(0, image.width() as i64 - 1) as u32;
            let py = (y + dy).clamp(0, image.height() as i64 - 1) as u32;
            let p = image.get_pixel(px, py).0;
            sum += Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32);
        }
    }
    sum / (9.0 * 255.0)
}

/// What each of the avatar's Gaussians is on the canonical body, worked out once per recolour.
struct CanonicalFacts {
    /// The surface normal of the template vertex nearest to it.
    normals: Vec<Vec3>,
    /// That vertex's body part.
    parts: Vec<u8>,
    /// Its skinning weight on the head ([`super::head_fit`]).
    head_weights: Vec<f32>,
    /// The landmarks it follows on uncalibrated photos ([`super::landmark_warp`]).
    ties: LandmarkTies,
}

impl CanonicalFacts {
    fn new(avatar: &Avatar, template: &BodyTemplate) -> Self {
        let (normals, parts) = canonical_normals(avatar, template);
        Self {
            normals,
            parts,
            head_weights: head_weights(avatar, template),
            ties: LandmarkTies::new(avatar, template),
        }
    }
}

/// Adds to `samples` each Gaussian's colour as the photo shows it, when the camera fit is good
/// enough (returns the fit's RMS miss and the avatar's Gaussians posed as in the photo); else
/// why not.
fn photo_colours(
    avatar: &Avatar,
    template: &BodyTemplate,
    photo: &PhotoSample<'_>,
    cfg: &PhotoColourConfig,
    canonical: &CanonicalFacts,
    index: u32,
    samples: &mut [Vec<Seen>],
) -> Result<(f32, Vec<Vec3>), String> {
    let CanonicalFacts {
        normals,
        head_weights,
        ties,
        ..
    } = canonical;
    let posed_landmarks =
        template_landmarks(template, photo.pose).map_err(|e| format!("landmarks: {e}"))?;
    let (mut pairs, height) = landmark_pairs(&posed_landmarks, photo.landmarks, cfg.min_visibility);
    let (projection, rms) = match photo.camera {
        Some(camera) => calibrated_projection(camera, &pairs, height, cfg)?,
        None => fitted_projection(&mut pairs, height, cfg)?,
    };
    let matrices = template.skeleton.skinning_matrices(photo.pose);
    let posed = avatar.animate(&matrices);
    let mut projected: Vec<Option<(Vec2, f32)>> = posed
        .positions
        .iter()
        .map(|p| projection.project(*p))
        .collect();
    let warp = match projection {
        // A calibrated camera and pose place the person as they stand.
        Projection::Pinhole { .. } => HeadWarp::IDENTITY,
        Projection::Affine { .. } => follow_landmarks(
            &FittedPhoto {
                template,
                photo,
                projection: &projection,
                posed_landmarks: &posed_landmarks,
                matrices: &matrices,
                height,
                min_visibility: cfg.min_visibility,
            },
            ties,
            head_weights,
            &mut projected,
        ),
    };
    tracing::debug!(photo = index, ?warp, "head warp");
    let cell = (height / 64.0).max(1.0);
    let (gw, gh) = (
        (photo.image.width() as f32 / cell).ceil() as usize + 1,
        (photo.image.height() as f32 / cell).ceil() as usize + 1,
    );
    let mut front = vec![f32::MAX; gw * gh];
    let mut placed = Vec::with_capacity(posed.len());
    for (i, at) in projected.iter().enumerate() {
        let Some((px, depth)) = *at else {
            placed.push(None);
            continue;
        };
        let px = warp.apply(px, head_weights[i]);
        let (cx, cy) = ((px.x / cell).floor(), (px.y / cell).floor());
        if posed.opacities[i] < 0.05
            || cx < 0.0
            || cy < 0.0
            || cx as usize >= gw
            || cy as usize >= gh
        {
            placed.push(None);
            continue;
        }
        let c = cy as usize * gw + cx as usize;
        front[c] = front[c].min(depth);
        placed.push(Some((px, depth, c)));
    }
    for (i, at) in placed.into_iter().enumerate() {
        let Some((px, depth, c)) = at else {
            continue;
        };
        if depth > front[c] + cfg.depth_tolerance {
            continue;
        }
        let (x, y) = (px.x.round() as i64, px.y.round() as i64);
        if !inside_mask(photo.mask, x, y, cfg.min_mask) {
            continue;
        }
        let normal = avatar
            .skin
            .blended(i, &matrices)
            .transform_vector3(normals[i])
            .normalize_or_zero();
        let facing = -normal.dot(projection.direction(posed.positions[i]));
        samples[i].push(Seen {
            weight: facing.max(MIN_FACING),
            colour: sample(photo.image, x, y),
            normal,
            position: posed.positions[i],
            lit: 1.0,
            photo: index,
        });
    }
    Ok((rms, posed.positions))
}

/// A photo whose camera was fitted to the landmarks, posed.
struct FittedPhoto<'a> {
    template: &'a BodyTemplate,
    photo: &'a PhotoSample<'a>,
    projection: &'a Projection,
    posed_landmarks: &'a [Vec3; BODY_LANDMARKS],
    matrices: &'a [Mat4],
    /// The person's height on the photo, pixels.
    height: f32,
    min_visibility: f32,
}

/// Moves where each Gaussian samples a photo whose camera was fitted: by the misses of the
/// landmarks it is tied to ([`super::landmark_warp`]), then the head's points scaled to the
/// head's mask ([`super::head_fit`]; returned, to apply by head weight).
fn follow_landmarks(
    fitted: &FittedPhoto<'_>,
    ties: &LandmarkTies,
    head_weights: &[f32],
    projected: &mut [Option<(Vec2, f32)>],
) -> HeadWarp {
    let FittedPhoto {
        template,
        photo,
        projection,
        ..
    } = fitted;
    let template_px: [Option<Vec2>; BODY_LANDMARKS] = std::array::from_fn(|i| {
        projection
            .project(fitted.posed_landmarks[i])
            .map(|(q, _)| q)
    });
    let misses = landmark_misses(
        photo.landmarks,
        &template_px,
        fitted.min_visibility,
        fitted.height,
    );
    let shifts = ties.shifts(&misses, projected.len());
    for (p, s) in projected.iter_mut().zip(shifts) {
        if let Some((px, _)) = p {
            *px += s;
        }
    }
    let Some(head) = template.skeleton.bone_index("head") else {
        return HeadWarp::IDENTITY;
    };
    let joint = fitted.matrices[head].transform_point3(template.skeleton.joints[head]);
    let Some((pivot, _)) = projection.project(joint) else {
        return HeadWarp::IDENTITY;
    };
    let pixels: Vec<Option<Vec2>> = projected.iter().map(|p| p.map(|(q, _)| q)).collect();
    fit_head_warp(
        &HeadEvidence {
            misses: &misses,
            mask: photo.mask,
            pivot,
            height: fitted.height,
        },
        &pixels,
        head_weights,
    )
}

/// The affine camera through the landmark pairs and its RMS miss (share of `height`): the
/// landmark the fit misses most is dropped while the fit misses and two thirds of them remain
/// (a limb the pose got wrong must not tilt the camera).
fn fitted_projection(
    pairs: &mut Vec<(Vec3, Vec2)>,
    height: f32,
    cfg: &PhotoColourConfig,
) -> Result<(Projection, f32), String> {
    let (camera, rms) = robust_affine(pairs, height, cfg.max_fit_error)?;
    let forward = camera.forward();
    Ok((Projection::Affine { camera, forward }, rms))
}

/// The affine camera through the landmark pairs and its RMS miss (share of `height`), the
/// landmark it misses most dropped (from `pairs`) while it misses by more than
/// `max_fit_error` and two thirds of them remain; refused when it still misses.
pub(crate) fn robust_affine(
    pairs: &mut Vec<(Vec3, Vec2)>,
    height: f32,
    max_fit_error: f32,
) -> Result<(AffineCamera, f32), String> {
    let keep = (2 * pairs.len()).div_ceil(3).max(MIN_FIT_LANDMARKS);
    let (camera, rms) = loop {
        let camera = fit_camera(pairs).ok_or("too few visible landmarks to place the camera")?;
        let errors: Vec<f32> = pairs
            .iter()
            .map(|(x, p)| camera.project(*x).distance_squared(*p))
            .collect();
        let rms = (errors.iter().sum::<f32>() / pairs.len() as f32).sqrt() / height;
        if rms <= max_fit_error || pairs.len() <= keep {
            break (camera, rms);
        }
        let worst = (0..errors.len())
            .max_by(|&a, &b| errors[a].total_cmp(&errors[b]))
            .expect("pairs are not empty");
        pairs.swap_remove(worst);
    };
    if rms > max_fit_error {
        return Err(format!(
            "the camera fit misses the landmarks by {:.1} % of the person's height",
            rms * 100.0
        ));
    }
    Ok((camera, rms))
}

/// The calibrated camera's projection, and how far (RMS, share of `height`) the posed
/// template's landmarks land from perception's; refused past [`CALIBRATED_MAX_MISS`] times
/// the fit's limit (the pose does not belong to this photo, or the camera is wrong).
fn calibrated_projection(
    camera: Camera,
    pairs: &[(Vec3, Vec2)],
    height: f32,
    cfg: &PhotoColourConfig,
) -> Result<(Projection, f32), String> {
    let projection = Projection::Pinhole {
        camera_from_world: camera.camera_from_world(),
        camera,
    };
    let misses: Vec<f32> = pairs
        .iter()
        .map(|(x, p)| match projection.project(*x) {
            Some((q, _)) => q.distance_squared(*p),
            None => f32::INFINITY,
        })
        .collect();
    let rms = if misses.is_empty() {
        0.0
    } else {
        (misses.iter().sum::<f32>() / misses.len() as f32).sqrt() / height
    };
    if rms > CALIBRATED_MAX_MISS * cfg.max_fit_error {
        return Err(format!(
            "the calibrated camera and pose miss the landmarks by {:.1} % of the person's height",
            rms * 100.0
        ));
    }
    Ok((projection, rms))
}

/// How many times [`PhotoColourConfig::max_fit_error`] a calibrated projection may miss
/// perception's landmarks (they carry perception's own error, which the fit absorbs).
const CALIBRATED_MAX_MISS: f32 = 2.0;

/// Least weight of a photo's colour of a Gaussian (the cosine between its normal and the line
/// of sight): at grazing angles a pixel spans a long stretch of surface and the edge of the
/// mask, so such photos count less, but they still count (leaving them out lost on the dev set).
const MIN_FACING: f32 = 0.2;

/// Height band (metres) of the groups taken to share an albedo when de-lighting.
const DELIGHT_BAND: f32 = 0.1;

/// Divides a key light out of the colours in `samples`, one light per set of photos that share
/// a frame (the calibrated ones together; with [`Delight::Always`] also each other photo
/// alone), with the cast shadows of the avatar posed in each photo (`posed`, its Gaussians'
/// positions per photo); returns the lights.
fn delight(
    samples: &mut [Vec<Seen>],
    parts: &[u8],
    heights: &[f32],
    calibrated: &[bool],
    posed: &[Vec<Vec3>],
    mode: Delight,
) -> Vec<KeyLight> {
    // Groups: body part × height band × hue of the Gaussian's colour over its photos.
    let mut keys: HashMap<(u8, i32, u32), u32> = HashMap::new();
    let group_of: Vec<u32> = samples
        .iter()
        .enumerate()
        .map(|(i, seen)| {
            let mean = seen.iter().map(|s| s.colour).sum::<Vec3>() / seen.len().max(1) as f32;
            let key = (
                parts[i],
                (heights[i] / DELIGHT_BAND).floor() as i32,
                hue_bin(mean),
            );
            let next = keys.len() as u32;
            *keys.entry(key).or_insert(next)
        })
        .collect();
    let frame_of = |photo: u32| {
        if calibrated[photo as usize] {
            0
        } else {
            1 + photo as usize
        }
    };
    let mut frames: Vec<usize> = (0..calibrated.len() as u32)
        .filter(|&k| match mode {
            Delight::Never => false,
            Delight::Calibrated => calibrated[k as usize],
            Delight::Always => true,
        })
        .map(frame_of)
        .collect();
    frames.sort_unstable();
    frames.dedup();
    // Cells the avatar occupies in each photo's pose, made once a light is found.
    let mut blockers: Option<Vec<HashSet<IVec3>>> = None;
    let mut lights = Vec::new();
    for frame in frames {
        let gather = |samples: &[Vec<Seen>]| {
            samples
                .iter()
                .enumerate()
                .flat_map(|(i, seen)| {
                    let group = group_of[i];
                    seen.iter()
                        .filter(|s| frame_of(s.photo) == frame)
                        .map(move |s| ShadedSample {
                            group,
                            view: s.photo,
                            normal: s.normal,
                            colour: s.colour,
                            lit: s.lit,
                        })
                })
                .collect::<Vec<ShadedSample>>()
        };
        // A first fit without cast shadows gives the light's direction; the avatar posed in
        // each photo then tells which points the key light cannot reach, and the light is
        // fitted again from the first one with those.
        let mut light = fit_key_light(&gather(samples), None);
        if light.key != Vec3::ZERO {
            let cells =
                blockers.get_or_insert_with(|| posed.iter().map(|p| occupied_cells(p)).collect());
            let dir = light.key.normalize();
            for s in samples.iter_mut().flatten() {
                if frame_of(s.photo) == frame {
                    let blocked = cells
                        .get(s.photo as usize)
                        .is_some_and(|c| in_shadow(c, s.position + s.normal * 0.02, dir));
                    s.lit = if blocked { 0.0 } else { 1.0 };
                }
            }
            light = fit_key_light(&gather(samples), Some(light.key));
        }
        if light.key != Vec3::ZERO {
            for s in samples.iter_mut().flatten() {
                if frame_of(s.photo) == frame {
                    let exposure = light.exposure.get(s.photo as usize).copied().unwrap_or(0.0);
                    s.colour = (s.colour * light.gain_lit(s.normal, s.lit) * (-exposure).exp())
                        .min(Vec3::ONE);
                }
            }
        }
        lights.push(light);
    }
    lights
}

/// One Gaussian's colour from the photos that show it, each weighted by how squarely it
/// faces the camera: the per-channel weighted median of three or more (a photo that
/// misplaces it, or shows what stands in front of it, is outvoted), else the weighted mean;
/// `None` when no photo shows it.
fn combined(samples: &[Seen]) -> Option<Vec3> {
    let total: f32 = samples.iter().map(|s| s.weight).sum();
    match samples.len() {
        0 => None,
        1 | 2 => Some(samples.iter().map(|s| s.colour * s.weight).sum::<Vec3>() / total),
        _ => {
            let median = |ch: usize| {
                let mut v: Vec<(f32, f32)> =
                    samples.iter().map(|s| (s.colour[ch], s.weight)).collect();
                v.sort_by(|a, b| a.0.total_cmp(&b.0));
                let mut acc = 0.0;
                for (value, w) in &v {
                    acc += w;
                    if acc >= 0.5 * total {
                        return *value;
                    }
                }
                v[v.len() - 1].0
            };
            Some(Vec3::new(median(0), median(1), median(2)))
        }
    }
}

/// The affine colour transform (`out = M · (rgb, 1)`, one row per channel) that best maps
/// `from` to `to`, pulled towards the identity by `ridge` per pair.
fn fit_colour_transform(pairs: &[(Vec3, Vec3)], ridge: f32) -> [Vec4; 3] {
    let n = pairs.len() as f32;
    let lambda = ridge * n.max(1.0);
    let mut ata = Mat4::from_diagonal(Vec4::new(lambda, lambda, lambda, 1e-6 * n.max(1.0)));
    let mut atb = [Vec4::ZERO; 3];
    let identity = [Vec4::X, Vec4::Y, Vec4::Z];
    for (c, row) in atb.iter_mut().enumerate() {
        *row = identity[c] * lambda;
    }
    for (from, to) in pairs {
        let h = from.extend(1.0);
        ata += Mat4::from_cols(h * h.x, h * h.y, h * h.z, h * h.w);
        for c in 0..3 {
            atb[c] += h * to[c];
        }
    }
    let inv = ata.inverse();
    [inv * atb[0], inv * atb[1], inv * atb[2]]
}

/// Recolours `avatar` (made from `photos` on `template`'s skeleton) from the photos: the
/// Gaussians they show take the photos' colours, the others the network's colours through the
/// fitted colour transform. Degree-0 colours only (higher SH bands are left as they are).
pub fn colour_from_photos(
    avatar: &mut Avatar,
    template: &BodyTemplate,
    photos: &[PhotoSample<'_>],
    cfg: &PhotoColourConfig,
) -> PhotoColourReport {
    let n = avatar.canonical.len();
    let canonical = CanonicalFacts::new(avatar, template);
    let mut samples = vec![Vec::new(); n];
    let mut posed_positions: Vec<Vec<Vec3>> = Vec::with_capacity(photos.len());
    let mut report = PhotoColourReport::default();
    for (k, photo) in photos.iter().enumerate() {
        match photo_colours(
            avatar,
            template,
            photo,
            cfg,
            &canonical,
            k as u32,
            &mut samples,
        ) {
            Ok((rms, posed)) => {
                report.photos_used += 1;
                report.fit_errors.push(rms);
                posed_positions.push(posed);
            }
            Err(why) => {
                report.skipped.push(format!("photo {k}: {why}"));
                posed_positions.push(Vec::new());
            }
        }
    }
    if cfg.delight != Delight::Never {
        let heights: Vec<f32> = avatar.canonical.positions.iter().map(|p| p.y).collect();
        let calibrated: Vec<bool> = photos.iter().map(|p| p.camera.is_some()).collect();
        report.lights = delight(
            &mut samples,
            &canonical.parts,
            &heights,
            &calibrated,
            &posed_positions,
            cfg.delight,
        );
        for light in &report.lights {
            tracing::debug!(
                key = ?light.key,
                residual = ?light.residual,
                "key light divided out of the photos' colours"
            );
        }
    }
    let g = &mut avatar.canonical;
    let k = g.sh_per_gaussian();
    let network: Vec<Vec3> = (0..n).map(|i| sh_dc_to_rgb(g.sh[i * k])).collect();
    let seen: Vec<Option<Vec3>> = samples.iter().map(|s| combined(s)).collect();
    let pairs: Vec<(Vec3, Vec3)> = (0..n)
        .filter_map(|i| Some((network[i], seen[i]?)))
        .collect();
    if pairs.is_empty() {
        return report;
    }
    let m = fit_colour_transform(&pairs, cfg.ridge);
    // Cameras that see no colour say nothing of the person's hues: the avatar is grey all
    // round, not grey where seen and the network's colours elsewhere.
    let monochrome = photos.iter().all(|p| is_monochrome(p.image, p.mask));
    if monochrome {
        tracing::info!("every photo is monochrome: the avatar is grey all round");
    }
    for i in 0..n {
        let rgb = if let Some(rgb) = seen[i] {
            report.seen += 1;
            rgb
        } else {
            report.mapped += 1;
            let h = network[i].extend(1.0);
            Vec3::new(m[0].dot(h), m[1].dot(h), m[2].dot(h))
        };
        let rgb = if monochrome {
            Vec3::splat(rgb.dot(MONO_LUMA))
        } else {
            rgb
        };
        g.sh[i * k] = rgb_to_sh_dc(rgb.clamp(Vec3::ZERO, Vec3::ONE));
        if monochrome {
            // Higher bands would tint the grey by view direction.
            for c in &mut g.sh[i * k + 1..(i + 1) * k] {
                let mean = (c[0] + c[1] + c[2]) / 3.0;
                *c = [mean; 3];
            }
        }
    }
    report
}

/// Rec. 709 luminance weights (the grey a monochrome camera records of a colour).
const MONO_LUMA: Vec3 = Vec3::new(0.2126, 0.7152, 0.0722);

/// Whether `image` holds no colour where `mask` shows the person: at least 99 % of those
/// pixels have channels within 3 levels of each other (a grey camera's frame, even after
/// compression).
pub fn is_monochrome(image: &RgbImage, mask: &GrayImage) -> bool {
    let (mut person, mut coloured) = (0usize, 0usize);
    for (p, m) in image.pixels().zip(mask.pixels()) {
        if m[0] < 128 {
            continue;
        }
        person += 1;
        let [r, g, b] = p.0.map(i16::from);
        if (r - g).abs() > 3 || (g - b).abs() > 3 || (r - b).abs() > 3 {
            coloured += 1;
        }
    }
    person > 0 && coloured * 100 <= person
}

/// A view's original frame as perception saw the person in it, kept (at most
/// [`ViewEvidence::MAX_SIDE`] pixels on its long side) so the avatar can take its colours from
/// it.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewEvidence {
    /// The frame, scaled down.
    pub frame: RgbImage,
    /// The person's mask on it.
    pub mask: GrayImage,
    /// Image landmarks in the scaled frame's pixels.
    pub image_landmarks: [Landmark; BODY_LANDMARKS],
    /// World landmarks (metres, hip-centred, the camera's axes).
    pub world_landmarks: [Landmark; BODY_LANDMARKS],
    /// The view's calibrated camera (intrinsics in the kept frame's pixels) and the person's
    /// pose in its world frame at the view's time, when both are known
    /// ([`ViewEvidence::with_calibration`]).
    pub calibration: Option<(Camera, Pose)>,
}

impl ViewEvidence {
    /// Longest side kept.
    pub const MAX_SIDE: u32 = 640;

    /// The evidence of a frame, scaled down to [`Self::MAX_SIDE`] when larger.
    pub fn new(
        frame: &RgbImage,
        mask: &GrayImage,
        image_landmarks: &[Landmark; BODY_LANDMARKS],
        world_landmarks: &[Landmark; BODY_LANDMARKS],
    ) -> Self {
        let (w, h) = frame.dimensions();
        let scale = (Self::MAX_SIDE as f32 / w.max(h) as f32).min(1.0);
        let mut image_landmarks = *image_landmarks;
        if scale >= 1.0 {
            return Self {
                frame: frame.clone(),
                mask: mask.clone(),
                image_landmarks,
                world_landmarks: *world_landmarks,
                calibration: None,
            };
        }
        let (sw, sh) = (
            ((w as f32 * scale).round() as u32).max(1),
            ((h as f32 * scale).round() as u32).max(1),
        );
        // Nearest: this runs on the pipeline thread for every stored view (a 1080p frame and
        // mask took 15-17 ms with a triangle filter, 6.5 ms so), and sampling averages 3×3
        // pixels anyway.
        let filter = image::imageops::FilterType::Nearest;
        for l in &mut image_landmarks {
            l.position.x *= sw as f32 / w as f32;
            l.position.y *= sh as f32 / h as f32;
        }
        Self {
            frame: image::imageops::resize(frame, sw, sh, filter),
            mask: image::imageops::resize(mask, sw, sh, filter),
            image_landmarks,
            world_landmarks: *world_landmarks,
            calibration: None,
        }
    }

    /// The evidence with the frame's calibrated `camera` (intrinsics of the original frame,
    /// rescaled here to the kept one) and the person's `pose` in the camera's world frame:
    /// colours are then projected through the camera rather than a camera fitted to the
    /// landmarks.
    pub fn with_calibration(mut self, mut camera: Camera, pose: Pose) -> Self {
        let k = &mut camera.intrinsics;
        let (sx, sy) = (
            self.frame.width() as f32 / k.width.max(1) as f32,
            self.frame.height() as f32 / k.height.max(1) as f32,
        );
        // Pixel centres sit at integer coordinates: scale about the corner at -0.5.
        k.fx *= sx;
        k.fy *= sy;
        k.cx = (k.cx + 0.5) * sx - 0.5;
        k.cy = (k.cy + 0.5) * sy - 0.5;
        k.width = self.frame.width();
        k.height = self.frame.height();
        self.calibration = Some((camera, pose));
        self
    }
}

/// Recolours `avatar` from the views perception saw the person in (a calibrated view through its
/// camera and given pose, the others with their pose solved from their world landmarks on
/// `template`), dividing a fitted key light out of the views `delight` names; nothing without
/// such views.
pub fn colour_from_evidence(
    avatar: &mut Avatar,
    template: &BodyTemplate,
    seen: &[&ViewEvidence],
    delight: Delight,
) -> PhotoColourReport {
    if seen.is_empty() {
        return PhotoColourReport::default();
    }
    let config = PoseEstimatorConfig {
        filter: None,
        ..PoseEstimatorConfig::default()
    };
    let Ok(mut solver) = PoseEstimator::new(template, config) else {
        return PhotoColourReport::default();
    };
    let poses: Vec<Pose> = seen
        .iter()
        .map(|e| match &e.calibration {
            Some((_, pose)) => pose.clone(),
            None => {
                solver.reset();
                solver.update(0.0, &e.world_landmarks)
            }
        })
        .collect();
    let samples: Vec<PhotoSample<'_>> = seen
        .iter()
        .zip(&poses)
        .map(|(e, pose)| PhotoSample {
            image: &e.frame,
            mask: &e.mask,
            landmarks: &e.image_landmarks,
            pose,
            camera: e.calibration.as_ref().map(|(camera, _)| *camera),
        })
        .collect();
    let cfg = PhotoColourConfig {
        delight,
        ..PhotoColourConfig::default()
    };
    let report = colour_from_photos(avatar, template, &samples, &cfg);
    tracing::debug!(
        views = report.photos_used,
        calibrated = seen.iter().filter(|e| e.calibration.is_some()).count(),
        seen = report.seen,
        mapped = report.mapped,
        skipped = report.skipped.len(),
        "colours from the views"
    );
    report
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An affine camera is recovered from its own projections, and looks along its rows'
    /// cross product (a camera in front of the person, +Z towards it, looks along −Z).
    #[test]
    fn the_camera_fit_recovers_a_camera() {
        let truth = AffineCamera {
            u: Vec4::new(300.0, 0.0, 0.0, 320.0),
            v: Vec4::new(0.0, -300.0, 0.0, 400.0),
        };
        let points = [
            Vec3::new(0.2, 1.4, 0.05),
            Vec3::new(-0.2, 1.4, 0.0),
            Vec3::new(0.1, 0.9, -0.05),
            Vec3::new(-0.1, 0.9, 0.1),
            Vec3::new(0.1, 0.1, 0.0),
            Vec3::new(-0.1, 0.5, 0.2),
        ];
        let pairs: Vec<(Vec3, Vec2)> = points.iter().map(|p| (*p, truth.project(*p))).collect();
        let fit = fit_camera(&pairs).unwrap();
        for p in points {
            assert!(fit.project(p).distance(truth.project(p)) < 1e-2);
        }
        assert!(
            fit.forward().distance(Vec3::NEG_Z) < 1e-4,
            "{}",
            fit.forward()
        );
        assert!(fit_camera(&pairs[..3]).is_none());
    }

    /// A calibrated camera follows its frame when the evidence keeps it scaled down: a world
    /// point lands on the same place of the person in the kept frame.
    #[test]
    fn calibration_is_rescaled_with_the_kept_frame() {
        use crate::splat::Intrinsics;
        let (w, h) = (1280, 960);
        let camera = Camera::look_at(
            Vec3::new(0.0, 1.0, 3.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::Y,
            Intrinsics::from_fov_y(w, h, 0.8),
        );
        let none = [Landmark {
            position: Vec3::ZERO,
            visibility: 0.0,
            presence: 0.0,
        }; BODY_LANDMARKS];
        let evidence = ViewEvidence::new(&RgbImage::new(w, h), &GrayImage::new(w, h), &none, &none)
            .with_calibration(camera, Pose::default());
        let (kept, _) = evidence.calibration.as_ref().unwrap();
        assert_eq!(kept.intrinsics.width, 640);
        assert_eq!(kept.intrinsics.height, 480);
        let p = Vec3::new(0.3, 1.6, 0.2);
        let full = camera.project_camera_point(camera.camera_from_world().transform_point3(p));
        let small = kept.project_camera_point(kept.camera_from_world().transform_point3(p));
        let expected = (full + 0.5) * 0.5 - 0.5;
        assert!(small.distance(expected) < 1e-3, "{small} vs {expected}");
    }

    /// The colour transform learns a consistent colour cast and leaves the identity alone.
    #[test]
    fn the_colour_transform_learns_a_cast() {
        let pairs: Vec<(Vec3, Vec3)> = (0..50)
            .map(|i| {
                let c = Vec3::new(
                    (i % 5) as f32 / 5.0,
                    (i % 7) as f32 / 7.0,
                    (i % 3) as f32 / 3.0,
                );
                (c, Vec3::new(0.8 * c.x + 0.1, c.y * 0.5, c.z))
            })
            .collect();
        let m = fit_colour_transform(&pairs, 1e-4);
        let h = Vec3::new(0.5, 0.6, 0.3).extend(1.0);
        let out = Vec3::new(m[0].dot(h), m[1].dot(h), m[2].dot(h));
        assert!(out.distance(Vec3::new(0.5, 0.3, 0.3)) < 1e-2, "{out}");
    }
}
