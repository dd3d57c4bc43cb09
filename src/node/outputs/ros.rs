//! The ROS 2 output: [`RosPublisher`] hands avatars (GaussianAvatar and its compact form,
//! CompactAvatar), statuses
//! (ReconstructionStatus), rendered frames (sensor_msgs/Image rgb8) and the preview to the
//! node's ROS 2 endpoint, with the message builders it uses.

use super::{AvatarUpdate, OutputError, Publisher};
use crate::msgs::{
    BodyPose, CompactAvatar, GaussianAvatar, GaussianCloud, GaussianColors, Header, Image, Point,
    ReconstructionStatus, Time,
};
use crate::node::pipeline::RenderedFrame;
use crate::node::ros::RosNode;
use crate::splat::{sh_dc_to_rgb, Gaussians};
use image::{GrayImage, RgbImage};
use std::sync::Arc;

/// Publishes on the ROS 2 endpoint.
pub struct RosPublisher(pub Arc<RosNode>);

impl Publisher for RosPublisher {
    fn avatar(&self, u: &AvatarUpdate<'_>) {
        match avatar_message(u) {
            Ok(msg) => {
                if let Err(e) = self.0.publish_avatar(msg) {
                    tracing::warn!("{e}");
                }
            }
            Err(e) => tracing::error!("avatar message: {e}"),
        }
        match compact_message(u) {
            Ok(msg) => {
                if let Err(e) = self.0.publish_compact_avatar(msg) {
                    tracing::warn!("{e}");
                }
            }
            Err(e) => tracing::error!("compact avatar message: {e}"),
        }
    }
    fn status(&self, msg: ReconstructionStatus) {
        if let Err(e) = self.0.publish_status(msg) {
            tracing::warn!("{e}");
        }
    }
    fn frame(&self, person: &str, camera: usize, frame: &RenderedFrame, stamp_ns: i64) {
        let msg = frame_message(
            frame.rgb8(),
            stamp_ns,
            &format!("lhmpp_virtual_cam{camera}"),
        );
        if let Err(e) = self.0.publish_person_frame(person, camera, msg) {
            tracing::warn!("{e}");
        }
    }
    fn preview(&self, posed: &Gaussians, stamp_ns: i64) {
        if let Err(e) = self.0.publish_preview(posed, stamp_ns) {
            tracing::warn!("{e}");
        }
    }
    fn mask(&self, camera: &str, mask: &GrayImage, stamp_ns: i64, frame_id: &str) {
        if let Err(e) = self
            .0
            .publish_mask(camera, mono8_image(mask, stamp_ns, frame_id))
        {
            tracing::warn!("{e}");
        }
    }
    fn pose(&self, pose: &BodyPose) {
        if let Err(e) = self.0.publish_pose(pose.clone()) {
            tracing::warn!("{e}");
        }
    }
}

/// A mono8 Image message of a mask.
pub fn mono8_image(mask: &GrayImage, stamp_ns: i64, frame_id: &str) -> Image {
    Image {
        header: Header::new(Time::from_nanos(stamp_ns), frame_id),
        height: mask.height(),
        width: mask.width(),
        encoding: "mono8".into(),
        is_bigendian: 0,
        step: mask.width(),
        data: mask.as_raw().clone(),
    }
}

/// The GaussianAvatar message of an avatar revision (canonical Gaussians, skinning,
/// skeleton, and whether its RGB is display-ready).
pub fn avatar_message(update: &AvatarUpdate<'_>) -> Result<GaussianAvatar, OutputError> {
    let AvatarUpdate {
        person,
        revision,
        views_used,
        stamp_ns,
        avatar,
        template,
        shape_params,
        rgb_display_ready,
        neural_renderer,
        compact: _,
    } = *update;
    let g = &avatar.canonical;
    let colors = (0..g.len())
        .map(|i| sh_dc_to_rgb(g.sh_of(i)[0]).to_array())
        .collect();
    let cloud = GaussianCloud {
        positions: g.positions.iter().map(|p| p.to_array()).collect(),
        scales: g.scales.iter().map(|s| s.to_array()).collect(),
        rotations: g.rotations.iter().map(|q| [q.w, q.x, q.y, q.z]).collect(),
        opacities: g.opacities.clone(),
        colors: GaussianColors::Rgb(colors),
        skin: avatar.skin.clone(),
    };
    let header = Header::new(Time::from_nanos(stamp_ns), "lhmpp_canonical");
    let skeleton = &template.skeleton;
    Ok(GaussianAvatar {
        gaussians: cloud.to_point_cloud(header.clone())?,
        header,
        person_id: person.to_owned(),
        revision: revision as u32,
        views_used: views_used as u32,
        body_model: avatar.body_model.clone(),
        shape_params: shape_params.to_vec(),
        sh_degree: 0,
        rgb_display_ready,
        neural_renderer: neural_renderer.to_owned(),
        bone_names: skeleton.bone_names.clone(),
        bone_parents: bone_parents(skeleton),
        bone_rest_positions: skeleton.joints.iter().map(|j| Point::from(*j)).collect(),
    })
}

/// The CompactAvatar message of an avatar revision: the same header, person, revision and
/// skeleton as [`avatar_message`], the Gaussians and the skin as compact blobs.
pub fn compact_message(update: &AvatarUpdate<'_>) -> Result<CompactAvatar, OutputError> {
    let blobs = update
        .compact()
        .map_err(|e| OutputError::Compact(e.to_owned()))?;
    let skeleton = &update.template.skeleton;
    Ok(CompactAvatar {
        header: Header::new(Time::from_nanos(update.stamp_ns), "lhmpp_canonical"),
        person_id: update.person.to_owned(),
        revision: update.revision as u32,
        views_used: update.views_used as u32,
        body_model: update.avatar.body_model.clone(),
        shape_params: update.shape_params.to_vec(),
        rgb_display_ready: update.rgb_display_ready,
        neural_renderer: update.neural_renderer.to_owned(),
        bone_names: skeleton.bone_names.clone(),
        bone_parents: bone_parents(skeleton),
        bone_rest_positions: skeleton.joints.iter().flat_map(|j| j.to_array()).collect(),
        gaussians: blobs.gaussians.clone(),
        skin: blobs.skin.clone(),
    })
}

/// Parent index of each bone, -1 for a root.
fn bone_parents(skeleton: &crate::body::Skeleton) -> Vec<i32> {
    skeleton
        .parents
        .iter()
        .map(|p| p.map_or(-1, |i| i as i32))
        .collect()
}

/// A ReconstructionStatus message; `render_ms` is the per-frame render time of the last
/// rendered batch (0 before the first).
#[allow(clippy::too_many_arguments)]
pub fn status_message(
    person: &str,
    views_held: usize,
    revision: u64,
    latency_ms: f64,
    render_ms: f64,
    state: u8,
    message: impl Into<String>,
    stamp_ns: i64,
) -> ReconstructionStatus {
    ReconstructionStatus {
        header: Header::new(Time::from_nanos(stamp_ns), "lhmpp_canonical"),
        person_id: person.to_owned(),
        views_held: views_held as u32,
        revision: revision as u32,
        last_latency_ms: latency_ms,
        last_render_ms: render_ms,
        state,
        message: message.into(),
        ..Default::default()
    }
}

/// An rgb8 Image message of a rendered frame.
pub fn frame_message(image: &RgbImage, stamp_ns: i64, frame_id: &str) -> Image {
    crate::node::ros::rgb8_image(image, stamp_ns, frame_id)
}
