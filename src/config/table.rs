//! The parameter reference: one row per parameter with its type, accepted values and meaning;
//! defaults come from [`NodeConfig::default`] and ranges from the constants the validation
//! uses. `lhmpp config --markdown` prints it as docs/configuration.md's table (a test keeps them equal).

use super::{
    Choice, ClusterConfig, ComputeDevice, Delight, Dtype, FrameQos, FrameStoreConfig, ImageQos,
    InputConfig, LandmarkModelChoice, ModelConfig, NodeConfig, OutputConfig, PerceptionConfig,
    PersonDetectorChoice, PersonMask, PoseSource, RefineSettings, RenderDevice, RendererChoice,
    TrackingSettings, RATE_RANGE,
};
use crate::model::LhmppConfig;
use std::fmt::Display;
use std::ops::RangeInclusive;

/// One parameter of [`NodeConfig`].
#[derive(Debug, Clone, PartialEq)]
pub struct Parameter {
    /// Dotted key, as in `--set KEY=VALUE`.
    pub key: &'static str,
    /// Type and accepted values, e.g. `int in 1..=64` or `` `cpu`/`cuda` ``.
    pub kind: String,
    /// What it does.
    pub meaning: &'static str,
}

fn string() -> String {
    "string".into()
}

fn strings() -> String {
    "string[]".into()
}

fn path() -> String {
    "path".into()
}

fn int() -> String {
    "int".into()
}

fn boolean() -> String {
    "bool".into()
}

fn int_in<T: Display>(range: &RangeInclusive<T>) -> String {
    format!("int in {}..={}", range.start(), range.end())
}

fn float_in<T: Display>(range: &RangeInclusive<T>) -> String {
    format!("float in {}..={}", range.start(), range.end())
}

fn rate() -> String {
    format!("float ≥ {}", RATE_RANGE.start)
}

fn names(names: &[&str]) -> String {
    names
        .iter()
        .map(|n| format!("`{n}`"))
        .collect::<Vec<_>>()
        .join("/")
}

fn choice<T: Choice>() -> String {
    let all: Vec<&str> = T::ALL.iter().map(|c| c.as_str()).collect();
    names(&all)
}

fn p(key: &'static str, kind: String, meaning: &'static str) -> Parameter {
    Parameter { key, kind, meaning }
}

