//! Per-view corrections for views whose camera and pose were not measured but fitted (photos:
//! a camera placed from the landmarks, a pose solved from them): the fit moves, per fitted
//! view, a rigid transform of the posed body in the camera's optical frame alongside the
//! avatar.
//!
//! In the optical frame a posed point `x` goes to `R (x − p) + p + t`: `R` a rotation about the
//! body's centre `p` (its yaw, pitch and roll against the camera: a small in-image rotation
//! and the facing the pose solver got wrong), `t` a translation whose `x` and `y` shift the
//! person in the image and whose `z` scales them (nearer or farther). The rotation is stepped
//! by a left perturbation `R ← exp(ω) R`; its gradient is taken with respect to `ω` at 0.
//! Gaussians' orientations turn with `R`. A prior pulls each correction back to none
//! ([`PRIOR_WEIGHT`] per ([`ROTATION_PRIOR`], [`TRANSLATION_PRIOR`])²), so views that agree
//! keep the camera they were given.

use super::params::Moments;
use crate::splat::grad::GaussianGrads;
use crate::splat::{Camera, Gaussians};
use glam::{Affine3A, Mat3, Quat, Vec3, Vec4};

/// Adam's learning rate of the rotation (radians per step).
const ROTATION_RATE: f32 = 2e-3;
/// Adam's learning rate of the translation (metres per step).
const TRANSLATION_RATE: f32 = 2e-3;
/// Rotation (radians) at which the prior costs [`PRIOR_WEIGHT`].
pub(crate) const ROTATION_PRIOR: f32 = 0.1;
/// Translation (metres) at which the prior costs [`PRIOR_WEIGHT`].
pub(crate) const TRANSLATION_PRIOR: f32 = 0.05;
/// Weight of the prior (in units of the view's loss).
pub(crate) const PRIOR_WEIGHT: f32 = 0.01;

/// One view's correction (see the module doc).
#[derive(Debug, Clone)]
pub(crate) struct ViewCorrection {
    /// `R`, in the optical frame.
    pub rotation: Quat,
    /// `t`, in the optical frame (metres).
    pub translation: Vec3,
    /// `p`, the body's centre in the optical frame.
    pivot: Vec3,
    rotation_moments: Moments,
    translation_moments: Moments,
    steps: i32,
}

impl ViewCorrection {
    /// No correction, rotations about `pivot` (optical frame).
    pub fn new(pivot: Vec3) -> Self {
        Self {
            rotation: Quat::IDENTITY,
            translation: Vec3::ZERO,
            pivot,
            rotation_moments: Moments::default(),
            translation_moments: Moments::default(),
            steps: 0,
        }
    }

    /// The correction as a rigid transform of the world, for a view seen by `camera`.
    pub fn world_transform(&self, camera: &Camera) -> Affine3A {
        let delta = Affine3A::from_translation(self.pivot + self.translation)
            * Affine3A::from_quat(self.rotation)
            * Affine3A::from_translation(-self.pivot);
        camera.world_from_camera * delta * camera.camera_from_world()
    }

    /// Moves the posed Gaussians `g` of a view seen by `camera` by the correction; returns the
    /// transform applied (for [`pull_back`]).
    pub fn apply(&self, camera: &Camera, g: &mut Gaussians) -> Affine3A {
        let t = self.world_transform(camera);
        let r = Quat::from_mat3(&Mat3::from(t.matrix3)).normalize();
        for p in &mut g.positions {
            *p = t.transform_point3(*p);
        }
        for q in &mut g.rotations {
            *q = r * *q;
        }
        t
    }

