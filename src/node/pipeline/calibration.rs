//! The cameras' calibration as the node hears it (CameraInfo per camera, the TF tree), and the
//! body height read from the perceived landmarks of calibrated views
//! ([`crate::perception::shape`]): the newest view of each camera, those within half a second
//! of the newest one triangulated together, the estimates averaged over time.

use crate::msgs::{CameraInfo, TransformStamped};
use crate::node::inputs::CameraFrame;
use crate::node::tf_buffer::TfBuffer;
use crate::perception::shape::{CalibratedView, ShapeReader};
use crate::perception::{Landmark, BODY_LANDMARKS};
use crate::tracking::FloorCamera;
use std::collections::{BTreeMap, HashMap};

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
    /// non-positive or non-finite focal length is ignored).
    pub fn camera_info(&mut self, index: usize, info: &CameraInfo) {
        let Some(camera) = self.cameras.get(index) else {
            return;
        };
        let k = info.k;
        let (fx, fy, cx, cy) = (k[0] as f32, k[4] as f32, k[2] as f32, k[5] as f32);
        if [fx, fy, cx, cy].iter().all(|v| v.is_finite()) && fx > 0.0 && fy > 0.0 {
            self.intrinsics.insert(camera.clone(), [fx, fy, cx, cy]);
        }
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
        let [fx, fy, cx, cy] = *self.intrinsics.get(&frame.topic)?;
        let world_from_camera = self.tf.lookup(&self.world_frame, &frame.frame_id)?;
        let view = CalibratedView {
            fx,
            fy,
            cx,
            cy,
            world_from_camera,
            landmarks: *landmarks,
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
