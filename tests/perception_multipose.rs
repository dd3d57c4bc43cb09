//! Parity of MoveNet MultiPose Lightning on our CPU kernels and our decoding with TF.js's
//! pure-JS CPU backend (`@tensorflow/tfjs` 4.22.0 in node,
//! `scripts/perception/reference_movenet.mjs`): `tests/fixtures/perception/movenet_*.safetensors`
//! hold a letterboxed real photo (Pose2Sim and Sports2D demo frames, BSD-3-Clause, see the
//! NOTICE there) and what TF.js computed for it: the final `[1, 6, 56]` output (`Identity`) and
//! the head maps. Every output must agree within 1e-4 relative
//! (`max |ours − TF.js| / max |TF.js|`); planted mistakes, in the network and in the decoding's
//! inputs, must break it.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use lhmpp::perception::multipose::{self, decode, heads, MultiPoseDetector, PERSON_VALUES};
use lhmpp::perception::network::Network;
use lhmpp::perception::weights;
use safetensors::{Dtype, SafeTensors};

/// The largest relative difference parity allows.
const TOLERANCE: f32 = 1e-4;

/// A fixture: input pixels, input size, and TF.js's outputs by name.
struct Fixture {
    pixels: Vec<u8>,
    height: usize,
    width: usize,
    outputs: HashMap<String, (Vec<usize>, Vec<f32>)>,
}

fn fixture_path(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/perception")
        .join(name)
}

fn read_fixture(name: &str) -> Fixture {
    let path = fixture_path(name);
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let st = SafeTensors::deserialize(&bytes).unwrap();
    let input = st.tensor("input").unwrap();
    assert_eq!(input.dtype(), Dtype::U8);
    let shape = input.shape().to_vec();
    assert!(
        shape.len() == 4 && shape[0] == 1 && shape[3] == 3,
        "{shape:?}"
    );
    let mut outputs = HashMap::new();
    for (name, view) in st.tensors() {
        if name == "input" {
            continue;
        }
        assert_eq!(view.dtype(), Dtype::F32, "{name}");
        let data: Vec<f32> = view
            .data()
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        outputs.insert(name, (view.shape().to_vec(), data));
    }
    Fixture {
        pixels: input.data().to_vec(),
        height: shape[1],
        width: shape[2],
        outputs,
    }
}

/// `max |a − b| / max |b|`.
fn relative(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    let scale = b
        .iter()
        .fold(0f32, |m, v| m.max(v.abs()))
        .max(f32::MIN_POSITIVE);
    a.iter().zip(b).fold(0f32, |m, (x, y)| m.max((x - y).abs())) / scale
}

/// Per output of the fixture: its name and our relative difference (heads the fixture holds,
/// then `Identity`).
fn differences(det: &MultiPoseDetector, fx: &Fixture) -> Vec<(String, f32)> {
    let heads_out = det.heads(&fx.pixels).unwrap();
    let mut diffs = Vec::new();
    for name in heads::ALL {
        if let Some((shape, want)) = fx.outputs.get(name) {
            let got = heads_out.tensor(name).unwrap();
            assert_eq!(&got.shape, shape, "{name}");
            diffs.push((name.to_string(), relative(&got.data, want)));
        }
    }
    let (shape, want) = &fx.outputs["Identity"];
    assert_eq!(shape, &[1, multipose::MAX_PEOPLE, PERSON_VALUES]);
    let got = decode(&heads_out, fx.height, fx.width).unwrap();
    diffs.push(("Identity".into(), relative(&got, want)));
    // the same through the public entry point
    assert_eq!(det.run(&fx.pixels).unwrap(), got);
    diffs
}

fn check(name: &str) {
    let fx = read_fixture(name);
    let det = MultiPoseDetector::embedded_sized(fx.height, fx.width).unwrap();
    assert_eq!(det.input_size(), (fx.height, fx.width));
    for (output, diff) in differences(&det, &fx) {
        println!("{name}: {output}: max relative difference {diff:.3e}");
        assert!(
            diff <= TOLERANCE,
            "{name}: {output} differs from TF.js by {diff:.3e} relative (allowed {TOLERANCE:e})"
        );
    }
}

