//! Node configuration: typed parameters loaded from ROS 2 parameter files
//! (`<node_name>: ros__parameters: {...}`) with `key=value` overrides from the command line.
//!
//! Every parameter lives in [`NodeConfig`]; unknown keys and invalid values are errors that
//! name the key and the file they came from.

mod choices;
mod people;
mod refine;
mod table;
mod validate;

pub use choices::{
    Choice, ComputeDevice, Delight, Dtype, FrameQos, ImageQos, LandmarkModelChoice,
    PersonDetectorChoice, PersonMask, PoseSource, RenderDevice, RendererChoice, UnknownDevice,
};
pub use people::{owner, ClusterConfig, TrackingSettings};
pub use refine::RefineSettings;
pub use table::{markdown_table, parameters, Parameter};

use serde::{Deserialize, Serialize};
use std::ops::{RangeFrom, RangeInclusive};
use std::path::{Path, PathBuf};

/// Node name used when a parameter file is written by us and the key under which
/// parameters are looked up when the file holds several nodes.
pub const NODE_NAME: &str = "lhmpp";

/// A configuration problem, always naming where it came from.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The parameter file could not be read.
    #[error("cannot read config file {path}: {source}")]
    Read {
        /// File that failed.
        path: PathBuf,
        /// Underlying I/O error.
        source: std::io::Error,
    },
    /// The file is not valid YAML or does not have the ROS 2 parameter-file layout.
    #[error("config file {path}: {message}")]
    Layout {
        /// File that failed.
        path: PathBuf,
        /// What is wrong with it.
        message: String,
    },
    /// A key is unknown or its value has the wrong type.
    #[error("config file {path}: {message}")]
    Parse {
        /// File that failed.
        path: PathBuf,
        /// serde's message, which names the key (and line).
        message: String,
    },
    /// A value has the right type but is out of range.
    #[error("config file {path}: parameter `{key}`: {message}")]
    Invalid {
        /// File that failed.
        path: PathBuf,
        /// Dotted parameter name.
        key: String,
        /// Why the value is rejected.
        message: String,
    },
    /// A command-line override is malformed.
    #[error("override `{0}`: expected KEY=VALUE with a dotted key, e.g. model.device=cpu")]
    Override(String),
}

/// All parameters of the `lhmpp` node. Field docs are the config reference.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NodeConfig {
    /// ROS 2 namespace of the node (`/` for none).
    pub namespace: String,
    /// DDS domain id in [`NodeConfig::DOMAIN_ID`]; `-1` means "read `ROS_DOMAIN_ID` or use 0".
    pub domain_id: i32,
    /// Network interfaces DDS may use, by IP address (e.g. `[127.0.0.1]` for loopback only);
    /// empty means all.
    pub dds_interfaces: Vec<String>,
    /// Id of the person reconstructed from the input topics.
    pub person_id: String,
    /// Input topics and their QoS.
    pub inputs: InputConfig,
    /// Frame-store bounds and view selection.
    pub frame_store: FrameStoreConfig,
    /// Reconstruction network.
    pub model: ModelConfig,
    /// Camera-only perception: person detection, segmentation and pose.
    pub perception: PerceptionConfig,
    /// What the node publishes and writes.
    pub outputs: OutputConfig,
    /// Bag replay instead of live topics (the demo uses this).
    pub replay: ReplayConfig,
    /// Several people: persons tracked in the camera images, one avatar each.
    pub tracking: TrackingSettings,
    /// Nodes sharing the tracked persons.
    pub cluster: ClusterConfig,
    /// Fitting each avatar to its views between network reruns.
    pub refine: RefineSettings,
}

impl NodeConfig {
    /// Accepted `domain_id` values.
    pub const DOMAIN_ID: RangeInclusive<i32> = -1..=232;

    /// Whether some camera's frames are masked by perception (`inputs.person_mask`:
    /// `perception`, or `auto` with a camera that has no mask topic).
    pub fn perception_masks(&self) -> bool {
        let inputs = &self.inputs;
        let cameras = inputs.image_topics.len() + inputs.compressed_image_topics.len();
        match inputs.person_mask {
            PersonMask::Perception => true,
            PersonMask::Auto => {
                inputs.mask_topic.trim().is_empty() && inputs.mask_topics.len() < cameras
            }
            PersonMask::Topic | PersonMask::Off => false,
        }
    }

