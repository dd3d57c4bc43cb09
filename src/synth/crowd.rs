//! Several seeded synthetic people walking across one room, seen by fixed cameras around it
//! (`lhmpp synth --people N`): paths that cross, so people occlude one another, with the
//! ground-truth identity of every pixel written beside each image.
//!
//! Each camera image comes with a mono8 id map on `<camera>/person_ids`: pixel value `k + 1`
//! where person `k` (`person_k`) is what the camera sees there (opacity ≥ ½, the person in
//! front where two overlap), 0 elsewhere. The id map comes from the same render as the image:
//! every Gaussian carries a one-hot feature of its person, blended like the colour.

use super::backdrop::Backdrop;
use super::camera_fx::CameraEffects;
use super::capture::{camera_info, camera_transform, image_topic, info_topic, optical_frame};
use super::capture::{START_NS, TF_STATIC_TOPIC};
use super::dressed::DressedPerson;
use super::lighting::Lighting;
use super::person::SynthError;
use super::scene::RigCamera;
use crate::bag::{BagWriter, BagWriterOptions};
use crate::body::motion::walk_pose;
use crate::msgs::{Header, Image, TFMessage, Time};
use crate::splat::{render, Camera, Gaussians, Intrinsics, RenderOptions};
use glam::{Quat, Vec2, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::path::Path;

/// Vertical field of view of the room cameras (radians), wide as a room camera.
const FOV_Y: f32 = 0.9;
/// Walk-cycle frames per second of the built-in walk (40 frames a cycle, a stride of two
/// steps in about 1.3 s).
const WALK_FPS: f32 = 30.0;
/// Half the length of each walking path (metres).
const PATH_HALF: f32 = 1.6;
/// Most people in one scene (ids are one byte, features one channel each).
pub const MAX_PEOPLE: usize = 8;

/// Id-map topic of camera `name`.
pub fn ids_topic(name: &str) -> String {
    format!("/{name}/person_ids")
}

/// Person id of person `k` of a crowd scene, as the id maps number them (`k + 1`).
pub fn crowd_person_id(k: usize) -> String {
    format!("person_{k}")
}

/// What `lhmpp synth --people N` makes.
#[derive(Debug, Clone, PartialEq)]
pub struct CrowdOptions {
    /// Seed of the people, their paths, the cameras and the lighting.
    pub seed: u64,
    /// People in the room (1..=[`MAX_PEOPLE`]).
    pub people: usize,
    /// Fixed cameras `cam0..` around the room.
    pub cameras: usize,
    /// Frames per camera.
    pub frames: usize,
    /// Camera frame rate (frames per second).
    pub fps: f32,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Gaussians per person.
    pub points: usize,
    /// Render only this person (`person_k`): the same scene (paths, cameras, lighting) with
    /// the others left out, the single-person reference of `lhmpp eval-crowd`.
    pub only: Option<usize>,
    /// The cameras' distance from the middle of the room, metres (`None`: as near as keeps a
    /// person at the near end of a path in view, about 3.8 m). Farther cameras see smaller
    /// people: a 1.7 m person in the middle of the room is about a tenth of the frame high at
    /// 17.6 m.
    pub camera_distance: Option<f32>,
}

impl Default for CrowdOptions {
    fn default() -> Self {
        Self {
            seed: 0,
            people: 3,
            cameras: 2,
            frames: 40,
            fps: 10.0,
            width: 640,
            height: 480,
            points: 30_000,
            only: None,
            camera_distance: None,
        }
    }
}

/// One person's straight walk across the room, at constant speed, turned along the path.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WalkPath {
    /// Floor position (x, z) at the first frame.
    pub start: Vec2,
    /// Floor position at the last frame.
    pub end: Vec2,
    /// Walk-cycle frame at the first frame.
    pub phase: f32,
}

