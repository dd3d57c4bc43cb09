//! The bad-input matrix: every kind of bad input the node can be given, each
//! with a clear error naming the input, while the node goes on serving everything else.
//!
//! - Messages: one replayed bag carries every bad message on every subscribed topic (raw and
//!   compressed images, camera infos, per-camera and shared masks, poses, shapes) ahead of four
//!   good views, one of them PNG-compressed. Each bad message is rejected once, by reason, with
//!   a warning naming its topic and the numbers; the good views still make an avatar.
//! - Files and config, as runs of the built binary: broken checkpoints, a missing or corrupt
//!   body prior, config files and overrides with unknown keys or invalid values. Each exits 1
//!   with one `Error:` line naming the file or key.
//! - Output directories: one under a regular file, a read-only one and a full one (tiny tmpfs
//!   mounts, where `mount` is allowed): an error naming the directory or file, exit 0, and the
//!   avatars still go to the publishers (the ROS 2 and shared-memory outputs).
//!
//! The rows of RELIABILITY.md's "bad-input matrix" quote what these tests print
//! (`cargo test --release --test bad_input_matrix -- --nocapture`).

mod bag_support;
mod load_support;

use lhmpp::bag::{BagReader, BagWriter};
use lhmpp::config::NodeConfig;
use lhmpp::msgs::{
    BodyPose, BodyShape, CameraInfo, CompressedImage, Header, Image, Quaternion,
    ReconstructionStatus, RosMessage, Transform,
};
use lhmpp::node::outputs::{AvatarUpdate, Publisher};
use lhmpp::node::pipeline::{Pipeline, RenderedFrame};
use lhmpp::node::replay::BagReplay;
use lhmpp::node::ros::{ResolvedTopics, RosNodeOptions};
use lhmpp::synth::capture::{
    image_topic, info_topic, mask_topic, POSE_TOPIC, SHAPE_TOPIC, START_NS,
};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// Raw image cameras; camera `RAW_VIEWS` is the compressed one.
const RAW_VIEWS: usize = 3;
/// The compressed camera's topic.
const COMPRESSED: &str = "/cam3/image_raw/compressed";
/// A shared mask topic that carries only bad messages.
const SHARED_MASK: &str = "/person_mask";

/// One planted bad message and what its rejection must say.
struct Bad {
    case: &'static str,
    topic: String,
    type_name: &'static str,
    data: Vec<u8>,
    reason: &'static str,
    /// Text the rejection's log line must hold (the numbers, the field, the type).
    needle: String,
}

fn cam(i: usize) -> String {
    format!("cam{i}")
}

fn image(width: u32, height: u32, encoding: &str, step: u32, data: Vec<u8>) -> Image {
    Image {
        width,
        height,
        encoding: encoding.into(),
        step,
        data,
        ..Default::default()
    }
}

fn compressed(format: &str, data: Vec<u8>) -> CompressedImage {
    CompressedImage {
        header: Header::default(),
        format: format.into(),
        data,
    }
}

fn pose(bones: &[&str], rotations: &[[f64; 4]]) -> BodyPose {
    BodyPose {
        header: Header::default(),
        person_id: "person_0".into(),
        bone_names: bones.iter().map(|b| b.to_string()).collect(),
        rotations: rotations
            .iter()
            .map(|&[x, y, z, w]| Quaternion { x, y, z, w })
            .collect(),
        root: Transform::default(),
    }
}

fn shape(model: &str, params: &[f32]) -> BodyShape {
    BodyShape {
        header: Header::default(),
        person_id: "person_0".into(),
        body_model: model.into(),
        shape_params: params.to_vec(),
    }
}

/// CRC-32 (ISO-HDLC) of `bytes`, as PNG chunks carry it.
fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 == 1 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

fn png_chunk(out: &mut Vec<u8>, kind: &[u8; 4], body: &[u8]) {
    out.extend_from_slice(&(body.len() as u32).to_be_bytes());
    let start = out.len();
    out.extend_from_slice(kind);
    out.extend_from_slice(body);
    let crc = crc32(&out[start..]);
    out.extend_from_slice(&crc.to_be_bytes());
}

/// A decompression bomb: a 57-byte PNG that declares `width`x`height` RGB pixels (60000² is
/// 10.8 GB decoded).
fn png_bomb(width: u32, height: u32) -> Vec<u8> {
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = Vec::new();
    ihdr.extend_from_slice(&width.to_be_bytes());
    ihdr.extend_from_slice(&height.to_be_bytes());
    ihdr.extend_from_slice(&[8, 2, 0, 0, 0]);
    png_chunk(&mut png, b"IHDR", &ihdr);
    // A zlib stream of one empty stored block: decoding would run out of data, not memory.
    png_chunk(
        &mut png,
        b"IDAT",
        &[0x78, 0x01, 0x01, 0x00, 0x00, 0xff, 0xff],
    );
    png_chunk(&mut png, b"IEND", &[]);
    png
}

fn encode(img: &image::RgbImage, format: image::ImageFormat) -> Vec<u8> {
    let mut bytes = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut bytes), format)
        .unwrap();
    bytes
}

/// A small JPEG whose frame header (SOF0) is patched to declare `width`x`height`.
fn jpeg_bomb(small: &[u8], width: u16, height: u16) -> Vec<u8> {
    let mut jpeg = small.to_vec();
    let sof = jpeg
        .windows(2)
        .position(|w| w == [0xFF, 0xC0])
        .expect("baseline JPEG has SOF0");
    jpeg[sof + 5..sof + 7].copy_from_slice(&height.to_be_bytes());
    jpeg[sof + 7..sof + 9].copy_from_slice(&width.to_be_bytes());
    jpeg
}

