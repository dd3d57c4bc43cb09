//! `lhmpp bench latency`: how long a camera frame takes to become a pose, a rendered frame and a
//! frame drawn by the live page, with the node running as users run it.
//!
//! For each scenario (one person; three people with tracking) the bench starts three processes
//! on this machine's loopback, in a DDS domain of their own:
//!
//! - the node, `lhmpp run` with `launch_configs/camera.yaml` (one person) or
//!   `launch_configs/people.yaml` (three), its camera pointed at the load, the live page on, and
//!   `frame_store.duplicate_similarity: 1` so that every frame changes the views and
//!   reconstructions keep running the whole time;
//! - the load, `lhmpp loadgen`: one camera at `--rate` Hz (640×480 JPEG by default) of a walking
//!   synthetic person (`--people 3`: three crossing a room), each frame stamped with this
//!   machine's clock as it is published;
//! - headless Chromium on the live page (`?latency=1`), which records when it first drew each
//!   pose (`performance.timeOrigin + performance.now()`, after reading a pixel back).
//!
//! The bench itself subscribes to the pose topic and the rendered frames (both carry the camera
//! frame's stamp) and the statuses. After `--warmup` seconds it keeps every sample for
//! `--seconds` and prints, per scenario, p50 / p95 / p99 / max of camera stamp → pose
//! received, → rendered frame received and → page frame drawn, with the reconstructions that
//! ran in the window and the machine's load average.

mod browser;
mod probe;

use anyhow::{bail, Context, Result};
use clap::Args;
use lhmpp::config::NodeConfig;
use lhmpp::node::ros::{ResolvedTopics, RosNodeOptions};
use probe::{Probe, Sample, Stage};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// Whether the page is measured.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum BrowserChoice {
    /// When `chromium` is on the PATH.
    Auto,
    /// Always (fails without `chromium`).
    On,
    /// Never.
    Off,
}

/// Options of `lhmpp bench latency`.
#[derive(Args, Debug)]
pub struct LatencyBenchArgs {
    /// Scenarios: how many people the camera sees (1: `camera.yaml`; more: `people.yaml`, with
    /// tracking).
    #[arg(long, value_delimiter = ',', default_values_t = [1u8, 3])]
    people: Vec<u8>,
    /// Seconds measured per scenario, after the warm-up.
    #[arg(long, default_value_t = 60)]
    seconds: u64,
    /// Seconds left out at the start of each scenario (the network loads, the first avatar is
    /// made and reaches the page).
    #[arg(long, default_value_t = 20)]
    warmup: u64,
    /// Camera frames per second.
    #[arg(long, default_value_t = 30.0)]
    rate: f64,
    /// Camera frame width.
    #[arg(long, default_value_t = 640)]
    width: u32,
    /// Camera frame height.
    #[arg(long, default_value_t = 480)]
    height: u32,
    /// Measure the live page in headless Chromium.
    #[arg(long, value_enum, default_value_t = BrowserChoice::Auto)]
    browser: BrowserChoice,
    /// The node binary to measure (default: this one), e.g. an earlier build to compare with.
    #[arg(long, value_name = "PATH")]
    node_bin: Option<PathBuf>,
    /// Name of this run in the table and the report folder.
    #[arg(long, default_value = "node")]
    label: String,
    /// Where the logs, the node's files and `latency.csv` go.
    #[arg(long, default_value = "target/bench-latency")]
    report: PathBuf,
    /// DDS domain (default: one from this process id, outside the ephemeral port range).
    #[arg(long)]
    domain: Option<u16>,
}

/// Runs `lhmpp bench latency`.
pub fn run(args: LatencyBenchArgs) -> Result<()> {
    if args.people.is_empty() || args.people.iter().any(|p| !(1..=8).contains(p)) {
        bail!(
            "--people {:?}: expected 1 to 8 people per scenario",
            args.people
        );
    }
    if !(args.rate > 0.0 && args.rate <= 120.0) {
        bail!(
            "--rate {}: expected frames per second in (0, 120]",
            args.rate
        );
    }
    if args.seconds == 0 {
        bail!("--seconds 0: nothing would be measured");
    }
    let me = std::env::current_exe().context("finding this binary")?;
    let node_bin = args.node_bin.clone().unwrap_or_else(|| me.clone());
    if !node_bin.is_file() {
        bail!("--node-bin {}: no such file", node_bin.display());
    }
    let browser = match args.browser {
        BrowserChoice::Off => false,
        BrowserChoice::On => {
            if !browser::available() {
                bail!("--browser on: `chromium` is not on the PATH (scripts/setup-test-deps installs it)");
            }
            true
        }
        BrowserChoice::Auto => browser::available(),
    };
    let mut results = Vec::new();
    for &people in &args.people {
        eprintln!("== {}: {people} person(s) ==", args.label);
        let scenario = Scenario {
            people,
            args: &args,
            me: &me,
            node_bin: &node_bin,
            browser,
        };
        results.push(scenario.run()?);
    }
    print_table(&args, browser, &results);
    write_csv(&args, &results)?;
    Ok(())
}

