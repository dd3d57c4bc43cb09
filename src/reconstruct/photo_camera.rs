//! A pinhole camera for an uncalibrated photo, placed from its landmarks, so that the photo
//! can be fitted to like a calibrated view ([`crate::refine`]).
//!
//! The person's pose is the one solved from perception's world landmarks
//! ([`super::photos::photo_pose`]); the posed template's landmarks and perception's image
//! landmarks are the correspondences. A photo carries no focal length we read (no EXIF), so
//! the focal length is assumed ([`PhotoCameraConfig::focal_per_side`]) and the principal point
//! put at the image's centre. The camera's rotation and position start from the weak-perspective
//! (affine) camera the colours are sampled with ([`super::photo_colours`]: rows scaled to unit
//! length and made orthogonal give the rotation, their scale the distance), then
//! Levenberg–Marquardt moves them to the least squared reprojection error of the landmarks the
//! affine fit kept (the one it missed most is dropped while it misses).

use super::photo_colours::{landmark_pairs, robust_affine, AffineCamera};
use crate::body::{BodyTemplate, Pose};
use crate::perception::pose::{template_landmarks, PoseSolveError};
use crate::perception::{Landmark, BODY_LANDMARKS};
use crate::splat::{Camera, Intrinsics};
use glam::{Affine3A, DMat3, DVec3, Vec2, Vec3};

/// Settings of [`photo_camera`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PhotoCameraConfig {
    /// Focal length in pixels as a multiple of the photo's longer side (1.0: a field of view
    /// of 53° across it, between a phone's wide lens and a portrait lens).
    pub focal_per_side: f32,
    /// Landmark visibility from which a landmark places the camera.
    pub min_visibility: f32,
    /// Largest RMS reprojection error, as a share of the person's height on the photo.
    pub max_fit_error: f32,
}

impl Default for PhotoCameraConfig {
    fn default() -> Self {
        Self {
            focal_per_side: 1.0,
            min_visibility: 0.5,
            max_fit_error: 0.06,
        }
    }
}

/// Why no camera could be placed.
#[derive(Debug, thiserror::Error)]
pub enum PhotoCameraError {
    /// The template's landmarks could not be posed.
    #[error(transparent)]
    Pose(#[from] PoseSolveError),
    /// Too few landmarks, or the landmarks do not agree with any camera.
    #[error("placing the photo's camera: {0}")]
    Fit(String),
}

/// A photo's camera and how well it fits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PhotoCamera {
    /// The camera, in the world frame of the pose it was fitted with, intrinsics in the
    /// photo's pixels.
    pub camera: Camera,
    /// RMS reprojection error of the landmarks used, as a share of the person's height.
    pub rms: f32,
    /// Landmarks used.
    pub landmarks: usize,
}

/// The pinhole camera of a `width` × `height` photo on which perception read `landmarks` of a
/// person whose pose on `template` is `pose` (see the module doc).
pub fn photo_camera(
    template: &BodyTemplate,
    pose: &Pose,
    landmarks: &[Landmark; BODY_LANDMARKS],
    (width, height): (u32, u32),
    config: &PhotoCameraConfig,
) -> Result<PhotoCamera, PhotoCameraError> {
    let posed = template_landmarks(template, pose)?;
    let (mut pairs, person) = landmark_pairs(&posed, landmarks, config.min_visibility);
    // The affine fit may reject a landmark at twice the final limit: perspective can be
    // what it misses.
    let (affine, _) = robust_affine(&mut pairs, person, 2.0 * config.max_fit_error)
        .map_err(PhotoCameraError::Fit)?;
    let intrinsics = centred_intrinsics(
        width,
        height,
        config.focal_per_side * width.max(height) as f32,
    );
    let start = from_affine(&affine, &pairs, &intrinsics)
        .ok_or_else(|| PhotoCameraError::Fit("the landmarks span no plane".into()))?;
    let pose = levenberg_marquardt(start, &pairs, &intrinsics);
    let camera = pose.camera(intrinsics);
    let rms = reprojection_rms(&camera, &pairs) / person;
    if !rms.is_finite() || rms > config.max_fit_error {
        return Err(PhotoCameraError::Fit(format!(
            "the camera misses the landmarks by {:.1} % of the person's height",
            rms * 100.0
        )));
    }
    Ok(PhotoCamera {
        camera,
        rms,
        landmarks: pairs.len(),
    })
}