/// Every parameter, in the order of docs/configuration.md's table.
pub fn parameters() -> Vec<Parameter> {
    vec![
        p("namespace", string(), "ROS 2 namespace"),
        p(
            "domain_id",
            int_in(&NodeConfig::DOMAIN_ID),
            "DDS domain; -1 reads `ROS_DOMAIN_ID` (else 0)",
        ),
        p(
            "dds_interfaces",
            strings(),
            "IP addresses of the interfaces DDS may use (`[127.0.0.1]`: loopback only); \
             empty = all",
        ),
        p("person_id", string(), "id of the reconstructed person"),
        p(
            "inputs.image_topics",
            strings(),
            "sensor_msgs/Image topics, one per camera",
        ),
        p(
            "inputs.compressed_image_topics",
            strings(),
            "sensor_msgs/CompressedImage topics (jpeg/png)",
        ),
        p(
            "inputs.camera_info_topics",
            strings(),
            "CameraInfo per image topic, by position",
        ),
        p(
            "inputs.mask_topic",
            string(),
            "optional person mask (mono8) shared by all cameras, matched by stamp and size",
        ),
        p(
            "inputs.mask_topics",
            strings(),
            "person mask (mono8) per camera, by position over `image_topics` then \
             `compressed_image_topics`; each camera's frames are cropped to its person (a \
             frame waits up to 150 ms for its mask, which usually comes after it, then goes \
             on whole; the run summary counts the frames cropped by mask)",
        ),
        p(
            "inputs.pose_topic",
            string(),
            "lhmpp_msgs/BodyPose driving animation",
        ),
        p(
            "inputs.shape_topic",
            string(),
            "optional lhmpp_msgs/BodyShape: `makehuman-cc0` [height_scale, girth_scale] in \
             0.5..2 reshapes the body (rerun), `smplx` betas are carried in the avatar \
             only; empty disables it",
        ),
        p(
            "inputs.image_qos",
            choice::<ImageQos>(),
            "image QoS (best effort keep-last, or reliable)",
        ),
        p(
            "inputs.max_image_side",
            int_in(&InputConfig::MAX_IMAGE_SIDE),
            "larger frames are rejected (compressed ones from their header, before decoding)",
        ),
        p(
            "inputs.max_rate_hz",
            rate(),
            "messages per second taken from each live input topic; faster ones are dropped \
             before decoding and counted (`rate-limited` in the run summary); 0 = no limit",
        ),
        p(
            "inputs.person_mask",
            choice::<PersonMask>(),
            "where each camera's person mask comes from: `auto` = its mask topic if it has \
             one, else perception; `topic` = mask topics only; `perception` = the camera-only \
             segmentation for every camera; `off` = whole frames. Inside a topic's mask \
             perception still reads the person (pose, camera fit, colours, refinement), \
             without its detector. A frame in which perception finds nobody never reaches the \
             frame store (counted in the run summary); a topic-masked one goes on without \
             what perception reads",
        ),
        p(
            "inputs.pose_source",
            choice::<PoseSource>(),
            "what animates the avatar: `auto` = the pose topic while another node publishes \
             on it, else the pose perception reads from the cameras, else the walk cycle; \
             `topic`, `camera` or `walk` force one",
        ),
        p(
            "frame_store.max_views",
            int_in(&FrameStoreConfig::MAX_VIEWS),
            "views held per person",
        ),
        p(
            "frame_store.duplicate_similarity",
            float_in(&FrameStoreConfig::DUPLICATE_SIMILARITY),
            "token cosine similarity above which a view is a duplicate",
        ),
        p(
            "frame_store.debounce_ms",
            int(),
            "wait after a view-set change before rerunning",
        ),
        p(
            "model.preset",
            names(&LhmppConfig::PRESETS),
            "network layout: `tiny` (the embedded trained default), `s`, `m`, `l`, \
             `lhmpp-700m` (the released LHMPP-700M / LHMPPS-700M layout), \
             `lhmpp-700m-pixelshuffle` and `lhmpp-700m-smplx-free` (the GS-supervised \
             releases, with the shape head)",
        ),
        p(
            "model.checkpoint",
            path(),
            "safetensors file or hub folder; empty = the embedded trained `tiny` default; \
             `random` / `random:SEED` = seeded random weights",
        ),
        p(
            "model.device",
            names(&ComputeDevice::FORMS),
            "compute device (`cuda` needs the `cuda` build)",
        ),
        p("model.dtype", choice::<Dtype>(), "compute dtype"),
        p(
            "model.num_points",
            int_in(&ModelConfig::NUM_POINTS),
            "anchor points on the body template",
        ),
        p("model.seed", int(), "anchor sampling seed"),
        p(
            "model.prior_dir",
            path(),
            "`LHMPP-Prior` folder: the official SMPL-X body for `lhmpp-700m` / hub \
             checkpoints; empty = MakeHuman body",
        ),
        p(
            "model.smplx_model",
            path(),
            "SMPL-X `.npz` replacing \
             `<prior_dir>/human_model_files/smplx/SMPLX_NEUTRAL.npz`",
        ),
        p(
            "model.max_views",
            int_in(&ModelConfig::MAX_VIEWS),
            "most views the network reads in one reconstruction (the most different ones by \
             their image tokens; every view still colours the avatar); 0 = as many as the \
             weights were trained on: 8 for the embedded default, 16 for other checkpoints",
        ),
        p(
            "perception.landmark_model",
            choice::<LandmarkModelChoice>(),
            "BlazePose landmark model: `lite` and `full` are embedded; `heavy` is read from \
             `perception.heavy_weights`",
        ),
        p(
            "perception.heavy_weights",
            path(),
            "the converted heavy landmark model (`assets/perception/README.md`)",
        ),
        p(
            "perception.person_detector",
            choice::<PersonDetectorChoice>(),
            "which detector finds the person a camera starts following (one person; it runs \
             only while nobody is followed, then the landmarks' crop follows them): `movenet` \
             = MoveNet MultiPose at `perception.people_detector_side`, the person last \
             followed where they were, else the most prominent (largest box, then nearest \
             the centre); `blazepose` = BlazePose's own detector, for a person filling much \
             of the frame",
        ),
        p(
            "perception.min_detection_score",
            float_in(&PerceptionConfig::UNIT),
            "BlazePose detector score that starts tracking a person (`person_detector: \
             blazepose`)",
        ),
        p(
            "perception.min_presence",
            float_in(&PerceptionConfig::UNIT),
            "pose presence that keeps tracking a person (below it the detector runs again)",
        ),
        p(
            "perception.mask_threshold",
            float_in(&PerceptionConfig::UNIT),
            "person probability at the mask's edge",
        ),
        p(
            "perception.mask_feather",
            float_in(&PerceptionConfig::FEATHER),
            "half-width of the mask's soft edge, in probability",
        ),
        p(
            "perception.min_visibility",
            float_in(&PerceptionConfig::UNIT),
            "landmarks less visible than this keep their bones' last rotation, then ease \
             back to rest",
        ),
        p(
            "perception.threads",
            int_in(&PerceptionConfig::THREADS),
            "CPU threads of the perception networks (live: a worker of its own, newest frame \
             per camera wins)",
        ),
        p(
            "perception.people_detector_side",
            format!(
                "multiple of 32 in {}..={}",
                PerceptionConfig::DETECTOR_SIDE.start(),
                PerceptionConfig::DETECTOR_SIDE.end()
            ),
            "short side of MoveNet MultiPose's input (every frame with `tracking.enabled`; \
             one person: the frames in which nobody is followed; the long side follows the \
             frame's aspect): 256 finds people down to about a sixth of the frame's height, \
             larger sides smaller people at a higher cost per frame \
             (`assets/perception/README.md`)",
        ),
        p(
            "perception.estimate_shape",
            boolean(),
            "read the body height from calibrated views (perceived landmarks of two or more \
             cameras with CameraInfo and TF frames in `outputs.world_frame`, from `/tf` and \
             `/tf_static`) when no shape topic gives the shape; published in the avatar's \
             `shape_params`",
        ),
        p(
            "perception.colours_from_views",
            boolean(),
            "the Gaussians a perceived view shows take their colours from that frame (an affine \
             camera fitted to the landmarks, a point z-buffer, inside the person's mask), the \
             others the network's colours through the colour transform fitted to them",
        ),
        p(
            "perception.delight",
            choice::<Delight>(),
            "which views' colours have a key light divided out before they colour the avatar \
             (ambient plus one directional light, fitted to how brightness follows the posed \
             normals; every point then looks as it would facing the light): `calibrated` (the \
             calibrated views together), `always` (also each uncalibrated view alone), `never`",
        ),
        p(
            "outputs.dir",
            path(),
            "PLY avatars and PNG frames; empty disables",
        ),
        p(
            "outputs.keep_revisions",
            int(),
            "numbered revision files `avatar_<person>_rev<N>.ply` kept per person besides \
             the latest `avatar_<person>.ply` (always whole: written by rename); 0 keeps the \
             latest only",
        ),
        p(
            "outputs.max_disk_mb",
            "float ≥ 0".into(),
            "cap in megabytes on every avatar and frame file under `outputs.dir`, those of \
             earlier runs included: the oldest frames and numbered revisions go first, then the \
             oldest latest avatars, never the files just written; 0: no cap",
        ),
        p(
            "outputs.render_rate_hz",
            rate(),
            "rendered frames per second per virtual camera",
        ),
        p(
            "outputs.render_size",
            int_in(&OutputConfig::RENDER_SIZE),
            "rendered frame side",
        ),
        p(
            "outputs.virtual_cameras",
            int(),
            "cameras orbiting the person",
        ),
        p(
            "outputs.render_device",
            choice::<RenderDevice>(),
            "rasteriser of the rendered frames: `cpu`, or `cuda` (GPU 0, `cuda` build; a \
             frame that fails on the GPU is rendered on the CPU)",
        ),
        p(
            "outputs.renderer",
            choice::<RendererChoice>(),
            "how frames are made: `gaussians` splats the Gaussians' RGB; `neural` splats \
             their latent features (white background feature) at the size rounded up to the \
             DPT patch (7), decodes them with the network's neural renderer and crops to \
             `render_size`; `auto` = `neural` when the checkpoint's RGB is not \
             display-ready (preset `lhmpp-700m`, hub folders with `neural_renderer.type: \
             patch_4dptonly` and no `shape_head`: LHMPP-700M, LHMPPS-700M) and the renderer \
             reads the Gaussians' feature width, else `gaussians`. `neural` with mismatched \
             widths fails at startup",
        ),
        p(
            "outputs.frame_qos",
            choice::<FrameQos>(),
            "QoS of the rendered-frame topics, volatile keep last 2: `reliable` is matched \
             by reliable subscribers (RViz2's image display, rqt) and best-effort ones; a \
             full send window drops the frame after 5 ms instead of stalling; `best_effort` \
             is matched by best-effort subscribers only. Avatar and status are always \
             reliable + transient-local (keep last 1)",
        ),
        p(
            "outputs.preview_rate_hz",
            rate(),
            "rate of the avatar preview `avatar/points` (sensor_msgs/PointCloud2: x, y, z \
             and a packed `rgb` float32, the posed Gaussian centres at the latest BodyPose, \
             reliable + transient-local) and of its `/tf` transform; 0 disables both",
        ),
        p(
            "outputs.preview_frame",
            string(),
            "TF frame of the preview cloud",
        ),
        p(
            "outputs.world_frame",
            string(),
            "parent of `preview_frame` on `/tf` (identity: the points are posed in the \
             BodyPose's world coordinates)",
        ),
        p("outputs.ros", boolean(), "publish over ROS 2"),
        p("outputs.shm", boolean(), "publish over iceoryx2"),
        p(
            "outputs.masks",
            boolean(),
            "publish each perceived camera's person mask (mono8 sensor_msgs/Image, the \
             camera's stamp and frame) on `<camera namespace>/person_mask`",
        ),
        p(
            "outputs.camera_pose",
            boolean(),
            "publish the pose read from the cameras (lhmpp_msgs/BodyPose) on \
             `inputs.pose_topic`, for other nodes",
        ),
        p(
            "outputs.web",
            string(),
            "`host:port` of the live page (e.g. `127.0.0.1:8765`): one HTML page and a \
             WebSocket showing each person's avatar rendered in the browser (Spark), moved by \
             the pose stream, with their status; empty disables it. An address other than \
             loopback needs `lhmpp run --web-token TOKEN` (open the page with `?token=TOKEN`); \
             cross-origin WebSocket upgrades are refused",
        ),
        p(
            "replay.bag",
            path(),
            "MCAP bag played into the node instead of live topics",
        ),
        p(
            "replay.rate",
            rate(),
            "playback rate; 0 = as fast as consumed",
        ),
        p(
            "replay.exit_when_done",
            boolean(),
            "exit after the bag and the last reconstruction",
        ),
        p(
            "tracking.enabled",
            boolean(),
            "several people: every frame is split into persons (MoveNet MultiPose, then the \
             landmark model per person), each tracked person (`person_<n>`) gets its own frame \
             store, avatar (`person_id` in the message) and frames \
             (`render/<person_id>/cam<i>/image_raw`); needs `inputs.person_mask` `auto` or \
             `perception`. Off: one person, `person_id`",
        ),
        p(
            "tracking.forget_after",
            float_in(&TrackingSettings::FORGET_AFTER),
            "seconds a tracked person is kept without a sighting (their avatar is kept)",
        ),
        p(
            "tracking.max_persons",
            int_in(&TrackingSettings::MAX_PERSONS),
            "persons tracked at once; past it the least recently seen is dropped",
        ),
        p(
            "tracking.min_similarity",
            float_in(&PerceptionConfig::UNIT),
            "colour-histogram similarity from which a detection is a person seen in another \
             camera or before",
        ),
        p(
            "tracking.max_floor_gap",
            float_in(&TrackingSettings::FLOOR_GAP),
            "metres: in calibrated cameras (CameraInfo, TF in `outputs.world_frame`, floor at \
             y = 0), a person another camera saw within 0.3 s is the same person only within \
             this distance on the floor",
        ),
        p(
            "cluster.members",
            int_in(&ClusterConfig::MEMBERS),
            "nodes sharing the tracked persons (same cameras, same config); needs \
             `tracking.enabled`",
        ),
        p(
            "refine.enabled",
            boolean(),
            "fit each avatar to the calibrated views perception saw it in (camera info, tf \
             and a pose) after each network reconstruction, on the jobs lane, stopped by any \
             new view or job; a replay refines once at its end; an avatar that beats the \
             network's on a held-out view is published as a new revision",
        ),
        p(
            "refine.budget_ms",
            int_in(&RefineSettings::BUDGET_MS),
            "wall-clock milliseconds one fit may take (it stops earlier once a held-out view \
             stops improving)",
        ),
        p(
            "refine.max_gaussians",
            int_in(&RefineSettings::MAX_GAUSSIANS),
            "most Gaussians an avatar may grow to where its views ask for more than the body \
             template gives (skirts, coats, hair)",
        ),
        p(
            "refine.max_iterations",
            int_in(&RefineSettings::MAX_ITERATIONS),
            "most optimiser steps of one fit",
        ),
        p(
            "refine.max_side",
            int_in(&RefineSettings::MAX_SIDE),
            "longest side (pixels) each view is cropped to and fitted at",
        ),
        p(
            "cluster.index",
            int(),
            "this node's index below `cluster.members`: it reconstructs the persons whose id \
             hashes to it (FNV-1a) and tracks all of them, so ids agree between nodes",
        ),
    ]
}