impl WalkPath {
    /// Floor position at fraction `s` (0..1) of the scene.
    pub fn at(&self, s: f32) -> Vec2 {
        self.start.lerp(self.end, s)
    }

    /// Rotation about +Y that turns the body (facing +Z) along the path.
    pub fn heading(&self) -> Quat {
        let d = self.end - self.start;
        Quat::from_rotation_y(d.x.atan2(d.y))
    }
}

/// A crowd scene: its people, their paths and the cameras.
pub struct Crowd {
    /// The people, `person_0..`.
    pub people: Vec<DressedPerson>,
    /// Their paths, by person.
    pub paths: Vec<WalkPath>,
    /// The room cameras.
    pub cameras: Vec<RigCamera>,
    options: CrowdOptions,
}

/// One rendered camera frame of a crowd scene.
pub struct CrowdFrame {
    /// The image (lit people over the room's backdrop, through camera effects).
    pub rgb: image::RgbImage,
    /// The id map (`k + 1` where person `k` shows, 0 elsewhere).
    pub ids: image::GrayImage,
}

impl Crowd {
    /// Makes the people and lays out their crossing paths and the cameras for `options`.
    pub fn new(options: &CrowdOptions) -> Result<Self, SynthError> {
        if !(1..=MAX_PEOPLE).contains(&options.people) {
            return Err(SynthError::Dataset(format!(
                "--people {}: a crowd scene holds 1 to {MAX_PEOPLE} people",
                options.people
            )));
        }
        if let Some(k) = options.only.filter(|&k| k >= options.people) {
            return Err(SynthError::Dataset(format!(
                "--only {k}: the scene has people 0 to {}",
                options.people - 1
            )));
        }
        let mut rng = ChaCha8Rng::seed_from_u64(options.seed ^ 0x63_726f_7764);
        // Distinct person seeds, far from the single-person seeds of the fixtures.
        let people = (0..options.people)
            .map(|k| {
                let seed = options
                    .seed
                    .wrapping_mul(1000)
                    .wrapping_add(700_000 + k as u64);
                DressedPerson::new(seed, options.points)
            })
            .collect::<Result<Vec<_>, _>>()?;
        // Paths through the middle of the room at spread angles, offset sideways so the people
        // pass one another (and cross in front of one another for most cameras).
        let start_angle = rng.gen_range(0.0..std::f32::consts::PI);
        let paths = (0..options.people)
            .map(|k| {
                let angle = start_angle
                    + std::f32::consts::PI * k as f32 / options.people as f32
                    + rng.gen_range(-0.2..0.2);
                let dir = Vec2::new(angle.sin(), angle.cos());
                let side = Vec2::new(-dir.y, dir.x) * rng.gen_range(-0.5..0.5);
                let flip = if rng.gen_bool(0.5) { 1.0 } else { -1.0 };
                WalkPath {
                    start: side - dir * PATH_HALF * flip,
                    end: side + dir * PATH_HALF * flip,
                    phase: rng.gen_range(0.0..40.0),
                }
            })
            .collect();
        let tallest = people
            .iter()
            .map(|p| p.template.height())
            .fold(0.0, f32::max);
        let cameras = room_cameras(
            &mut rng,
            options.cameras,
            (options.width, options.height),
            tallest,
            options.camera_distance,
        );
        Ok(Self {
            people,
            paths,
            cameras,
            options: options.clone(),
        })
    }