    /// The gradient of a loss with respect to the rotation's perturbation `ω` (optical axes)
    /// and the translation, given its gradients `grads` with respect to the Gaussians
    /// `corrected` that [`ViewCorrection::apply`] left.
    pub fn gradient(
        &self,
        camera: &Camera,
        corrected: &Gaussians,
        grads: &GaussianGrads,
    ) -> (Vec3, Vec3) {
        let view = camera.camera_from_world();
        let to_optical = Mat3::from(view.matrix3);
        // The world directions of the optical axes (rows of the world → optical rotation).
        let axes = [Vec3::X, Vec3::Y, Vec3::Z].map(|e| to_optical.transpose() * e);
        let (mut d_omega, mut d_t) = (Vec3::ZERO, Vec3::ZERO);
        for i in 0..corrected.len() {
            let d_x = grads.positions[i];
            if d_x != Vec3::ZERO {
                let g = to_optical * d_x;
                let v =
                    view.transform_point3(corrected.positions[i]) - self.pivot - self.translation;
                d_t += g;
                d_omega += v.cross(g);
            }
            let d_q = grads.rotations[i];
            if d_q != Vec4::ZERO {
                let q = corrected.rotations[i];
                for (k, a) in axes.iter().enumerate() {
                    let turn = Quat::from_xyzw(a.x, a.y, a.z, 0.0) * q;
                    d_omega[k] += 0.5 * d_q.dot(Vec4::from(turn));
                }
            }
        }
        (d_omega, d_t)
    }

    /// One Adam step along `(d_omega, d_t)` ([`ViewCorrection::gradient`]) plus the prior's
    /// gradient.
    pub fn step(&mut self, (d_omega, d_t): (Vec3, Vec3)) {
        let d_omega = d_omega
            + self.rotation.to_scaled_axis()
                * (2.0 * PRIOR_WEIGHT / (ROTATION_PRIOR * ROTATION_PRIOR));
        let d_t =
            d_t + self.translation * (2.0 * PRIOR_WEIGHT / (TRANSLATION_PRIOR * TRANSLATION_PRIOR));
        self.steps += 1;
        let mut omega = [0.0f32; 3];
        self.rotation_moments
            .step(&mut omega, &d_omega.to_array(), ROTATION_RATE, self.steps);
        let mut shift = [0.0f32; 3];
        self.translation_moments
            .step(&mut shift, &d_t.to_array(), TRANSLATION_RATE, self.steps);
        self.rotation =
            (Quat::from_scaled_axis(Vec3::from_array(omega)) * self.rotation).normalize();
        self.translation += Vec3::from_array(shift);
    }
}