/// Every bad message, in the order they are written (and rejected).
fn bad_messages() -> Vec<Bad> {
    let mut bad = Vec::new();
    let mut add = |case, topic: &str, type_name, data: Vec<u8>, reason, needle: &str| {
        bad.push(Bad {
            case,
            topic: topic.to_string(),
            type_name,
            data,
            reason,
            needle: needle.to_string(),
        })
    };
    let (c0, c1, c2) = (
        image_topic(&cam(0)),
        image_topic(&cam(1)),
        image_topic(&cam(2)),
    );
    let garbage = vec![0u8, 1, 0, 0, 0xde, 0xad, 0xbe, 0xef, 0x01];
    let good_image = image(4, 4, "rgb8", 12, vec![0; 48]).encode_cdr();
    let cut = |b: &[u8]| b[..b.len() / 2].to_vec();

    // cdr: garbage, cut, empty or mistyped payloads on every subscribed topic.
    let img = Image::TYPE_NAME;
    add("garbage CDR, image", &c0, img, garbage.clone(), "cdr", img);
    add(
        "truncated CDR, image",
        &c0,
        img,
        cut(&good_image),
        "cdr",
        img,
    );
    add(
        "empty payload, image",
        &c0,
        img,
        Vec::new(),
        "cdr",
        "buffer of 0 bytes",
    );
    let mut big_endian_header = good_image.clone();
    big_endian_header[1] = 0x07;
    add(
        "unknown CDR encapsulation, image",
        &c0,
        img,
        big_endian_header,
        "cdr",
        "encapsulation [00, 07]",
    );
    let png = encode(&image::RgbImage::new(8, 8), image::ImageFormat::Png);
    let ci = CompressedImage::TYPE_NAME;
    add(
        "garbage CDR, compressed image",
        COMPRESSED,
        ci,
        garbage.clone(),
        "cdr",
        ci,
    );
    let cdr = compressed("png", png.clone()).encode_cdr();
    add(
        "truncated CDR, compressed image",
        COMPRESSED,
        ci,
        cut(&cdr),
        "cdr",
        ci,
    );
    let info = info_topic(&cam(0));
    let inf = CameraInfo::TYPE_NAME;
    add(
        "garbage CDR, camera info",
        &info,
        inf,
        garbage.clone(),
        "cdr",
        inf,
    );
    let cdr = CameraInfo::default().encode_cdr();
    add(
        "truncated CDR, camera info",
        &info,
        inf,
        cut(&cdr),
        "cdr",
        inf,
    );
    let mask = mask_topic(&cam(1));
    add(
        "garbage CDR, camera mask",
        &mask,
        img,
        garbage.clone(),
        "cdr",
        img,
    );
    let cdr = image(4, 4, "mono8", 4, vec![0; 16]).encode_cdr();
    add(
        "truncated CDR, shared mask",
        SHARED_MASK,
        img,
        cut(&cdr),
        "cdr",
        img,
    );
    let bp = BodyPose::TYPE_NAME;
    add(
        "garbage CDR, pose",
        POSE_TOPIC,
        bp,
        garbage.clone(),
        "cdr",
        bp,
    );
    let cdr = pose(&["spine"], &[[0.0, 0.0, 0.0, 1.0]]).encode_cdr();
    add("truncated CDR, pose", POSE_TOPIC, bp, cut(&cdr), "cdr", bp);
    let bs = BodyShape::TYPE_NAME;
    add(
        "garbage CDR, shape",
        SHAPE_TOPIC,
        bs,
        garbage.clone(),
        "cdr",
        bs,
    );
    let cdr = shape("makehuman-cc0", &[1.0, 1.0]).encode_cdr();
    add(
        "truncated CDR, shape",
        SHAPE_TOPIC,
        bs,
        cut(&cdr),
        "cdr",
        bs,
    );

    // image: raw images that decode from CDR but cannot be used.
    let raw = |w, h, enc: &str, step, n: usize| image(w, h, enc, step, vec![0; n]).encode_cdr();
    add(
        "step and size disagree",
        &c1,
        img,
        raw(4, 4, "rgb8", 12, 47),
        "image",
        "data has 47 bytes but step 12 x height 4 = 48",
    );
    add(
        "step shorter than a row",
        &c1,
        img,
        raw(4, 4, "rgb8", 11, 44),
        "image",
        "step 11 is smaller than width 4 x 3 bytes",
    );
    add(
        "step x height overflows u32 (2^31 x 2 = 2^32, no data)",
        &c1,
        img,
        raw(4, 2, "rgb8", 1 << 31, 0),
        "image",
        "data has 0 bytes but step 2147483648 x height 2 = 4294967296",
    );
    add(
        "step u32::MAX",
        &c1,
        img,
        raw(4, 2, "rgb8", u32::MAX, 24),
        "image",
        "step 4294967295 x height 2 = 8589934590",
    );
    add(
        "unsupported encoding 16UC1",
        &c2,
        img,
        raw(4, 4, "16UC1", 8, 32),
        "image",
        "unsupported encoding `16UC1`",
    );
    add(
        "unsupported encoding yuv422",
        &c2,
        img,
        raw(4, 4, "yuv422", 8, 32),
        "image",
        "unsupported encoding `yuv422`",
    );
    add(
        "empty encoding",
        &c2,
        img,
        raw(4, 4, "", 12, 48),
        "image",
        "unsupported encoding ``",
    );
    add(
        "0x0 image",
        &c2,
        img,
        raw(0, 0, "rgb8", 0, 0),
        "image",
        "empty image (0x0, encoding rgb8)",
    );
    add(
        "image over inputs.max_image_side (9000 > 8192), no pixels sent",
        &c2,
        img,
        raw(9000, 2, "rgb8", 27000, 0),
        "image",
        "image 9000x2 exceeds the size limit of 8192 pixels per side",
    );
    // image: compressed images.
    let jpeg = encode(
        &image::RgbImage::from_fn(32, 32, |x, y| image::Rgb([x as u8 * 8, y as u8 * 8, 90])),
        image::ImageFormat::Jpeg,
    );
    let comp = |format: &str, data: Vec<u8>| compressed(format, data).encode_cdr();
    add(
        "PNG bomb: 57 bytes declaring 60000x60000",
        COMPRESSED,
        ci,
        comp("png", png_bomb(60000, 60000)),
        "image",
        "image 60000x60000 exceeds the size limit of 8192 pixels per side",
    );
    add(
        "JPEG bomb: 32x32 JPEG patched to declare 60000x60000",
        COMPRESSED,
        ci,
        comp("rgb8; jpeg compressed bgr8", jpeg_bomb(&jpeg, 60000, 60000)),
        "image",
        "image 60000x60000 exceeds the size limit of 8192 pixels per side",
    );
    add(
        "truncated PNG",
        COMPRESSED,
        ci,
        comp("png", png[..png.len() / 2].to_vec()),
        "image",
        "corrupt png data",
    );
    let mut bad_crc = png.clone();
    let last = bad_crc.len() - 20;
    bad_crc[last] ^= 0xff;
    add(
        "PNG with a damaged chunk",
        COMPRESSED,
        ci,
        comp("png", bad_crc),
        "image",
        "corrupt png data",
    );
    add(
        "JPEG cut inside its headers",
        COMPRESSED,
        ci,
        comp("jpeg", jpeg[..100].to_vec()),
        "image",
        "corrupt jpeg data: Format error decoding Jpeg: I/O errors Not enough bytes",
    );
    add(
        "garbage labelled jpeg",
        COMPRESSED,
        ci,
        comp("jpeg", b"this is not a jpeg".to_vec()),
        "image",
        "corrupt jpeg data",
    );
    add(
        "unsupported compressed format",
        COMPRESSED,
        ci,
        comp("16UC1; compressedDepth", png.clone()),
        "image",
        "unsupported compressed format `16UC1; compressedDepth`",
    );
    // image: masks.
    add(
        "rgb8 mask",
        &mask,
        img,
        raw(4, 4, "rgb8", 12, 48),
        "image",
        "mask encoding `rgb8` is not mono8",
    );
    add(
        "mask whose step and size disagree",
        SHARED_MASK,
        img,
        raw(4, 4, "mono8", 4, 15),
        "image",
        "data has 15 bytes but step 4 x height 4 = 16",
    );

    // pose: values the skeleton refuses.
    let p = |bones: &[&str], q: &[[f64; 4]]| pose(bones, q).encode_cdr();
    add(
        "pose: NaN rotation",
        POSE_TOPIC,
        bp,
        p(&["spine"], &[[f64::NAN, 0.0, 0.0, 1.0]]),
        "pose",
        "rotation of bone `spine` (x NaN, y 0, z 0, w 1) is not finite",
    );
    add(
        "pose: unknown bone",
        POSE_TOPIC,
        bp,
        p(&["tail_07"], &[[0.0, 0.0, 0.0, 1.0]]),
        "pose",
        "tail_07",
    );
    add(
        "pose: non-unit quaternion (norm 2)",
        POSE_TOPIC,
        bp,
        p(&["spine"], &[[0.0, 0.0, 0.0, 2.0]]),
        "pose",
        "is not a unit quaternion: squared norm 4",
    );
    add(
        "pose: zero quaternion",
        POSE_TOPIC,
        bp,
        p(&["head"], &[[0.0; 4]]),
        "pose",
        "squared norm 0",
    );
    add(
        "pose: 2 bone names, 1 rotation",
        POSE_TOPIC,
        bp,
        p(&["spine", "head"], &[[0.0, 0.0, 0.0, 1.0]]),
        "pose",
        "2 bone names but 1 rotations",
    );
    let mut moved = pose(&["spine"], &[[0.0, 0.0, 0.0, 1.0]]);
    moved.root.translation.x = f64::INFINITY;
    add(
        "pose: infinite root translation",
        POSE_TOPIC,
        bp,
        moved.encode_cdr(),
        "pose",
        "root translation (x inf, y 0, z 0) is not finite",
    );

    // shape: out of range, NaN, wrong length, unknown model.
    let s = |model: &str, params: &[f32]| shape(model, params).encode_cdr();
    add(
        "shape: height_scale 3.0 out of range",
        SHAPE_TOPIC,
        bs,
        s("makehuman-cc0", &[3.0, 1.0]),
        "shape",
        "shape_params[0] = 3 is not a finite value in",
    );
    add(
        "shape: NaN girth_scale",
        SHAPE_TOPIC,
        bs,
        s("makehuman-cc0", &[1.0, f32::NAN]),
        "shape",
        "shape_params[1] = NaN is not a finite value in",
    );
    add(
        "shape: 3 parameters",
        SHAPE_TOPIC,
        bs,
        s("makehuman-cc0", &[1.0, 1.0, 1.0]),
        "shape",
        "shape_params has 3 values; body_model `makehuman-cc0` needs 2",
    );
    add(
        "shape: unknown body model",
        SHAPE_TOPIC,
        bs,
        s("smpl-9000", &[1.0]),
        "shape",
        "body_model `smpl-9000` is not `makehuman-cc0` or `smplx`",
    );
    bad
}

