//! `lhmpp fuzz`: a randomised mutation fuzzer for the parsers that read untrusted input: the
//! CDR decoding of every input message type (and the checks the node applies after it), image
//! decoding, MCAP reading (whole file and streaming), `.msg` parsing and parameter files.
//!
//! Each case takes a seed input (the corpus: files under `fuzz/corpus/<target>/`, the repo's
//! `msg/` and `launch_configs/`, and messages built here), mutates it (bit flips, interesting
//! bytes and integers, truncation, deletion, splicing from another seed) and runs the target
//! under `catch_unwind`. A panic is a finding: its first input is written to the crash folder
//! and the run ends with an error. Errors returned by the parsers are the expected outcome.

use anyhow::{Context, Result};
use lhmpp::bag::BagReader;
use lhmpp::msgs::{
    BodyPose, BodyShape, CameraInfo, CompressedImage, Header, Image, RosMessage, TFMessage,
};
use lhmpp::reconstruct::image_decode::{decode_compressed, decode_mask, decode_raw, RawImage};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::panic::AssertUnwindSafe;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Largest image side the image targets accept: small, so that a mutated header that declares
/// a large image is refused like an oversized one instead of making every case slow.
const MAX_SIDE: u32 = 256;

/// What `lhmpp fuzz` exercises.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Target {
    /// CDR bodies of Image, CompressedImage, CameraInfo, BodyPose, BodyShape and TFMessage,
    /// decoded and then checked as the node does (image decoding, pose and shape checks).
    Cdr,
    /// PNG and JPEG bytes through the CompressedImage decoder.
    Image,
    /// Whole MCAP files through the bag reader (with salvage) and its messages' CDR.
    Mcap,
    /// MCAP files through the streaming reader (`BagStream`).
    McapStream,
    /// `.msg` definition text.
    Msg,
    /// Parameter files (YAML) and `--set` overrides.
    Config,
}

/// Arguments of `lhmpp fuzz`.
#[derive(clap::Args, Debug)]
pub struct FuzzArgs {
    /// Target to fuzz.
    #[arg(value_enum)]
    target: Target,
    /// Seconds to run (the run also ends at --cases).
    #[arg(long, default_value_t = 60.0)]
    seconds: f64,
    /// Most cases to run (0: no limit).
    #[arg(long, default_value_t = 0)]
    cases: u64,
    /// Random seed of the mutations.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Folder of extra seed inputs (`<target>/` below it is read).
    #[arg(long, default_value = "fuzz/corpus")]
    corpus: PathBuf,
    /// Folder the first input of each panic is written to.
    #[arg(long, default_value = "target/fuzz/crashes")]
    crashes: PathBuf,
}

/// Kinds a corpus file may be named after (`BodyPose-1.cdr`, `jpeg-1.bin`), as
/// [`decode_and_check`] and the image target read them.
const CORPUS_KINDS: [&str; 9] = [
    "Image",
    "mask",
    "CompressedImage",
    "CameraInfo",
    "BodyPose",
    "BodyShape",
    "TFMessage",
    "png",
    "jpeg",
];

/// One seed input, with the message type it holds for the CDR target.
struct Seed {
    kind: &'static str,
    bytes: Vec<u8>,
}

