//! Node configuration: typed parameters loaded from ROS 2 parameter files
//! (`<node_name>: ros__parameters: {...}`) with `key=value` overrides from the command line.
//!
//! Every parameter lives in [`NodeConfig`]; unknown keys and invalid values are errors that
//! name the key and the file they came from.

use serde::{Deserialize, Serialize};
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
    /// DDS domain id; `-1` means "read `ROS_DOMAIN_ID` or use 0".
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
    /// What the node publishes and writes.
    pub outputs: OutputConfig,
    /// Bag replay instead of live topics (the demo uses this).
    pub replay: ReplayConfig,
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
    pub image_qos: String,
    /// Largest accepted image side in pixels; larger frames are rejected.
    pub max_image_side: u32,
}

/// Frame store bounds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FrameStoreConfig {
    /// Most views held per person (the paper's gains saturate past 16).
    pub max_views: usize,
    /// Views whose image-token cosine similarity to a held view exceeds this are duplicates.
    pub duplicate_similarity: f32,
    /// Wait this long after a view-set change before rerunning (ms).
    pub debounce_ms: u64,
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
    pub device: String,
    /// Compute dtype: `f32`, `f16` or `bf16`.
    pub dtype: String,
    /// Anchor points sampled on the body template.
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
}

/// Outputs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputConfig {
    /// Directory for PLY avatars and rendered PNG frames; empty disables file output.
    pub dir: String,
    /// Rendered-frame rate per virtual camera (Hz); 0 disables rendering.
    pub render_rate_hz: f64,
    /// Side of the square rendered frames (pixels).
    pub render_size: u32,
    /// Number of virtual cameras orbiting the person.
    pub virtual_cameras: u32,
    /// Rasteriser of the rendered frames: `cpu`, or `cuda` (GPU 0; needs a build with the
    /// `cuda` feature).
    pub render_device: String,
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

impl RendererChoice {
    /// The value as written in a parameter file.
    pub fn as_str(self) -> &'static str {
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

impl FrameQos {
    /// The value as written in a parameter file.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Reliable => "reliable",
            Self::BestEffort => "best_effort",
        }
    }
}

/// Replay settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReplayConfig {
    /// MCAP bag to play into the node; empty means live topics.
    pub bag: String,
    /// Playback rate; 0 plays as fast as the node consumes.
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
            outputs: OutputConfig::default(),
            replay: ReplayConfig::default(),
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
            image_qos: "sensor_data".into(),
            max_image_side: 8192,
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
            device: "cpu".into(),
            dtype: "f32".into(),
            num_points: 4096,
            seed: 1,
            prior_dir: String::new(),
            smplx_model: String::new(),
        }
    }
}