/// A synthetic person's bag (4 views, the last one PNG-compressed) with every bad message
/// written first.
fn bag_with_every_bad_message(dir: &Path, bad: &[Bad]) -> PathBuf {
    let synth = bag_support::synthetic_person_bag(dir, "synth.mcap", RAW_VIEWS + 1);
    let source = BagReader::open(&synth).unwrap();
    let path = dir.join("bad_inputs.mcap");
    let mut bag = BagWriter::create(&path).unwrap();
    for (i, b) in bad.iter().enumerate() {
        // Before the good messages, in this order.
        let t = START_NS - (bad.len() - i) as u64;
        bag.write_raw(&b.topic, b.type_name, t, &b.data).unwrap();
    }
    let last_camera = image_topic(&cam(RAW_VIEWS));
    for m in source.messages() {
        if *m.topic == *last_camera {
            let raw: Image = source.decode(m).unwrap();
            let rgb = image::RgbImage::from_raw(raw.width, raw.height, raw.data.clone())
                .expect("synthetic views are rgb8");
            assert_eq!(raw.encoding, "rgb8");
            let msg = CompressedImage {
                header: raw.header.clone(),
                format: "rgb8; png compressed rgb8".into(),
                data: encode(&rgb, image::ImageFormat::Png),
            };
            bag.write(COMPRESSED, m.log_time, &msg).unwrap();
        } else {
            bag.write_raw(&m.topic, &m.type_name, m.log_time, &m.data)
                .unwrap();
        }
    }
    bag.finish().unwrap();
    path
}

