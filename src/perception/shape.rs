//! Body shape from calibrated views. The person's image landmarks in two or more calibrated
//! cameras (intrinsics and world pose known: CameraInfo and TF) are triangulated into metric
//! 3D points; the lengths of the body's rigid segments between them (upper arms, thighs,
//! shins, torso sides) against the same segments of the template give the MakeHuman height
//! scale (`body::MakeHumanShape`: height scales the whole body).
//!
//! A single view cannot do this: a crop of a taller person far away looks like a shorter one
//! close by. Without calibrated views the node keeps the template's shape.

use super::landmark::{Landmark, LandmarkId, BODY_LANDMARKS};
use super::pose::{LandmarkRig, PoseSolveError};
use crate::body::{BodyTemplate, MakeHumanShape};
use glam::{Affine3A, Mat3, Vec2, Vec3};

/// One view of the person by a calibrated camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CalibratedView {
    /// Focal lengths and principal point, pixels (OpenCV pinhole: x right, y down, z forward).
    pub fx: f32,
    /// Focal length along y, pixels.
    pub fy: f32,
    /// Principal point x, pixels.
    pub cx: f32,
    /// Principal point y, pixels.
    pub cy: f32,
    /// The camera's optical frame in the world.
    pub world_from_camera: Affine3A,
    /// The person's image landmarks in this view (pixels, with visibility).
    pub landmarks: [Landmark; BODY_LANDMARKS],
}

impl CalibratedView {
    /// The world ray through pixel `p`: origin and unit direction.
    fn ray(&self, p: Vec2) -> (Vec3, Vec3) {
        let dir = Vec3::new((p.x - self.cx) / self.fx, (p.y - self.cy) / self.fy, 1.0);
        let origin = self.world_from_camera.translation.into();
        (
            origin,
            self.world_from_camera.transform_vector3(dir).normalize(),
        )
    }
}

/// The segments measured: pairs of landmarks on one rigid body part each.
pub const SEGMENTS: [(LandmarkId, LandmarkId); 12] = {
    use LandmarkId::*;
    [
        (LeftShoulder, LeftElbow),
        (RightShoulder, RightElbow),
        (LeftElbow, LeftWrist),
        (RightElbow, RightWrist),
        (LeftHip, LeftKnee),
        (RightHip, RightKnee),
        (LeftKnee, LeftAnkle),
        (RightKnee, RightAnkle),
        (LeftShoulder, LeftHip),
        (RightShoulder, RightHip),
        (LeftShoulder, RightShoulder),
        (LeftHip, RightHip),
    ]
};

/// Per segment: how long BlazePose's (`full`) landmarks make it relative to the same segment
/// between the template's landmark anchors (their points differ: BlazePose's hip is not the
/// femoral head), and the spread of that ratio; `None` for the segments too noisy to use
/// (forearms, shoulder and hip widths: spreads of 9–13 %). Measured on 30 training people
/// (seeds 1,000,000..=1,000,029, never evaluated on; random poses, 8 views on a ring at
/// 256 px): `lhmpp eval-perception --shape-segments` on `lhmpp synth --seed S --views 8
/// --heldout 1 --pose random --publish-shape` bags of those seeds.
const SEGMENT_BIAS: [Option<(f32, f32)>; 12] = [
    Some((1.0669, 0.0877)),
    Some((1.0445, 0.0643)),
    None,
    None,
    Some((0.9134, 0.0377)),
    Some((0.8966, 0.0323)),
    Some((0.9475, 0.0356)),
    Some((0.9724, 0.0396)),
    Some((1.0542, 0.0174)),
    Some((1.0558, 0.0235)),
    None,
    None,
];

/// The measured length of each of the 12 [`SEGMENTS`] (`None` where an end was not
/// triangulated).
pub fn segment_lengths(views: &[CalibratedView], min_visibility: f32) -> [Option<f32>; 12] {
    let points: Vec<Option<Vec3>> = (0..BODY_LANDMARKS)
        .map(|k| triangulate(views, k, min_visibility))
        .collect();
    SEGMENTS.map(|(a, b)| Some(points[a.index()]?.distance(points[b.index()]?)))
}

/// The 12 [`SEGMENTS`]' lengths between a template's landmark anchors (e.g. its rest pose,
/// [`LandmarkRig::rest`]).
pub fn template_segment_lengths(landmarks: &[Vec3; BODY_LANDMARKS]) -> [f32; 12] {
    SEGMENTS.map(|(a, b)| landmarks[a.index()].distance(landmarks[b.index()]))
}

/// A shape read from the views.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShapeEstimate {
    /// The MakeHuman height and girth scales.
    pub shape: MakeHumanShape,
    /// Segments used (at most 8).
    pub segments: usize,
    /// Weighted root-mean-square relative spread of the segments' height ratios.
    pub misfit: f32,
}

