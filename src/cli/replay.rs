//! `lhmpp replay BAG`: run the node on a bag (shorthand for `run` with `replay.bag` set).
//! Without `--config` (and without `--set inputs.*`), the cameras are the bag's own.

use super::config_source::ConfigSource;
use anyhow::Result;
use lhmpp::bag::BagStream;
use std::path::PathBuf;

/// Arguments of `lhmpp replay`.
#[derive(clap::Args, Debug)]
pub struct ReplayArgs {
    /// MCAP bag (file or rosbag2 directory) to play into the node.
    bag: PathBuf,
    /// Playback rate relative to the recording (1 = real time).
    #[arg(long, default_value_t = 1.0, conflicts_with = "fast")]
    rate: f64,
    /// Play as fast as the node consumes the messages (no pacing, nothing dropped).
    #[arg(long)]
    fast: bool,
    /// Everything else (topics, model, outputs). Without `--config` or `--set inputs.*`, the
    /// inputs are the bag's cameras: its Image / CompressedImage topics (not masks, held-out
    /// or ground-truth views, not rendered frames), with their `camera_info` and `mask`
    /// siblings when every camera has one, and `/lhmpp/body_shape` when recorded.
    #[command(flatten)]
    pub source: ConfigSource,
}

/// Runs the node on the bag and prints the run summary.
pub fn run(args: ReplayArgs) -> Result<()> {
    let mut source = args.source;
    let chooses_inputs =
        source.config.is_some() || source.overrides.iter().any(|o| o.starts_with("inputs."));
    if !chooses_inputs {
        let topics = BagStream::open(&args.bag)?.summary_topics();
        let inputs = inputs_from_topics(&topics);
        if inputs.is_empty() {
            tracing::warn!(
                bag = %args.bag.display(),
                "the bag lists no camera topics; replaying with the default inputs"
            );
        } else {
            tracing::info!(?inputs, "inputs from the bag's topics");
        }
        source.overrides.splice(0..0, inputs);
    }
    let overrides = &mut source.overrides;
    overrides.push(format!("replay.bag={}", args.bag.display()));
    overrides.push(format!(
        "replay.rate={}",
        if args.fast { 0.0 } else { args.rate }
    ));
    overrides.push("replay.exit_when_done=true".into());
    super::run::run(super::run::RunArgs {
        source,
        remaps: Vec::new(),
        web_token: None,
    })
}

const IMAGE: &str = "sensor_msgs/msg/Image";
const COMPRESSED: &str = "sensor_msgs/msg/CompressedImage";

/// `--set` overrides naming a bag's cameras as the node's inputs, from its (topic, type) list.
fn inputs_from_topics(topics: &[(String, String)]) -> Vec<String> {
    let has =
        |topic: &str, type_name: &str| topics.iter().any(|(t, ty)| t == topic && ty == type_name);
    let is_camera = |topic: &str| {
        let mut parts = topic.trim_start_matches('/').split('/');
        let first = parts.next().unwrap_or("");
        let last = topic.rsplit('/').next().unwrap_or("");
        !(first.starts_with("heldout")
            || first == "truth"
            || first == "render"
            || last.ends_with("mask"))
    };
    let cameras = |type_name: &str| -> Vec<&str> {
        topics
            .iter()
            .filter(|(t, ty)| ty == type_name && is_camera(t))
            .map(|(t, _)| t.as_str())
            .collect()
    };
    let (raw, compressed) = (cameras(IMAGE), cameras(COMPRESSED));
    if raw.is_empty() && compressed.is_empty() {
        return Vec::new();
    }
    let list = |items: &[String]| format!("[{}]", items.join(","));
    let owned = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    let sibling = |camera: &str, name: &str| match camera.rsplit_once('/') {
        Some((ns, _)) => format!("{ns}/{name}"),
        None => name.to_owned(),
    };
    let all: Vec<&str> = raw.iter().chain(&compressed).copied().collect();
    let mut out = vec![
        format!("inputs.image_topics={}", list(&owned(&raw))),
        format!(
            "inputs.compressed_image_topics={}",
            list(&owned(&compressed))
        ),
    ];
    let infos: Vec<String> = all.iter().map(|c| sibling(c, "camera_info")).collect();
    if infos.iter().all(|t| has(t, "sensor_msgs/msg/CameraInfo")) {
        out.push(format!("inputs.camera_info_topics={}", list(&infos)));
    }
    let masks: Vec<String> = all.iter().map(|c| sibling(c, "mask")).collect();
    if masks.iter().all(|t| has(t, IMAGE)) {
        out.push(format!("inputs.mask_topics={}", list(&masks)));
    }
    if has("/lhmpp/body_shape", "lhmpp_msgs/msg/BodyShape") {
        out.push("inputs.shape_topic=/lhmpp/body_shape".into());
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn topics(list: &[(&str, &str)]) -> Vec<(String, String)> {
        list.iter()
            .map(|(t, ty)| (t.to_string(), ty.to_string()))
            .collect()
    }

    #[test]
    fn a_synthetic_bag_gives_its_input_cameras_with_their_info_and_masks() {
        let t = topics(&[
            ("/cam0/image_raw", IMAGE),
            ("/cam0/camera_info", "sensor_msgs/msg/CameraInfo"),
            ("/cam0/mask", IMAGE),
            ("/cam1/image_raw", IMAGE),
            ("/cam1/camera_info", "sensor_msgs/msg/CameraInfo"),
            ("/cam1/mask", IMAGE),
            ("/heldout0/image_raw", IMAGE),
            ("/render/cam0/image_raw", IMAGE),
            ("/lhmpp/body_shape", "lhmpp_msgs/msg/BodyShape"),
        ]);
        assert_eq!(
            inputs_from_topics(&t),
            [
                "inputs.image_topics=[/cam0/image_raw,/cam1/image_raw]",
                "inputs.compressed_image_topics=[]",
                "inputs.camera_info_topics=[/cam0/camera_info,/cam1/camera_info]",
                "inputs.mask_topics=[/cam0/mask,/cam1/mask]",
                "inputs.shape_topic=/lhmpp/body_shape",
            ]
        );
    }

    #[test]
    fn siblings_are_used_only_when_every_camera_has_one() {
        let t = topics(&[
            ("/a/image_raw", IMAGE),
            ("/a/camera_info", "sensor_msgs/msg/CameraInfo"),
            ("/b/image/compressed", COMPRESSED),
        ]);
        assert_eq!(
            inputs_from_topics(&t),
            [
                "inputs.image_topics=[/a/image_raw]",
                "inputs.compressed_image_topics=[/b/image/compressed]",
            ]
        );
        assert!(inputs_from_topics(&topics(&[("/tf", "tf2_msgs/msg/TFMessage")])).is_empty());
    }
}
