//! Value checks that the types cannot express: ranges (the constants next to the fields),
//! non-empty names, and settings that depend on each other or on the build.

use super::{
    Choice, ClusterConfig, ConfigError, FrameStoreConfig, InputConfig, LandmarkModelChoice,
    ModelConfig, NodeConfig, OutputConfig, PerceptionConfig, PersonMask, RenderDevice,
    TrackingSettings, RATE_RANGE,
};
use std::fmt::Display;
use std::ops::RangeInclusive;
use std::path::Path;

/// `Err(message)` when `value` is outside `range`.
fn in_range<T: PartialOrd + Display>(value: T, range: &RangeInclusive<T>) -> Result<(), String> {
    if range.contains(&value) {
        Ok(())
    } else {
        Err(format!(
            "{value} is not in {}..={}",
            range.start(),
            range.end()
        ))
    }
}

/// `Err(message)` when a rate is not finite or below [`RATE_RANGE`].
fn rate(value: f64) -> Result<(), String> {
    if value.is_finite() && RATE_RANGE.contains(&value) {
        Ok(())
    } else {
        Err(format!(
            "{value} must be finite and >= {}",
            RATE_RANGE.start
        ))
    }
}

impl NodeConfig {
    /// Checks value ranges; the error names the offending key.
    pub fn validate(&self, origin: &Path) -> Result<(), ConfigError> {
        let bad = |key: &str, message: String| ConfigError::Invalid {
            path: origin.to_path_buf(),
            key: key.into(),
            message,
        };
        let check = |key: &str, result: Result<(), String>| result.map_err(|m| bad(key, m));
        check("domain_id", in_range(self.domain_id, &Self::DOMAIN_ID))?;
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
        check(
            "inputs.max_image_side",
            in_range(self.inputs.max_image_side, &InputConfig::MAX_IMAGE_SIDE),
        )?;
        check("inputs.max_rate_hz", rate(self.inputs.max_rate_hz))?;
        let store = &self.frame_store;
        check(
            "frame_store.max_views",
            in_range(store.max_views, &FrameStoreConfig::MAX_VIEWS),
        )?;
        check(
            "frame_store.duplicate_similarity",
            in_range(
                store.duplicate_similarity,
                &FrameStoreConfig::DUPLICATE_SIMILARITY,
            ),
        )?;
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
        check(
            "model.num_points",
            in_range(self.model.num_points, &ModelConfig::NUM_POINTS),
        )?;
        check(
            "model.max_views",
            in_range(self.model.max_views, &ModelConfig::MAX_VIEWS),
        )?;
        if !self.model.smplx_model.is_empty() && self.model.prior_dir.is_empty() {
            return Err(bad(
                "model.smplx_model",
                "is only used with model.prior_dir (the official LHMPP-Prior body)".to_string(),
            ));
        }
        let perception = &self.perception;
        for (key, value) in [
            (
                "perception.min_detection_score",
                perception.min_detection_score,
            ),
            ("perception.min_presence", perception.min_presence),
            ("perception.mask_threshold", perception.mask_threshold),
            ("perception.min_visibility", perception.min_visibility),
        ] {
            check(key, in_range(value, &PerceptionConfig::UNIT))?;
        }
        check(
            "perception.mask_feather",
            in_range(perception.mask_feather, &PerceptionConfig::FEATHER),
        )?;
        check(
            "perception.threads",
            in_range(perception.threads, &PerceptionConfig::THREADS),
        )?;
        check(
            "perception.people_detector_side",
            in_range(
                perception.people_detector_side,
                &PerceptionConfig::DETECTOR_SIDE,
            ),
        )?;
        let multiple = crate::perception::multipose::SIDE_MULTIPLE;
        if perception.people_detector_side % multiple != 0 {
            return Err(bad(
                "perception.people_detector_side",
                format!(
                    "{} is not a multiple of {multiple} (the detector's stride)",
                    perception.people_detector_side
                ),
            ));
        }
        if perception.landmark_model == LandmarkModelChoice::Heavy
            && perception.heavy_weights.is_empty()
        {
            return Err(bad(
                "perception.heavy_weights",
                "landmark_model `heavy` needs the converted heavy model, which is not embedded: \
                 make it as assets/perception/README.md says (scripts/perception/setup, then \
                 convert.py into target/perception/pose_landmark_heavy.safetensors) and set \
                 perception.heavy_weights to that file"
                    .to_string(),
            ));
        }
        let out = &self.outputs;
        if !(out.max_disk_mb.is_finite() && out.max_disk_mb >= 0.0) {
            return Err(bad(
                "outputs.max_disk_mb",
                format!("{} must be finite and >= 0 (0: no cap)", out.max_disk_mb),
            ));
        }
        check("outputs.render_rate_hz", rate(out.render_rate_hz))?;
        check(
            "outputs.render_size",
            in_range(out.render_size, &OutputConfig::RENDER_SIZE),
        )?;
        check("outputs.preview_rate_hz", rate(out.preview_rate_hz))?;
        for (key, frame) in [
            ("outputs.preview_frame", &out.preview_frame),
            ("outputs.world_frame", &out.world_frame),
        ] {
            if frame.trim().is_empty() || frame.contains(char::is_whitespace) {
                return Err(bad(key, format!("`{frame}` is not a TF frame name")));
            }
        }
        if out.preview_frame == out.world_frame {
            return Err(bad(
                "outputs.preview_frame",
                format!(
                    "`{}` is also outputs.world_frame; the preview needs a frame of its own",
                    out.preview_frame
                ),
            ));
        }
        if !out.web.is_empty() && out.web.parse::<std::net::SocketAddr>().is_err() {
            return Err(bad(
                "outputs.web",
                format!(
                    "`{}` is not a host:port address (e.g. 127.0.0.1:8765, or empty to disable \
                     the live page)",
                    out.web
                ),
            ));
        }
        if out.render_device == RenderDevice::Cuda && !cfg!(feature = "cuda") {
            return Err(bad(
                "outputs.render_device",
                "`cuda` needs a binary built with the `cuda` feature (scripts/build-cuda)"
                    .to_string(),
            ));
        }
        check("replay.rate", rate(self.replay.rate))?;
        self.validate_people(&bad)
    }

