//! Running the node: wires an input source (live ROS 2 subscriptions or a bag replay) and the
//! ROS 2 publishers to the [`Pipeline`] on the calling thread, until the bag ends
//! (`replay.exit_when_done`) or SIGINT/SIGTERM. Live, the pipeline's reconstructions and
//! renders run on threads of their own beside it ([`Pipeline::work_beside`]). The tokio
//! runtime hosts only the DDS endpoint, the live page and the signal handlers.

use super::memory_trim::{trim_period, MemoryTrimmer};
use super::outputs::{Fanout, Publisher, RosPublisher, ShmOutputs, WebPublisher};
use super::pipeline::membership::HEARTBEAT_PERIOD;
use super::pipeline::{Pipeline, PipelineError, PipelineStats};
use super::replay::{BagReplay, Replayed};
use super::ros::{LiveInputs, ResolvedTopics, RosError, RosNode, RosNodeOptions};
use crate::bag::Salvage;
use crate::config::NodeConfig;
use crate::node::rejections::Rejections;
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Frames of the walk animation written at the end of a replay (24 fps → 1 s).
const ANIMATION_FRAMES: usize = 24;
/// Wake-up period of the live loop when nothing is scheduled.
const IDLE_WAIT: Duration = Duration::from_millis(200);

/// Why the node could not run.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The pipeline could not start.
    #[error(transparent)]
    Pipeline(#[from] PipelineError),
    /// The ROS 2 endpoint could not start.
    #[error("ROS 2: {0}")]
    Ros(#[from] RosError),
    /// The bag could not be opened.
    #[error(transparent)]
    Bag(#[from] crate::bag::BagError),
    /// The shared-memory outputs could not start.
    #[error("shared memory: {0}")]
    Shm(#[from] crate::transport::ShmError),
    /// The async runtime could not start.
    #[error("tokio runtime: {0}")]
    Runtime(#[from] std::io::Error),
    /// The live page could not start.
    #[error("live page: {0}")]
    Web(#[from] crate::web::WebError),
}

/// What a run did.
#[derive(Debug, Clone)]
pub struct RunSummary {
    /// Pipeline counters.
    pub stats: PipelineStats,
    /// Input messages rejected on every path (live, replay, pipeline), by reason.
    pub rejections: Rejections,
    /// Live messages dropped by the per-topic rate limit (`inputs.max_rate_hz`).
    pub rate_limited: u64,
    /// Live messages decoded into input events (before the input queue), all topics.
    pub received: u64,
    /// Live input events the full input queue dropped (`inputs` overflow policy).
    pub queue_dropped: u64,
    /// Frames perception dropped unperceived (a newer frame of their camera came first).
    pub perception_dropped: u64,
    /// What reading the replayed bag skipped (`None` for a live run).
    pub bag: Option<Salvage>,
    /// Views held at the end.
    pub views_held: usize,
    /// The body shape in use at the end (`GaussianAvatar.shape_params`; empty: the template's).
    pub shape_params: Vec<f32>,
    /// Latest avatar revision.
    pub revision: u64,
    /// Views the network encoded.
    pub encoded_views: usize,
    /// Animation frames written at the end of a replay.
    pub animation_frames: usize,
    /// What the files under `outputs.dir` took and gave back (`None`: no files written).
    pub files: Option<crate::node::outputs::DiskUsage>,
    /// Every person followed at the end (one without tracking).
    pub persons: Vec<PersonSummary>,
    /// The person tracker's counters (`tracking.enabled` only).
    pub tracking: Option<crate::tracking::TrackingStats>,
    /// Wall time.
    pub wall: Duration,
}

/// One followed person at the end of a run.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PersonSummary {
    /// Person id.
    pub id: String,
    /// Whether this node reconstructs them (`cluster`).
    pub reconstructed_here: bool,
    /// Views held.
    pub views: usize,
    /// Latest avatar revision (0: none).
    pub revision: u64,
}

/// Runs the node with `config`; `remap` holds command-line topic remappings.
pub fn run(config: &NodeConfig, remap: BTreeMap<String, String>) -> Result<RunSummary, RunError> {
    run_with(config, remap, None)
}

/// [`run`] with the live page's token (`lhmpp run --web-token`), which `outputs.web` needs
/// on any address other than loopback.
pub fn run_with(
    config: &NodeConfig,
    remap: BTreeMap<String, String>,
    web_token: Option<String>,
) -> Result<RunSummary, RunError> {
    let started = Instant::now();
    let clock = move || started.elapsed();
    let options = RosNodeOptions::from_config(
        config,
        remap,
        std::env::var("ROS_DOMAIN_ID").ok().as_deref(),
    )?;
    // Everything that can fail on the config alone (network, checkpoint, prior, devices,
    // output directory, bag) is set up before the DDS participant is created, so such a
    // config fails with its own error and no DDS traffic or log.
    let mut pipeline = Pipeline::new(config, None)?;
    let topics = ResolvedTopics::from_options(&options)?;
    pipeline.set_masked_cameras(topics.camera_masks.iter().map(|(_, camera)| camera.clone()));
    pipeline.set_cameras(
        topics
            .images
            .iter()
            .chain(&topics.compressed_images)
            .cloned()
            .collect(),
    );
    let live = config.replay.bag.is_empty();
    let mut replay = if live {
        None
    } else {
        Some(BagReplay::open(
            Path::new(&config.replay.bag),
            topics,
            config.inputs.max_image_side,
        )?)
    };
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()?;
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        runtime.spawn(async move {
            super::signal::interrupt_or_terminate().await;
            tracing::info!("shutdown requested");
            stop.store(true, Ordering::SeqCst);
        });
    }
    // Live inputs wait in the endpoint's one bounded queue (its overflow policy applies and
    // counts what it drops) until the pipeline takes them on this thread.
    let mut inputs = None;
    let ros = if config.outputs.ros || live {
        let _guard = runtime.enter();
        let (node, queue) = RosNode::start_with_clock(&options, started)?;
        tracing::info!(domain = node.domain_id(), topics = ?node.topics(), "ROS 2 endpoint up");
        if live {
            inputs = Some(queue);
            if config.tracking.enabled && config.cluster.members > 1 {
                // Live: the members hear each other's heartbeats, and a silent one's persons
                // go to the others.
                pipeline.expect_heartbeats(started.elapsed());
            }
        }
        Some(Arc::new(node))
    } else {
        None
    };
    let mut publishers: Vec<Box<dyn Publisher>> = Vec::new();
    if let (Some(node), true) = (&ros, config.outputs.ros) {
        publishers.push(Box::new(RosPublisher(node.clone())));
    }
    if config.outputs.shm {
        let shm = ShmOutputs::new(
            &config.person_id,
            config.outputs.virtual_cameras,
            2 * config.tracking.max_persons,
        )?;
        tracing::info!(services = ?shm.services(), "shared-memory outputs up");
        publishers.push(Box::new(shm));
    }
    let web = match config.outputs.web.parse::<std::net::SocketAddr>() {
        Ok(addr) => {
            let state = Arc::new(crate::web::LiveState::default());
            let server =
                crate::web::WebServer::start(addr, web_token, state.clone(), runtime.handle())?;
            publishers.push(Box::new(WebPublisher(state)));
            Some(server)
        }
        // Empty: off (anything else was refused when the config was validated).
        Err(_) => None,
    };
    pipeline.set_publisher(
        (!publishers.is_empty()).then(|| Box::new(Fanout(publishers)) as Box<dyn Publisher>),
    );
    if live {
        // Live, the pose path must not wait for reconstructions or renders; a replay runs
        // them in order on this thread (the same avatars whatever the machine's speed).
        pipeline.work_beside();
    }
    let mut animation_frames = 0;
    if let Some(replay) = &mut replay {
        tracing::info!(bag = %config.replay.bag, messages = replay.len(), "replaying");
        run_replay(&mut pipeline, replay, config.replay.rate, &stop, &clock);
        if !stop.load(Ordering::SeqCst) && pipeline.refine_at_end(clock()) {
            tracing::info!("refining the avatars against their views (refine.enabled)");
            settle(&mut pipeline, &stop, &clock);
        }
        if !stop.load(Ordering::SeqCst) && config.replay.exit_when_done {
            animation_frames = pipeline.write_animation(ANIMATION_FRAMES);
        } else if !config.replay.exit_when_done {
            run_live(&mut pipeline, None, None, &stop, &clock);
        }
    } else {
        let _trimmer = trim_period().map(MemoryTrimmer::start);
        run_live(
            &mut pipeline,
            inputs.as_mut(),
            ros.as_deref(),
            &stop,
            &clock,
        );
    }
    let input_stats = ros.as_ref().map(|n| n.input_stats()).unwrap_or_default();
    let summary = RunSummary {
        stats: pipeline.stats().clone(),
        rejections: pipeline.rejections(),
        rate_limited: input_stats.rate_limited.values().sum(),
        received: input_stats.accepted.values().sum(),
        queue_dropped: input_stats.queue_dropped,
        perception_dropped: pipeline.perception_dropped(),
        bag: replay.as_ref().map(|r| r.salvage().clone()),
        views_held: pipeline.views_held(),
        shape_params: pipeline.shape_params(),
        revision: pipeline.revision(),
        encoded_views: pipeline.encoded_views(),
        animation_frames,
        files: pipeline.disk_usage(),
        persons: pipeline
            .persons()
            .into_iter()
            .map(|id| PersonSummary {
                reconstructed_here: pipeline.reconstructs(&id),
                views: pipeline.views_held_by(&id),
                revision: pipeline.revision_of(&id),
                id,
            })
            .collect(),
        tracking: pipeline.tracking_stats(),
        wall: started.elapsed(),
    };
    drop(pipeline);
    drop(web);
    if let Some(node) = ros {
        match Arc::try_unwrap(node) {
            Ok(node) => node.shutdown(),
            Err(_) => tracing::warn!("ROS 2 endpoint still shared at shutdown"),
        }
    }
    runtime.shutdown_timeout(Duration::from_secs(2));
    Ok(summary)
}

/// Feeds live events until a stop is requested; runs due work in between. `inputs`: the
/// subscriptions whose rejection counts the pipeline reports.
fn run_live(
    pipeline: &mut Pipeline,
    mut events: Option<&mut LiveInputs>,
    inputs: Option<&RosNode>,
    stop: &AtomicBool,
    clock: &impl Fn() -> Duration,
) {
    let sync = |pipeline: &mut Pipeline| {
        if let Some(node) = inputs {
            pipeline.set_input_rejections(node.input_stats().rejections);
        }
    };
    let mut next_heartbeat = Duration::ZERO;
    while !stop.load(Ordering::SeqCst) {
        sync(pipeline);
        let now = clock();
        if let (Some(node), Some(_), true) = (inputs, pipeline.heartbeat(), now >= next_heartbeat) {
            if let Err(e) = node.publish_heartbeat() {
                tracing::warn!("cluster heartbeat: {e}");
            }
            next_heartbeat = now + HEARTBEAT_PERIOD;
        }
        let wait = pipeline
            .next_deadline()
            .map_or(IDLE_WAIT, |d| d.saturating_sub(now).min(IDLE_WAIT))
            .min(HEARTBEAT_PERIOD);
        match events.as_deref_mut() {
            Some(queue) if !(queue.is_closed() && queue.is_empty()) => {
                if let Some(event) = queue.recv_timeout(wait) {
                    pipeline.handle(event, clock());
                }
            }
            _ => std::thread::sleep(wait),
        }
        pipeline.step(clock(), clock);
    }
    // The run summary counts what the subscriptions rejected up to the stop.
    sync(pipeline);
}

/// Plays the bag into the pipeline (paced by `rate`, or as fast as consumed when 0), counting
/// the messages that do not decode, then waits for the last reconstruction.
pub fn run_replay(
    pipeline: &mut Pipeline,
    replay: &mut BagReplay,
    rate: f64,
    stop: &AtomicBool,
    clock: &impl Fn() -> Duration,
) {
    let begin = clock();
    while let Some((offset, item)) = replay.next(clock) {
        if stop.load(Ordering::SeqCst) {
            return;
        }
        if rate > 0.0 {
            let due = begin + offset.div_f64(rate);
            while clock() < due && !stop.load(Ordering::SeqCst) {
                pipeline.step(clock(), clock);
                let now = clock();
                let until = pipeline.next_deadline().map_or(due, |d| d.min(due));
                std::thread::sleep(until.saturating_sub(now).min(IDLE_WAIT));
            }
        }
        match item {
            Replayed::Event(event) => pipeline.handle(event, clock()),
            Replayed::Rejected {
                topic,
                reason,
                detail,
            } => pipeline.reject(&topic, reason, &detail),
        }
        pipeline.step(clock(), clock);
    }
    // The bag is over: let the debounce expire and the last reconstruction run.
    settle(pipeline, stop, clock);
}

/// Steps `pipeline` until nothing is due or in flight (or `stop`).
fn settle(pipeline: &mut Pipeline, stop: &AtomicBool, clock: &impl Fn() -> Duration) {
    while !pipeline.idle() && !stop.load(Ordering::SeqCst) {
        let now = clock();
        if let Some(d) = pipeline.next_deadline() {
            std::thread::sleep(d.saturating_sub(now).min(IDLE_WAIT));
        }
        pipeline.step(clock(), clock);
    }
}
