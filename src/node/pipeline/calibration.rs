//! The cameras' calibration as the node hears it (CameraInfo per camera, the TF tree), and the
//! body height read from the perceived landmarks of calibrated views
//! ([`crate::perception::shape`]): the newest view of each camera, those within half a second
//! of the newest one triangulated together, the estimates averaged over time.

use crate::msgs::{CameraInfo, TransformStamped};
use crate::node::inputs::CameraFrame;
use crate::node::tf_buffer::TfBuffer;
use crate::perception::shape::{CalibratedView, ShapeReader};
use crate::perception::{Landmark, BODY_LANDMARKS};
use crate::tracking::{FloorCamera, LensDistortion};
use std::collections::{BTreeMap, HashMap, HashSet};

/// Views whose stamps are this close to the newest one are triangulated together.
const SYNC_WINDOW_NS: i64 = 500_000_000;
/// The applied height changes only when the averaged estimate moves this much (relative).
const REAPPLY: f32 = 0.01;
/// Weight of a new estimate in the running average, once there have been this many.
const AVERAGE_OVER: f32 = 10.0;

/// Camera calibration and the body height read from calibrated views.
pub struct Calibration {
    /// Camera topics in configuration order: images, then compressed images (CameraInfo
    /// topics pair with them by position).
    cameras: Vec<String>,
    intrinsics: HashMap<String, [f32; 4]>,
    /// Each camera's lens distortion (`None`: a pinhole, or rectified images).
    lenses: HashMap<String, Option<LensDistortion>>,
    /// Cameras whose distortion model was logged as not supported (logged once each).
    unsupported_lens: HashSet<String>,
    tf: TfBuffer,
    world_frame: String,
    reader: Option<ShapeReader>,
    min_visibility: f32,
}

/// One person's body height as read from calibrated views.
#[derive(Debug, Clone, Default)]
pub struct HeightReading {
    /// Newest calibrated view of each camera, with its stamp.
    views: BTreeMap<String, (i64, CalibratedView)>,
    /// Running average of the height estimates, and how many went in.
    average: Option<(f32, f32)>,
    /// The height last handed out for applying.
    applied: Option<f32>,
}

impl Calibration {
    /// Calibration for cameras in `world_frame`; `reader` reads the shape (`None`: no shape
    /// is read, only calibration is kept).
    pub fn new(world_frame: &str, reader: Option<ShapeReader>, min_visibility: f32) -> Self {
        Self {
            cameras: Vec::new(),
            intrinsics: HashMap::new(),
            lenses: HashMap::new(),
            unsupported_lens: HashSet::new(),
            tf: TfBuffer::default(),
            world_frame: world_frame.to_owned(),
            reader,
            min_visibility,
        }
    }

    /// Sets the camera topics (resolved; images then compressed images).
    pub fn set_cameras(&mut self, cameras: Vec<String>) {
        self.cameras = cameras;
    }

    /// A CameraInfo for camera `index`: keeps its pinhole intrinsics (a matrix with a
    /// non-positive or non-finite focal length is ignored) and its lens distortion
    /// (`plumb_bob`, `rational_polynomial`; another model is logged once and its points are
    /// used as they are).
    pub fn camera_info(&mut self, index: usize, info: &CameraInfo) {
        let Some(camera) = self.cameras.get(index) else {
            return;
        };
        let k = info.k;
        let (fx, fy, cx, cy) = (k[0] as f32, k[4] as f32, k[2] as f32, k[5] as f32);
        if [fx, fy, cx, cy].iter().all(|v| v.is_finite()) && fx > 0.0 && fy > 0.0 {
            self.intrinsics.insert(camera.clone(), [fx, fy, cx, cy]);
        }
        let lens = match LensDistortion::from_camera_info(&info.distortion_model, &info.d) {
            Ok(lens) => lens,
            Err(e) => {
                if self.unsupported_lens.insert(camera.clone()) {
                    tracing::warn!(camera = %camera, "camera_info: {e}");
                }
                None
            }
        };
        self.lenses.insert(camera.clone(), lens);
    }

    /// Camera `topic`'s lens distortion, if it has one.
    fn lens(&self, topic: &str) -> Option<LensDistortion> {
        self.lenses.get(topic).copied().flatten()
    }

    /// Transforms from `/tf` or `/tf_static`.
    pub fn transforms(&mut self, transforms: &[TransformStamped]) {
        self.tf.insert(transforms);
    }

    /// The world frame cameras are placed in.
    pub fn world_frame(&self) -> &str {
        &self.world_frame
    }

    /// Whether the body shape is read here.
    pub fn reads_shape(&self) -> bool {
        self.reader.is_some()
    }

    /// `frame`'s camera as the person tracker needs it, when it is calibrated (CameraInfo and
    /// its optical frame in the world frame).
    pub fn floor_camera(&self, frame: &CameraFrame) -> Option<FloorCamera> {
        let intrinsics = *self.intrinsics.get(&frame.topic)?;
        let world_from_camera = self.tf.lookup(&self.world_frame, &frame.frame_id)?;
        Some(FloorCamera {
            intrinsics,
            distortion: self.lens(&frame.topic),
            world_from_camera,
        })
    }

