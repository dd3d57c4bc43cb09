//! launch_configs/foxglove_layout.json is valid JSON whose panels name the topics and frames
//! the node publishes with its default parameters (input camera, rendered frames, preview
//! cloud coloured by its packed `rgb` field, status), so the layout does not drift.

use lhmpp::config::NodeConfig;
use lhmpp::node::ros::{ResolvedTopics, RosNodeOptions};
use std::collections::BTreeMap;

#[test]
fn the_foxglove_layout_shows_the_nodes_default_topics() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/launch_configs/foxglove_layout.json"
    );
    let layout: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(path).unwrap()).expect("valid JSON");
    let cfg = NodeConfig::default();
    let topics = ResolvedTopics::from_options(
        &RosNodeOptions::from_config(&cfg, BTreeMap::new(), None).unwrap(),
    )
    .unwrap();
    let panels = &layout["configById"];
    assert_eq!(
        panels["Image!input"]["imageMode"]["imageTopic"],
        topics.images[0].as_str()
    );
    assert_eq!(
        panels["Image!render"]["imageMode"]["imageTopic"],
        topics.frames[0].as_str()
    );
    let cloud = &panels["3D!avatar"]["topics"][topics.preview.as_str()];
    assert_eq!(cloud["visible"], true, "{cloud}");
    assert_eq!(cloud["colorField"], "rgb");
    assert_eq!(cloud["colorMode"], "rgb");
    assert_eq!(
        panels["3D!avatar"]["followTf"],
        cfg.outputs.preview_frame.as_str()
    );
    assert_eq!(
        panels["3D!avatar"]["layers"]["grid"]["frameId"],
        cfg.outputs.world_frame.as_str()
    );
    assert_eq!(
        panels["RawMessages!status"]["topicPath"],
        topics.status.as_str()
    );
    // Every panel in the mosaic has a config.
    fn leaves(v: &serde_json::Value, out: &mut Vec<String>) {
        match v {
            serde_json::Value::String(s) => out.push(s.clone()),
            serde_json::Value::Object(m) => {
                for k in ["first", "second"] {
                    if let Some(c) = m.get(k) {
                        leaves(c, out);
                    }
                }
            }
            _ => {}
        }
    }
    let mut ids = Vec::new();
    leaves(&layout["layout"], &mut ids);
    assert_eq!(ids.len(), 4, "{ids:?}");
    for id in ids {
        assert!(panels.get(&id).is_some(), "panel {id} has no config");
    }
}
