//! The README's commands, run as a newcomer would run them. Every fenced block whose info
//! string starts with `sh doctest` is extracted, and each of its commands (a line, or lines
//! joined by `\`, comments stripped) runs in a scratch folder that holds the repository's
//! `launch_configs/` and `bags/`, with `lhmpp` (and `cargo run --release --`) meaning the
//! binary under test. Then what the README says you will see is checked:
//!
//! - `sh doctest`: every command exits 0, and its outputs are there;
//! - `sh doctest=setup`: the same, except `scripts/test` (the suite this test is part of);
//! - `sh doctest=live`: the node stays up with no publisher, warns about the silent camera
//!   topic by name after 5 s, and stops cleanly on SIGINT;
//! - `sh doctest=needs-download`: the downloads (`huggingface-cli`, network and licences) are
//!   not run; the node then fails with one error naming the missing file and the download.
//!
//! The photo recipe's `photo.jpg` is a synthetic dressed person (`lhmpp synth --realism
//! dressed`), written as a JPEG first.

mod dds_domain;

mod load_support;

use load_support::{interrupt, lhmpp, KillOnDrop};
use std::path::{Path, PathBuf};
use std::process::{Output, Stdio};
use std::time::{Duration, Instant};

/// One fenced block marked for this test.
#[derive(Debug)]
struct Block {
    mode: String,
    commands: Vec<String>,
}

fn readme_blocks() -> Vec<Block> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("README.md")).expect("README.md");
    let mut blocks = Vec::new();
    let mut lines = text.lines();
    while let Some(line) = lines.next() {
        let Some(info) = line.strip_prefix("```sh doctest") else {
            continue;
        };
        let mode = info.strip_prefix('=').unwrap_or("run").trim().to_owned();
        let mut commands = Vec::new();
        let mut pending = String::new();
        for line in lines.by_ref() {
            if line.starts_with("```") {
                break;
            }
            let code = strip_comment(line).trim_end();
            if let Some(head) = code.strip_suffix('\\') {
                pending.push_str(head);
                continue;
            }
            pending.push_str(code);
            if !pending.trim().is_empty() {
                commands.push(pending.split_whitespace().collect::<Vec<_>>().join(" "));
            }
            pending.clear();
        }
        blocks.push(Block { mode, commands });
    }
    blocks
}

/// `line` without a trailing `# comment` (a `#` after whitespace, outside quotes).
fn strip_comment(line: &str) -> &str {
    let mut quote = None;
    let mut prev = ' ';
    for (i, c) in line.char_indices() {
        match (quote, c) {
            (None, '\'' | '"') => quote = Some(c),
            (Some(q), c) if c == q => quote = None,
            (None, '#') if prev.is_whitespace() => return &line[..i],
            _ => {}
        }
        prev = c;
    }
    line
}

/// The command's words with `lhmpp` / `cargo run --release --` replaced by the binary.
fn argv(command: &str) -> Vec<String> {
    let words: Vec<String> = command.split_whitespace().map(str::to_owned).collect();
    let rest = if words.first().map(String::as_str) == Some("lhmpp") {
        &words[1..]
    } else if words.starts_with(&["cargo", "run", "--release", "--"].map(String::from)) {
        &words[4..]
    } else {
        panic!("README doctest command is not an lhmpp command: `{command}`");
    };
    rest.to_vec()
}

/// A scratch folder with the repository's launch configs and bags.
fn scratch() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    for name in ["launch_configs", "bags"] {
        std::os::unix::fs::symlink(root.join(name), dir.path().join(name)).unwrap();
    }
    dir
}

fn domain() -> String {
    dds_domain::test_domain(20).to_string()
}