    /// Whether some camera's frames come with a mask from a topic, inside which perception
    /// reads the person (`inputs.person_mask`: `auto` or `topic`, with a mask topic).
    pub fn given_masks(&self) -> bool {
        let inputs = &self.inputs;
        matches!(inputs.person_mask, PersonMask::Auto | PersonMask::Topic)
            && (!inputs.mask_topic.trim().is_empty() || !inputs.mask_topics.is_empty())
    }

    /// Whether perception finds people in some camera's frames itself (for masks, tracking or
    /// the pose, `inputs.pose_source: camera`), making masks of its own.
    pub fn perception_finds_people(&self) -> bool {
        self.perception_masks()
            || self.inputs.pose_source == PoseSource::Camera
            || self.tracking.enabled
    }

    /// Whether camera-only perception runs: where it finds people itself, or inside given
    /// masks.
    pub fn runs_perception(&self) -> bool {
        self.perception_finds_people() || self.given_masks()
    }
}

/// Input topics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct InputConfig {
    /// sensor_msgs/Image topics, one per camera.
    pub image_topics: Vec<String>,
    /// sensor_msgs/CompressedImage topics (jpeg/png).
    pub compressed_image_topics: Vec<String>,
    /// sensor_msgs/CameraInfo topics, matched to image topics by position (may be empty).
    pub camera_info_topics: Vec<String>,
    /// Optional person-mask topic (mono8 Image) shared by every camera, matched to a frame by
    /// stamp and size; empty disables it.
    pub mask_topic: String,
    /// Person-mask topics (mono8 Image), one per camera, matched by position to
    /// `image_topics` followed by `compressed_image_topics` (may be shorter); a camera's frames
    /// are cropped to the person by its own mask of the same stamp.
    pub mask_topics: Vec<String>,
    /// lhmpp_msgs/BodyPose topic that drives animation.
    pub pose_topic: String,
    /// Optional lhmpp_msgs/BodyShape topic (body shape of the person); empty disables it.
    pub shape_topic: String,
    /// Image QoS: `sensor_data` (best effort, keep last) or `reliable`.
    pub image_qos: ImageQos,
    /// Largest accepted image side in pixels; larger frames are rejected (compressed ones from
    /// their header, before their pixels are decoded).
    pub max_image_side: u32,
    /// Most messages per second taken from one live input topic; faster ones are dropped
    /// before they are decoded, and counted (0 disables the limit).
    pub max_rate_hz: f64,
    /// Where each camera's person mask comes from: `auto` (its mask topic if it has one,
    /// else perception), `topic`, `perception` or `off` (whole frames).
    pub person_mask: PersonMask,
    /// What animates the avatar: `auto` (the pose topic while another node publishes on it,
    /// else the cameras through perception, else the walk cycle), `topic`, `camera` or
    /// `walk`.
    pub pose_source: PoseSource,
}

impl InputConfig {
    /// Accepted `inputs.max_image_side` values (65535 is the largest side a JPEG can declare).
    pub const MAX_IMAGE_SIDE: RangeInclusive<u32> = 16..=65535;
}

/// Frame store bounds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FrameStoreConfig {
    /// Most views held per person (the paper's gains saturate past 16), in
    /// [`FrameStoreConfig::MAX_VIEWS`].
    pub max_views: usize,
    /// Views whose image-token cosine similarity to a held view exceeds this are duplicates
    /// (in [`FrameStoreConfig::DUPLICATE_SIMILARITY`]).
    pub duplicate_similarity: f32,
    /// Wait this long after a view-set change before rerunning (ms).
    pub debounce_ms: u64,
}

impl FrameStoreConfig {
    /// Accepted `frame_store.max_views` values.
    pub const MAX_VIEWS: RangeInclusive<usize> = 1..=64;
    /// Accepted `frame_store.duplicate_similarity` values.
    pub const DUPLICATE_SIMILARITY: RangeInclusive<f32> = 0.0..=1.0;
}

