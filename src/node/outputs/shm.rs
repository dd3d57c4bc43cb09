//! The shared-memory output: [`ShmOutputs`] publishes avatars and rendered frames as iceoryx2
//! services. Failures are logged; they never stop the pipeline.

use super::{AvatarUpdate, Publisher};
use crate::msgs::ReconstructionStatus;
use crate::node::pipeline::RenderedFrame;
use crate::splat::sh_dc_to_rgb;
use crate::transport::{
    AvatarView, FrameShape, PayloadBody, ShmError, ShmNode, ShmOptions, ShmPublisher, Stamp,
};

/// Publishes avatars and rendered frames over iceoryx2 (layout: `docs/shm-layout.md`).
pub struct ShmOutputs {
    _node: ShmNode,
    avatar: ShmPublisher,
    frames: Vec<ShmPublisher>,
}

impl ShmOutputs {
    /// Services `lhmpp/<person>/avatar` and `lhmpp/<person>/frame/cam<i>` for each virtual
    /// camera.
    pub fn new(person: &str, virtual_cameras: u32) -> Result<Self, ShmError> {
        let node = ShmNode::new(&format!("lhmpp_{person}"), ShmOptions::default())?;
        let avatar = node.avatar_publisher(person)?;
        let frames = (0..virtual_cameras)
            .map(|i| node.frame_publisher(person, &format!("cam{i}")))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Self {
            _node: node,
            avatar,
            frames,
        })
    }

    /// Names of the services published on.
    pub fn services(&self) -> Vec<String> {
        std::iter::once(&self.avatar)
            .chain(&self.frames)
            .map(|p| p.service().to_owned())
            .collect()
    }
}

impl Publisher for ShmOutputs {
    fn avatar(&self, u: &AvatarUpdate<'_>) {
        let g = &u.avatar.canonical;
        let positions: Vec<[f32; 3]> = g.positions.iter().map(|p| p.to_array()).collect();
        let scales: Vec<[f32; 3]> = g.scales.iter().map(|s| s.to_array()).collect();
        let rotations: Vec<[f32; 4]> = g.rotations.iter().map(|q| [q.w, q.x, q.y, q.z]).collect();
        let colours: Vec<f32> = (0..g.len())
            .flat_map(|i| sh_dc_to_rgb(g.sh_of(i)[0]).to_array())
            .collect();
        let view = AvatarView {
            positions: &positions,
            scales: &scales,
            rotations: &rotations,
            opacities: &g.opacities,
            sh_coeffs: 1,
            colours: &colours,
            bones: &u.avatar.skin.bones,
            weights: &u.avatar.skin.weights,
            rgb_latent: !u.rgb_display_ready,
        };
        if let Err(e) = self
            .avatar
            .publish(Stamp::now(u.revision), &PayloadBody::Avatar(view))
        {
            tracing::warn!("{e}");
        }
    }
    fn status(&self, _msg: ReconstructionStatus) {}
    /// Converts the render straight into a loaned shared-memory sample (no intermediate
    /// image) and sends it; the frame sequence number is the render stamp.
    fn frame(&self, camera: usize, frame: &RenderedFrame, stamp_ns: i64) {
        let Some(publisher) = self.frames.get(camera) else {
            return;
        };
        let stamp = Stamp {
            revision: stamp_ns as u64,
            timestamp_ns: crate::transport::layout::unix_time_ns(),
        };
        let sent = publisher
            .loan_frame(stamp, FrameShape::rgb8(frame.width(), frame.height()))
            .and_then(|mut loan| {
                frame.write_rgb8(loan.pixels_mut());
                loan.set_timestamp_ns(crate::transport::layout::unix_time_ns());
                loan.send()
            });
        if let Err(e) = sent {
            tracing::warn!("{e}");
        }
    }
}