    /// A person's image landmarks in `frame`: kept in `reading` as that camera's newest view
    /// when the camera is calibrated; returns a new height when the person's averaged estimate
    /// moved by more than 1 % from the one last returned.
    pub fn landmarks(
        &self,
        reading: &mut HeightReading,
        frame: &CameraFrame,
        landmarks: &[Landmark; BODY_LANDMARKS],
    ) -> Option<f32> {
        let reader = self.reader.as_ref()?;
        let intrinsics = *self.intrinsics.get(&frame.topic)?;
        let [fx, fy, cx, cy] = intrinsics;
        let world_from_camera = self.tf.lookup(&self.world_frame, &frame.frame_id)?;
        let mut landmarks = *landmarks;
        if let Some(lens) = self.lens(&frame.topic) {
            for l in &mut landmarks {
                let [x, y] = lens.undistort_pixel([l.position.x, l.position.y], intrinsics);
                (l.position.x, l.position.y) = (x, y);
            }
        }
        let view = CalibratedView {
            fx,
            fy,
            cx,
            cy,
            world_from_camera,
            landmarks,
        };
        reading
            .views
            .insert(frame.topic.clone(), (frame.stamp_ns, view));
        let newest = reading.views.values().map(|(t, _)| *t).max()?;
        let synced: Vec<CalibratedView> = reading
            .views
            .values()
            .filter(|(t, _)| newest - *t <= SYNC_WINDOW_NS)
            .map(|(_, v)| *v)
            .collect();
        let estimate = reader.estimate(&synced, self.min_visibility)?;
        let h = estimate.shape.height_scale;
        tracing::debug!(
            camera = %frame.topic,
            views = synced.len(),
            height_scale = format!("{h:.3}"),
            misfit = format!("{:.3}", estimate.misfit),
            segments = estimate.segments,
            "height estimate"
        );
        if !estimate.agrees() {
            return None;
        }
        let (mean, n) = reading.average.unwrap_or((h, 0.0));
        let n = n + 1.0;
        let mean = mean + (h - mean) / n.min(AVERAGE_OVER);
        reading.average = Some((mean, n));
        let moved = reading
            .applied
            .is_none_or(|applied| (mean / applied - 1.0).abs() > REAPPLY);
        if moved {
            reading.applied = Some(mean);
            Some(mean)
        } else {
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::{Header, Transform};
    use glam::{Quat, Vec3};
    use image::RgbImage;
    use std::sync::Arc;
    use std::time::Duration;

    fn info(model: &str, d: Vec<f64>) -> CameraInfo {
        CameraInfo {
            header: Header {
                frame_id: "cam0_optical".into(),
                ..Header::default()
            },
            height: 480,
            width: 640,
            distortion_model: model.into(),
            d,
            k: [500.0, 0.0, 320.0, 0.0, 500.0, 240.0, 0.0, 0.0, 1.0],
            ..CameraInfo::default()
        }
    }

    /// The floor camera a frame gets carries its camera's lens from CameraInfo; a model the
    /// node cannot undo leaves the points as they are, and so does a rectified camera.
    #[test]
    fn a_frames_floor_camera_carries_the_lens_its_camera_info_gives() {
        let mut calibration = Calibration::new("world", None, 0.5);
        calibration.set_cameras(vec!["/cam0/image_raw".into()]);
        calibration.transforms(&[TransformStamped {
            header: Header {
                frame_id: "world".into(),
                ..Header::default()
            },
            child_frame_id: "cam0_optical".into(),
            transform: Transform {
                translation: Vec3::new(0.0, 2.0, 3.0).into(),
                rotation: Quat::from_rotation_x(std::f32::consts::PI).into(),
            },
        }]);
        let frame = CameraFrame {
            topic: "/cam0/image_raw".into(),
            frame_id: "cam0_optical".into(),
            stamp_ns: 0,
            arrival: Duration::ZERO,
            image: Arc::new(RgbImage::new(640, 480)),
        };
        assert_eq!(calibration.floor_camera(&frame), None, "no CameraInfo yet");
        let wide = vec![-0.3, 0.08, 0.001, 0.0, 0.0];
        calibration.camera_info(0, &info("plumb_bob", wide.clone()));
        let floor = calibration.floor_camera(&frame).expect("calibrated");
        assert_eq!(floor.intrinsics, [500.0, 500.0, 320.0, 240.0]);
        assert_eq!(
            floor.distortion,
            LensDistortion::from_camera_info("plumb_bob", &wide).unwrap()
        );
        assert!(floor.distortion.is_some());
        calibration.camera_info(0, &info("equidistant", vec![0.1, 0.0, 0.0, 0.0]));
        assert_eq!(calibration.floor_camera(&frame).unwrap().distortion, None);
        calibration.camera_info(0, &info("plumb_bob", vec![0.0; 5]));
        assert_eq!(calibration.floor_camera(&frame).unwrap().distortion, None);
    }
}