/// The node's parameters for the matrix bag (every input topic subscribed).
fn matrix_overrides() -> Vec<String> {
    let list = |v: Vec<String>| format!("[{}]", v.join(","));
    let raw: Vec<String> = (0..RAW_VIEWS).map(|i| image_topic(&cam(i))).collect();
    let infos: Vec<String> = (0..=RAW_VIEWS).map(|i| info_topic(&cam(i))).collect();
    let masks: Vec<String> = (0..=RAW_VIEWS).map(|i| mask_topic(&cam(i))).collect();
    vec![
        format!("inputs.image_topics={}", list(raw)),
        format!("inputs.compressed_image_topics=[{COMPRESSED}]"),
        format!("inputs.camera_info_topics={}", list(infos)),
        format!("inputs.mask_topics={}", list(masks)),
        format!("inputs.mask_topic={SHARED_MASK}"),
        format!("inputs.shape_topic={SHAPE_TOPIC}"),
    ]
}

/// Small, fast and quiet: no ROS 2, no rendering.
fn quick_overrides() -> Vec<String> {
    [
        "model.num_points=1024",
        "frame_store.debounce_ms=0",
        "outputs.ros=false",
        "outputs.render_rate_hz=0",
    ]
    .map(String::from)
    .to_vec()
}

fn lhmpp(args: &[&str], sets: &[String]) -> Output {
    let mut command = Command::new(env!("CARGO_BIN_EXE_lhmpp"));
    command.args(args).env_remove("RUST_LOG");
    for s in sets {
        command.args(["--set", s]);
    }
    command.output().unwrap()
}

/// Peak resident memory (kB) of `lhmpp args`, measured by GNU time when it is installed.
fn peak_rss_kb(args: &[&str], sets: &[String]) -> Option<u64> {
    let time = Path::new("/usr/bin/time");
    if !time.exists() {
        println!("no /usr/bin/time: peak RSS not measured");
        return None;
    }
    let mut command = Command::new(time);
    command
        .args(["-f", "lhmpp-peak-rss-kb=%M", env!("CARGO_BIN_EXE_lhmpp")])
        .args(args);
    for s in sets {
        command.args(["--set", s]);
    }
    let out = command.output().unwrap();
    assert!(out.status.success(), "{}", plain(&out.stderr));
    plain(&out.stderr)
        .lines()
        .find_map(|l| l.strip_prefix("lhmpp-peak-rss-kb="))
        .and_then(|kb| kb.trim().parse().ok())
}

/// stderr without ANSI colours.
fn plain(bytes: &[u8]) -> String {
    load_support::without_ansi(&String::from_utf8_lossy(bytes))
}

/// Log records: a record starts with its timestamp; a message that spans lines (a decoder's
/// multi-line error) is joined with ` / `.
fn log_records(stderr: &str) -> Vec<String> {
    let mut records: Vec<String> = Vec::new();
    for line in stderr.lines() {
        let starts = line.len() > 20 && line.starts_with("20") && line.as_bytes()[10] == b'T';
        match records.last_mut() {
            Some(last) if !starts => {
                last.push_str(" / ");
                last.push_str(line);
            }
            _ => records.push(line.to_string()),
        }
    }
    records
}

/// Keeps every status and counts the avatars published.
#[derive(Clone, Default)]
struct Published {
    statuses: Arc<Mutex<Vec<ReconstructionStatus>>>,
    avatars: Arc<Mutex<Vec<u64>>>,
}

impl Publisher for Published {
    fn avatar(&self, update: &AvatarUpdate<'_>) {
        self.avatars.lock().unwrap().push(update.revision);
    }
    fn status(&self, msg: ReconstructionStatus) {
        self.statuses.lock().unwrap().push(msg);
    }
    fn frame(&self, _: &str, _: usize, _: &RenderedFrame, _: i64) {}
}