impl Default for OutputConfig {
    fn default() -> Self {
        Self {
            dir: "out".into(),
            render_rate_hz: 10.0,
            render_size: 256,
            virtual_cameras: 1,
            render_device: "cpu".into(),
            renderer: RendererChoice::Auto,
            frame_qos: FrameQos::Reliable,
            preview_rate_hz: 1.0,
            preview_frame: "lhmpp_avatar".into(),
            world_frame: "world".into(),
            ros: true,
            shm: false,
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

    /// Checks value ranges; the error names the offending key.
    pub fn validate(&self, origin: &Path) -> Result<(), ConfigError> {
        let bad = |key: &str, message: String| ConfigError::Invalid {
            path: origin.to_path_buf(),
            key: key.into(),
            message,
        };
        if !(-1..=232).contains(&self.domain_id) {
            return Err(bad(
                "domain_id",
                format!("{} is not in -1..=232", self.domain_id),
            ));
        }
        if let Some(address) = self
            .dds_interfaces
            .iter()
            .find(|a| a.parse::<std::net::IpAddr>().is_err())
        {
            return Err(bad(
                "dds_interfaces",
                format!("`{address}` is not an IP address"),
            ));
        }
        if self.person_id.is_empty() {
            return Err(bad("person_id", "must not be empty".into()));
        }
        if self.inputs.image_topics.is_empty() && self.inputs.compressed_image_topics.is_empty() {
            return Err(bad(
                "inputs.image_topics",
                "no image topic configured (set image_topics or compressed_image_topics)".into(),
            ));
        }
        let cameras = self.inputs.image_topics.len() + self.inputs.compressed_image_topics.len();
        if self.inputs.mask_topics.len() > cameras {
            return Err(bad(
                "inputs.mask_topics",
                format!(
                    "{} mask topics for {cameras} camera topics (one mask topic per camera, by position)",
                    self.inputs.mask_topics.len()
                ),
            ));
        }
        if !["sensor_data", "reliable"].contains(&self.inputs.image_qos.as_str()) {
            return Err(bad(
                "inputs.image_qos",
                format!(
                    "`{}` is not `sensor_data` or `reliable`",
                    self.inputs.image_qos
                ),
            ));
        }
        if !(1..=64).contains(&self.frame_store.max_views) {
            return Err(bad(
                "frame_store.max_views",
                format!("{} is not in 1..=64", self.frame_store.max_views),
            ));
        }
        if !(0.0..=1.0).contains(&self.frame_store.duplicate_similarity) {
            return Err(bad(
                "frame_store.duplicate_similarity",
                format!("{} is not in 0..=1", self.frame_store.duplicate_similarity),
            ));
        }
        if crate::model::LhmppConfig::preset(&self.model.preset).is_err() {
            return Err(bad(
                "model.preset",
                format!(
                    "`{}` is not one of {}",
                    self.model.preset,
                    crate::model::LhmppConfig::PRESETS.join(", ")
                ),
            ));
        }
        let device_ok = self.model.device == "cpu"
            || self.model.device == "cuda"
            || self
                .model
                .device
                .strip_prefix("cuda:")
                .is_some_and(|n| n.parse::<usize>().is_ok());
        if !device_ok {
            return Err(bad(
                "model.device",
                format!("`{}` is not cpu, cuda or cuda:N", self.model.device),
            ));
        }
        if !["f32", "f16", "bf16"].contains(&self.model.dtype.as_str()) {
            return Err(bad(
                "model.dtype",
                format!("`{}` is not f32, f16 or bf16", self.model.dtype),
            ));
        }
        if !(64..=400_000).contains(&self.model.num_points) {
            return Err(bad(
                "model.num_points",
                format!("{} is not in 64..=400000", self.model.num_points),
            ));
        }
        if !self.model.smplx_model.is_empty() && self.model.prior_dir.is_empty() {
            return Err(bad(
                "model.smplx_model",
                "is only used with model.prior_dir (the official LHMPP-Prior body)".to_string(),
            ));
        }
        if !(self.outputs.render_rate_hz.is_finite() && self.outputs.render_rate_hz >= 0.0) {
            return Err(bad(
                "outputs.render_rate_hz",
                format!("{} must be finite and >= 0", self.outputs.render_rate_hz),
            ));
        }
        if !(16..=4096).contains(&self.outputs.render_size) {
            return Err(bad(
                "outputs.render_size",
                format!("{} is not in 16..=4096", self.outputs.render_size),
            ));
        }
        if !(self.outputs.preview_rate_hz.is_finite() && self.outputs.preview_rate_hz >= 0.0) {
            return Err(bad(
                "outputs.preview_rate_hz",
                format!("{} must be finite and >= 0", self.outputs.preview_rate_hz),
            ));
        }
        for (key, frame) in [
            ("outputs.preview_frame", &self.outputs.preview_frame),
            ("outputs.world_frame", &self.outputs.world_frame),
        ] {
            if frame.trim().is_empty() || frame.contains(char::is_whitespace) {
                return Err(bad(key, format!("`{frame}` is not a TF frame name")));
            }
        }
        if self.outputs.preview_frame == self.outputs.world_frame {
            return Err(bad(
                "outputs.preview_frame",
                format!(
                    "`{}` is also outputs.world_frame; the preview needs a frame of its own",
                    self.outputs.preview_frame
                ),
            ));
        }
        match self.outputs.render_device.as_str() {
            "cpu" => {}
            "cuda" if cfg!(feature = "cuda") => {}
            "cuda" => {
                return Err(bad(
                    "outputs.render_device",
                    "`cuda` needs a binary built with the `cuda` feature (scripts/build-cuda)"
                        .to_string(),
                ))
            }
            other => {
                return Err(bad(
                    "outputs.render_device",
                    format!("`{other}` is not cpu or cuda"),
                ))
            }
        }
        if !(self.replay.rate.is_finite() && self.replay.rate >= 0.0) {
            return Err(bad(
                "replay.rate",
                format!("{} must be finite and >= 0", self.replay.rate),
            ));
        }
        Ok(())
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
mod tests {
    use super::*;

    const FILE: &str = "test.yaml";

    fn load(text: &str, overrides: &[&str]) -> Result<NodeConfig, ConfigError> {
        let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
        NodeConfig::from_yaml(text, Path::new(FILE), &o)
    }

    #[test]
    fn parameter_file_layout_is_read() {
        let c = load(
            "lhmpp:\n  ros__parameters:\n    person_id: alice\n    frame_store:\n      max_views: 8\n",
            &[],
        )
        .unwrap();
        assert_eq!(c.person_id, "alice");
        assert_eq!(c.frame_store.max_views, 8);
        assert_eq!(c.model, ModelConfig::default());
    }

    #[test]
    fn unknown_key_names_key_and_file() {
        let e = load(
            "lhmpp:\n  ros__parameters:\n    frame_store:\n      max_veiws: 8\n",
            &[],
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("max_veiws"), "{e}");
        assert!(e.contains(FILE), "{e}");
    }

    #[test]
    fn invalid_value_names_key_and_file() {
        let e = load(
            "lhmpp:\n  ros__parameters:\n    model:\n      device: tpu\n",
            &[],
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("model.device") && e.contains(FILE), "{e}");
        let e = load(
            "lhmpp:\n  ros__parameters:\n    frame_store:\n      max_views: banana\n",
            &[],
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("max_views") && e.contains(FILE), "{e}");
    }

    #[test]
    fn more_mask_topics_than_cameras_is_refused_naming_the_key() {
        let yaml = |masks: &str| {
            format!(
                "lhmpp:\n  ros__parameters:\n    inputs:\n      image_topics: [/a, /b]\n      mask_topics: [{masks}]\n"
            )
        };
        assert_eq!(
            load(&yaml("/a_mask, /b_mask"), &[])
                .unwrap()
                .inputs
                .mask_topics
                .len(),
            2
        );
        let e = load(&yaml("/a_mask, /b_mask, /c_mask"), &[])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("inputs.mask_topics") && e.contains("3 mask topics"),
            "{e}"
        );
    }

    #[test]
    fn render_device_must_be_cpu_or_a_cuda_this_binary_supports() {
        let yaml = |d: &str| {
            format!("lhmpp:\n  ros__parameters:\n    outputs:\n      render_device: {d}\n")
        };
        assert_eq!(
            load(&yaml("cpu"), &[]).unwrap().outputs.render_device,
            "cpu"
        );
        let e = load(&yaml("vulkan"), &[]).unwrap_err().to_string();
        assert!(
            e.contains("outputs.render_device") && e.contains("vulkan"),
            "{e}"
        );
        let cuda = load(&yaml("cuda"), &[]);
        if cfg!(feature = "cuda") {
            assert_eq!(cuda.unwrap().outputs.render_device, "cuda");
        } else {
            let e = cuda.unwrap_err().to_string();
            assert!(
                e.contains("outputs.render_device") && e.contains("feature"),
                "{e}"
            );
        }
    }

    #[test]
    fn every_network_preset_is_accepted_and_another_name_is_refused_naming_them() {
        let yaml = |p: &str| format!("lhmpp:\n  ros__parameters:\n    model:\n      preset: {p}\n");
        for name in crate::model::LhmppConfig::PRESETS {
            assert_eq!(load(&yaml(name), &[]).unwrap().model.preset, name);
        }
        let e = load(&yaml("lhmpp-9000m"), &[]).unwrap_err().to_string();
        assert!(
            e.contains("model.preset") && e.contains("lhmpp-9000m"),
            "{e}"
        );
        assert!(e.contains("lhmpp-700m-pixelshuffle"), "{e}");
    }

    #[test]
    fn renderer_is_auto_gaussians_or_neural_and_a_bad_value_names_the_key() {
        let yaml =
            |r: &str| format!("lhmpp:\n  ros__parameters:\n    outputs:\n      renderer: {r}\n");
        assert_eq!(
            load("lhmpp:\n  ros__parameters: {}\n", &[])
                .unwrap()
                .outputs
                .renderer,
            RendererChoice::Auto
        );
        for (text, want) in [
            ("auto", RendererChoice::Auto),
            ("gaussians", RendererChoice::Gaussians),
            ("neural", RendererChoice::Neural),
        ] {
            assert_eq!(load(&yaml(text), &[]).unwrap().outputs.renderer, want);
            assert_eq!(want.as_str(), text);
        }
        let e = load(&yaml("dpt"), &[]).unwrap_err().to_string();
        assert!(
            e.contains("outputs.renderer") && e.contains("dpt") && e.contains(FILE),
            "{e}"
        );
        assert!(e.contains("neural") && e.contains("gaussians"), "{e}");
        let e = load(&yaml("gaussians"), &["outputs.renderer=Neural"])
            .unwrap_err()
            .to_string();
        assert!(e.contains("outputs.renderer"), "{e}");
    }

    #[test]
    fn frame_qos_is_reliable_by_default_and_a_bad_value_names_the_key() {
        let yaml =
            |q: &str| format!("lhmpp:\n  ros__parameters:\n    outputs:\n      frame_qos: {q}\n");
        assert_eq!(
            load("lhmpp:\n  ros__parameters: {}\n", &[])
                .unwrap()
                .outputs
                .frame_qos,
            FrameQos::Reliable
        );
        for (text, want) in [
            ("reliable", FrameQos::Reliable),
            ("best_effort", FrameQos::BestEffort),
        ] {
            assert_eq!(load(&yaml(text), &[]).unwrap().outputs.frame_qos, want);
            assert_eq!(want.as_str(), text);
        }
        let e = load(&yaml("sensor_data"), &[]).unwrap_err().to_string();
        assert!(
            e.contains("outputs.frame_qos") && e.contains("sensor_data") && e.contains(FILE),
            "{e}"
        );
        assert!(e.contains("reliable") && e.contains("best_effort"), "{e}");
        let c = load(&yaml("reliable"), &["outputs.frame_qos=best_effort"]).unwrap();
        assert_eq!(c.outputs.frame_qos, FrameQos::BestEffort);
    }

    #[test]
    fn preview_rate_and_frames_are_validated_naming_the_key() {
        let base = "lhmpp:\n  ros__parameters: {}\n";
        let c = load(base, &[]).unwrap();
        assert_eq!(c.outputs.preview_rate_hz, 1.0);
        assert_eq!(c.outputs.preview_frame, "lhmpp_avatar");
        assert_eq!(c.outputs.world_frame, "world");
        for (set, key) in [
            ("outputs.preview_rate_hz=-1", "outputs.preview_rate_hz"),
            ("outputs.preview_frame=''", "outputs.preview_frame"),
            ("outputs.world_frame=a b", "outputs.world_frame"),
            ("outputs.preview_frame=world", "outputs.preview_frame"),
        ] {
            let e = load(base, &[set]).unwrap_err().to_string();
            assert!(e.contains(key), "{set}: {e}");
        }
        assert_eq!(
            load(base, &["outputs.preview_rate_hz=0"])
                .unwrap()
                .outputs
                .preview_rate_hz,
            0.0
        );
    }

    #[test]
    fn overrides_win_and_are_validated() {
        let text = "lhmpp:\n  ros__parameters:\n    model:\n      device: cpu\n";
        let c = load(text, &["model.num_points=8192", "outputs.dir=/tmp/x"]).unwrap();
        assert_eq!(c.model.num_points, 8192);
        assert_eq!(c.outputs.dir, "/tmp/x");
        let e = load(text, &["model.num_points=3"]).unwrap_err().to_string();
        assert!(e.contains("model.num_points"), "{e}");
        assert!(load(text, &["noequals"]).is_err());
    }

    #[test]
    fn wrong_layout_is_explained() {
        let e = load("person_id: x\n", &[]).unwrap_err().to_string();
        assert!(e.contains("ros__parameters") && e.contains(FILE), "{e}");
    }

    #[test]
    fn printed_config_round_trips() {
        let c = load("lhmpp:\n  ros__parameters:\n    person_id: bob\n", &[]).unwrap();
        assert_eq!(load(&c.to_param_file(), &[]).unwrap(), c);
    }
}