/// Reconstruction network settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ModelConfig {
    /// Network preset: `tiny`, `s`, `m`, `l` or `lhmpp-700m`.
    pub preset: String,
    /// Checkpoint (safetensors file or hub folder); empty means the embedded default (the
    /// trained `tiny` network), `random` or `random:SEED` seeded random weights.
    pub checkpoint: String,
    /// `cpu` or `cuda` (or `cuda:N`).
    pub device: ComputeDevice,
    /// Compute dtype: `f32`, `f16` or `bf16`.
    pub dtype: Dtype,
    /// Anchor points sampled on the body template, in [`ModelConfig::NUM_POINTS`].
    pub num_points: usize,
    /// Seed for anchor sampling.
    pub seed: u64,
    /// Official-checkpoint body prior: the `LHMPP-Prior` download folder (holding
    /// `dense_sample_points/1_160000.ply`, `voxel_grid/cano_1_volume.npz` and
    /// `human_model_files/smplx/SMPLX_NEUTRAL.npz`). Empty keeps the MakeHuman body. Only used
    /// with preset `lhmpp-700m` or a hub-folder checkpoint; `num_points` then picks that many
    /// of the prior's points (160000 = all).
    pub prior_dir: String,
    /// SMPL-X model file overriding `<prior_dir>/human_model_files/smplx/SMPLX_NEUTRAL.npz`.
    pub smplx_model: String,
    /// Most views the network reads in one reconstruction, in [`ModelConfig::MAX_VIEWS`]:
    /// when more are given, the most different ones by their image tokens (all of them still
    /// colour the avatar with `perception.colours_from_views`); 0 = as many as the weights
    /// were trained on ([`ModelConfig::network_views`]).
    pub max_views: usize,
}

impl ModelConfig {
    /// Accepted `model.num_points` values.
    pub const NUM_POINTS: RangeInclusive<usize> = 64..=400_000;

    /// Accepted `model.max_views` values (0 = as trained).
    pub const MAX_VIEWS: RangeInclusive<usize> = 0..=64;

    /// Views the embedded default was trained on at most (`scripts/train/run`: the data set's
    /// `--max-views`).
    pub const EMBEDDED_TRAINED_VIEWS: usize = 8;

    /// Views the official LHM++ models were trained on at most (1–16 views in their second
    /// stage), and the default for any checkpoint but the embedded one.
    pub const OFFICIAL_TRAINED_VIEWS: usize = 16;

    /// The most views the network reads: `max_views`, or when 0, as many as the weights were
    /// trained on ([`Self::EMBEDDED_TRAINED_VIEWS`] for the embedded default, else
    /// [`Self::OFFICIAL_TRAINED_VIEWS`]).
    pub fn network_views(&self) -> usize {
        match (self.max_views, self.checkpoint.is_empty()) {
            (0, true) => Self::EMBEDDED_TRAINED_VIEWS,
            (0, false) => Self::OFFICIAL_TRAINED_VIEWS,
            (n, _) => n,
        }
    }
}

/// Camera-only perception (MediaPipe BlazePose on the CPU).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PerceptionConfig {
    /// Landmark model: `lite`, `full` (embedded) or `heavy` (from `heavy_weights`).
    pub landmark_model: LandmarkModelChoice,
    /// The converted heavy landmark model (`assets/perception/README.md` says how to make
    /// it); only read with `landmark_model: heavy`.
    pub heavy_weights: String,
    /// Which detector finds the person a camera starts following (one person): MoveNet
    /// MultiPose at `people_detector_side`, or BlazePose's own.
    pub person_detector: PersonDetectorChoice,
    /// BlazePose detector score that starts tracking a person (`person_detector: blazepose`),
    /// in [`PerceptionConfig::UNIT`].
    pub min_detection_score: f32,
    /// Pose presence that keeps tracking a person, in [`PerceptionConfig::UNIT`].
    pub min_presence: f32,
    /// Person probability at the mask's edge, in [`PerceptionConfig::UNIT`].
    pub mask_threshold: f32,
    /// Half-width of the mask's soft edge in probability, in [`PerceptionConfig::FEATHER`].
    pub mask_feather: f32,
    /// Landmarks less visible than this keep their bones' last rotation, then ease to rest,
    /// in [`PerceptionConfig::UNIT`].
    pub min_visibility: f32,
    /// CPU threads of the perception networks, in [`PerceptionConfig::THREADS`].
    pub threads: usize,
    /// Short side of MoveNet MultiPose's input (every frame with `tracking.enabled`; with one
    /// person, the frames in which nobody is followed): a multiple of 32 in
    /// [`PerceptionConfig::DETECTOR_SIDE`]; larger finds people who fill less of the frame, at
    /// a higher cost per frame.
    pub people_detector_side: usize,
    /// Read the body height from calibrated views (CameraInfo and the cameras' TF frames in
    /// `outputs.world_frame`, two or more cameras) when no shape topic gives the shape.
    pub estimate_shape: bool,
    /// The Gaussians a perceived view shows take their colours from that view, the others the
    /// network's colours matched to them (`crate::reconstruct::photo_colours`).
    pub colours_from_views: bool,
    /// Which views' colours have a fitted key light divided out before they colour the avatar
    /// (`crate::reconstruct::delight`).
    pub delight: Delight,
}