    /// The `tracking` and `cluster` sections.
    fn validate_people(
        &self,
        bad: &dyn Fn(&str, String) -> ConfigError,
    ) -> Result<(), ConfigError> {
        let check = |key: &str, r: Result<(), String>| r.map_err(|m| bad(key, m));
        let t = &self.tracking;
        if !t.forget_after.is_finite() {
            return Err(bad("tracking.forget_after", "must be finite".into()));
        }
        check(
            "tracking.forget_after",
            in_range(t.forget_after, &TrackingSettings::FORGET_AFTER),
        )?;
        check(
            "tracking.max_persons",
            in_range(t.max_persons, &TrackingSettings::MAX_PERSONS),
        )?;
        check(
            "tracking.min_similarity",
            in_range(t.min_similarity, &PerceptionConfig::UNIT),
        )?;
        check(
            "tracking.max_floor_gap",
            in_range(t.max_floor_gap, &TrackingSettings::FLOOR_GAP),
        )?;
        if t.enabled && matches!(self.inputs.person_mask, PersonMask::Off | PersonMask::Topic) {
            return Err(bad(
                "tracking.enabled",
                format!(
                    "tracked persons are cut out by perception's masks, but inputs.person_mask                      is `{}`: set it to `auto` or `perception`",
                    self.inputs.person_mask.as_str()
                ),
            ));
        }
        let c = &self.cluster;
        check(
            "cluster.members",
            in_range(c.members, &ClusterConfig::MEMBERS),
        )?;
        if c.index >= c.members {
            return Err(bad(
                "cluster.index",
                format!("{} is not below cluster.members ({})", c.index, c.members),
            ));
        }
        if c.members > 1 && !t.enabled {
            return Err(bad(
                "cluster.members",
                "nodes share tracked persons: set tracking.enabled to true".into(),
            ));
        }
        Ok(())
    }
}