/// What one scenario measured.
struct Measured {
    people: u8,
    /// Load averages (1, 5, 15 min) when the scenario started and ended.
    load_before: String,
    load_after: String,
    /// Latencies (ms) by stage.
    samples: BTreeMap<Stage, Vec<f64>>,
    /// Avatar revisions published in the window, all persons.
    reconstructions: usize,
    /// Persons whose poses were received in the window.
    persons: usize,
    /// Camera frames published in the window (per loadgen's rate).
    window: Duration,
}

struct Scenario<'a> {
    people: u8,
    args: &'a LatencyBenchArgs,
    me: &'a Path,
    node_bin: &'a Path,
    browser: bool,
}

impl Scenario<'_> {
    fn run(&self) -> Result<Measured> {
        let args = self.args;
        let dir = args.report.join(format!("{}-{}p", args.label, self.people));
        std::fs::create_dir_all(&dir).with_context(|| format!("{}", dir.display()))?;
        let domain = args.domain.unwrap_or_else(default_domain);
        let port = free_port()?;
        let (config_file, overrides) = self.node_config(&dir, domain, port);
        let config = NodeConfig::load(&config_file, &overrides)
            .with_context(|| format!("{}", config_file.display()))?;
        let topics = ResolvedTopics::from_options(&RosNodeOptions::from_config(
            &config,
            BTreeMap::new(),
            Some(&domain.to_string()),
        )?)?;
        let load_before = load_average();
        let mut node_cmd = Command::new(self.node_bin);
        node_cmd
            .arg("run")
            .arg("--config")
            .arg(&config_file)
            .env_remove("ROS_DOMAIN_ID")
            .env_remove("RUST_LOG");
        for o in &overrides {
            node_cmd.args(["--set", o]);
        }
        let mut node = Running::spawn(
            node_cmd
                .stdout(file(&dir.join("node.txt"))?)
                .stderr(file(&dir.join("node.log"))?),
            "the node",
        )?;
        let probe = Probe::start(domain, &topics, self.people)?;
        let total = args.warmup + args.seconds;
        let mut load_cmd = Command::new(self.me);
        load_cmd
            .args(["loadgen", "--cameras", "1", "--prefix", "/loadgen"])
            .args(["--rate", &args.rate.to_string()])
            .args(["--width", &args.width.to_string()])
            .args(["--height", &args.height.to_string()])
            .args(["--seconds", &total.to_string()])
            .args(["--domain", &domain.to_string()])
            .args(["--wait-subscribers", "120"])
            .env_remove("ROS_DOMAIN_ID");
        if self.people > 1 {
            load_cmd.args(["--people", &self.people.to_string(), "--frames", "120"]);
        } else {
            load_cmd.args(["--frames", "60"]);
        }
        let mut load = Running::spawn(
            load_cmd
                .stdout(file(&dir.join("loadgen.txt"))?)
                .stderr(file(&dir.join("loadgen.log"))?),
            "lhmpp loadgen",
        )?;
        let mut page = if self.browser {
            Some(browser::Page::open(
                port,
                &dir.join("chromium"),
                Duration::from_secs(120),
            )?)
        } else {
            None
        };
        // The load starts once the node subscribes (after the loadgen renders its frames):
        // the warm-up counts from its first pose.
        let mut window: Option<(i64, i64)> = None;
        let mut samples: Vec<Sample> = Vec::new();
        let mut revisions: Vec<(String, u32, i64)> = Vec::new();
        let mut last_note = Instant::now();
        loop {
            std::thread::sleep(Duration::from_millis(250));
            for item in probe.drain() {
                match item {
                    probe::Item::Sample(s) => {
                        if window.is_none() && s.stage == Stage::Pose {
                            let from = s.stamp_ns + secs_ns(args.warmup);
                            window = Some((from, from + secs_ns(args.seconds)));
                            eprintln!("first pose received: measuring from {} s on", args.warmup);
                        }
                        samples.push(s);
                    }
                    probe::Item::Revision {
                        person,
                        revision,
                        at_ns,
                    } => revisions.push((person, revision, at_ns)),
                }
            }
            if let Some(page) = &mut page {
                samples.extend(page.take_draws()?);
            }
            if last_note.elapsed() >= Duration::from_secs(5) {
                last_note = Instant::now();
                eprintln!(
                    "  {} samples, {} revisions so far",
                    samples.len(),
                    revisions.len()
                );
            }
            if let Some(status) = load.try_wait()? {
                if !status.success() {
                    bail!(
                        "lhmpp loadgen failed ({status}); see {}",
                        dir.join("loadgen.log").display()
                    );
                }
                break;
            }
            if let Some(status) = node.try_wait()? {
                bail!(
                    "the node ended early ({status}); see {}",
                    dir.join("node.log").display()
                );
            }
        }
        // What was on its way when the load stopped.
        std::thread::sleep(Duration::from_secs(1));
        for item in probe.drain() {
            if let probe::Item::Sample(s) = item {
                samples.push(s);
            }
        }
        if let Some(page) = &mut page {
            samples.extend(page.take_draws()?);
        }
        drop(page);
        drop(probe);
        node.interrupt_and_wait(Duration::from_secs(20));
        let load_after = load_average();
        let Some((from, to)) = window else {
            bail!(
                "no pose was received from the node; see {}",
                dir.join("node.log").display()
            );
        };
        let mut by_stage: BTreeMap<Stage, Vec<f64>> = BTreeMap::new();
        let mut persons = BTreeSet::new();
        for s in samples.iter().filter(|s| (from..to).contains(&s.stamp_ns)) {
            by_stage.entry(s.stage).or_default().push(s.latency_ms);
            if s.stage == Stage::Pose {
                persons.insert(s.person.clone());
            }
        }
        // Statuses repeat a revision: each counts where it was first seen.
        let mut first_seen: BTreeMap<(String, u32), i64> = BTreeMap::new();
        for (p, r, at) in revisions {
            first_seen.entry((p, r)).or_insert(at);
        }
        let reconstructions = first_seen
            .values()
            .filter(|at| (from..to).contains(*at))
            .count();
        write_samples(&dir.join("samples.csv"), &samples)?;
        Ok(Measured {
            people: self.people,
            load_before,
            load_after,
            samples: by_stage,
            reconstructions,
            persons: persons.len(),
            window: Duration::from_nanos((to - from) as u64),
        })
    }

    /// The node's config file and overrides: the launch config a user would start from, its
    /// camera pointed at the load on loopback, the live page on `port`, files under `dir`.
    fn node_config(&self, dir: &Path, domain: u16, port: u16) -> (PathBuf, Vec<String>) {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let file = if self.people > 1 {
            "launch_configs/people.yaml"
        } else {
            "launch_configs/camera.yaml"
        };
        let mut overrides = vec![
            "inputs.image_topics=[]".to_string(),
            "inputs.compressed_image_topics=[/loadgen/cam0/image_raw/compressed]".into(),
            "inputs.camera_info_topics=[/loadgen/cam0/camera_info]".into(),
            "inputs.image_qos=sensor_data".into(),
            "dds_interfaces=[127.0.0.1]".into(),
            format!("domain_id={domain}"),
            format!("outputs.dir={}", dir.join("files").display()),
            format!("outputs.web=127.0.0.1:{port}"),
            "outputs.ros=true".into(),
            "outputs.camera_pose=true".into(),
            // Every frame is a new view: the views keep changing, reconstructions keep running.
            "frame_store.duplicate_similarity=1".into(),
        ];
        if self.people > 1 {
            overrides.push("replay.bag=''".into());
        }
        (root.join(file), overrides)
    }
}

