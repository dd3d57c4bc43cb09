//! The closed sets of the node's string parameters, as enums whose serde names are the values
//! written in parameter files.

use serde::{Deserialize, Serialize};
use std::fmt;

/// A parameter value from a closed set of names.
pub trait Choice: Copy + 'static {
    /// Every value, in the order the docs list them.
    const ALL: &'static [Self];
    /// The value as written in a parameter file.
    fn as_str(self) -> &'static str;
}

/// Implements `Display` through [`Choice::as_str`].
macro_rules! display_choice {
    ($($t:ty),*) => {$(
        impl fmt::Display for $t {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str(self.as_str())
            }
        }
    )*};
}
display_choice!(
    ImageQos,
    Dtype,
    RenderDevice,
    Delight,
    RendererChoice,
    FrameQos,
    PersonMask,
    PoseSource,
    LandmarkModelChoice
);

/// `inputs.image_qos`: QoS of the image subscriptions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ImageQos {
    /// `sensor_data`: best effort, volatile, keep last 5 (as rclcpp's SensorDataQoS).
    #[default]
    SensorData,
    /// `reliable`: reliable, volatile, keep last 5.
    Reliable,
}

impl Choice for ImageQos {
    const ALL: &'static [Self] = &[Self::SensorData, Self::Reliable];
    fn as_str(self) -> &'static str {
        match self {
            Self::SensorData => "sensor_data",
            Self::Reliable => "reliable",
        }
    }
}

/// `model.dtype`: the network's compute dtype.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Dtype {
    /// 32-bit floats.
    #[default]
    F32,
    /// 16-bit floats.
    F16,
    /// bfloat16.
    Bf16,
}

impl Choice for Dtype {
    const ALL: &'static [Self] = &[Self::F32, Self::F16, Self::Bf16];
    fn as_str(self) -> &'static str {
        match self {
            Self::F32 => "f32",
            Self::F16 => "f16",
            Self::Bf16 => "bf16",
        }
    }
}

impl Dtype {
    /// The candle dtype.
    pub fn candle(self) -> candle_core::DType {
        match self {
            Self::F32 => candle_core::DType::F32,
            Self::F16 => candle_core::DType::F16,
            Self::Bf16 => candle_core::DType::BF16,
        }
    }
}

/// `perception.delight`: which views' colours have a fitted key light divided out
/// (`crate::reconstruct::delight`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Delight {
    /// Keep the colours as the views show them.
    Never,
    /// The calibrated views together (one world frame, the person seen from several sides, so
    /// the light's direction is seen); views placed by a fitted camera keep their colours.
    #[default]
    Calibrated,
    /// Every view: the calibrated ones together, each other view alone.
    Always,
}

impl Choice for Delight {
    const ALL: &'static [Self] = &[Self::Never, Self::Calibrated, Self::Always];
    fn as_str(self) -> &'static str {
        match self {
            Self::Never => "never",
            Self::Calibrated => "calibrated",
            Self::Always => "always",
        }
    }
}

/// `outputs.render_device`: where the rendered frames are rasterised.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RenderDevice {
    /// The CPU rasteriser.
    #[default]
    Cpu,
    /// The CUDA rasteriser on GPU 0 (needs a build with the `cuda` feature).
    Cuda,
}

impl Choice for RenderDevice {
    const ALL: &'static [Self] = &[Self::Cpu, Self::Cuda];
    fn as_str(self) -> &'static str {
        match self {
            Self::Cpu => "cpu",
            Self::Cuda => "cuda",
        }
    }
}

/// `outputs.renderer`: how the node makes its frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RendererChoice {
    /// `neural` for checkpoints whose Gaussian RGB is not display-ready, else `gaussians`.
    #[default]
    Auto,
    /// Splat the Gaussians' RGB.
    Gaussians,
    /// Splat the latent features and decode them with the DPT neural renderer.
    Neural,
}

impl Choice for RendererChoice {
    const ALL: &'static [Self] = &[Self::Auto, Self::Gaussians, Self::Neural];
    fn as_str(self) -> &'static str {
        match self {
            Self::Auto => "auto",
            Self::Gaussians => "gaussians",
            Self::Neural => "neural",
        }
    }
}

/// `outputs.frame_qos`: reliability of the rendered-frame publishers (keep last 2 either way).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FrameQos {
    /// Reliable: RViz2, rqt and best-effort subscribers all match.
    #[default]
    Reliable,
    /// Best effort: a reliable subscriber does not match (incompatible RELIABILITY).
    BestEffort,
}

impl Choice for FrameQos {
    const ALL: &'static [Self] = &[Self::Reliable, Self::BestEffort];
    fn as_str(self) -> &'static str {
        match self {
            Self::Reliable => "reliable",
            Self::BestEffort => "best_effort",
        }
    }
}

/// `inputs.person_mask`: where a camera's person mask comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PersonMask {
    /// `topic` for cameras with a mask topic, `perception` for the others.
    #[default]
    Auto,
    /// Only mask topics; cameras without one go on as whole frames.
    Topic,
    /// The perception's segmentation for every camera (mask topics are ignored).
    Perception,
    /// No masks: whole frames.
    Off,
}

impl Choice for PersonMask {
    const ALL: &'static [Self] = &[Self::Auto, Self::Topic, Self::Perception, Self::Off];
    fn as_str(self) -> &'static str {
        match self {
            Self::Auto => "auto",
            Self::Topic => "topic",
            Self::Perception => "perception",
            Self::Off => "off",
        }
    }
}