/// Estimates whose segments disagree more than this ([`ShapeEstimate::misfit`], relative)
/// are not one person's: two cameras that see two different people under one id triangulate
/// phantom points, and their segments then scale inconsistently (on crowd scenes such
/// estimates ran from 1.0 to 7.5 times the template's height; agreeing ones stayed within
/// 0.9–1.2 and below this misfit).
pub const MAX_MISFIT: f32 = 0.15;

/// Height scales a person can have (MakeHuman template: 1.34–2.09 m).
pub const PLAUSIBLE_HEIGHT: std::ops::RangeInclusive<f32> = 0.8..=1.25;

impl ShapeEstimate {
    /// Whether the estimate reads as one plausible person: segments that agree
    /// ([`MAX_MISFIT`]) and a height in [`PLAUSIBLE_HEIGHT`].
    pub fn agrees(&self) -> bool {
        self.misfit <= MAX_MISFIT && PLAUSIBLE_HEIGHT.contains(&self.shape.height_scale)
    }
}

/// The point nearest (least squares) to the rays of the views where landmark `k` is at least
/// `min_visibility` visible, weighted by visibility; `None` with fewer than two such views or
/// nearly parallel rays.
pub fn triangulate(views: &[CalibratedView], k: usize, min_visibility: f32) -> Option<Vec3> {
    let mut a = Mat3::ZERO;
    let mut b = Vec3::ZERO;
    let mut used = 0;
    for v in views {
        let l = v.landmarks[k];
        if l.visibility < min_visibility || !l.position.is_finite() {
            continue;
        }
        let (origin, dir) = v.ray(l.position.truncate());
        let w = l.visibility;
        // (I − d dᵀ): the distance of p from the ray is |(I − d dᵀ)(p − o)|.
        let m = Mat3::IDENTITY - Mat3::from_cols(dir * dir.x, dir * dir.y, dir * dir.z);
        a += m * w;
        b += m * origin * w;
        used += 1;
    }
    if used < 2 || a.determinant().abs() < 1e-6 {
        return None;
    }
    let p = a.inverse() * b;
    p.is_finite().then_some(p)
}

/// Reads body shapes for one template: its segment lengths in the rest pose, computed once.
#[derive(Debug, Clone)]
pub struct ShapeReader {
    rest: [f32; 12],
}

impl ShapeReader {
    /// A reader for `template` (the unshaped template the shape scales).
    pub fn new(template: &BodyTemplate) -> Result<Self, PoseSolveError> {
        Ok(Self {
            rest: template_segment_lengths(&LandmarkRig::new(template)?.rest()),
        })
    }

    /// The height scale that makes the template's segments as long as the triangulated ones
    /// (each measured length corrected by its [`SEGMENT_BIAS`], the ratios averaged with
    /// weights 1/spread²), or `None` when fewer than three usable segments were measured.
    /// The girth scale stays 1: widths between landmarks spread too much (13 %) to read it,
    /// and it matters little (`lhmpp eval --shape`: height alone recovers nearly all of the
    /// true shape's PSNR).
    pub fn estimate(&self, views: &[CalibratedView], min_visibility: f32) -> Option<ShapeEstimate> {
        let measured = segment_lengths(views, min_visibility);
        let ratios: Vec<(f32, f32)> = (0..SEGMENTS.len())
            .filter_map(|i| {
                let (bias, spread) = SEGMENT_BIAS[i]?;
                let length = measured[i]?;
                Some((length / bias / self.rest[i], 1.0 / (spread * spread)))
            })
            .collect();
        if ratios.len() < 3 {
            return None;
        }
        let total: f32 = ratios.iter().map(|r| r.1).sum();
        let h = ratios.iter().map(|(r, w)| r * w).sum::<f32>() / total;
        let misfit = (ratios
            .iter()
            .map(|(r, w)| w * (r / h - 1.0).powi(2))
            .sum::<f32>()
            / total)
            .sqrt();
        Some(ShapeEstimate {
            shape: MakeHumanShape {
                height_scale: h,
                girth_scale: 1.0,
            },
            segments: ratios.len(),
            misfit,
        })
    }
}