impl PerceptionConfig {
    /// Accepted probability-like values.
    pub const UNIT: RangeInclusive<f32> = 0.0..=1.0;
    /// Accepted `perception.mask_feather` values.
    pub const FEATHER: RangeInclusive<f32> = 0.0..=0.5;
    /// Accepted `perception.threads` values.
    pub const THREADS: RangeInclusive<usize> = 1..=64;
    /// Accepted `perception.people_detector_side` values (multiples of 32).
    pub const DETECTOR_SIDE: RangeInclusive<usize> = 128..=1024;

    /// Loads the detector and the landmark model this configuration names.
    pub fn networks(
        &self,
    ) -> Result<crate::perception::PoseNetworks, crate::perception::PerceptionError> {
        let heavy = (!self.heavy_weights.is_empty()).then(|| Path::new(&self.heavy_weights));
        crate::perception::PoseNetworks::load(self.landmark_model.model(), heavy)
    }

    /// One camera's one-person tracker settings this configuration gives (`smooth_masks`:
    /// blend the previous frame's mask in, for live video).
    pub fn tracker(&self, smooth_masks: bool) -> crate::perception::TrackerConfig {
        crate::perception::TrackerConfig {
            detector: self.person_detector.detector(),
            min_detection_score: self.min_detection_score,
            people: self.people(),
            min_presence: self.min_presence,
            smooth_masks,
            check_looks: true,
        }
    }

    /// The several-people finder's settings this configuration gives.
    pub fn people(&self) -> crate::perception::PeopleConfig {
        crate::perception::PeopleConfig {
            min_presence: self.min_presence,
            mask_threshold: self.mask_threshold,
            mask_feather: self.mask_feather,
            detector_side: self.people_detector_side,
            ..crate::perception::PeopleConfig::default()
        }
    }
}

/// Outputs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputConfig {
    /// Directory for PLY avatars and rendered PNG frames; empty disables file output. One that
    /// cannot be written (or fills up) is logged as an error and costs only the files: the
    /// ROS 2 and shared-memory outputs go on.
    pub dir: String,
    /// Numbered revision files (`avatar_<person>_rev<N>.ply`) kept per person besides the
    /// latest (`avatar_<person>.ply`); 0 (the default) keeps the latest only.
    pub keep_revisions: u32,
    /// Cap on everything the node writes under `dir` (avatars, frames; those of earlier runs
    /// included), megabytes (finite, >= 0): the oldest files are removed first; 0: no cap.
    pub max_disk_mb: f64,
    /// Rendered-frame rate per virtual camera (Hz, finite, >= 0); 0 disables rendering.
    pub render_rate_hz: f64,
    /// Side of the square rendered frames (pixels), in [`OutputConfig::RENDER_SIZE`].
    pub render_size: u32,
    /// Number of virtual cameras orbiting the person.
    pub virtual_cameras: u32,
    /// Rasteriser of the rendered frames: `cpu`, or `cuda` (GPU 0; needs a build with the
    /// `cuda` feature).
    pub render_device: RenderDevice,
    /// How frames are made: `gaussians` splats the Gaussians' RGB, `neural` splats their
    /// latent features and decodes them with the network's DPT neural renderer (as the
    /// official app does), `auto` picks `neural` when the checkpoint's RGB is not display-ready
    /// (the released LHMPP-700M / LHMPPS-700M) and its neural renderer fits, else `gaussians`.
    pub renderer: RendererChoice,
    /// QoS of the rendered-frame topics: `reliable` (default; keep last 2, matched by reliable
    /// and best-effort subscribers alike) or `best_effort` (only best-effort subscribers match).
    pub frame_qos: FrameQos,
    /// Rate of the avatar preview (`avatar/points`, sensor_msgs/PointCloud2 with packed
    /// `rgb`, posed at the latest BodyPose) and its `/tf` transform, Hz; 0 disables both.
    pub preview_rate_hz: f64,
    /// TF frame of the preview cloud.
    pub preview_frame: String,
    /// Parent frame of `preview_frame` on `/tf` (the BodyPose's world frame).
    pub world_frame: String,
    /// Publish over ROS 2 DDS.
    pub ros: bool,
    /// Publish over iceoryx2 shared memory.
    pub shm: bool,
    /// Publish each perceived camera's person mask (mono8 `sensor_msgs/Image`) on
    /// `<camera namespace>/person_mask`.
    pub masks: bool,
    /// Publish the pose read from the cameras on `inputs.pose_topic`.
    pub camera_pose: bool,
    /// `host:port` of the live page (one HTML page and a WebSocket: each person's avatar
    /// rendered in the browser, moved by the pose stream); empty disables it. An address other
    /// than loopback needs `lhmpp run --web-token`.
    pub web: String,
}