/// Turns `grads` with respect to Gaussians moved by the rigid `transform` into gradients with
/// respect to the Gaussians before it (positions and orientations; the rest do not move).
pub(crate) fn pull_back(transform: &Affine3A, grads: &mut GaussianGrads) {
    let m = Mat3::from(transform.matrix3);
    let r = Quat::from_mat3(&m).normalize();
    for d in &mut grads.positions {
        *d = m.transpose() * *d;
    }
    for d in &mut grads.rotations {
        *d = Vec4::from(r.conjugate() * Quat::from_vec4(*d));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::splat::grad::tests::{analytic, check, options, scene, Loss};

    fn corrected(c: &ViewCorrection, g: &Gaussians, camera: &Camera) -> Gaussians {
        let mut g = g.clone();
        c.apply(camera, &mut g);
        g
    }

    /// A correction of the scene's small camera, turned and moved a little.
    fn correction(camera: &Camera, g: &Gaussians) -> ViewCorrection {
        let view = camera.camera_from_world();
        let centre = g.positions.iter().copied().sum::<Vec3>() / g.len() as f32;
        let mut c =
            ViewCorrection::new(view.transform_point3(centre) + Vec3::new(0.02, -0.01, 0.0));
        c.rotation = Quat::from_scaled_axis(Vec3::new(0.03, -0.05, 0.04));
        c.translation = Vec3::new(0.01, -0.02, 0.05);
        c
    }

    /// The correction's rotation and translation gradients, and the gradients pulled back to
    /// the uncorrected Gaussians, match central finite differences of the rendered loss.
    #[test]
    fn correction_gradients_match_finite_differences() {
        let mut checked = 0;
        for seed in 1..=10 {
            let (g, camera) = scene(seed);
            let loss = Loss::new(&camera, seed + 100);
            let c = correction(&camera, &g);
            let moved = corrected(&c, &g, &camera);
            // Two Gaussians within a step of the same depth swap places in the sort (a step
            // of the loss that finite differences see and the gradient does not).
            let view = camera.camera_from_world();
            let depths: Vec<f32> = moved
                .positions
                .iter()
                .map(|p| view.transform_point3(*p).z)
                .collect();
            let tie = depths
                .iter()
                .enumerate()
                .any(|(i, a)| depths[i + 1..].iter().any(|b| (a - b).abs() < 4e-3));
            if tie {
                continue;
            }
            checked += 1;
            let mut grads = analytic(&moved, &camera, &loss);
            let (d_omega, d_t) = c.gradient(&camera, &moved, &grads);
            let value = |c: &ViewCorrection, g: &Gaussians| {
                loss.value(&corrected(c, g, &camera), &camera, &options())
            };
            let h = 1e-3;
            let mut rotation = Vec::new();
            let mut translation = Vec::new();
            for k in 0..3 {
                let e = Vec3::AXES[k];
                let (mut plus, mut minus) = (c.clone(), c.clone());
                // Turns are composed in f32: a larger step keeps rounding out of the
                // difference.
                let hr = 3e-3;
                plus.rotation = Quat::from_scaled_axis(e * hr) * c.rotation;
                minus.rotation = Quat::from_scaled_axis(-e * hr) * c.rotation;
                let n = (value(&plus, &g) - value(&minus, &g)) / (2.0 * hr as f64);
                rotation.push((d_omega[k] as f64, n));
                let (mut plus, mut minus) = (c.clone(), c.clone());
                plus.translation += e * h;
                minus.translation -= e * h;
                let n = (value(&plus, &g) - value(&minus, &g)) / (2.0 * h as f64);
                translation.push((d_t[k] as f64, n));
            }
            let mut fails = check("rotation", &rotation, 0.02);
            fails.extend(check("translation", &translation, 0.01));
            pull_back(&c.world_transform(&camera), &mut grads);
            let mut positions = Vec::new();
            let mut orientations = Vec::new();
            for i in 0..g.len() {
                for d in 0..3 {
                    let (mut plus, mut minus) = (g.clone(), g.clone());
                    plus.positions[i][d] += h;
                    minus.positions[i][d] -= h;
                    let n = (value(&c, &plus) - value(&c, &minus)) / (2.0 * h as f64);
                    positions.push((grads.positions[i][d] as f64, n));
                }
                for d in 0..4 {
                    let h = 3e-3;
                    let (mut plus, mut minus) = (g.clone(), g.clone());
                    let mut v = Vec4::from(plus.rotations[i]);
                    v[d] += h;
                    plus.rotations[i] = Quat::from_vec4(v);
                    let mut v = Vec4::from(minus.rotations[i]);
                    v[d] -= h;
                    minus.rotations[i] = Quat::from_vec4(v);
                    let n = (value(&c, &plus) - value(&c, &minus)) / (2.0 * h as f64);
                    orientations.push((grads.rotations[i][d] as f64, n));
                }
            }
            fails.extend(check("pulled-back position", &positions, 0.01));
            fails.extend(check("pulled-back rotation", &orientations, 0.01));
            assert!(fails.is_empty(), "seed {seed}:\n{}", fails.join("\n"));
            assert!(d_t.length() > 0.0 && d_omega.length() > 0.0);
        }
        assert!(checked >= 3, "only {checked} scenes without depth ties");
    }

    /// Stepping a correction along its own gradient of a loss that wants the body shifted in
    /// the image moves it there; the prior holds a correction with no gradient at none.
    #[test]
    fn steps_follow_the_gradient_and_the_prior_holds_still() {
        let mut c = ViewCorrection::new(Vec3::new(0.0, 0.0, 3.0));
        let target = Vec3::new(0.02, -0.01, 0.0);
        for _ in 0..200 {
            // L = 50 |t − target|² (the prior is small beside it).
            c.step((Vec3::ZERO, (c.translation - target) * 100.0));
        }
        assert!(c.translation.distance(target) < 2e-3, "{}", c.translation);
        let mut still = ViewCorrection::new(Vec3::ZERO);
        for _ in 0..50 {
            still.step((Vec3::ZERO, Vec3::ZERO));
        }
        assert_eq!(still.translation, Vec3::ZERO);
        assert_eq!(still.rotation, Quat::IDENTITY);
    }
}