/// [`ShapeReader::estimate`] for `template`.
pub fn estimate_shape(
    template: &BodyTemplate,
    views: &[CalibratedView],
    min_visibility: f32,
) -> Result<Option<ShapeEstimate>, PoseSolveError> {
    Ok(ShapeReader::new(template)?.estimate(views, min_visibility))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::Pose;
    use crate::perception::pose::template_landmarks;

    /// A ring of calibrated cameras looking at the middle of a body of height ~1.7 m.
    fn cameras(n: usize) -> Vec<(Affine3A, (f32, f32, f32, f32))> {
        (0..n)
            .map(|i| {
                let a = std::f32::consts::TAU * i as f32 / n as f32 + 0.3;
                let eye = Vec3::new(3.0 * a.sin(), 1.2, 3.0 * a.cos());
                let target = Vec3::new(0.0, 0.9, 0.0);
                let z = (target - eye).normalize();
                let y = (-Vec3::Y).reject_from_normalized(z).normalize();
                let x = y.cross(z);
                (
                    Affine3A::from_mat3_translation(Mat3::from_cols(x, y, z), eye),
                    (400.0, 400.0, 320.0, 240.0),
                )
            })
            .collect()
    }

    /// The views of the posed, shaped template's landmarks, all visible.
    fn views_of(template: &BodyTemplate, pose: &Pose, n: usize) -> Vec<CalibratedView> {
        let world = template_landmarks(template, pose).unwrap();
        cameras(n)
            .into_iter()
            .map(|(pose, (fx, fy, cx, cy))| {
                let from_world = pose.inverse();
                let landmarks = world.map(|p| {
                    let c = from_world.transform_point3(p);
                    Landmark {
                        position: Vec3::new(fx * c.x / c.z + cx, fy * c.y / c.z + cy, 0.0),
                        visibility: 1.0,
                        presence: 1.0,
                    }
                });
                CalibratedView {
                    fx,
                    fy,
                    cx,
                    cy,
                    world_from_camera: pose,
                    landmarks,
                }
            })
            .collect()
    }

    #[test]
    fn segment_lengths_come_back_from_exact_landmarks() {
        let base = BodyTemplate::load_default().unwrap();
        let shaped = MakeHumanShape {
            height_scale: 1.07,
            girth_scale: 1.0,
        }
        .shaped(&base);
        let pose = crate::body::motion::walk_pose(10.0);
        let views = views_of(&shaped, &pose, 4);
        let measured = segment_lengths(&views, 0.5);
        let posed = template_segment_lengths(&template_landmarks(&shaped, &pose).unwrap());
        for (m, r) in measured.iter().zip(posed) {
            assert!((m.unwrap() - r).abs() < 2e-3, "{m:?} vs {r}");
        }
    }

    #[test]
    fn a_taller_person_reads_taller_by_the_same_factor() {
        // Exact landmarks carry none of BlazePose's biases, so the estimate is off by their
        // mean; the ratio between two people is not.
        let base = BodyTemplate::load_default().unwrap();
        let pose = crate::body::motion::walk_pose(10.0);
        let estimate = |h: f32| {
            let shaped = MakeHumanShape {
                height_scale: h,
                girth_scale: 1.0,
            }
            .shaped(&base);
            let views = views_of(&shaped, &pose, 4);
            estimate_shape(&base, &views, 0.5).unwrap().unwrap()
        };
        let (short, tall) = (estimate(0.94), estimate(1.06));
        assert_eq!(tall.segments, 8);
        let ratio = tall.shape.height_scale / short.shape.height_scale;
        assert!((ratio - 1.06 / 0.94).abs() < 0.005, "{ratio}");
        assert_eq!(tall.shape.girth_scale, 1.0);
    }

    /// Two cameras that see two different people under one id give an estimate that does
    /// not read as one person; the same person's views do.
    #[test]
    fn views_of_two_people_do_not_agree() {
        let base = BodyTemplate::load_default().unwrap();
        let pose = crate::body::motion::walk_pose(10.0);
        let mut views = views_of(&base, &pose, 2);
        assert!(estimate_shape(&base, &views, 0.5)
            .unwrap()
            .unwrap()
            .agrees());
        // The second camera sees someone else, 0.6 m to the side of the first person.
        let other = views_of(&base, &pose, 2)[1];
        views[1].world_from_camera =
            Affine3A::from_translation(Vec3::new(0.6, 0.0, 0.0)) * other.world_from_camera;
        let phantom = estimate_shape(&base, &views, 0.5).unwrap();
        assert!(phantom.is_none_or(|e| !e.agrees()), "{phantom:?}");
    }

    #[test]
    fn one_view_is_not_enough() {
        let base = BodyTemplate::load_default().unwrap();
        let views = views_of(&base, &Pose::identity(), 1);
        assert_eq!(estimate_shape(&base, &views, 0.5).unwrap(), None);
    }

    #[test]
    fn triangulation_finds_the_point_the_rays_meet_at() {
        let base = BodyTemplate::load_default().unwrap();
        let views = views_of(&base, &Pose::identity(), 3);
        let want = template_landmarks(&base, &Pose::identity()).unwrap();
        let nose = triangulate(&views, 0, 0.5).unwrap();
        assert!(nose.distance(want[0]) < 1e-3, "{nose} vs {}", want[0]);
    }
}