/// Replays `bag` through the node's replay path in this process.
fn replay_in_process(bag: &Path, overrides: &[String]) -> (Pipeline, Published) {
    let mut overrides = overrides.to_vec();
    overrides.push(format!("replay.bag={}", bag.display()));
    let text = NodeConfig::default().to_param_file();
    let cfg = NodeConfig::from_yaml(&text, "<defaults>".as_ref(), &overrides).unwrap();
    let published = Published::default();
    let mut pipeline = Pipeline::new(&cfg, Some(Box::new(published.clone()))).unwrap();
    let options = RosNodeOptions::from_config(&cfg, BTreeMap::new(), None).unwrap();
    let topics = ResolvedTopics::from_options(&options).unwrap();
    let mut replay = BagReplay::open(bag, topics, cfg.inputs.max_image_side).unwrap();
    let start = Instant::now();
    let clock = move || start.elapsed();
    lhmpp::node::run::run_replay(
        &mut pipeline,
        &mut replay,
        0.0,
        &AtomicBool::new(false),
        &clock,
    );
    (pipeline, published)
}

#[test]
fn every_bad_message_is_rejected_by_reason_naming_its_topic_and_the_good_views_make_an_avatar() {
    let dir = tempfile::tempdir().unwrap();
    let bad = bad_messages();
    let bag = bag_with_every_bad_message(dir.path(), &bad);
    let mut planted: BTreeMap<String, u64> = BTreeMap::new();
    for b in &bad {
        *planted.entry(b.reason.to_string()).or_default() += 1;
    }
    let mut sets = matrix_overrides();
    sets.extend(quick_overrides());
    sets.push("outputs.dir=''".into());

    // In process: the counters, the views held, the avatar, the last status.
    let (pipeline, published) = replay_in_process(&bag, &sets);
    let counted: BTreeMap<String, u64> = pipeline
        .rejections()
        .nonzero()
        .map(|(r, n)| (r.as_str().to_string(), n))
        .collect();
    assert_eq!(counted, planted, "rejections by reason");
    assert_eq!(
        pipeline.views_held(),
        RAW_VIEWS + 1,
        "all 4 good views held"
    );
    assert!(pipeline.revision() >= 1, "an avatar was made");
    assert!(!published.avatars.lock().unwrap().is_empty());
    let last = published.statuses.lock().unwrap().last().cloned().unwrap();
    let in_status: BTreeMap<String, u64> = last
        .rejected_reasons
        .iter()
        .cloned()
        .zip(last.rejected_counts.iter().copied())
        .collect();
    assert_eq!(in_status, planted, "{last:?}");

    // `lhmpp replay`: one warning per bad message, in bag order, naming its topic and numbers.
    let mut args = vec!["replay", "--fast"];
    let bag_arg = bag.display().to_string();
    args.push(&bag_arg);
    let started = Instant::now();
    let out = lhmpp(&args, &sets);
    let wall = started.elapsed().as_secs_f64();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = plain(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    // The bombs were refused before their pixels were allocated (60000² RGB is 10.8 GB): the
    // whole replay's peak resident memory, where GNU time can measure it.
    if let Some(kb) = peak_rss_kb(&args, &sets) {
        println!("peak RSS of the replay: {} MiB", kb / 1024);
        assert!(kb < 1024 * 1024, "peak RSS {kb} kB");
    }
    let records = log_records(&stderr);
    let rejected: Vec<&String> = records
        .iter()
        .filter(|l| l.contains(" rejected: "))
        .collect();
    assert_eq!(rejected.len(), bad.len(), "{stderr}");
    for (b, line) in bad.iter().zip(&rejected) {
        let detail = line.split(" rejected: ").nth(1).unwrap();
        println!("[{}] {} -> {detail}", b.reason, b.case);
        assert!(
            !line.contains(" / "),
            "{}: a multi-line error: {line}",
            b.case
        );
        assert!(
            line.contains(&format!("topic={} ", b.topic)) || line.ends_with(&b.topic),
            "{}: the line names another topic than {}: {line}",
            b.case,
            b.topic
        );
        assert!(
            line.contains(&b.needle),
            "{}: `{}` not in: {line}",
            b.case,
            b.needle
        );
        let reason_ok = match b.reason {
            "pose" => line.contains("body pose rejected"),
            "shape" => line.contains("body shape rejected"),
            r => line.contains(&format!("reason=\"{r}\"")),
        };
        assert!(reason_ok, "{}: not counted as {}: {line}", b.case, b.reason);
    }
    // With the side limit raised to 65535 the bombs pass that check; the image decoder's own
    // allocation limit (512 MiB) refuses them, still before their pixels are allocated.
    let mut raised = sets.clone();
    raised.push("inputs.max_image_side=65535".into());
    let out = lhmpp(&args, &raised);
    let raised_log = log_records(&plain(&out.stderr));
    assert!(out.status.success());
    let rejected: Vec<&String> = raised_log
        .iter()
        .filter(|l| l.contains(" rejected: "))
        .collect();
    assert_eq!(rejected.len(), bad.len());
    for (b, line) in bad.iter().zip(&rejected) {
        if b.case.contains(" bomb: ") {
            let detail = line.split(" rejected: ").nth(1).unwrap();
            println!(
                "[{}] {}, max_image_side 65535 -> {detail}",
                b.reason, b.case
            );
            assert!(
                line.contains(COMPRESSED)
                    && line.contains("reason=\"image\"")
                    && line
                        .contains("declares 60000x60000 pixels, more than the decoder's 512 MiB"),
                "{line}"
            );
        }
    }
    if let Some(kb) = peak_rss_kb(&args, &raised) {
        println!(
            "peak RSS of the replay with max_image_side 65535: {} MiB",
            kb / 1024
        );
        assert!(kb < 1024 * 1024, "peak RSS {kb} kB");
    }

    let summary: Vec<String> = planted.iter().map(|(r, n)| format!("{r} {n}")).collect();
    let expected = format!("rejected messages {} ({}),", bad.len(), summary.join(", "));
    println!("{stdout}(wall {wall:.1} s)");
    assert!(stdout.contains(&expected), "`{expected}` not in {stdout}");
    assert!(stdout.contains("views held 4,"), "{stdout}");
    assert!(!stdout.contains("revision 0,"), "{stdout}");
}

/// A good 3-view bag for the file and config runs.
fn small_bag(dir: &Path) -> PathBuf {
    bag_support::synthetic_person_bag(dir, "small.mcap", 3)
}

fn small_bag_overrides() -> Vec<String> {
    let mut sets = vec![format!(
        "inputs.image_topics=[{}]",
        (0..3)
            .map(|i| image_topic(&cam(i)))
            .collect::<Vec<_>>()
            .join(",")
    )];
    sets.extend(quick_overrides());
    sets
}

/// Runs `lhmpp` expecting exit 1 and one `Error:` line holding every needle; returns the line.
fn refused(case: &str, args: &[&str], sets: &[String], needles: &[&str]) -> String {
    let started = Instant::now();
    let out = lhmpp(args, sets);
    let wall = started.elapsed().as_secs_f64();
    let stderr = plain(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{case}: {stderr}");
    let error = stderr
        .lines()
        .find(|l| l.starts_with("Error: "))
        .unwrap_or_else(|| panic!("{case}: no `Error:` line in {stderr}"));
    // A multi-line error (a checkpoint's list of problems) continues on the next lines.
    let rest: String = stderr
        .lines()
        .skip_while(|l| !l.starts_with("Error: "))
        .collect::<Vec<_>>()
        .join("\n");
    for needle in needles {
        assert!(rest.contains(needle), "{case}: `{needle}` not in {rest}");
    }
    println!("{case} (exit 1, {wall:.2} s): {rest}");
    error.to_string()
}

/// Rewrites `good` with one tensor dropped, one reshaped and one stored as f64.
fn broken_checkpoint(good: &Path, bad: &Path, missing: &str, misshapen: &str, mistyped: &str) {
    let bytes = std::fs::read(good).unwrap();
    let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let mut owned: Vec<(String, safetensors::Dtype, Vec<usize>, Vec<u8>)> = Vec::new();
    for (name, view) in st.tensors() {
        if name == missing {
            continue;
        }
        let (mut dtype, mut shape, mut data) =
            (view.dtype(), view.shape().to_vec(), view.data().to_vec());
        if name == misshapen {
            shape = vec![shape.iter().product::<usize>()];
        }
        if name == mistyped {
            data = data
                .chunks_exact(4)
                .flat_map(|c| f64::from(f32::from_le_bytes(c.try_into().unwrap())).to_le_bytes())
                .collect();
            dtype = safetensors::Dtype::F64;
        }
        owned.push((name, dtype, shape, data));
    }
    let views: Vec<(String, safetensors::tensor::TensorView)> = owned
        .iter()
        .map(|(n, d, s, b)| {
            let view = safetensors::tensor::TensorView::new(*d, s.clone(), b).unwrap();
            (n.clone(), view)
        })
        .collect();
    safetensors::serialize_to_file(views, None, bad).unwrap();
}

#[test]
fn broken_checkpoints_body_priors_and_configs_are_refused_naming_the_file_or_key() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let bag = small_bag(d);
    let bag_arg = bag.display().to_string();
    let replay = ["replay", "--fast", bag_arg.as_str()];
    let base = small_bag_overrides();
    let with = |extra: &[String]| {
        let mut s = base.clone();
        s.extend(extra.iter().cloned());
        s
    };
    let path = |name: &str| d.join(name).display().to_string();

    // Checkpoints (`model.checkpoint=PATH`).
    let good = path("tiny.safetensors");
    let out = lhmpp(&["model", "init", "-o", &good], &[]);
    assert!(out.status.success(), "{}", plain(&out.stderr));
    let bytes = std::fs::read(&good).unwrap();
    let header_len = u64::from_le_bytes(bytes[..8].try_into().unwrap());
    let cut = bytes.len() / 2;
    std::fs::write(path("truncated.safetensors"), &bytes[..cut]).unwrap();
    std::fs::write(path("header_cut.safetensors"), &bytes[..100]).unwrap();
    std::fs::write(path("tiny_file.safetensors"), &bytes[..5]).unwrap();
    std::fs::write(path("garbage.safetensors"), b"garbage, not safetensors").unwrap();
    let (missing, misshapen, mistyped) = (
        "encoder.model.norm.bias",
        "motion_embed_mlp.0.weight",
        "renderer.background_embedding",
    );
    broken_checkpoint(
        good.as_ref(),
        path("broken.safetensors").as_ref(),
        missing,
        misshapen,
        mistyped,
    );
    let ckpt = |name: &str| with(&[format!("model.checkpoint={}", path(name))]);
    let needed = format!("need {} bytes, the file has {cut}: truncated", bytes.len());
    refused(
        "checkpoint cut in half",
        &replay,
        &ckpt("truncated.safetensors"),
        &["truncated.safetensors", &needed],
    );
    let says = format!("the header length says {header_len} bytes, the file has 100 bytes");
    refused(
        "checkpoint cut inside its header",
        &replay,
        &ckpt("header_cut.safetensors"),
        &["header_cut.safetensors", &says],
    );
    refused(
        "checkpoint of 5 bytes",
        &replay,
        &ckpt("tiny_file.safetensors"),
        &["tiny_file.safetensors", "the file has 5 bytes"],
    );
    refused(
        "checkpoint of garbage",
        &replay,
        &ckpt("garbage.safetensors"),
        &["garbage.safetensors", "not a valid safetensors file"],
    );
    refused(
        "checkpoint with a missing, a misshapen and a mistyped tensor",
        &replay,
        &ckpt("broken.safetensors"),
        &[
            "broken.safetensors",
            "3 problems",
            missing,
            misshapen,
            mistyped,
        ],
    );
    refused(
        "checkpoint that does not exist",
        &replay,
        &ckpt("absent.safetensors"),
        &["absent.safetensors", "does not exist"],
    );

    // The body prior (`model.prior_dir`, `model.smplx_model`): the node's only body template
    // read from disk (the MakeHuman template is built in). Refused before any weights load.
    let official = |extra: &[String]| {
        let mut s = with(&["model.preset=lhmpp-700m".to_string()]);
        s.extend(extra.iter().cloned());
        s
    };
    refused(
        "missing body prior",
        &replay,
        &official(&[format!("model.prior_dir={}", path("no_prior"))]),
        &[
            "no_prior/dense_sample_points/1_160000.ply",
            "file not found",
        ],
    );
    let prior = d.join("prior");
    for file in [
        "dense_sample_points/1_160000.ply",
        "voxel_grid/cano_1_volume.npz",
        "human_model_files/smplx/SMPLX_NEUTRAL.npz",
    ] {
        let p = prior.join(file);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, b"corrupt").unwrap();
    }
    let prior_set = format!("model.prior_dir={}", prior.display());
    refused(
        "corrupt body prior (SMPL-X model not a zip)",
        &replay,
        &official(std::slice::from_ref(&prior_set)),
        &["SMPLX_NEUTRAL.npz", "invalid Zip archive"],
    );
    refused(
        "corrupt model.smplx_model",
        &replay,
        &official(&[prior_set.clone(), format!("model.smplx_model={good}")]),
        &["tiny.safetensors", "invalid Zip archive"],
    );
    refused(
        "body prior with the tiny preset",
        &replay,
        &with(std::slice::from_ref(&prior_set)),
        &["model.prior_dir is only used with the official network"],
    );

    // Configs: unknown keys and invalid values, in a file and as overrides.
    let file = d.join("bad.yaml");
    std::fs::write(
        &file,
        "lhmpp:\n  ros__parameters:\n    frame_store:\n      max_veiws: 8\n",
    )
    .unwrap();
    let file_arg = file.display().to_string();
    refused(
        "config file with an unknown key",
        &["config", "--config", &file_arg],
        &[],
        &["bad.yaml", "frame_store.max_veiws", "unknown field"],
    );
    let yaml = d.join("broken.yaml");
    std::fs::write(&yaml, "lhmpp: [\n").unwrap();
    let yaml_arg = yaml.display().to_string();
    refused(
        "config file that is not YAML",
        &["run", "--config", &yaml_arg],
        &[],
        &["broken.yaml", "line 2 column 1"],
    );
    refused(
        "unknown key as an override",
        &replay,
        &with(&["outputs.colour=red".into()]),
        &["outputs.colour", "unknown field"],
    );
    for (set, needles) in [
        (
            "model.num_points=3",
            &["model.num_points", "3 is not in 64..=400000"][..],
        ),
        (
            "inputs.max_image_side=banana",
            &["inputs.max_image_side", "invalid type: string \"banana\""][..],
        ),
        (
            "inputs.max_image_side=0",
            &["inputs.max_image_side", "0 is not in 16..=65535"][..],
        ),
        (
            "outputs.renderer=dpt",
            &["outputs.renderer", "unknown variant `dpt`"][..],
        ),
        ("model.device=tpu", &["model.device", "`tpu`"][..]),
        (
            "domain_id=400",
            &["domain_id", "400 is not in -1..=232"][..],
        ),
    ] {
        refused(
            &format!("invalid value {set}"),
            &replay,
            &with(&[set.to_string()]),
            needles,
        );
    }
    refused(
        "override without =",
        &replay,
        &with(&["model.num_points".into()]),
        &["override `model.num_points`", "KEY=VALUE"],
    );
}