/// The native 256×256 input: every head map and the final output.
#[test]
fn multipose_256_matches_tfjs() {
    check("movenet_multipose_256.safetensors");
}

/// A 256×448 input (the graph re-derived for another, non-square size; a 16:9 frame): the
/// centre heatmap and the final output.
#[test]
fn multipose_256x448_matches_tfjs() {
    check("movenet_multipose_256x448.safetensors");
}

/// Planted mistakes must break parity: a ReLU dropped in the FPN's last layer (network), and
/// the box-offset head zeroed before decoding (decoding inputs).
#[test]
fn planted_mistakes_break_parity() {
    let fx = read_fixture("movenet_multipose_256.safetensors");
    let net = Network::from_bytes_edited(weights::MOVENET_MULTIPOSE, "planted", |g| {
        let op = g
            .ops
            .iter_mut()
            .find(|o| o.outputs[0].ends_with("re_lu_2/Relu"))
            .expect("the FPN's last layer");
        assert_eq!(op.options["activation"], "RELU");
        op.options["activation"] = "NONE".into();
    })
    .unwrap();
    let det = MultiPoseDetector::from_network(net).unwrap();
    let diffs = differences(&det, &fx);
    println!("planted activation: {diffs:?}");
    for (output, diff) in &diffs {
        assert!(*diff > TOLERANCE, "{output} still matches: {diff:e}");
    }

    let det = MultiPoseDetector::embedded(256).unwrap();
    let mut out = det.heads(&fx.pixels).unwrap();
    let t = out
        .tensors
        .iter_mut()
        .find(|t| t.name == heads::BOX_OFFSET)
        .unwrap();
    t.data.iter_mut().for_each(|v| *v = 0.0);
    let got = decode(&out, 256, 256).unwrap();
    let diff = relative(&got, &fx.outputs["Identity"].1);
    println!("planted zero box offsets: Identity {diff:.3e}");
    assert!(diff > TOLERANCE, "Identity still matches: {diff:e}");
}

/// Wrong input sides and wrong pixel counts are refused, naming the model.
#[test]
fn bad_sizes_are_refused() {
    let err = MultiPoseDetector::embedded(250).unwrap_err().to_string();
    assert!(
        err.contains("multiple of 32") && err.contains("movenet"),
        "{err}"
    );
    // the graph itself refuses a side its FPN cannot add up (250 → 125 → 63 → 32 → 16 → 8,
    // upsampled 8 → 16 → 32 → 64 ≠ 63)
    let err = Network::from_bytes_resized(weights::MOVENET_MULTIPOSE, "movenet", 250, 250)
        .unwrap_err()
        .to_string();
    assert!(err.contains("250×250") && err.contains("ADD"), "{err}");
    let net = Network::from_bytes_resized(weights::MOVENET_MULTIPOSE, "movenet", 320, 224).unwrap();
    assert_eq!(net.input_shape(), [1, 320, 224, 3]);
    let det = MultiPoseDetector::embedded(256).unwrap();
    let err = det.run(&[0; 10]).unwrap_err().to_string();
    assert!(err.contains("196608"), "{err}");
    let err = MultiPoseDetector::embedded_sized(256, 100)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("multiple of 32") && err.contains("100"),
        "{err}"
    );
    let err = MultiPoseDetector::load(Path::new("/nonexistent/movenet.safetensors"), 256, 256)
        .unwrap_err()
        .to_string();
    assert!(err.contains("/nonexistent/movenet.safetensors"), "{err}");
}

