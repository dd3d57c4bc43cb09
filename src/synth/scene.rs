//! Synthetic capture rigs: seeded camera rings around a person, or one camera moving around
//! them, split into input views (fed to the node) and held-out views (used only for scoring).

use crate::splat::{Camera, Intrinsics};
use glam::Vec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A named camera of a synthetic rig.
#[derive(Debug, Clone)]
pub struct RigCamera {
    /// Camera name, used in topic and frame names (`cam0`, `heldout1`, ...).
    pub name: String,
    /// Pose and intrinsics.
    pub camera: Camera,
}

/// Input and held-out cameras around a person standing at the origin (+Y up).
#[derive(Debug, Clone)]
pub struct Rig {
    /// Cameras whose images the node sees.
    pub inputs: Vec<RigCamera>,
    /// Cameras kept for evaluation.
    pub heldout: Vec<RigCamera>,
}

/// Vertical field of view of the synthetic cameras (radians).
const FOV_Y: f32 = 0.75;

impl Rig {
    /// `views` input cameras evenly spread on a ring (seeded jitter in angle, height and
    /// distance) and `heldout` cameras between them, all `size`×`size` pixels, looking at the
    /// middle of a body of `height` metres.
    pub fn ring(seed: u64, views: usize, heldout: usize, size: u32, height: f32) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x7269_6721);
        let intrinsics = Intrinsics::from_fov_y(size, size, FOV_Y);
        let target = Vec3::new(0.0, 0.5 * height, 0.0);
        // Distance at which the whole body fits with a margin.
        let distance = 0.62 * height / (0.5 * FOV_Y).tan();
        let start = rng.gen_range(0.0..std::f32::consts::TAU);
        let place = |angle: f32, rng: &mut ChaCha8Rng| {
            let r = distance * rng.gen_range(0.95..1.08);
            let up = rng.gen_range(-0.1..0.35) * height;
            let eye = target + Vec3::new(angle.sin() * r, up, angle.cos() * r);
            Camera::look_at(eye, target, Vec3::Y, intrinsics)
        };
        let step = std::f32::consts::TAU / views.max(1) as f32;
        let inputs = (0..views)
            .map(|i| {
                let angle = start + step * i as f32 + rng.gen_range(-0.15..0.15) * step;
                RigCamera {
                    name: format!("cam{i}"),
                    camera: place(angle, &mut rng),
                }
            })
            .collect();
        let hstep = std::f32::consts::TAU / heldout.max(1) as f32;
        let heldout = (0..heldout)
            .map(|i| {
                let angle = start + 0.5 * step + hstep * i as f32;
                RigCamera {
                    name: format!("heldout{i}"),
                    camera: place(angle, &mut rng),
                }
            })
            .collect();
        Self { inputs, heldout }
    }
}

impl Rig {
    /// One input camera `cam0` moving over `frames` frames along a seeded path around the
    /// person: one full orbit, its height rising and falling and its distance breathing,
    /// always looking at the middle of the body. The held-out cameras are those of
    /// [`Rig::ring`] with the same arguments, so scoring sees the same kind of views.
    pub fn moving(seed: u64, frames: usize, heldout: usize, size: u32, height: f32) -> Self {
        let ring = Self::ring(seed, frames, heldout, size, height);
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x6d6f_7669_6e67);
        let intrinsics = Intrinsics::from_fov_y(size, size, FOV_Y);
        let target = Vec3::new(0.0, 0.5 * height, 0.0);
        let distance = 0.62 * height / (0.5 * FOV_Y).tan();
        let start = rng.gen_range(0.0..std::f32::consts::TAU);
        let direction = if rng.gen_bool(0.5) { 1.0 } else { -1.0 };
        let rise = rng.gen_range(0.1..0.25) * height;
        let phase = rng.gen_range(0.0..std::f32::consts::TAU);
        let inputs = (0..frames)
            .map(|k| {
                let t = k as f32 / frames.max(1) as f32;
                let wave = (std::f32::consts::TAU * t + phase).sin();
                let angle = start + direction * std::f32::consts::TAU * t;
                let r = distance * (1.02 + 0.04 * wave);
                let up = 0.1 * height + rise * wave;
                let eye = target + Vec3::new(angle.sin() * r, up, angle.cos() * r);
                RigCamera {
                    name: "cam0".into(),
                    camera: Camera::look_at(eye, target, Vec3::Y, intrinsics),
                }
            })
            .collect();
        Self {
            inputs,
            heldout: ring.heldout,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rig_is_deterministic_and_sees_the_body_centre() {
        let a = Rig::ring(3, 4, 2, 128, 1.7);
        let b = Rig::ring(3, 4, 2, 128, 1.7);
        assert_eq!(a.inputs.len(), 4);
        assert_eq!(a.heldout.len(), 2);
        for (x, y) in a.inputs.iter().zip(&b.inputs) {
            assert_eq!(x.camera, y.camera);
        }
        for cam in a.inputs.iter().chain(&a.heldout) {
            let p = cam
                .camera
                .camera_from_world()
                .transform_point3(Vec3::new(0.0, 0.85, 0.0));
            assert!(p.z > 1.0, "body in front of {}", cam.name);
            let px = cam.camera.project_camera_point(p);
            assert!(
                (px.x - 64.0).abs() < 4.0 && (px.y - 64.0).abs() < 20.0,
                "{px}"
            );
        }
    }

    #[test]
    fn moving_camera_orbits_once_and_keeps_the_body_centred() {
        let rig = Rig::moving(3, 8, 2, 128, 1.7);
        assert_eq!(rig.inputs.len(), 8);
        assert!(rig.inputs.iter().all(|c| c.name == "cam0"));
        let eyes: Vec<Vec3> = rig
            .inputs
            .iter()
            .map(|c| c.camera.world_from_camera.translation.into())
            .collect();
        for (i, a) in eyes.iter().enumerate() {
            for b in &eyes[i + 1..] {
                assert!(a.distance(*b) > 0.3, "{a} vs {b}");
            }
        }
        for cam in &rig.inputs {
            let p = cam
                .camera
                .camera_from_world()
                .transform_point3(Vec3::new(0.0, 0.85, 0.0));
            let px = cam.camera.project_camera_point(p);
            assert!((px.x - 64.0).abs() < 4.0, "{px}");
        }
        assert_eq!(rig.heldout.len(), 2);
    }
}