    /// Renders frame `f` from every camera, in camera order. Each person is posed (and its
    /// key-light shadow computed) once per frame; only the shading depends on the camera.
    pub fn render_frame(&self, f: usize) -> Result<Vec<CrowdFrame>, SynthError> {
        let o = &self.options;
        let s = f as f32 / (o.frames.max(2) - 1) as f32;
        let seconds = f as f32 / o.fps;
        let mut lights = ChaCha8Rng::seed_from_u64(o.seed ^ 0x6c69_6768_7473);
        let lighting = Lighting::random(&mut lights);
        let key = lighting.lights.first().map(|l| l.direction);
        let mut posed_people = Vec::with_capacity(self.people.len());
        for (k, (person, path)) in self.people.iter().zip(&self.paths).enumerate() {
            if o.only.is_some_and(|only| only != k) {
                posed_people.push(None);
                continue;
            }
            let pose = walk_pose(path.phase + seconds * WALK_FPS);
            let matrices = person
                .template
                .skeleton
                .try_skinning_matrices(&pose)
                .map_err(|e| SynthError::Pose(e.to_string()))?;
            let posed = person.avatar.animate(&matrices);
            let shadow = match key {
                Some(d) => Some(person.light_visibility(&matrices, &posed, d)?),
                None => None,
            };
            let floor = path.at(s);
            posed_people.push(Some(PosedPerson {
                posed,
                shadow,
                heading: path.heading(),
                offset: Vec3::new(floor.x, 0.0, floor.y),
            }));
        }
        Ok((0..self.cameras.len())
            .map(|c| self.render_camera(f, c, &lighting, &posed_people))
            .collect())
    }

    /// Shades the posed people for camera `c` (lit in each body's frame), renders them
    /// together with their one-hot person features, and composes image and id map. People
    /// left out of the scene ([`CrowdOptions::only`]) are `None`.
    fn render_camera(
        &self,
        f: usize,
        c: usize,
        lighting: &Lighting,
        posed_people: &[Option<PosedPerson>],
    ) -> CrowdFrame {
        let o = &self.options;
        let n = self.people.len();
        let rig = &self.cameras[c];
        let eye = Vec3::from(rig.camera.world_from_camera.translation);
        let mut scene: Option<Gaussians> = None;
        for (k, (person, p)) in self.people.iter().zip(posed_people).enumerate() {
            let Some(p) = p else { continue };
            // Light in the body's frame: the camera's eye brought into it.
            let eye_body = p.heading.inverse() * (eye - p.offset);
            let mut lit = lighting.lit(person, &p.posed, eye_body, p.shadow.as_deref(), false);
            place(&mut lit, p.heading, p.offset);
            lit.feature_channels = n;
            lit.features = (0..lit.len())
                .flat_map(|_| (0..n).map(move |j| if j == k { 1.0 } else { 0.0 }))
                .collect();
            scene = Some(match scene {
                None => lit,
                Some(mut all) => {
                    append(&mut all, lit);
                    all
                }
            });
        }
        let scene = scene.expect("at least one person");
        let options = RenderOptions {
            background: Vec3::ZERO,
            render_features: true,
            ..RenderOptions::default()
        };
        let out = render(&scene, &rig.camera, &options);
        let (w, h) = (out.width, out.height);
        // A fixed camera keeps its exposure, white balance and optics; only the noise is new
        // each frame. Its backdrop is a room or a smooth texture, not a test pattern.
        let mut fx_rng = ChaCha8Rng::seed_from_u64(o.seed ^ 0x6678 ^ ((c as u64) << 16));
        let mut effects = CameraEffects::random(&mut fx_rng);
        effects.seed ^= (f as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15);
        let mut bg_rng = ChaCha8Rng::seed_from_u64(o.seed ^ 0x726f_6f6d ^ c as u64);
        let backdrop = std::iter::repeat_with(|| Backdrop::random(&mut bg_rng))
            .find(|b| matches!(b, Backdrop::Room { .. } | Backdrop::Smooth { .. }))
            .expect("rooms and smooth textures are drawn half the time");
        let mut composed = out.rgb.clone();
        for (i, px) in composed.chunks_exact_mut(3).enumerate() {
            let (x, y) = (i as u32 % w, i as u32 / w);
            let bg = backdrop.at(x, y, w, h) * (1.0 - out.alpha[i]);
            for (ch, b) in px.iter_mut().zip(bg.to_array()) {
                *ch += b;
            }
        }
        let rgb = effects.apply(&composed, w, h);
        let ids = image::GrayImage::from_fn(w, h, |x, y| {
            let i = (y * w + x) as usize;
            let weights = &out.features[i * n..(i + 1) * n];
            let (best, weight) =
                weights.iter().enumerate().fold(
                    (0, 0.0f32),
                    |acc, (j, &v)| if v > acc.1 { (j, v) } else { acc },
                );
            image::Luma([if weight >= 0.5 { best as u8 + 1 } else { 0 }])
        });
        CrowdFrame { rgb, ids }
    }
}