/// Intrinsics of a `width` × `height` image with focal length `f` (pixels) and the principal
/// point at its centre.
fn centred_intrinsics(width: u32, height: u32, f: f32) -> Intrinsics {
    Intrinsics::from_fov_y(width, height, 2.0 * (0.5 * height as f32 / f).atan())
}

/// RMS distance (pixels) between each pair's pixel and its point projected by `camera`
/// (infinite when a point is behind it).
pub fn reprojection_rms(camera: &Camera, pairs: &[(Vec3, Vec2)]) -> f32 {
    let view = camera.camera_from_world();
    let sum: f32 = pairs
        .iter()
        .map(|(x, p)| {
            let c = view.transform_point3(*x);
            if c.z <= 1e-3 {
                f32::INFINITY
            } else {
                camera.project_camera_point(c).distance_squared(*p)
            }
        })
        .sum();
    (sum / pairs.len().max(1) as f32).sqrt()
}

/// A camera's pose as the fit moves it: a point `X` is at `rotation · (X − centroid) + at`
/// in the optical frame.
#[derive(Debug, Clone, Copy)]
struct Placement {
    rotation: DMat3,
    centroid: DVec3,
    at: DVec3,
}

impl Placement {
    fn camera(&self, intrinsics: Intrinsics) -> Camera {
        let r = self.rotation.as_mat3();
        let camera_from_world =
            Affine3A::from_mat3_translation(r, (self.at - self.rotation * self.centroid).as_vec3());
        Camera {
            intrinsics,
            world_from_camera: camera_from_world.inverse(),
        }
    }

    /// Sum of squared pixel residuals.
    fn cost(&self, pairs: &[(Vec3, Vec2)], k: &Intrinsics) -> f64 {
        pairs
            .iter()
            .map(|(x, p)| {
                let c = self.rotation * (x.as_dvec3() - self.centroid) + self.at;
                if c.z <= 1e-6 {
                    return f64::INFINITY;
                }
                let u = k.fx as f64 * c.x / c.z + k.cx as f64 - p.x as f64;
                let v = k.fy as f64 * c.y / c.z + k.cy as f64 - p.y as f64;
                u * u + v * v
            })
            .sum()
    }
}

/// The pinhole placement that projects like `affine` near the landmarks' centroid: the rows'
/// directions, made orthogonal, are the optical x and y axes, their mean length `s` (pixels
/// per metre) puts the centroid at depth `f / s`.
fn from_affine(affine: &AffineCamera, pairs: &[(Vec3, Vec2)], k: &Intrinsics) -> Option<Placement> {
    let (m1, m2) = (
        affine.u.truncate().as_dvec3(),
        affine.v.truncate().as_dvec3(),
    );
    let (s1, s2) = (m1.length(), m2.length());
    if s1 < 1e-9 || s2 < 1e-9 {
        return None;
    }
    let r1 = m1 / s1;
    let r2 = (m2 / s2 - r1 * r1.dot(m2 / s2)).try_normalize()?;
    let r3 = r1.cross(r2);
    let centroid =
        pairs.iter().map(|(x, _)| x.as_dvec3()).sum::<DVec3>() / pairs.len().max(1) as f64;
    let pixel = affine.project(centroid.as_vec3()).as_dvec2();
    let depth = k.fx as f64 / (0.5 * (s1 + s2));
    Some(Placement {
        rotation: DMat3::from_cols(r1, r2, r3).transpose(),
        centroid,
        at: DVec3::new(
            (pixel.x - k.cx as f64) * depth / k.fx as f64,
            (pixel.y - k.cy as f64) * depth / k.fy as f64,
            depth,
        ),
    })
}

/// Steps of [`levenberg_marquardt`].
const LM_STEPS: usize = 50;