/// A child process, killed when dropped.
struct Running {
    child: Child,
}

impl Running {
    fn spawn(cmd: &mut Command, what: &str) -> Result<Self> {
        let child = cmd.spawn().with_context(|| format!("starting {what}"))?;
        Ok(Self { child })
    }

    fn try_wait(&mut self) -> Result<Option<std::process::ExitStatus>> {
        Ok(self.child.try_wait()?)
    }

    /// SIGINT, then up to `grace` for the process to end, then SIGKILL.
    fn interrupt_and_wait(mut self, grace: Duration) {
        // SAFETY: kill(2) on our own child's pid.
        unsafe {
            libc::kill(self.child.id() as i32, libc::SIGINT);
        }
        let deadline = Instant::now() + grace;
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

fn file(path: &Path) -> Result<std::fs::File> {
    std::fs::File::create(path).with_context(|| format!("{}", path.display()))
}

fn secs_ns(s: u64) -> i64 {
    s as i64 * 1_000_000_000
}

/// Nanoseconds since the epoch now.
pub(crate) fn unix_ns() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as i64)
}

/// A domain from this process id whose ports stay outside the ephemeral range (1–100).
fn default_domain() -> u16 {
    1 + (std::process::id() % 100) as u16
}

fn free_port() -> Result<u16> {
    Ok(std::net::TcpListener::bind("127.0.0.1:0")
        .context("finding a free port")?
        .local_addr()?
        .port())
}