impl OutputConfig {
    /// Accepted `outputs.render_size` values.
    pub const RENDER_SIZE: RangeInclusive<u32> = 16..=4096;
}

/// Accepted rates (`outputs.render_rate_hz`, `outputs.preview_rate_hz`, `replay.rate`): finite
/// and in this range.
pub const RATE_RANGE: RangeFrom<f64> = 0.0..;

/// Replay settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReplayConfig {
    /// MCAP bag to play into the node; empty means live topics.
    pub bag: String,
    /// Playback rate (finite, >= 0); 0 plays as fast as the node consumes.
    pub rate: f64,
    /// Exit after the bag ends and the last reconstruction is written.
    pub exit_when_done: bool,
}

impl Default for NodeConfig {
    fn default() -> Self {
        Self {
            namespace: "/".into(),
            domain_id: -1,
            dds_interfaces: Vec::new(),
            person_id: "person_0".into(),
            inputs: InputConfig::default(),
            frame_store: FrameStoreConfig::default(),
            model: ModelConfig::default(),
            perception: PerceptionConfig::default(),
            outputs: OutputConfig::default(),
            replay: ReplayConfig::default(),
            tracking: TrackingSettings::default(),
            cluster: ClusterConfig::default(),
            refine: RefineSettings::default(),
        }
    }
}

impl Default for InputConfig {
    fn default() -> Self {
        Self {
            image_topics: vec!["/camera/image_raw".into()],
            compressed_image_topics: Vec::new(),
            camera_info_topics: Vec::new(),
            mask_topic: String::new(),
            mask_topics: Vec::new(),
            pose_topic: "/lhmpp/body_pose".into(),
            shape_topic: String::new(),
            image_qos: ImageQos::SensorData,
            max_image_side: 8192,
            max_rate_hz: 120.0,
            person_mask: PersonMask::Auto,
            pose_source: PoseSource::Auto,
        }
    }
}

impl Default for FrameStoreConfig {
    fn default() -> Self {
        Self {
            max_views: 16,
            duplicate_similarity: 0.995,
            debounce_ms: 200,
        }
    }
}

impl Default for ModelConfig {
    fn default() -> Self {
        Self {
            preset: "tiny".into(),
            checkpoint: String::new(),
            device: ComputeDevice::Cpu,
            dtype: Dtype::F32,
            num_points: 4096,
            seed: 1,
            prior_dir: String::new(),
            smplx_model: String::new(),
            max_views: 0,
        }
    }
}