/// `detect` letterboxes the frame and maps people back into frame pixels: a 512×512 frame made
/// of the 256 fixture's pixels doubled gives the network exactly the fixture's input (the
/// letterbox samples every second pixel), so its people are TF.js's, scaled by 512.
#[test]
fn detect_maps_people_into_the_frame() {
    let fx = read_fixture("movenet_multipose_256.safetensors");
    let frame = image::RgbImage::from_fn(512, 512, |x, y| {
        let at = ((y / 2) as usize * 256 + (x / 2) as usize) * 3;
        image::Rgb([fx.pixels[at], fx.pixels[at + 1], fx.pixels[at + 2]])
    });
    let det = MultiPoseDetector::embedded(256).unwrap();
    let people = det.detect(&frame, 0.1).unwrap();
    let want = &fx.outputs["Identity"].1;
    let mut rows: Vec<&[f32]> = want
        .chunks_exact(PERSON_VALUES)
        .filter(|p| p[PERSON_VALUES - 1] >= 0.1)
        .collect();
    rows.sort_by(|a, b| b[PERSON_VALUES - 1].total_cmp(&a[PERSON_VALUES - 1]));
    assert!(rows.len() >= 2, "the fixture shows two people");
    assert_eq!(people.len(), rows.len());
    let close = |a: f32, b: f32| (a - b).abs() < 0.05;
    for (p, r) in people.iter().zip(rows) {
        assert!(close(p.score, r[PERSON_VALUES - 1]), "{p:?}");
        let b = &r[3 * multipose::KEYPOINTS..];
        assert!(
            close(p.min.y, b[0] * 512.0) && close(p.min.x, b[1] * 512.0),
            "{p:?}"
        );
        assert!(
            close(p.max.y, b[2] * 512.0) && close(p.max.x, b[3] * 512.0),
            "{p:?}"
        );
        for (k, kp) in p.keypoints.iter().enumerate() {
            assert!(close(kp.position.y, r[3 * k] * 512.0), "{k}: {kp:?}");
            assert!(close(kp.position.x, r[3 * k + 1] * 512.0), "{k}: {kp:?}");
            assert!((kp.score - r[3 * k + 2]).abs() < 1e-4, "{k}: {kp:?}");
        }
    }
}

/// The same for a non-square input: a 448×256 frame holding the 256×448 fixture's pixels is
/// the input itself (no bars), so its people are TF.js's scaled by 448 across and 256 down.
#[test]
fn detect_maps_people_of_a_wide_input() {
    let fx = read_fixture("movenet_multipose_256x448.safetensors");
    let (h, w) = (fx.height as u32, fx.width as u32);
    let frame = image::RgbImage::from_fn(w, h, |x, y| {
        let at = (y * w + x) as usize * 3;
        image::Rgb([fx.pixels[at], fx.pixels[at + 1], fx.pixels[at + 2]])
    });
    let det = MultiPoseDetector::embedded_sized(fx.height, fx.width).unwrap();
    let rect = det.letterbox(w, h);
    assert_eq!(rect.size, glam::Vec2::new(w as f32, h as f32));
    let people = det.detect(&frame, 0.3).unwrap();
    let want = &fx.outputs["Identity"].1;
    let best = want
        .chunks_exact(PERSON_VALUES)
        .max_by(|a, b| a[PERSON_VALUES - 1].total_cmp(&b[PERSON_VALUES - 1]))
        .unwrap();
    assert_eq!(people.len(), 1, "{people:?}");
    let p = &people[0];
    let (sx, sy) = (w as f32, h as f32);
    let close = |a: f32, b: f32| (a - b).abs() < 0.05;
    assert!((p.score - best[PERSON_VALUES - 1]).abs() < 1e-4, "{p:?}");
    let b = &best[3 * multipose::KEYPOINTS..];
    assert!(
        close(p.min.y, b[0] * sy) && close(p.min.x, b[1] * sx),
        "{p:?}"
    );
    assert!(
        close(p.max.y, b[2] * sy) && close(p.max.x, b[3] * sx),
        "{p:?}"
    );
    for (k, kp) in p.keypoints.iter().enumerate() {
        assert!(close(kp.position.y, best[3 * k] * sy), "{k}: {kp:?}");
        assert!(close(kp.position.x, best[3 * k + 1] * sx), "{k}: {kp:?}");
    }
    // a 9:16 portrait frame gets bars left and right
    let rect = det.letterbox(720, 1280);
    assert_eq!(rect.size, glam::Vec2::new(1280.0 * 448.0 / 256.0, 1280.0));
}