/// The avatar revision in a replay summary (`..., revision N, ...`).
fn summary_revision(stdout: &str) -> u64 {
    stdout
        .split(", ")
        .find_map(|p| p.strip_prefix("revision "))
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no revision in {stdout}"))
}

/// A tmpfs of `size` at `dir`, if this process may mount one (root with CAP_SYS_ADMIN).
fn try_tmpfs(dir: &Path, size: &str) -> bool {
    std::fs::create_dir_all(dir).unwrap();
    let ok = Command::new("mount")
        .args(["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs"])
        .arg(dir)
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        println!(
            "cannot mount a tmpfs at {} here (needs root and CAP_SYS_ADMIN): skipped",
            dir.display()
        );
    }
    ok
}

fn umount(dir: &Path) {
    let out = Command::new("umount").arg(dir).output().unwrap();
    assert!(out.status.success(), "{}", plain(&out.stderr));
}

/// Every PLY and PNG left in `dir` is whole (read back without error); returns their count.
fn only_whole_files(dir: &Path) -> usize {
    let mut n = 0;
    for entry in walk(dir) {
        let name = entry.display().to_string();
        if name.ends_with(".ply") {
            lhmpp::splat::read_ply(&entry).unwrap_or_else(|e| panic!("partial PLY left: {e}"));
        } else if name.ends_with(".png") {
            image::open(&entry).unwrap_or_else(|e| panic!("partial PNG {name} left: {e}"));
        } else {
            panic!("unexpected file {name}");
        }
        n += 1;
    }
    n
}

