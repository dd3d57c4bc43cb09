//! The live page in a real browser: the node replays the demo bag with two BodyPoses (a walk
//! pose at 1.5 s, another at 20 s) and serves `outputs.web`; headless Chromium (Debian) opens
//! the page, and once it has drawn the avatar at each pose takes a screenshot (DevTools
//! protocol). Each screenshot is compared with the CPU rasteriser's render of the avatar the
//! node wrote (PLY), at the same pose and camera: ≥ 30 dB PSNR. The pose moves the avatar: the
//! two screenshots differ, where the two CPU renders differ, and each matches its own pose's
//! render better than the other's. Images go to target/web_page/.

mod rclpy_support;

use base64::Engine;
use futures::{SinkExt, StreamExt};
use glam::Vec3;
use lhmpp::avatar::Avatar;
use lhmpp::bag::{BagReader, BagWriter, QosProfile};
use lhmpp::body::{motion::walk_pose, BodyTemplate, Pose};
use lhmpp::eval::metrics::{psnr, ImageRef};
use lhmpp::msgs::{BodyPose, Header, Time};
use lhmpp::splat::{read_ply, render, Camera, Intrinsics, RenderOptions};
use rclpy_support::KillOnDrop;
use serde_json::{json, Value};
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};
use tokio_tungstenite::tungstenite::Message;

const SIDE: u32 = 384;
const FOV_DEG: f32 = 45.0;
const EYE: Vec3 = Vec3::new(0.8, 1.1, 3.0);
const TARGET: Vec3 = Vec3::new(0.0, 0.9, 0.0);
/// The demo bag's start (ns).
const START_NS: u64 = 1_700_000_000_000_000_000;
const POSE_A_NS: u64 = START_NS + 1_500_000_000;
const POSE_B_NS: u64 = START_NS + 20_000_000_000;

fn poses() -> [Pose; 2] {
    [walk_pose(8.0), walk_pose(20.0)]
}

