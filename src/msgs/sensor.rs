//! `sensor_msgs`: images (raw and compressed), camera calibration and point clouds.

use super::message::ros_message;
use super::Header;
use serde::{Deserialize, Serialize};

/// `sensor_msgs/msg/Image`: an uncompressed image, `step * height` bytes of pixels.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Image {
    /// Acquisition time and camera optical frame.
    pub header: Header,
    /// Number of rows.
    pub height: u32,
    /// Number of columns.
    pub width: u32,
    /// Pixel encoding, e.g. `rgb8`, `bgr8`, `mono8`.
    pub encoding: String,
    /// 1 when multi-byte pixel values are big endian.
    pub is_bigendian: u8,
    /// Row length in bytes.
    pub step: u32,
    /// Pixel bytes, row major.
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
}
ros_message!(
    Image,
    "sensor_msgs",
    "Image",
    include_str!("defs/sensor_msgs/Image.msg")
);

/// `sensor_msgs/msg/CompressedImage`: a JPEG or PNG image.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct CompressedImage {
    /// Acquisition time and camera optical frame.
    pub header: Header,
    /// Compression format, e.g. `jpeg` or `png`.
    pub format: String,
    /// Compressed bytes.
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
}
ros_message!(
    CompressedImage,
    "sensor_msgs",
    "CompressedImage",
    include_str!("defs/sensor_msgs/CompressedImage.msg")
);

/// `sensor_msgs/msg/RegionOfInterest`: a sub-window of an image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct RegionOfInterest {
    /// Leftmost pixel.
    pub x_offset: u32,
    /// Topmost pixel.
    pub y_offset: u32,
    /// Height in pixels.
    pub height: u32,
    /// Width in pixels.
    pub width: u32,
    /// Whether a rectified ROI should be computed.
    pub do_rectify: bool,
}
ros_message!(
    RegionOfInterest,
    "sensor_msgs",
    "RegionOfInterest",
    include_str!("defs/sensor_msgs/RegionOfInterest.msg")
);

/// `sensor_msgs/msg/CameraInfo`: calibration of a camera (intrinsics K, distortion D,
/// rectification R, projection P), all matrices row major.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct CameraInfo {
    /// Acquisition time and camera optical frame.
    pub header: Header,
    /// Calibrated image height.
    pub height: u32,
    /// Calibrated image width.
    pub width: u32,
    /// Distortion model, e.g. `plumb_bob`.
    pub distortion_model: String,
    /// Distortion parameters.
    pub d: Vec<f64>,
    /// Intrinsic matrix, 3x3.
    pub k: [f64; 9],
    /// Rectification matrix, 3x3.
    pub r: [f64; 9],
    /// Projection matrix, 3x4.
    pub p: [f64; 12],
    /// Horizontal binning.
    pub binning_x: u32,
    /// Vertical binning.
    pub binning_y: u32,
    /// Region of interest.
    pub roi: RegionOfInterest,
}
ros_message!(
    CameraInfo,
    "sensor_msgs",
    "CameraInfo",
    include_str!("defs/sensor_msgs/CameraInfo.msg")
);

/// `sensor_msgs/msg/PointField`: name, byte offset and type of one point-cloud channel.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct PointField {
    /// Channel name, e.g. `x`.
    pub name: String,
    /// Byte offset within a point.
    pub offset: u32,
    /// One of the datatype constants ([`PointField::FLOAT32`], ...).
    pub datatype: u8,
    /// Number of elements.
    pub count: u32,
}
ros_message!(
    PointField,
    "sensor_msgs",
    "PointField",
    include_str!("defs/sensor_msgs/PointField.msg")
);

impl PointField {
    /// `int8` datatype.
    pub const INT8: u8 = 1;
    /// `uint8` datatype.
    pub const UINT8: u8 = 2;
    /// `int16` datatype.
    pub const INT16: u8 = 3;
    /// `uint16` datatype.
    pub const UINT16: u8 = 4;
    /// `int32` datatype.
    pub const INT32: u8 = 5;
    /// `uint32` datatype.
    pub const UINT32: u8 = 6;
    /// `float32` datatype.
    pub const FLOAT32: u8 = 7;
    /// `float64` datatype.
    pub const FLOAT64: u8 = 8;

    /// Size in bytes of one element of `datatype`, `None` for an unknown datatype.
    pub fn datatype_size(datatype: u8) -> Option<usize> {
        match datatype {
            Self::INT8 | Self::UINT8 => Some(1),
            Self::INT16 | Self::UINT16 => Some(2),
            Self::INT32 | Self::UINT32 | Self::FLOAT32 => Some(4),
            Self::FLOAT64 => Some(8),
            _ => None,
        }
    }
}

/// `sensor_msgs/msg/PointCloud2`: points as a binary blob laid out by `fields`.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct PointCloud2 {
    /// Time and frame of the points.
    pub header: Header,
    /// Rows (1 for an unordered cloud).
    pub height: u32,
    /// Points per row.
    pub width: u32,
    /// Channels of each point.
    pub fields: Vec<PointField>,
    /// True when the data is big endian.
    pub is_bigendian: bool,
    /// Bytes per point.
    pub point_step: u32,
    /// Bytes per row.
    pub row_step: u32,
    /// Point bytes, `row_step * height`.
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
    /// True when no point is invalid (NaN).
    pub is_dense: bool,
}
ros_message!(
    PointCloud2,
    "sensor_msgs",
    "PointCloud2",
    include_str!("defs/sensor_msgs/PointCloud2.msg")
);