/// Runs the fuzzer; a progress line every 10 s, then a summary. Fails on the first panic.
pub fn run(args: FuzzArgs) -> Result<()> {
    let seeds = seeds(args.target, &args.corpus)?;
    anyhow::ensure!(!seeds.is_empty(), "no seed inputs for {:?}", args.target);
    let scratch_file = scratch_root().join(format!("lhmpp-fuzz-{}.mcap", std::process::id()));
    let panic_site = Arc::new(Mutex::new(None::<String>));
    {
        let site = panic_site.clone();
        std::panic::set_hook(Box::new(move |info| {
            let place = info
                .location()
                .map_or_else(String::new, |l| format!("{}:{}", l.file(), l.line()));
            *site.lock().expect("panic site") = Some(format!("{place}: {info}"));
        }));
    }
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed);
    let started = Instant::now();
    let limit = Duration::from_secs_f64(args.seconds);
    let mut next_report = Duration::from_secs(10);
    let (mut cases, mut accepted) = (0u64, 0u64);
    while started.elapsed() < limit && (args.cases == 0 || cases < args.cases) {
        let seed = &seeds[rng.gen_range(0..seeds.len())];
        let other = &seeds[rng.gen_range(0..seeds.len())].bytes;
        let mut input = seed.bytes.clone();
        mutate(&mut rng, &mut input, other);
        let outcome = std::panic::catch_unwind(AssertUnwindSafe(|| {
            run_case(args.target, seed.kind, &input, &scratch_file)
        }));
        cases += 1;
        match outcome {
            Ok(true) => accepted += 1,
            Ok(false) => {}
            Err(_) => {
                let site = panic_site.lock().expect("panic site").take();
                let site = site.unwrap_or_else(|| "unknown".into());
                std::fs::create_dir_all(&args.crashes)
                    .with_context(|| format!("creating {}", args.crashes.display()))?;
                let file = args
                    .crashes
                    .join(format!("{:?}-{}-{cases}.bin", args.target, seed.kind).to_lowercase());
                std::fs::write(&file, &input)
                    .with_context(|| format!("writing {}", file.display()))?;
                anyhow::bail!(
                    "{:?}: case {cases} panicked ({site}); input written to {}",
                    args.target,
                    file.display()
                );
            }
        }
        if started.elapsed() >= next_report {
            next_report += Duration::from_secs(10);
            eprintln!(
                "{:?}: {cases} cases, {:.0}/s, {accepted} accepted",
                args.target,
                cases as f64 / started.elapsed().as_secs_f64()
            );
        }
    }
    let _ = std::fs::remove_file(&scratch_file);
    let secs = started.elapsed().as_secs_f64();
    println!(
        "{:?}: {cases} cases in {secs:.1} s ({:.0}/s) from {} seeds, {accepted} accepted, 0 panics",
        args.target,
        cases as f64 / secs,
        seeds.len()
    );
    Ok(())
}

/// `/dev/shm` when it exists (the streaming target writes one file per case), else the temp dir.
fn scratch_root() -> PathBuf {
    let shm = Path::new("/dev/shm");
    if shm.is_dir() {
        shm.to_path_buf()
    } else {
        std::env::temp_dir()
    }
}

/// Runs one case; `true` when the input was accepted (parsed without an error).
fn run_case(target: Target, kind: &str, input: &[u8], scratch: &Path) -> bool {
    match target {
        Target::Cdr => decode_and_check(kind, input),
        Target::Image => {
            let format = if kind == "jpeg" { "jpeg" } else { "png" };
            decode_compressed("/fuzz", format, input, MAX_SIDE).is_ok()
        }
        Target::Mcap => match BagReader::from_bytes(PathBuf::from("fuzz.mcap"), input) {
            Ok(bag) => {
                for message in bag.messages() {
                    decode_and_check(&message.type_name, &message.data);
                }
                true
            }
            Err(_) => false,
        },
        Target::McapStream => {
            if std::fs::write(scratch, input).is_err() {
                return false;
            }
            match lhmpp::bag::BagStream::open(scratch) {
                Ok(stream) => {
                    for message in stream {
                        decode_and_check(&message.type_name, &message.data);
                    }
                    true
                }
                Err(_) => false,
            }
        }
        Target::Msg => lhmpp::msgs::definition::parse_msg(&String::from_utf8_lossy(input)).is_ok(),
        Target::Config => {
            let text = String::from_utf8_lossy(input);
            // Half the cases also feed a line of the input as a `--set` override.
            let overrides: Vec<String> = if input.len() % 2 == 0 {
                text.lines().take(1).map(str::to_owned).collect()
            } else {
                Vec::new()
            };
            lhmpp::config::NodeConfig::from_yaml(&text, Path::new("fuzz.yaml"), &overrides).is_ok()
        }
    }
}