impl Default for OutputConfig {
    fn default() -> Self {
        Self {
            dir: "out".into(),
            keep_revisions: 0,
            max_disk_mb: 1024.0,
            render_rate_hz: 10.0,
            render_size: 256,
            virtual_cameras: 1,
            render_device: RenderDevice::Cpu,
            renderer: RendererChoice::Auto,
            frame_qos: FrameQos::Reliable,
            preview_rate_hz: 1.0,
            preview_frame: "lhmpp_avatar".into(),
            world_frame: "world".into(),
            ros: true,
            shm: false,
            masks: true,
            camera_pose: true,
            web: String::new(),
        }
    }
}

impl Default for PerceptionConfig {
    fn default() -> Self {
        Self {
            landmark_model: LandmarkModelChoice::Full,
            heavy_weights: String::new(),
            person_detector: PersonDetectorChoice::Movenet,
            min_detection_score: 0.5,
            min_presence: 0.5,
            mask_threshold: 0.5,
            mask_feather: 0.1,
            min_visibility: 0.5,
            threads: 1,
            people_detector_side: crate::perception::multipose::NATIVE_SIDE,
            estimate_shape: true,
            colours_from_views: true,
            delight: Delight::Calibrated,
        }
    }
}

impl Default for ReplayConfig {
    fn default() -> Self {
        Self {
            bag: String::new(),
            rate: 1.0,
            exit_when_done: true,
        }
    }
}

impl NodeConfig {
    /// Loads a ROS 2 parameter file, applies `key=value` overrides and validates the result.
    pub fn load(path: &Path, overrides: &[String]) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_yaml(&text, path, overrides)
    }

    /// Parses parameter-file text; `origin` names the file in errors.
    pub fn from_yaml(text: &str, origin: &Path, overrides: &[String]) -> Result<Self, ConfigError> {
        let layout = |message: String| ConfigError::Layout {
            path: origin.to_path_buf(),
            message,
        };
        let doc: serde_yaml_ng::Value =
            serde_yaml_ng::from_str(text).map_err(|e| layout(e.to_string()))?;
        let nodes = doc
            .as_mapping()
            .ok_or_else(|| layout("expected `<node_name>: ros__parameters: {...}`".into()))?;
        let node = nodes
            .get(NODE_NAME)
            .or_else(|| nodes.get("/**"))
            .or_else(|| (nodes.len() == 1).then(|| nodes.values().next()).flatten())
            .ok_or_else(|| layout(format!("no section for node `{NODE_NAME}` (or `/**`)")))?;
        let mut params = node
            .get("ros__parameters")
            .cloned()
            .ok_or_else(|| layout("missing `ros__parameters` under the node name".into()))?;
        for item in overrides {
            apply_override(&mut params, item)?;
        }
        let config: NodeConfig =
            serde_path_to_error::deserialize(params).map_err(|e| ConfigError::Parse {
                path: origin.to_path_buf(),
                message: format!("parameter `{}`: {}", e.path(), e.inner()),
            })?;
        config.validate(origin)?;
        Ok(config)
    }

    /// The config as a ROS 2 parameter file (what `lhmpp config show` prints).
    pub fn to_param_file(&self) -> String {
        let mut params = serde_yaml_ng::Mapping::new();
        params.insert(
            "ros__parameters".into(),
            serde_yaml_ng::to_value(self).expect("config serialises"),
        );
        let mut root = serde_yaml_ng::Mapping::new();
        root.insert(NODE_NAME.into(), params.into());
        serde_yaml_ng::to_string(&root).expect("config serialises")
    }
}

/// Sets `a.b.c=value` inside the parameter mapping; the value is parsed as YAML.
fn apply_override(params: &mut serde_yaml_ng::Value, item: &str) -> Result<(), ConfigError> {
    let (key, raw) = item
        .split_once('=')
        .filter(|(k, _)| !k.is_empty())
        .ok_or_else(|| ConfigError::Override(item.into()))?;
    let value: serde_yaml_ng::Value =
        serde_yaml_ng::from_str(raw).map_err(|_| ConfigError::Override(item.into()))?;
    let mut slot = params;
    for part in key.split('.') {
        if slot.is_null() {
            *slot = serde_yaml_ng::Mapping::new().into();
        }
        let map = slot
            .as_mapping_mut()
            .ok_or_else(|| ConfigError::Override(item.into()))?;
        slot = map.entry(part.into()).or_insert(serde_yaml_ng::Value::Null);
    }
    *slot = value;
    Ok(())
}

#[cfg(test)]
mod tests;