fn run(dir: &Path, command: &str) -> Output {
    let out = lhmpp()
        .args(argv(command))
        .current_dir(dir)
        .env("ROS_DOMAIN_ID", domain())
        .output()
        .unwrap_or_else(|e| panic!("`{command}`: {e}"));
    assert!(
        out.status.success(),
        "README command `{command}` failed ({:?}):\n{}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// `photo.jpg` in `dir`: the front input view of a dressed synthetic person.
fn write_photo(dir: &Path) -> PathBuf {
    let bag = dir.join("photo_source.mcap");
    let out = lhmpp()
        .args([
            "synth",
            "--seed",
            "41",
            "--realism",
            "dressed",
            "--views",
            "1",
        ])
        .args(["--heldout", "1", "--size", "384", "-o"])
        .arg(&bag)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let reader = lhmpp::bag::BagReader::open(&bag).unwrap();
    let (_, image) = reader
        .read_topic::<lhmpp::msgs::Image>("/cam0/image_raw")
        .unwrap()
        .remove(0);
    assert_eq!(image.encoding, "rgb8");
    let rgb = image::RgbImage::from_raw(image.width, image.height, image.data.to_vec()).unwrap();
    let photo = dir.join("photo.jpg");
    rgb.save(&photo).unwrap();
    photo
}

fn check_outputs(dir: &Path, command: &str, out: &Output) {
    let stdout = String::from_utf8_lossy(&out.stdout);
    let exists = |p: &str| {
        assert!(
            dir.join(p).exists(),
            "after `{command}`: {p} is missing\n{stdout}"
        )
    };
    let words = argv(command);
    match words[0].as_str() {
        "run" if command.contains("demo.yaml") => {
            exists("out/avatar_person_0.ply");
            let frames = std::fs::read_dir(dir.join("out/frames")).map_or(0, |d| d.count());
            assert_eq!(frames, 96, "the demo renders 96 frames\n{stdout}");
        }
        "run" if command.contains("camera_only.yaml") => {
            exists("out/camera_only/avatar_person_0.ply");
            assert!(stdout.contains("perception: frames"), "{stdout}");
        }
        "run" if command.contains("people.yaml") => {
            exists("out/people/avatar_person_0.ply");
            exists("out/people/avatar_person_1.ply");
            assert!(stdout.contains("persons: 2 tracked"), "{stdout}");
            assert!(stdout.contains("  person_1: views held"), "{stdout}");
        }
        "avatar" => {
            for f in ["avatar.ply", "turntable.gif", "walk.gif", "masks"] {
                exists(&format!("out/me/{f}"));
            }
        }
        "synth" if command.contains("--people") => exists("out/people.mcap"),
        "synth" => exists("out/person.mcap"),
        "replay" => {
            exists("out/person/avatar_person_0.ply");
            // The views, then their rerun at the end to refine them against the masked,
            // calibrated views (perception reads the person inside the bag's masks).
            assert!(stdout.contains("reconstructions 2"), "{stdout}");
            assert!(stdout.contains("refinements 1"), "{stdout}");
        }
        "eval" => {
            for views in [1, 4, 8] {
                assert!(
                    stdout.contains(&format!("| out/person.mcap | {views} |")),
                    "eval prints a row for {views} views\n{stdout}"
                );
            }
        }
        other => panic!("README doctest: no expectation written for `{other}` (`{command}`)"),
    }
}

fn live(dir: &Path, command: &str) {
    let log = dir.join("live.log");
    let mut node = KillOnDrop(
        lhmpp()
            .args(argv(command))
            .current_dir(dir)
            .env("ROS_DOMAIN_ID", domain())
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .unwrap(),
    );
    let start = Instant::now();
    let warned = |text: &str| text.contains("no message on camera topic /my_camera/image_raw");
    loop {
        if let Some(status) = node.0.try_wait().unwrap() {
            panic!(
                "`{command}` exited ({status:?}) instead of waiting for the camera:\n{}",
                std::fs::read_to_string(&log).unwrap()
            );
        }
        if warned(&std::fs::read_to_string(&log).unwrap())
            || start.elapsed() > Duration::from_secs(30)
        {
            break;
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    let text = std::fs::read_to_string(&log).unwrap();
    assert!(
        warned(&text),
        "no silent-camera warning within 30 s:\n{text}"
    );
    assert!(
        text.contains("ros2 topic info -v /my_camera/image_raw"),
        "{text}"
    );
    interrupt(node.0.id());
    let deadline = Instant::now() + Duration::from_secs(20);
    let status = loop {
        if let Some(status) = node.0.try_wait().unwrap() {
            break status;
        }
        assert!(Instant::now() < deadline, "the node did not stop on SIGINT");
        std::thread::sleep(Duration::from_millis(100));
    };
    assert!(status.success(), "exit {status:?}\n{text}");
}

fn needs_download(dir: &Path, commands: &[String]) {
    let node: Vec<&String> = commands
        .iter()
        .filter(|c| !c.starts_with("huggingface-cli"))
        .collect();
    assert_eq!(
        node.len(),
        1,
        "one node command after the downloads: {commands:?}"
    );
    let out = lhmpp()
        .args(argv(node[0]))
        .current_dir(dir)
        .env("ROS_DOMAIN_ID", domain())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success(),
        "without the download it must fail:\n{stderr}"
    );
    let errors: Vec<&str> = stderr.lines().filter(|l| l.starts_with("Error:")).collect();
    assert_eq!(errors.len(), 1, "one Error: line\n{stderr}");
    assert!(
        errors[0].contains("huggingface-cli download 3DAIGC/")
            && errors[0].contains("pretrained_models/"),
        "the error names the download that brings the missing file:\n{stderr}"
    );
}

#[test]
fn readme_commands_run_and_show_what_the_readme_says() {
    let blocks = readme_blocks();
    let modes: Vec<&str> = blocks.iter().map(|b| b.mode.as_str()).collect();
    for needed in ["setup", "live", "run", "needs-download"] {
        assert!(
            modes.contains(&needed),
            "README has a `sh doctest={needed}` block: {modes:?}"
        );
    }
    let dir = scratch();
    write_photo(dir.path());
    let mut ran = Vec::new();
    for block in &blocks {
        match block.mode.as_str() {
            "run" | "setup" => {
                for command in &block.commands {
                    if block.mode == "setup" && command == "scripts/test" {
                        continue;
                    }
                    let out = run(dir.path(), command);
                    check_outputs(dir.path(), command, &out);
                    ran.push(command.clone());
                }
            }
            "live" => {
                for command in &block.commands {
                    live(dir.path(), command);
                    ran.push(command.clone());
                }
            }
            "needs-download" => {
                needs_download(dir.path(), &block.commands);
                ran.extend(block.commands.iter().cloned());
            }
            other => panic!("unknown README doctest mode `{other}`"),
        }
    }
    println!("README commands checked:");
    for command in &ran {
        println!("  {command}");
    }
    assert!(ran.len() >= 8, "{ran:?}");
}

#[test]
fn comments_and_continuations_are_read_as_a_shell_would() {
    assert_eq!(strip_comment("lhmpp x   # note"), "lhmpp x   ");
    assert_eq!(strip_comment("echo 'a # b'"), "echo 'a # b'");
    assert_eq!(strip_comment("a#b"), "a#b");
    assert_eq!(
        argv("cargo run --release -- run --config x.yaml"),
        ["run", "--config", "x.yaml"]
    );
}