/// The default of `key` as the table shows it: `` `value` ``, or `empty` for an empty string.
fn default_text(defaults: &serde_yaml_ng::Value, key: &str) -> String {
    let value = key
        .split('.')
        .try_fold(defaults, |v, part| v.get(part))
        .unwrap_or_else(|| panic!("parameter `{key}` is not a field of NodeConfig"));
    match value {
        serde_yaml_ng::Value::String(s) if s.is_empty() => "empty".into(),
        serde_yaml_ng::Value::String(s) => format!("`{s}`"),
        serde_yaml_ng::Value::Sequence(items) => {
            let items: Vec<String> = items.iter().map(scalar_text).collect();
            format!("`[{}]`", items.join(", "))
        }
        other => format!("`{}`", scalar_text(other)),
    }
}

fn scalar_text(value: &serde_yaml_ng::Value) -> String {
    match value {
        serde_yaml_ng::Value::String(s) => s.clone(),
        serde_yaml_ng::Value::Number(n) => match n.as_f64().filter(|_| n.is_f64()) {
            // An f32 field reads back as the f64 nearest it: show the f32 (`0.995`).
            Some(f) if f64::from(f as f32) == f => (f as f32).to_string(),
            Some(f) => f.to_string(),
            None => n.to_string(),
        },
        serde_yaml_ng::Value::Bool(b) => b.to_string(),
        other => serde_yaml_ng::to_string(other)
            .expect("config serialises")
            .trim()
            .to_string(),
    }
}