/// One person posed for a frame, before shading.
struct PosedPerson {
    /// Posed Gaussians in the body's frame.
    posed: Gaussians,
    /// How much of the key light reaches each Gaussian.
    shadow: Option<Vec<f32>>,
    /// Turn along the walking path.
    heading: Quat,
    /// Floor position in the room.
    offset: Vec3,
}

/// Turns Gaussians posed in a body frame by `heading` and moves them by `offset`.
fn place(g: &mut Gaussians, heading: Quat, offset: Vec3) {
    for p in &mut g.positions {
        *p = heading * *p + offset;
    }
    for r in &mut g.rotations {
        *r = (heading * *r).normalize();
    }
}

/// Appends `more` to `all` (same SH degree and feature channels).
fn append(all: &mut Gaussians, more: Gaussians) {
    all.positions.extend(more.positions);
    all.scales.extend(more.scales);
    all.rotations.extend(more.rotations);
    all.opacities.extend(more.opacities);
    all.sh.extend(more.sh);
    all.features.extend(more.features);
}

/// `count` cameras on a circle around the room, at head height with seeded jitter, looking
/// at the middle of the room, every path in view: `distance` from the middle (`None`: far
/// enough that a person at the near end of a path still fits vertically in view).
fn room_cameras(
    rng: &mut ChaCha8Rng,
    count: usize,
    (width, height): (u32, u32),
    body_height: f32,
    distance: Option<f32>,
) -> Vec<RigCamera> {
    let intrinsics = Intrinsics::from_fov_y(width, height, FOV_Y);
    let target = Vec3::new(0.0, 0.5 * body_height, 0.0);
    let distance = distance.unwrap_or_else(|| PATH_HALF + 0.62 * body_height / (0.5 * FOV_Y).tan());
    let start = rng.gen_range(0.0..std::f32::consts::TAU);
    (0..count)
        .map(|i| {
            let angle = start
                + std::f32::consts::TAU * i as f32 / count.max(1) as f32
                + rng.gen_range(-0.2..0.2);
            let up = rng.gen_range(0.1..0.35) * body_height;
            let eye = target + Vec3::new(angle.sin() * distance, up, angle.cos() * distance);
            RigCamera {
                name: format!("cam{i}"),
                camera: Camera::look_at(eye, target, Vec3::Y, intrinsics),
            }
        })
        .collect()
}

