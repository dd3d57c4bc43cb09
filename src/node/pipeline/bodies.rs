//! What the pipeline learns of persons' bodies, to their [`Person`](super::person::Person): poses
//! (the pose topic, the cameras' landmarks) for their pose path, and body shapes (the shape
//! topic, the height read from calibrated views) for their reconstructions.

use super::Pipeline;
use crate::msgs::{BodyPose, BodyShape, Header, Time};
use crate::node::inputs::CameraFrame;
use crate::node::outputs::Publisher;
use crate::node::rejections::RejectReason;
use crate::perception::{Landmark, BODY_LANDMARKS};
use crate::reconstruct::shape::{self, AcceptedShape};
use std::time::Duration;

impl Pipeline {
    /// A pose from the pose topic for the person it names, checked against the skeleton.
    pub(super) fn on_topic_pose(&mut self, topic: &str, msg: &BodyPose, arrival: Duration) {
        let Some(person) = self.addressee(&msg.person_id) else {
            tracing::debug!(%topic, "body pose for person `{}` ignored (not followed here)", msg.person_id);
            return;
        };
        let checked = msg.to_pose().map_err(|e| e.to_string()).and_then(|p| {
            self.network
                .skeleton()
                .check_pose(&p)
                .map(|()| p)
                .map_err(|e| e.to_string())
        });
        match checked {
            Ok(p) => {
                self.outputs.topic_pose(&person, msg);
                self.person_mut(&person).pose.topic_pose(
                    p,
                    arrival,
                    msg.header.stamp.as_nanos(),
                    msg.header.frame_id.clone(),
                )
            }
            Err(e) => {
                self.stats.rejections.add(RejectReason::Pose);
                tracing::warn!(%topic, "body pose rejected: {e}");
            }
        }
    }

    /// `camera`'s world landmarks of `person` to their pose path; the pose it reads, when that
    /// camera drives their pose, is published.
    pub(super) fn on_camera_landmarks(
        &mut self,
        person: &str,
        frame: &CameraFrame,
        world: &[Landmark; BODY_LANDMARKS],
        now: Duration,
    ) {
        let Some(state) = self.persons.get_mut(person) else {
            return;
        };
        let t = if frame.stamp_ns > 0 {
            frame.stamp_ns as f64 * 1e-9
        } else {
            frame.arrival.as_secs_f64()
        };
        let Some(pose) = state
            .pose
            .camera_landmarks(&frame.topic, (t, frame.stamp_ns), world, now)
        else {
            return;
        };
        self.stats.camera_poses += 1;
        if let (Some(world_frame), true) = (&self.setup.publish_pose, self.outputs.live()) {
            let header = Header::new(Time::from_nanos(frame.stamp_ns), world_frame.as_str());
            self.outputs
                .pose(&BodyPose::from_pose(header, person.to_owned(), &pose));
            if let Some(age) = super::intake::live_age(frame.stamp_ns) {
                self.stats.pose_ages.record(age);
            }
        }
    }

    /// `person`'s image landmarks in a calibrated camera to their body height: a height read
    /// from their views is applied (girth 1) unless the shape topic has given their shape; a
    /// change reruns their reconstruction.
    pub(super) fn on_calibrated_landmarks(
        &mut self,
        person: &str,
        frame: &CameraFrame,
        image: &[Landmark; BODY_LANDMARKS],
        now: Duration,
    ) {
        let Some(state) = self.persons.get_mut(person) else {
            return;
        };
        let Some(height) = self
            .calibration
            .landmarks(&mut state.shape.heights, frame, image)
        else {
            return;
        };
        if state.shape.topic_gave_it() {
            return;
        }
        let shape = crate::body::MakeHumanShape {
            height_scale: height.clamp(0.5, 2.0),
            girth_scale: 1.0,
        };
        tracing::debug!(
            person,
            height_scale = format!("{height:.3}"),
            "body height read from the calibrated views"
        );
        self.apply_shape(person, AcceptedShape::MakeHuman(shape), frame.arrival, now);
    }

    /// A body shape from the shape topic for the person it names: checked against the
    /// network's body model, then used for that person's reconstructions (it wins over the
    /// height read from the views).
    pub(super) fn on_shape(
        &mut self,
        topic: &str,
        msg: &BodyShape,
        arrival: Duration,
        now: Duration,
    ) {
        let Some(person) = self.addressee(&msg.person_id) else {
            tracing::debug!(
                %topic,
                "body shape for person `{}` ignored (not followed here)",
                msg.person_id
            );
            return;
        };
        let accepted = match shape::check_shape(topic, msg, self.network.body_model()) {
            Ok(s) => s,
            Err(e) => {
                self.stats.shapes_rejected += 1;
                self.stats.rejections.add(RejectReason::Shape);
                tracing::warn!(%topic, "body shape rejected: {e}");
                return;
            }
        };
        // The person's next reconstruction applies it to the network (which serves every
        // person); a shape for the network's body model always fits it.
        self.person_mut(&person).shape.given_by_topic();
        self.apply_shape(&person, accepted, arrival, now);
        tracing::debug!(%topic, person, "body shape from the shape topic");
    }

    /// Uses `shape` for `person` from their next reconstruction on; a change reruns it.
    fn apply_shape(
        &mut self,
        person: &str,
        shape: AcceptedShape,
        arrival: Duration,
        now: Duration,
    ) {
        let state = self.person_mut(person);
        if !state.use_shape(shape, arrival, now) {
            return;
        }
        let params = state.shape.shape().map(AcceptedShape::params);
        self.stats.shapes_applied += 1;
        tracing::info!(person, shape_params = ?params, "body shape applied");
    }

    /// `frame`'s calibrated camera and `person`'s pose in the world frame at the frame's time,
    /// when both are known: the camera calibrated (CameraInfo, TF to `outputs.world_frame`)
    /// and a pose-topic pose given in the world frame near the frame's stamp.
    pub(super) fn calibrated_view(
        &self,
        person: &str,
        frame: &CameraFrame,
    ) -> Option<(crate::splat::Camera, crate::body::Pose)> {
        let pose = self
            .persons
            .get(person)?
            .pose
            .pose_at_view(frame.stamp_ns, self.calibration.world_frame())?;
        let floor = self.calibration.floor_camera(frame)?;
        let [fx, fy, cx, cy] = floor.intrinsics;
        let camera = crate::splat::Camera {
            intrinsics: crate::splat::Intrinsics {
                fx,
                fy,
                cx,
                cy,
                width: frame.image.width(),
                height: frame.image.height(),
            },
            world_from_camera: floor.world_from_camera,
        };
        Some((camera, pose.clone()))
    }
}