/// Decodes `data` as the message type `kind` (a full or short ROS 2 type name) and applies
/// the checks the node applies next; `true` when everything accepted it.
fn decode_and_check(kind: &str, data: &[u8]) -> bool {
    let short = kind.rsplit('/').next().unwrap_or(kind);
    match short {
        "Image" | "mask" => match Image::decode_cdr(data) {
            Ok(msg) => {
                let raw = RawImage::from(&msg);
                if msg.encoding == "mono8" {
                    decode_mask("/fuzz", &raw, MAX_SIDE).is_ok()
                } else {
                    decode_raw("/fuzz", &raw, MAX_SIDE).is_ok()
                }
            }
            Err(_) => false,
        },
        "CompressedImage" => match CompressedImage::decode_cdr(data) {
            Ok(msg) => decode_compressed("/fuzz", &msg.format, &msg.data, MAX_SIDE).is_ok(),
            Err(_) => false,
        },
        "CameraInfo" => CameraInfo::decode_cdr(data).is_ok(),
        "BodyPose" => BodyPose::decode_cdr(data).is_ok_and(|pose| pose.to_pose().is_ok()),
        "BodyShape" => BodyShape::decode_cdr(data).is_ok_and(|shape| {
            lhmpp::reconstruct::shape::check_shape("/fuzz", &shape, "makehuman-cc0").is_ok()
        }),
        "TFMessage" => TFMessage::decode_cdr(data).is_ok(),
        _ => false,
    }
}

/// Applies 1 to 4 random mutations to `data`; `other` is another seed to splice from.
fn mutate(rng: &mut ChaCha8Rng, data: &mut Vec<u8>, other: &[u8]) {
    const INTERESTING: [u32; 8] = [0, 1, 0x7f, 0x80, 0xff, 0x7fff_ffff, 0x8000_0000, u32::MAX];
    for _ in 0..rng.gen_range(1..=4) {
        let len = data.len();
        match rng.gen_range(0..8) {
            0 if len > 0 => {
                let i = rng.gen_range(0..len);
                data[i] ^= 1 << rng.gen_range(0..8);
            }
            1 if len > 0 => {
                let i = rng.gen_range(0..len);
                data[i] = rng.gen();
            }
            2 if len >= 4 => {
                // An interesting little-endian u32: lengths, counts and sizes in CDR and MCAP.
                let i = rng.gen_range(0..=len - 4);
                let v = INTERESTING[rng.gen_range(0..INTERESTING.len())];
                data[i..i + 4].copy_from_slice(&v.to_le_bytes());
            }
            3 if len > 0 => {
                let i = rng.gen_range(0..len);
                data[i] = INTERESTING[rng.gen_range(0..5)] as u8;
            }
            4 => data.truncate(rng.gen_range(0..=len)),
            5 if len > 1 => {
                let start = rng.gen_range(0..len);
                let end = rng.gen_range(start..=len.min(start + 64));
                data.drain(start..end);
            }
            6 if !other.is_empty() => {
                let start = rng.gen_range(0..other.len());
                let end = rng.gen_range(start..=other.len().min(start + 256));
                let at = rng.gen_range(0..=len);
                data.splice(at..at, other[start..end].iter().copied());
            }
            _ => {
                // Duplicate a short range in place (repeated records, fields, lines).
                if len > 0 {
                    let start = rng.gen_range(0..len);
                    let end = rng.gen_range(start..=len.min(start + 32));
                    let copy = data[start..end].to_vec();
                    data.splice(end..end, copy);
                }
            }
        }
    }
}