fn walk(dir: &Path) -> Vec<PathBuf> {
    let mut files = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            files.extend(walk(&p));
        } else {
            files.push(p);
        }
    }
    files
}

#[test]
fn unusable_output_directories_cost_the_files_only_and_the_avatars_are_still_published() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let bag = small_bag(d);
    let bag_arg = bag.display().to_string();
    let replay = ["replay", "--fast", bag_arg.as_str()];
    // 24 animation frames are written at the end of a replay when rendering is on.
    let mut base = small_bag_overrides();
    base.retain(|s| !s.starts_with("outputs.render_rate_hz"));
    let run = |case: &str, out_dir: &Path, needles: &[&str]| {
        let mut sets = base.clone();
        sets.push(format!("outputs.dir={}", out_dir.display()));
        let out = lhmpp(&replay, &sets);
        let stdout = String::from_utf8_lossy(&out.stdout).to_string();
        let stderr = plain(&out.stderr);
        assert!(out.status.success(), "{case}: {stderr}");
        let errors: Vec<&str> = stderr.lines().filter(|l| l.contains(" ERROR ")).collect();
        for needle in needles {
            assert!(
                errors.iter().any(|l| l.contains(needle)),
                "{case}: no error line with `{needle}` in {stderr}"
            );
        }
        let published = stderr
            .lines()
            .filter(|l| l.contains("avatar published"))
            .count();
        let revision = summary_revision(&stdout);
        assert!(
            revision >= 1 && published as u64 == revision,
            "{case}: {stdout}"
        );
        println!("{case}: exit 0, {published} avatars published, revision {revision}");
        for e in &errors {
            println!("  {}", e.split(" ERROR ").nth(1).unwrap_or(e));
        }
        stdout
    };

    // A path under a regular file: the directory cannot be created.
    let file = d.join("a_file");
    std::fs::write(&file, b"x").unwrap();
    let under_file = file.join("out");
    let shown = under_file.display().to_string();
    run(
        "outputs.dir under a regular file",
        &under_file,
        &[
            &format!("outputs.dir `{shown}`: {shown}: Not a directory"),
            "no avatar PLY files or PNG frames will be written, the ROS 2 and shared-memory \
             outputs go on",
        ],
    );
    // In process: the publishers (ROS 2, shared memory) still get every avatar.
    let mut sets = base.clone();
    sets.push(format!("outputs.dir={shown}"));
    let (pipeline, published) = replay_in_process(&bag, &sets);
    let avatars = published.avatars.lock().unwrap().clone();
    assert!(pipeline.revision() >= 1);
    assert_eq!(
        avatars.last().copied(),
        Some(pipeline.revision()),
        "{avatars:?}"
    );
    println!("  in process, the publishers (ROS 2, shared memory) got revisions {avatars:?}");
    // And a shared-memory subscriber in another process receives the avatar.
    let person = format!("badout{}", std::process::id());
    let mut echo = Command::new(env!("CARGO_BIN_EXE_lhmpp"))
        .args(["shm-echo", "--person", &person, "--count", "1"])
        .args(["--timeout", "120"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut lines = std::io::BufRead::lines(std::io::BufReader::new(echo.stdout.take().unwrap()));
    let ready = lines.next().unwrap().unwrap();
    assert!(ready.starts_with("ready"), "{ready}");
    let mut sets = base.clone();
    sets.extend([
        format!("outputs.dir={shown}"),
        "outputs.shm=true".into(),
        format!("person_id={person}"),
    ]);
    let out = lhmpp(&replay, &sets);
    assert!(out.status.success(), "{}", plain(&out.stderr));
    let line = lines.next().unwrap().unwrap();
    assert!(echo.wait().unwrap().success());
    assert!(
        line.contains(&format!("person={person}")) && line.contains("rev="),
        "{line}"
    );
    println!("  with outputs.shm=true, `lhmpp shm-echo` in another process printed: {line}");

    // Read-only and full directories need a mount.
    let ro = d.join("ro");
    if try_tmpfs(&ro, "1m") {
        let remount = Command::new("mount")
            .args(["-o", "remount,ro"])
            .arg(&ro)
            .output()
            .unwrap();
        assert!(remount.status.success(), "{}", plain(&remount.stderr));
        let shown = ro.display().to_string();
        run(
            "read-only outputs.dir (tmpfs remounted ro)",
            &ro,
            &[&format!(
                "outputs.dir `{shown}`: {shown}/frames: Read-only file system"
            )],
        );
        umount(&ro);
    }
    let full = d.join("full");
    if try_tmpfs(&full, "64k") {
        let stdout = run(
            "full disk (64 KiB tmpfs)",
            &full,
            &[
                "No space left on device",
                "frame files of 24 could not be written",
            ],
        );
        let whole = only_whole_files(&full);
        println!("  files left, all whole: {whole}\n  {}", stdout.trim());
        umount(&full);
    }
}