/// The demo bag without its pose, plus pose A at 1.5 s and pose B at 20 s.
fn write_bag(path: &Path) {
    let demo =
        BagReader::open(Path::new(env!("CARGO_MANIFEST_DIR")).join("bags/demo.mcap")).unwrap();
    let mut bag = BagWriter::create(path).unwrap();
    for t in demo.topics() {
        bag.add_topic(&t.name, &t.type_name, &QosProfile::default())
            .unwrap();
    }
    for m in demo.messages() {
        if m.type_name.as_ref() != "lhmpp_msgs/msg/BodyPose" {
            bag.write_raw(&m.topic, &m.type_name, m.log_time, &m.data)
                .unwrap();
        }
    }
    for (pose, at) in poses().iter().zip([POSE_A_NS, POSE_B_NS]) {
        let header = Header::new(Time::from_nanos(at as i64), "world");
        let msg = BodyPose::from_pose(header, "person_0", pose);
        bag.write("/lhmpp/body_pose", at, &msg).unwrap();
    }
    bag.finish().unwrap();
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// A DevTools protocol session on one page.
struct Cdp {
    ws: tokio_tungstenite::WebSocketStream<
        tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>,
    >,
    next: u64,
    session: Option<String>,
}

impl Cdp {
    async fn call(&mut self, method: &str, params: Value) -> Value {
        self.next += 1;
        let mut msg = json!({"id": self.next, "method": method, "params": params});
        if let Some(s) = &self.session {
            msg["sessionId"] = json!(s);
        }
        self.ws
            .send(Message::Text(msg.to_string().into()))
            .await
            .unwrap();
        loop {
            let reply = tokio::time::timeout(Duration::from_secs(30), self.ws.next())
                .await
                .unwrap_or_else(|_| panic!("{method}: no reply in 30 s"))
                .expect("DevTools link open")
                .unwrap();
            let Message::Text(text) = reply else { continue };
            let v: Value = serde_json::from_str(&text).unwrap();
            if v["id"] == json!(self.next) {
                assert!(v.get("error").is_none(), "{method}: {v}");
                return v["result"].clone();
            }
        }
    }
}

/// The page's `window.lhmppState`.
async fn page_state(cdp: &mut Cdp) -> Value {
    let r = cdp
        .call(
            "Runtime.evaluate",
            json!({"expression": "JSON.stringify(window.lhmppState || null)", "returnByValue": true}),
        )
        .await;
    serde_json::from_str(r["result"]["value"].as_str().unwrap_or("null")).unwrap_or(Value::Null)
}

/// Waits until the page has drawn person_0's avatar at the pose stamped `stamp` for 40 more
/// frames (Spark sorts in a worker), then takes a screenshot (RGB f32, `SIDE`²).
async fn screenshot_at(cdp: &mut Cdp, stamp: u64, deadline: Instant) -> Vec<f32> {
    let img = screenshot_png_at(cdp, stamp, deadline).await;
    assert_eq!(img.dimensions(), (SIDE, SIDE));
    img.as_raw().iter().map(|&v| v as f32 / 255.0).collect()
}

/// [`screenshot_at`] as an image of the viewport's size.
async fn screenshot_png_at(cdp: &mut Cdp, stamp: u64, deadline: Instant) -> image::RgbImage {
    let mut since: Option<u64> = None;
    loop {
        let s = page_state(cdp).await;
        let p = &s["persons"]["person_0"];
        let frames = s["frames"].as_u64().unwrap_or(0);
        let ready =
            p["revision"].as_u64().unwrap_or(0) >= 1 && p["pose_stamp_ns"].as_u64() == Some(stamp);
        since = match (ready, since) {
            (true, None) => Some(frames),
            (true, Some(f)) => Some(f),
            (false, _) => None,
        };
        if since.is_some_and(|f| frames >= f + 40) {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "the page never drew pose {stamp}: {s}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let shot = cdp
        .call("Page.captureScreenshot", json!({"format": "png"}))
        .await;
    let after = page_state(cdp).await;
    assert_eq!(
        after["persons"]["person_0"]["pose_stamp_ns"].as_u64(),
        Some(stamp),
        "the pose changed while the screenshot was taken (a slow start: the page came up \
         after the next pose)"
    );
    let png = base64::engine::general_purpose::STANDARD
        .decode(shot["data"].as_str().unwrap())
        .unwrap();
    image::load_from_memory(&png).unwrap().to_rgb8()
}

fn save(path: &Path, rgb: &[f32]) {
    let bytes: Vec<u8> = rgb
        .iter()
        .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect();
    image::RgbImage::from_raw(SIDE, SIDE, bytes)
        .unwrap()
        .save(path)
        .unwrap();
}

/// The whole page with numbered labels on its parts (docs/live-page.png).
fn save_labelled(path: &Path, page: image::RgbImage) {
    use lhmpp::picture::draw_text;
    let blue = image::Rgb([30, 80, 200]);
    let (w, h) = page.dimensions();
    let mut out = image::RgbImage::from_pixel(w, h + 44, image::Rgb([255, 255, 255]));
    image::imageops::replace(&mut out, &page, 0, 0);
    draw_text(
        &mut out,
        8,
        h + 6,
        "1 persons: revision, views, pose age, state",
        1,
        blue,
    );
    draw_text(
        &mut out,
        8,
        h + 24,
        "2 each avatar drawn by Spark in the browser, skinned by the pose stream (drag: orbit)",
        1,
        blue,
    );
    draw_text(&mut out, 200, 8, "1", 2, blue);
    draw_text(&mut out, 280, 8, "2", 2, blue);
    out.save(path).unwrap();
}

fn score(a: &[f32], b: &[f32]) -> f64 {
    let s = SIDE as usize;
    psnr(ImageRef::new(a, s, s, 3), ImageRef::new(b, s, s, 3))
}

/// Pixels where `a` and `b` differ by more than 0.1 in some channel.
fn changed(a: &[f32], b: &[f32]) -> Vec<bool> {
    a.chunks(3)
        .zip(b.chunks(3))
        .map(|(x, y)| x.iter().zip(y).any(|(p, q)| (p - q).abs() > 0.1))
        .collect()
}

#[test]
fn the_page_draws_the_avatar_at_each_pose_as_the_cpu_rasteriser_does() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let tmp = tempfile::tempdir().unwrap();
    let bag = tmp.path().join("poses.mcap");
    write_bag(&bag);
    let port = free_port();
    let out = tmp.path().join("out");
    let mut node = Command::new(env!("CARGO_BIN_EXE_lhmpp"));
    node.args(["run", "--config"])
        .arg(root.join("launch_configs/demo.yaml"))
        .args(["--set", &format!("replay.bag={}", bag.display())])
        .args([
            "--set",
            "replay.rate=1",
            "--set",
            "replay.exit_when_done=false",
        ])
        .args(["--set", &format!("outputs.dir={}", out.display())])
        .args(["--set", &format!("outputs.web=127.0.0.1:{port}")])
        .args(["--set", "outputs.virtual_cameras=1"]);
    let _node = KillOnDrop(
        node.stdout(Stdio::null())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("lhmpp starts"),
    );
    let profile = tmp.path().join("chromium");
    let mut chromium = KillOnDrop(
        Command::new("chromium")
            .args([
                "--headless=new",
                "--no-sandbox",
                "--disable-gpu",
                "--disable-quic",
                "--no-first-run",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                "--enable-unsafe-swiftshader",
                "--use-angle=swiftshader",
                "--remote-debugging-port=0",
                &format!("--window-size={SIDE},{SIDE}"),
                &format!("--user-data-dir={}", profile.display()),
                "about:blank",
            ])
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("chromium starts (scripts/setup-test-deps installs it)"),
    );
    let devtools = BufReader::new(chromium.0.stderr.take().unwrap())
        .lines()
        .map_while(Result::ok)
        .find_map(|l| {
            l.split_once("DevTools listening on ")
                .map(|(_, u)| u.trim().to_owned())
        })
        .expect("chromium prints its DevTools address");
    let started = Instant::now();
    let eye_target = [EYE.x, EYE.y, EYE.z, TARGET.x, TARGET.y, TARGET.z]
        .map(|v| v.to_string())
        .join(",");
    let url = format!("http://127.0.0.1:{port}/?bare=1&fov={FOV_DEG}&camera={eye_target}");
    let runtime = tokio::runtime::Runtime::new().unwrap();
    let shots = runtime.block_on(async {
        let (ws, _) = tokio_tungstenite::connect_async(devtools.as_str())
            .await
            .unwrap();
        let mut cdp = Cdp {
            ws,
            next: 0,
            session: None,
        };
        let target = cdp
            .call("Target.createTarget", json!({"url": "about:blank"}))
            .await;
        let attached = cdp
            .call(
                "Target.attachToTarget",
                json!({"targetId": target["targetId"], "flatten": true}),
            )
            .await;
        cdp.session = Some(attached["sessionId"].as_str().unwrap().to_owned());
        cdp.call(
            "Emulation.setDeviceMetricsOverride",
            json!({"width": SIDE, "height": SIDE, "deviceScaleFactor": 1, "mobile": false}),
        )
        .await;
        // The node may still be loading: retry the page until it is served.
        let deadline = Instant::now() + Duration::from_secs(60);
        loop {
            cdp.call("Page.navigate", json!({"url": url})).await;
            tokio::time::sleep(Duration::from_millis(500)).await;
            if page_state(&mut cdp).await != Value::Null {
                break;
            }
            assert!(Instant::now() < deadline, "the page never loaded");
        }
        let a = screenshot_at(&mut cdp, POSE_A_NS, deadline).await;
        let b = screenshot_at(&mut cdp, POSE_B_NS, deadline).await;
        // The whole page, list included, for the docs.
        cdp.call(
            "Emulation.setDeviceMetricsOverride",
            json!({"width": 900, "height": 520, "deviceScaleFactor": 1, "mobile": false}),
        )
        .await;
        let page_url = format!("http://127.0.0.1:{port}/?camera={eye_target}");
        cdp.call("Page.navigate", json!({"url": page_url})).await;
        tokio::time::sleep(Duration::from_millis(500)).await;
        let _ = screenshot_png_at(&mut cdp, POSE_B_NS, deadline).await;
        tokio::time::sleep(Duration::from_millis(1500)).await;
        let page = screenshot_png_at(&mut cdp, POSE_B_NS, deadline).await;
        ([a, b], page)
    });
    let (shots, page) = shots;
    eprintln!("screenshots after {:.1} s", started.elapsed().as_secs_f64());

    // The CPU rasteriser's renders of the avatar the node wrote.
    let ply = read_ply(&out.join("avatar_person_0.ply")).unwrap();
    let avatar = Avatar::new(
        ply.gaussians,
        ply.skin.unwrap(),
        ply.body_model.unwrap_or_default(),
    )
    .unwrap();
    let template = BodyTemplate::load_default().unwrap();
    let camera = Camera::look_at(
        EYE,
        TARGET,
        Vec3::Y,
        Intrinsics::from_fov_y(SIDE, SIDE, FOV_DEG.to_radians()),
    );
    let options = RenderOptions {
        background: Vec3::ONE,
        ..Default::default()
    };
    let cpu: Vec<Vec<f32>> = poses()
        .iter()
        .map(|pose| {
            let posed = avatar.animate(&template.skeleton.skinning_matrices(pose));
            render(&posed, &camera, &options)
                .rgb
                .iter()
                .map(|v| v.clamp(0.0, 1.0))
                .collect()
        })
        .collect();
    let dir = root.join("target/web_page");
    std::fs::create_dir_all(&dir).unwrap();
    save_labelled(&dir.join("live-page.png"), page);
    for (name, img) in [
        ("browser_pose_a.png", &shots[0]),
        ("browser_pose_b.png", &shots[1]),
        ("cpu_pose_a.png", &cpu[0]),
        ("cpu_pose_b.png", &cpu[1]),
    ] {
        save(&dir.join(name), img);
    }
    let (aa, bb) = (score(&shots[0], &cpu[0]), score(&shots[1], &cpu[1]));
    let (ab, ba) = (score(&shots[0], &cpu[1]), score(&shots[1], &cpu[0]));
    let tile = |rgb: &[f32]| {
        let bytes = rgb
            .iter()
            .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
            .collect();
        image::RgbImage::from_raw(SIDE, SIDE, bytes).unwrap()
    };
    let tiles = [
        tile(&shots[0]),
        tile(&cpu[0]),
        tile(&shots[1]),
        tile(&cpu[1]),
    ];
    let captions = [
        "browser, pose A".to_string(),
        format!("CPU, pose A ({aa:.1} dB)"),
        "browser, pose B".to_string(),
        format!("CPU, pose B ({bb:.1} dB)"),
    ];
    let row: Vec<(&image::RgbImage, &str)> = tiles
        .iter()
        .zip(&captions)
        .map(|(t, c)| (t, c.as_str()))
        .collect();
    lhmpp::picture::captioned_row(&row, 2, 8, image::Rgb([255, 255, 255]))
        .save(dir.join("browser-vs-cpu.png"))
        .unwrap();
    eprintln!(
        "PSNR browser vs CPU: pose A {aa:.2} dB, pose B {bb:.2} dB; crossed (A vs B's render) \
         {ab:.2} dB, (B vs A's) {ba:.2} dB; images in {}",
        dir.display()
    );
    assert!(aa >= 30.0 && bb >= 30.0, "A {aa:.2} dB, B {bb:.2} dB");
    assert!(
        aa > ab && bb > ba,
        "each screenshot matches its own pose best"
    );
    let moved_browser = changed(&shots[0], &shots[1]);
    let moved_cpu = changed(&cpu[0], &cpu[1]);
    let both = moved_browser
        .iter()
        .zip(&moved_cpu)
        .filter(|(a, b)| **a && **b)
        .count();
    let either = moved_browser
        .iter()
        .zip(&moved_cpu)
        .filter(|(a, b)| **a || **b)
        .count();
    let moved = moved_browser.iter().filter(|m| **m).count();
    eprintln!(
        "pixels changed between the poses: {moved} in the browser, IoU {:.2} with the CPU's",
        both as f64 / either.max(1) as f64
    );
    assert!(
        moved > 500,
        "the pose barely moved the avatar: {moved} pixels"
    );
    assert!(both as f64 >= 0.5 * either as f64, "they moved elsewhere");
}