/// `inputs.pose_source`: what drives the avatar's animation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PoseSource {
    /// The pose topic while someone else publishes on it, else the camera when perception
    /// runs, else the walk cycle.
    #[default]
    Auto,
    /// Only the pose topic (the walk cycle until a pose arrives).
    Topic,
    /// The pose read from the cameras by perception.
    Camera,
    /// The built-in walk cycle.
    Walk,
}

impl Choice for PoseSource {
    const ALL: &'static [Self] = &[Self::Auto, Self::Topic, Self::Camera, Self::Walk];
    fn as_str(self) -> &'static str {
        match self {
            Self::Auto => "auto",
            Self::Topic => "topic",
            Self::Camera => "camera",
            Self::Walk => "walk",
        }
    }
}

/// `perception.landmark_model`: which BlazePose landmark model reads the person.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LandmarkModelChoice {
    /// The smallest and fastest (embedded).
    Lite,
    /// The default balance of speed and accuracy (embedded).
    #[default]
    Full,
    /// The most accurate; not embedded (`perception.heavy_weights`).
    Heavy,
}

impl Choice for LandmarkModelChoice {
    const ALL: &'static [Self] = &[Self::Lite, Self::Full, Self::Heavy];
    fn as_str(self) -> &'static str {
        match self {
            Self::Lite => "lite",
            Self::Full => "full",
            Self::Heavy => "heavy",
        }
    }
}

impl LandmarkModelChoice {
    /// The landmark model this choice names.
    pub fn model(self) -> crate::perception::LandmarkModel {
        use crate::perception::LandmarkModel;
        match self {
            Self::Lite => LandmarkModel::Lite,
            Self::Full => LandmarkModel::Full,
            Self::Heavy => LandmarkModel::Heavy,
        }
    }
}

/// `perception.person_detector`: which detector finds the person a camera starts following
/// (one person, `tracking.enabled` off).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PersonDetectorChoice {
    /// MoveNet MultiPose (the several-people finder), then the person last followed or the
    /// most prominent one.
    #[default]
    Movenet,
    /// BlazePose's own detector (people filling much of the frame).
    Blazepose,
}

impl Choice for PersonDetectorChoice {
    const ALL: &'static [Self] = &[Self::Movenet, Self::Blazepose];
    fn as_str(self) -> &'static str {
        match self {
            Self::Movenet => "movenet",
            Self::Blazepose => "blazepose",
        }
    }
}

impl PersonDetectorChoice {
    /// The detector this choice names.
    pub fn detector(self) -> crate::perception::PersonDetector {
        use crate::perception::PersonDetector;
        match self {
            Self::Movenet => PersonDetector::MultiPose,
            Self::Blazepose => PersonDetector::BlazePose,
        }
    }
}

/// `model.device`: `cpu`, `cuda` (GPU 0) or `cuda:N`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub enum ComputeDevice {
    /// The CPU.
    #[default]
    Cpu,
    /// A CUDA GPU: `None` as written `cuda` (GPU 0), `Some(n)` as written `cuda:n`.
    Cuda(Option<usize>),
}

impl ComputeDevice {
    /// The accepted forms, as the docs list them.
    pub const FORMS: [&'static str; 3] = ["cpu", "cuda", "cuda:N"];

    /// The CUDA ordinal (`None` for the CPU).
    pub fn cuda_index(self) -> Option<usize> {
        match self {
            Self::Cpu => None,
            Self::Cuda(n) => Some(n.unwrap_or(0)),
        }
    }
}

/// A `model.device` value that is not `cpu`, `cuda` or `cuda:N`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("`{0}` is not cpu, cuda or cuda:N")]
pub struct UnknownDevice(pub String);

impl std::str::FromStr for ComputeDevice {
    type Err = UnknownDevice;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "cpu" => Ok(Self::Cpu),
            "cuda" => Ok(Self::Cuda(None)),
            _ => s
                .strip_prefix("cuda:")
                .and_then(|n| n.parse().ok())
                .map(|n| Self::Cuda(Some(n)))
                .ok_or_else(|| UnknownDevice(s.to_string())),
        }
    }
}

impl TryFrom<String> for ComputeDevice {
    type Error = UnknownDevice;
    fn try_from(s: String) -> Result<Self, Self::Error> {
        s.parse()
    }
}

impl From<ComputeDevice> for String {
    fn from(d: ComputeDevice) -> Self {
        d.to_string()
    }
}

impl fmt::Display for ComputeDevice {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Cpu => f.write_str("cpu"),
            Self::Cuda(None) => f.write_str("cuda"),
            Self::Cuda(Some(n)) => write!(f, "cuda:{n}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every value of `T` is written and read back under its [`Choice::as_str`] name.
    fn names_round_trip<T>()
    where
        T: Choice + PartialEq + fmt::Debug + fmt::Display + Serialize + serde::de::DeserializeOwned,
    {
        for &value in T::ALL {
            let text = serde_yaml_ng::to_string(&value).unwrap();
            assert_eq!(text.trim(), value.as_str(), "{value:?}");
            let back: T = serde_yaml_ng::from_str(value.as_str()).unwrap();
            assert_eq!(back, value);
            assert_eq!(value.to_string(), value.as_str());
        }
    }

    #[test]
    fn serde_names_are_the_documented_names() {
        names_round_trip::<ImageQos>();
        names_round_trip::<Dtype>();
        names_round_trip::<RenderDevice>();
        names_round_trip::<RendererChoice>();
        names_round_trip::<FrameQos>();
        names_round_trip::<PersonMask>();
        names_round_trip::<PoseSource>();
        names_round_trip::<LandmarkModelChoice>();
    }
}