/// Renders the crowd scene of `options` and writes its bag at `path`: `/tf_static` with the
/// cameras, then per frame and camera `camera_info`, `image_raw` (rgb8) and `person_ids`
/// (mono8), frames `1 / fps` apart. `progress(done, total)` after each image.
pub fn write_crowd_bag(
    path: &Path,
    options: &CrowdOptions,
    mut progress: impl FnMut(usize, usize),
) -> Result<super::SynthSummary, SynthError> {
    if options.cameras == 0 || options.frames == 0 || options.fps <= 0.0 {
        return Err(SynthError::Dataset(
            "a crowd scene needs at least one camera, one frame and a positive frame rate".into(),
        ));
    }
    let crowd = Crowd::new(options)?;
    let mut bag = BagWriter::create_with(
        path,
        BagWriterOptions {
            flush_interval: None,
            ..BagWriterOptions::default()
        },
    )?;
    let ns = START_NS;
    bag.write(
        TF_STATIC_TOPIC,
        ns,
        &TFMessage {
            transforms: crowd
                .cameras
                .iter()
                .map(|c| camera_transform(c, ns))
                .collect(),
        },
    )?;
    let period = (1e9 / options.fps as f64) as u64;
    let total = options.frames * options.cameras;
    for f in 0..options.frames {
        let frames = crowd.render_frame(f)?;
        for (c, (rig, frame)) in crowd.cameras.iter().zip(frames).enumerate() {
            // Cameras triggered together; 1 ms apart so every message has its own stamp.
            let t = ns + period * (f as u64 + 1) + 1_000_000 * c as u64;
            let name = &rig.name;
            bag.write(&info_topic(name), t, &camera_info(rig, t))?;
            let size = frame.rgb.dimensions();
            let rgb = image_message(name, t, "rgb8", size, 3, frame.rgb.into_raw());
            bag.write(&image_topic(name), t, &rgb)?;
            let ids = image_message(name, t, "mono8", size, 1, frame.ids.into_raw());
            bag.write(&ids_topic(name), t, &ids)?;
            progress(f * options.cameras + c + 1, total);
        }
    }
    let messages = bag.finish()?;
    let bytes = std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
    Ok(super::SynthSummary { messages, bytes })
}

/// Renders every frame of the crowd scene of `options` from every camera, for a live stream
/// (`lhmpp loadgen --people N`): `images[frame][camera]`, with the room cameras.
/// `progress(done, total)` after each frame.
pub fn render_crowd_stream(
    options: &CrowdOptions,
    mut progress: impl FnMut(usize, usize),
) -> Result<super::stream::StreamFrames, SynthError> {
    let crowd = Crowd::new(options)?;
    let mut images = Vec::with_capacity(options.frames);
    for f in 0..options.frames {
        images.push(crowd.render_frame(f)?.into_iter().map(|c| c.rgb).collect());
        progress(f + 1, options.frames);
    }
    Ok(super::stream::StreamFrames {
        cameras: crowd.cameras,
        images,
    })
}

/// A raw image message of camera `name`'s optical frame: `channels` bytes per pixel.
fn image_message(
    name: &str,
    ns: u64,
    encoding: &str,
    (width, height): (u32, u32),
    channels: u32,
    data: Vec<u8>,
) -> Image {
    Image {
        header: Header::new(Time::from_nanos(ns as i64), optical_frame(name)),
        height,
        width,
        encoding: encoding.into(),
        is_bigendian: 0,
        step: channels * width,
        data,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn small() -> CrowdOptions {
        CrowdOptions {
            seed: 3,
            people: 2,
            cameras: 2,
            frames: 5,
            width: 160,
            height: 120,
            points: 3000,
            ..CrowdOptions::default()
        }
    }

    /// Every person shows in the id maps of the first frame, and the paths cross: in the
    /// middle frame the two people stand closer together than at the ends.
    #[test]
    fn people_show_and_paths_cross() {
        let crowd = Crowd::new(&small()).unwrap();
        let frame = &crowd.render_frame(0).unwrap()[0];
        for k in 1..=2u8 {
            let count = frame.ids.pixels().filter(|p| p.0[0] == k).count();
            assert!(count > 50, "person {k} shows in {count} pixels");
        }
        let gap = |s: f32| crowd.paths[0].at(s).distance(crowd.paths[1].at(s));
        assert!(gap(0.5) < gap(0.0) && gap(0.5) < gap(1.0));
    }

    /// Ids stay in range, and a scene without people is refused.
    #[test]
    fn ids_are_in_range() {
        let crowd = Crowd::new(&small()).unwrap();
        let frame = &crowd.render_frame(2).unwrap()[1];
        assert!(frame.ids.pixels().all(|p| p.0[0] <= 2));
        assert!(Crowd::new(&CrowdOptions {
            people: 0,
            ..small()
        })
        .is_err());
    }
}
