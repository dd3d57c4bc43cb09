//! The avatar preview that ROS tools show as is: a top-level `sensor_msgs/PointCloud2` of the
//! posed Gaussian centres with x, y, z and a packed `rgb` float32 field (the layout RViz2's
//! RGB8 colour transformer and Foxglove read), and the `/tf` transform that places its frame
//! in the world frame.

use crate::msgs::{
    Header, PointCloud2, PointField, Quaternion, TFMessage, Time, Transform, TransformStamped,
    Vector3,
};
use crate::splat::{Gaussians, SH_C0};

/// Bytes per preview point: x, y, z, rgb (4 × float32).
pub const POINT_STEP: u32 = 16;

/// Packs an 8-bit colour as RViz2 and PCL do: the bytes of `0x00RRGGBB` (little endian) read
/// as a float32.
pub fn pack_rgb(r: u8, g: u8, b: u8) -> f32 {
    f32::from_bits(((r as u32) << 16) | ((g as u32) << 8) | b as u32)
}

/// Inverse of [`pack_rgb`].
pub fn unpack_rgb(packed: f32) -> [u8; 3] {
    let bits = packed.to_bits();
    [(bits >> 16) as u8, (bits >> 8) as u8, bits as u8]
}

/// The display colour of Gaussian `i` (degree-0 SH term, `0.5 + SH_C0 · dc`, clamped).
fn colour(g: &Gaussians, i: usize) -> [u8; 3] {
    let per = (g.sh_degree + 1) * (g.sh_degree + 1);
    let dc = g.sh.get(i * per).copied().unwrap_or([0.0; 3]);
    dc.map(|c| ((0.5 + SH_C0 * c).clamp(0.0, 1.0) * 255.0).round() as u8)
}

/// The preview cloud of posed Gaussians in `frame_id`.
pub fn preview_cloud(posed: &Gaussians, stamp_ns: i64, frame_id: &str) -> PointCloud2 {
    let field = |name: &str, offset: u32| PointField {
        name: name.into(),
        offset,
        datatype: PointField::FLOAT32,
        count: 1,
    };
    let mut data = Vec::with_capacity(posed.len() * POINT_STEP as usize);
    for (i, p) in posed.positions.iter().enumerate() {
        let [r, g, b] = colour(posed, i);
        for v in [p.x, p.y, p.z, pack_rgb(r, g, b)] {
            data.extend_from_slice(&v.to_le_bytes());
        }
    }
    let width = posed.len() as u32;
    PointCloud2 {
        header: Header::new(Time::from_nanos(stamp_ns), frame_id),
        height: 1,
        width,
        fields: vec![
            field("x", 0),
            field("y", 4),
            field("z", 8),
            field("rgb", 12),
        ],
        is_bigendian: false,
        point_step: POINT_STEP,
        row_step: POINT_STEP * width,
        is_dense: posed.positions.iter().all(|p| p.is_finite()),
        data,
    }
}

/// `/tf` message placing `child` at the origin of `world` (the preview's points are already
/// posed in the BodyPose's world coordinates).
pub fn preview_transform(stamp_ns: i64, world: &str, child: &str) -> TFMessage {
    TFMessage {
        transforms: vec![TransformStamped {
            header: Header::new(Time::from_nanos(stamp_ns), world),
            child_frame_id: child.into(),
            transform: Transform {
                translation: Vector3::default(),
                rotation: Quaternion::default(),
            },
        }],
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::splat::rgb_to_sh_dc;
    use glam::{Quat, Vec3};

    #[test]
    fn packed_rgb_is_the_bytes_of_0x00rrggbb() {
        assert_eq!(pack_rgb(0x12, 0x34, 0x56).to_bits(), 0x0012_3456);
        assert_eq!(unpack_rgb(pack_rgb(255, 0, 7)), [255, 0, 7]);
    }

    #[test]
    fn cloud_has_xyz_and_packed_rgb_of_each_gaussian() {
        let g = Gaussians {
            positions: vec![Vec3::new(1.0, 2.0, 3.0), Vec3::new(-1.0, 0.5, 0.0)],
            scales: vec![Vec3::splat(0.01); 2],
            rotations: vec![Quat::IDENTITY; 2],
            opacities: vec![1.0; 2],
            sh_degree: 0,
            sh: vec![
                rgb_to_sh_dc(Vec3::new(1.0, 0.0, 0.0)),
                rgb_to_sh_dc(Vec3::new(0.0, 0.5, 1.0)),
            ],
            feature_channels: 0,
            features: vec![],
        };
        let c = preview_cloud(&g, 5, "avatar");
        assert_eq!(
            (c.width, c.height, c.point_step, c.row_step),
            (2, 1, 16, 32)
        );
        let names: Vec<_> = c.fields.iter().map(|f| f.name.as_str()).collect();
        assert_eq!(names, ["x", "y", "z", "rgb"]);
        assert_eq!(c.data.len(), 32);
        let f = |i: usize| f32::from_le_bytes(c.data[i * 4..i * 4 + 4].try_into().unwrap());
        assert_eq!([f(0), f(1), f(2)], [1.0, 2.0, 3.0]);
        assert_eq!(unpack_rgb(f(3)), [255, 0, 0]);
        assert_eq!(unpack_rgb(f(7)), [0, 128, 255]);
        assert!(c.is_dense);
        assert_eq!(c.header.frame_id, "avatar");
        let tf = preview_transform(5, "world", "avatar");
        assert_eq!(tf.transforms[0].header.frame_id, "world");
        assert_eq!(tf.transforms[0].child_frame_id, "avatar");
        assert_eq!(tf.transforms[0].transform.rotation.w, 1.0);
    }
}
