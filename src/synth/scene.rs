//! Synthetic capture rigs: seeded camera rings around a person, split into input views (fed to
//! the node) and held-out views (used only for scoring).

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
}