/// Moves `start` to the least squared reprojection error of `pairs`: rotation by a left
/// perturbation about the centroid, and the centroid's place in the optical frame.
fn levenberg_marquardt(start: Placement, pairs: &[(Vec3, Vec2)], k: &Intrinsics) -> Placement {
    let (fx, fy) = (k.fx as f64, k.fy as f64);
    let mut current = start;
    let mut cost = current.cost(pairs, k);
    let mut lambda = 1e-3;
    for _ in 0..LM_STEPS {
        let mut jtj = [[0.0f64; 6]; 6];
        let mut jtr = [0.0f64; 6];
        for (x, p) in pairs {
            let v = current.rotation * (x.as_dvec3() - current.centroid);
            let c = v + current.at;
            let inv = 1.0 / c.z;
            let residual = [
                fx * c.x * inv + k.cx as f64 - p.x as f64,
                fy * c.y * inv + k.cy as f64 - p.y as f64,
            ];
            // ∂pixel/∂c, then c moves by ω × v (rotation) and by the step (translation).
            let dp = [
                DVec3::new(fx * inv, 0.0, -fx * c.x * inv * inv),
                DVec3::new(0.0, fy * inv, -fy * c.y * inv * inv),
            ];
            for (row, r) in dp.iter().zip(residual) {
                let mut j = [0.0f64; 6];
                for (a, axis) in [DVec3::X, DVec3::Y, DVec3::Z].into_iter().enumerate() {
                    j[a] = row.dot(axis.cross(v));
                    j[3 + a] = row[a];
                }
                for a in 0..6 {
                    jtr[a] += j[a] * r;
                    for b in 0..6 {
                        jtj[a][b] += j[a] * j[b];
                    }
                }
            }
        }
        let mut improved = false;
        for _ in 0..8 {
            let mut damped = jtj;
            for (a, row) in damped.iter_mut().enumerate() {
                row[a] += lambda * jtj[a][a].max(1e-9);
            }
            let Some(step) = solve6(damped, jtr.map(|v| -v)) else {
                lambda *= 10.0;
                continue;
            };
            let omega = DVec3::new(step[0], step[1], step[2]);
            let candidate = Placement {
                rotation: rotation_matrix(omega) * current.rotation,
                centroid: current.centroid,
                at: current.at + DVec3::new(step[3], step[4], step[5]),
            };
            let c = candidate.cost(pairs, k);
            if c < cost {
                current = candidate;
                improved = cost - c > 1e-12 * cost.max(1.0);
                cost = c;
                lambda = (lambda * 0.3).max(1e-9);
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    current
}

/// The rotation by the rotation vector `w` (Rodrigues).
fn rotation_matrix(w: DVec3) -> DMat3 {
    let angle = w.length();
    if angle < 1e-12 {
        return DMat3::IDENTITY;
    }
    DMat3::from_axis_angle(w / angle, angle)
}

/// Solves the 6 × 6 system `a x = b` by Gaussian elimination with partial pivoting.
fn solve6(mut a: [[f64; 6]; 6], mut b: [f64; 6]) -> Option<[f64; 6]> {
    for col in 0..6 {
        let pivot = (col..6).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        if a[pivot][col].abs() < 1e-300 {
            return None;
        }
        a.swap(col, pivot);
        b.swap(col, pivot);
        for row in col + 1..6 {
            let f = a[row][col] / a[col][col];
            let pivot_row = a[col];
            for (v, p) in a[row].iter_mut().zip(pivot_row).skip(col) {
                *v -= f * p;
            }
            b[row] -= f * b[col];
        }
    }
    let mut x = [0.0; 6];
    for row in (0..6).rev() {
        let s: f64 = (row + 1..6).map(|c| a[row][c] * x[c]).sum();
        x[row] = (b[row] - s) / a[row][row];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Quat;

    /// Perception's landmarks as `camera` would see the posed template's, all visible.
    fn seen_by(camera: &Camera, posed: &[Vec3; BODY_LANDMARKS]) -> [Landmark; BODY_LANDMARKS] {
        let view = camera.camera_from_world();
        posed.map(|p| {
            let c = view.transform_point3(p);
            Landmark {
                position: camera.project_camera_point(c).extend(c.z),
                visibility: 1.0,
                presence: 1.0,
            }
        })
    }

    /// An upright camera at `eye` looking at `target`.
    fn looking(eye: Vec3, target: Vec3, k: Intrinsics) -> Camera {
        Camera::look_at(eye, target, Vec3::Y, k)
    }

    fn a_pose() -> Pose {
        let mut pose = Pose::identity();
        pose.rotations
            .insert("upperarm01.L".into(), Quat::from_rotation_z(0.6));
        pose.rotations
            .insert("upperleg01.R".into(), Quat::from_rotation_x(-0.4));
        pose.root_rotation = Quat::from_rotation_y(0.5);
        pose
    }

    /// With the focal length it was given, the fit finds a known camera from the landmarks it
    /// projects: it reprojects the posed body's landmarks onto the photo's and sits where the
    /// camera was.
    #[test]
    fn a_known_camera_is_recovered_from_its_landmarks() {
        let template = BodyTemplate::load_default().unwrap();
        let pose = a_pose();
        let posed = template_landmarks(&template, &pose).unwrap();
        let (w, h) = (640, 960);
        let k = centred_intrinsics(w, h, 1.3 * h as f32);
        let truth = looking(Vec3::new(0.8, 1.3, 3.2), Vec3::new(0.05, 0.9, 0.0), k);
        let landmarks = seen_by(&truth, &posed);
        let config = PhotoCameraConfig {
            focal_per_side: 1.3,
            ..PhotoCameraConfig::default()
        };
        let fit = photo_camera(&template, &pose, &landmarks, (w, h), &config).unwrap();
        assert_eq!(fit.landmarks, 15);
        let (pairs, _) = landmark_pairs(&posed, &landmarks, 0.5);
        let miss = reprojection_rms(&fit.camera, &pairs);
        assert!(miss < 0.05, "reprojection {miss} px");
        assert!(
            fit.camera.center().distance(truth.center()) < 1e-2,
            "{} vs {}",
            fit.camera.center(),
            truth.center()
        );
        // Every landmark, the face and hands too, lands where the photo has it.
        for (p, l) in posed.iter().zip(&landmarks) {
            let c = fit.camera.camera_from_world().transform_point3(*p);
            let px = fit.camera.project_camera_point(c);
            assert!(px.distance(l.position.truncate()) < 0.1);
        }
    }

    /// With the wrong focal length and a pixel of noise the landmarks still land within 1 %
    /// of the person's height; a photo with too few landmarks seen is refused, by name.
    #[test]
    fn a_wrong_focal_length_still_reprojects_and_too_few_landmarks_are_refused() {
        let template = BodyTemplate::load_default().unwrap();
        let pose = a_pose();
        let posed = template_landmarks(&template, &pose).unwrap();
        let (w, h) = (1280, 720);
        let truth = looking(
            Vec3::new(-0.5, 1.0, 4.0),
            Vec3::new(0.0, 1.0, 0.0),
            Intrinsics::from_fov_y(w, h, 0.7),
        );
        let mut landmarks = seen_by(&truth, &posed);
        for (i, l) in landmarks.iter_mut().enumerate() {
            let wobble = ((i * 7919) % 13) as f32 / 6.0 - 1.0;
            l.position.x += wobble;
            l.position.y -= 0.5 * wobble;
        }
        let fit = photo_camera(
            &template,
            &pose,
            &landmarks,
            (w, h),
            &PhotoCameraConfig::default(),
        )
        .unwrap();
        assert!(fit.rms < 0.01, "{}", fit.rms);
        for l in landmarks.iter_mut().skip(3) {
            l.visibility = 0.0;
        }
        let err = photo_camera(
            &template,
            &pose,
            &landmarks,
            (w, h),
            &PhotoCameraConfig::default(),
        )
        .unwrap_err();
        assert!(err.to_string().contains("landmarks"), "{err}");
    }
}
