//! Loading and running the converted BlazePose graphs: malformed files and graphs fail with
//! errors that name the file and the op or tensor; runs from several threads agree.

use std::collections::HashMap;
use std::path::Path;

use lhmpp::perception::network::{GraphDef, Network};
use lhmpp::perception::weights::{self, LandmarkModel};
use lhmpp::perception::PerceptionError;
use safetensors::SafeTensors;

/// The embedded lite model re-serialised with `edit` applied to its metadata.
fn with_metadata(edit: impl FnOnce(&mut HashMap<String, String>)) -> Vec<u8> {
    let bytes = weights::POSE_LANDMARK_LITE;
    let (_, meta) = SafeTensors::read_metadata(bytes).unwrap();
    let mut meta = meta.metadata().clone().unwrap();
    edit(&mut meta);
    let st = SafeTensors::deserialize(bytes).unwrap();
    safetensors::serialize(st.tensors(), Some(meta)).unwrap()
}

fn load_error(bytes: &[u8], edit: impl FnOnce(&mut GraphDef)) -> String {
    Network::from_bytes_edited(bytes, "lite.safetensors", edit)
        .unwrap_err()
        .to_string()
}

#[test]
fn a_newer_format_version_is_refused() {
    let bytes = with_metadata(|m| {
        m.insert("format_version".into(), "2".into());
    });
    let err = Network::from_bytes(&bytes, "lite.safetensors")
        .unwrap_err()
        .to_string();
    assert!(
        err.starts_with("lite.safetensors: format version 2"),
        "{err}"
    );
    let bytes = with_metadata(|m| {
        m.remove("graph");
    });
    let err = Network::from_bytes(&bytes, "lite.safetensors")
        .unwrap_err()
        .to_string();
    assert!(err.contains("`graph` is missing"), "{err}");
    let err = Network::from_bytes(b"not a file", "x.safetensors")
        .unwrap_err()
        .to_string();
    assert!(
        err.starts_with("x.safetensors: not a safetensors file"),
        "{err}"
    );
}

#[test]
fn graph_mistakes_name_the_op_and_tensor() {
    let lite = weights::POSE_LANDMARK_LITE;
    // an output shape the op does not compute
    let err = load_error(lite, |g| {
        let out = g.ops[1].outputs[0].clone();
        g.tensors.get_mut(&out).unwrap()[3] += 1;
    });
    assert!(
        err.contains("op 1 (CONV_2D)") && err.contains("is declared"),
        "{err}"
    );
    // an op type the runtime does not have
    let err = load_error(lite, |g| g.ops[3].op_type = "SOFTMAX".into());
    assert!(
        err.contains("op 3 (SOFTMAX): op type SOFTMAX is not supported"),
        "{err}"
    );
    // a weight the file does not hold
    let err = load_error(lite, |g| {
        let w = g.ops[1].inputs[1].clone();
        g.ops[1].inputs[1] = format!("{w}-missing");
    });
    assert!(
        err.contains("op 1 (CONV_2D): weight `") && err.contains("-missing`"),
        "{err}"
    );
    // an activation read before it is written
    let err = load_error(lite, |g| g.ops.swap(1, 2));
    assert!(err.contains("is read before any op writes it"), "{err}");
    // an unsupported option value
    let err = load_error(lite, |g| {
        g.ops[1].options.insert("activation".into(), "TANH".into());
    });
    assert!(err.contains("op 1 (CONV_2D): fused activation"), "{err}");
    // a weight whose stored shape disagrees with the graph (the file's own metadata)
    let bytes = with_metadata(|m| {
        let mut g: serde_json::Value = serde_json::from_str(&m["graph"]).unwrap();
        let w = g["ops"][1]["inputs"][1].as_str().unwrap().to_string();
        g["weights"][&w]["shape"][0] = 25.into();
        m.insert("graph".into(), g.to_string());
    });
    let err = Network::from_bytes(&bytes, "lite.safetensors")
        .unwrap_err()
        .to_string();
    assert!(
        err.starts_with("lite.safetensors: weight `") && err.contains("the graph says [25"),
        "{err}"
    );
}

#[test]
fn inputs_of_the_wrong_size_are_errors() {
    let net = weights::pose_detector().unwrap();
    assert_eq!(net.input_shape(), [1, 224, 224, 3]);
    let err = net.run(&[0.0; 10]).unwrap_err();
    assert!(matches!(err, PerceptionError::Input { .. }), "{err}");
}

#[test]
fn the_heavy_model_without_weights_names_the_command() {
    let err = LandmarkModel::Heavy
        .load(Some(Path::new("/nonexistent/heavy.safetensors")))
        .unwrap_err()
        .to_string();
    assert!(err.contains("/nonexistent/heavy.safetensors"), "{err}");
    assert!(err.contains("scripts/perception/convert.py"), "{err}");
}

#[test]
fn concurrent_runs_agree_with_a_single_run() {
    let net = LandmarkModel::Lite.load(None).unwrap();
    let n: usize = net.input_shape().iter().product();
    let inputs: Vec<Vec<f32>> = (0..3)
        .map(|s| {
            (0..n)
                .map(|i| ((i * 31 + s * 7) % 255) as f32 / 255.0)
                .collect()
        })
        .collect();
    let single: Vec<_> = inputs.iter().map(|x| net.run(x).unwrap()).collect();
    std::thread::scope(|scope| {
        let handles: Vec<_> = inputs
            .iter()
            .map(|x| scope.spawn(|| net.run(x).unwrap()))
            .collect();
        for (h, want) in handles.into_iter().zip(&single) {
            assert_eq!(&h.join().unwrap(), want);
        }
    });
    assert_ne!(single[0], single[1]);
}