/// The seed inputs of `target`: built-in ones plus the files under `corpus/<target>/`.
fn seeds(target: Target, corpus: &Path) -> Result<Vec<Seed>> {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut seeds = match target {
        Target::Cdr => message_seeds(),
        Target::Image => image_seeds()?,
        Target::Mcap | Target::McapStream => Vec::new(),
        Target::Msg => files_with(&repo.join("msg"), "msg", "msg")?
            .into_iter()
            .chain(files_with(&repo.join("src/msgs/defs"), "msg", "msg")?)
            .collect(),
        Target::Config => files_with(&repo.join("launch_configs"), "yaml", "yaml")?,
    };
    let dir_name = match target {
        Target::McapStream => "mcap".to_owned(),
        other => format!("{other:?}").to_lowercase(),
    };
    let dir = corpus.join(dir_name);
    if dir.is_dir() {
        for entry in
            std::fs::read_dir(&dir).with_context(|| format!("reading {}", dir.display()))?
        {
            let path = entry?.path();
            if path.is_file() {
                let bytes =
                    std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
                // Corpus files of the CDR target are named after their type: `BodyPose-1.cdr`.
                let kind = path
                    .file_stem()
                    .and_then(|s| s.to_str())
                    .and_then(|s| s.split('-').next())
                    .and_then(|k| CORPUS_KINDS.iter().copied().find(|known| *known == k))
                    .unwrap_or("file");
                seeds.push(Seed { kind, bytes });
            }
        }
    }
    Ok(seeds)
}

/// Every file with extension `ext` below `dir` (recursively), as seeds of kind `kind`.
fn files_with(dir: &Path, ext: &str, kind: &'static str) -> Result<Vec<Seed>> {
    let mut out = Vec::new();
    if !dir.is_dir() {
        return Ok(out);
    }
    for entry in std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))? {
        let path = entry?.path();
        if path.is_dir() {
            out.extend(files_with(&path, ext, kind)?);
        } else if path.extension().is_some_and(|e| e == ext) {
            let bytes =
                std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
            out.push(Seed { kind, bytes });
        }
    }
    Ok(out)
}

/// Valid messages of every input type, CDR-encoded.
fn message_seeds() -> Vec<Seed> {
    let header = Header::default();
    let image = |encoding: &str, channels: u32| Image {
        header: header.clone(),
        height: 4,
        width: 3,
        encoding: encoding.into(),
        is_bigendian: 0,
        step: 3 * channels,
        data: (0..12 * channels).map(|i| i as u8).collect(),
    };
    let mut seeds = vec![
        Seed {
            kind: "Image",
            bytes: image("rgb8", 3).encode_cdr(),
        },
        Seed {
            kind: "Image",
            bytes: image("bgra8", 4).encode_cdr(),
        },
        Seed {
            kind: "mask",
            bytes: image("mono8", 1).encode_cdr(),
        },
        Seed {
            kind: "CameraInfo",
            bytes: CameraInfo::default().encode_cdr(),
        },
        Seed {
            kind: "BodyShape",
            bytes: BodyShape {
                header: header.clone(),
                person_id: "person_0".into(),
                body_model: "makehuman-cc0".into(),
                shape_params: vec![1.0, 1.0],
            }
            .encode_cdr(),
        },
        Seed {
            kind: "BodyPose",
            bytes: BodyPose {
                header: header.clone(),
                bone_names: vec!["root".into(), "spine01".into()],
                rotations: vec![Default::default(); 2],
                ..Default::default()
            }
            .encode_cdr(),
        },
        Seed {
            kind: "TFMessage",
            bytes: TFMessage::default().encode_cdr(),
        },
    ];
    for (kind, format) in [
        ("png", image::ImageFormat::Png),
        ("jpeg", image::ImageFormat::Jpeg),
    ] {
        let data = encoded_image(format);
        seeds.push(Seed {
            kind: "CompressedImage",
            bytes: CompressedImage {
                header: header.clone(),
                format: kind.into(),
                data,
            }
            .encode_cdr(),
        });
    }
    seeds
}

/// An 8×6 test image encoded as `format`.
fn encoded_image(format: image::ImageFormat) -> Vec<u8> {
    let img = image::RgbImage::from_fn(8, 6, |x, y| image::Rgb([x as u8 * 30, y as u8 * 40, 90]));
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, format)
        .expect("encoding a small image in memory");
    out.into_inner()
}

/// PNG and JPEG seeds for the image target.
fn image_seeds() -> Result<Vec<Seed>> {
    Ok(vec![
        Seed {
            kind: "png",
            bytes: encoded_image(image::ImageFormat::Png),
        },
        Seed {
            kind: "jpeg",
            bytes: encoded_image(image::ImageFormat::Jpeg),
        },
    ])
}