/// The defaults as the parameter file writes them.
fn defaults() -> serde_yaml_ng::Value {
    let text = NodeConfig::default().to_param_file();
    let file: serde_yaml_ng::Value = serde_yaml_ng::from_str(&text).expect("config parses");
    file[super::NODE_NAME]["ros__parameters"].clone()
}

/// docs/configuration.md's parameter table (Markdown, one line per parameter, ending in a newline).
pub fn markdown_table() -> String {
    let defaults = defaults();
    let mut out = String::from("| parameter | type (default) | meaning |\n| --- | --- | --- |\n");
    for p in parameters() {
        out.push_str(&format!(
            "| `{}` | {} ({}) | {} |\n",
            p.key,
            p.kind,
            default_text(&defaults, p.key),
            p.meaning
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The dotted keys of every leaf of the defaults.
    fn leaf_keys(value: &serde_yaml_ng::Value, prefix: &str, out: &mut Vec<String>) {
        match value.as_mapping() {
            Some(map) => {
                for (k, v) in map {
                    let k = k.as_str().expect("string keys");
                    let key = if prefix.is_empty() {
                        k.to_string()
                    } else {
                        format!("{prefix}.{k}")
                    };
                    leaf_keys(v, &key, out);
                }
            }
            None => out.push(prefix.to_string()),
        }
    }

    #[test]
    fn every_field_has_exactly_one_row() {
        let mut fields = Vec::new();
        leaf_keys(&defaults(), "", &mut fields);
        fields.sort();
        let mut rows: Vec<String> = parameters().iter().map(|p| p.key.to_string()).collect();
        rows.sort();
        assert_eq!(rows, fields);
    }

    #[test]
    fn rows_show_ranges_choices_and_defaults() {
        let table = markdown_table();
        for row in [
            "| `frame_store.max_views` | int in 1..=64 (`16`) |",
            "| `frame_store.duplicate_similarity` | float in 0..=1 (`0.995`) |",
            "| `inputs.image_qos` | `sensor_data`/`reliable` (`sensor_data`) |",
            "| `model.device` | `cpu`/`cuda`/`cuda:N` (`cpu`) |",
            "| `model.checkpoint` | path (empty) |",
            "| `inputs.image_topics` | string[] (`[/camera/image_raw]`) |",
            "| `replay.rate` | float ≥ 0 (`1`) |",
        ] {
            assert!(table.contains(row), "{row}\n{table}");
        }
        assert!(table.contains("`lhmpp-700m-smplx-free`"), "{table}");
    }
}