/// `/proc/loadavg`'s three averages.
fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_else(|| "?".into())
}

/// The `q` quantile (0..=1) of sorted `v`, nearest rank.
fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let rank = (q * sorted.len() as f64).ceil() as usize;
    sorted[rank.clamp(1, sorted.len()) - 1]
}

fn print_table(args: &LatencyBenchArgs, browser: bool, results: &[Measured]) {
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    println!(
        "\nlatency from the camera frame's stamp ({}: {cores} cores, 1 camera × {} Hz × {}×{} JPEG, \
         reconstructions running; {} s measured after {} s)",
        args.label, args.rate, args.width, args.height, args.seconds, args.warmup
    );
    println!(
        "| people | stage | samples | p50 ms | p95 ms | p99 ms | max ms | reconstructions | load avg before / after |"
    );
    println!("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | --- |");
    for m in results {
        for stage in Stage::ALL {
            if stage == Stage::Page && !browser {
                continue;
            }
            let mut v = m.samples.get(&stage).cloned().unwrap_or_default();
            v.sort_by(f64::total_cmp);
            let cell = |q: f64| {
                if v.is_empty() {
                    "—".to_string()
                } else {
                    format!("{:.1}", quantile(&v, q))
                }
            };
            println!(
                "| {} | {} | {} | {} | {} | {} | {} | {} | {} / {} |",
                m.people,
                stage.label(),
                v.len(),
                cell(0.50),
                cell(0.95),
                cell(0.99),
                cell(1.0),
                m.reconstructions,
                m.load_before,
                m.load_after
            );
        }
        println!(
            "  ({} people: poses of {} person(s) received, {} avatar revisions in {:.0} s)",
            m.people,
            m.persons,
            m.reconstructions,
            m.window.as_secs_f64()
        );
    }
}

fn write_csv(args: &LatencyBenchArgs, results: &[Measured]) -> Result<()> {
    let path = args.report.join(format!("{}-summary.csv", args.label));
    let mut text =
        String::from("people,stage,samples,p50_ms,p95_ms,p99_ms,max_ms,reconstructions\n");
    for m in results {
        for (stage, v) in &m.samples {
            let mut v = v.clone();
            v.sort_by(f64::total_cmp);
            text.push_str(&format!(
                "{},{},{},{:.2},{:.2},{:.2},{:.2},{}\n",
                m.people,
                stage.label(),
                v.len(),
                quantile(&v, 0.5),
                quantile(&v, 0.95),
                quantile(&v, 0.99),
                quantile(&v, 1.0),
                m.reconstructions
            ));
        }
    }
    std::fs::write(&path, text).with_context(|| format!("{}", path.display()))?;
    println!("samples and logs under {}/", args.report.display());
    Ok(())
}

fn write_samples(path: &Path, samples: &[Sample]) -> Result<()> {
    let mut text = String::from("stage,person,stamp_ns,latency_ms\n");
    for s in samples {
        text.push_str(&format!(
            "{},{},{},{:.3}\n",
            s.stage.label(),
            s.person,
            s.stamp_ns,
            s.latency_ms
        ));
    }
    std::fs::write(path, text).with_context(|| format!("{}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_are_nearest_rank() {
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        assert_eq!(quantile(&v, 0.5), 50.0);
        assert_eq!(quantile(&v, 0.95), 95.0);
        assert_eq!(quantile(&v, 0.99), 99.0);
        assert_eq!(quantile(&v, 1.0), 100.0);
        assert_eq!(quantile(&[7.0], 0.5), 7.0);
        assert!(quantile(&[], 0.5).is_nan());
    }
}
