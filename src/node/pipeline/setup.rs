//! Building the pipeline from the node config: the network, the outputs (files first, then
//! the live publishers), the frame renderers, perception and the pose estimator each person
//! gets a copy of.

use super::calibration::Calibration;
use super::jobs::{self, SharedNetwork};
use super::lane::Lane;
use super::masks::MaskPairing;
use super::membership::Membership;
use super::neural_frames::{choose_renderer, FrameSource, NeuralFrames, RendererSetupError};
use super::perceive::{Finders, MaskSettings, Perception};
use super::render::{FrameRasterizer, FrameRasterizerError, FrameRenderer, VirtualCameras};
use super::{PersonSetup, Pipeline, PipelineStats};
use crate::config::{NodeConfig, PoseSource};
use crate::node::frame_store::StoreLimits;
use crate::node::outputs::{Fanout, FileOutputs, Publisher, Retention};
use crate::node::rejections::Rejections;
use crate::node::scheduler::SchedulerConfig;
use crate::perception::pose::{PoseEstimator, PoseEstimatorConfig};
use crate::perception::shape::ShapeReader;
use crate::perception::PerceptionError;
use crate::reconstruct::preprocess::PreprocessConfig;
use crate::reconstruct::{ReconstructError, Reconstructor};
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// Masks kept to pair with frames by stamp (and camera, for per-camera mask topics).
const MASKS_KEPT: usize = 32;
/// How long a frame of a camera with its own mask topic waits for its mask.
const MASK_WAIT: Duration = Duration::from_millis(150);

/// Errors that stop the pipeline from starting.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// The network or body template could not be set up.
    #[error(transparent)]
    Reconstruct(#[from] ReconstructError),
    /// The frame rasteriser's device is unavailable.
    #[error(transparent)]
    Rasterizer(#[from] FrameRasterizerError),
    /// The perception networks could not be loaded.
    #[error("perception: {0}")]
    Perception(#[from] PerceptionError),
    /// The pose solver does not fit the body template.
    #[error("perception pose: {0}")]
    PoseSolver(#[from] crate::perception::pose::PoseSolveError),
    /// `outputs.renderer` cannot be honoured with this network.
    #[error(transparent)]
    Renderer(#[from] RendererSetupError),
}

/// The pipeline `config` describes, publishing to the files and `publisher`.
pub(super) fn pipeline(
    config: &NodeConfig,
    publisher: Option<Box<dyn Publisher>>,
) -> Result<Pipeline, PipelineError> {
    // The token cache holds every person's views.
    let people = if config.tracking.enabled {
        config.tracking.max_persons
    } else {
        1
    };
    let recon = Reconstructor::new(&config.model, config.frame_store.max_views * people)?;
    let (h, w) = recon.input_size();
    let rgb = recon.rgb_kind();
    // An unusable output directory costs the files only: the ROS 2 and shared-memory
    // outputs go on.
    let files = (!config.outputs.dir.is_empty())
        .then(|| {
            FileOutputs::new(
                Path::new(&config.outputs.dir),
                Retention::from_config(&config.outputs),
            )
        })
        .and_then(|made| {
            made.map_err(|e| {
                tracing::error!(
                    "outputs.dir `{}`: {e}; no avatar PLY files or PNG frames will be \
                     written, the ROS 2 and shared-memory outputs go on",
                    config.outputs.dir
                )
            })
            .ok()
        })
        .map(|f| match rgb.display_ready() {
            true => f,
            false => f.with_latent_rgb(recon.checkpoint_kind()),
        })
        .map(|f| Box::new(f) as Box<dyn Publisher>);
    // The files first (an avatar's PLY is written before it is published), then the live
    // publishers.
    let outputs = Arc::new(Fanout(files.into_iter().chain(publisher).collect()));
    let cameras = VirtualCameras::ring(
        config.outputs.virtual_cameras,
        config.outputs.render_size,
        recon.template().height(),
    );
    let rasterizer = FrameRasterizer::new(config.outputs.render_device)?;
    let decision = choose_renderer(
        config.outputs.renderer,
        rgb,
        recon.feature_channels(),
        recon.background_channels(),
        recon.neural_renderer_config().in_channels,
    )?;
    let neural = match decision.source {
        FrameSource::Gaussians => None,
        FrameSource::Neural => Some(NeuralFrames::new(
            recon.neural_renderer(),
            &recon.white_background_feature()?,
        )?),
    };
    tracing::info!(
        renderer = match decision.source {
            FrameSource::Gaussians => "gaussians",
            FrameSource::Neural => "neural",
        },
        checkpoint = recon.checkpoint_kind(),
        "frames: {}",
        decision.reason
    );
    let render_period = (config.outputs.render_rate_hz > 0.0)
        .then(|| Duration::from_secs_f64(1.0 / config.outputs.render_rate_hz));
    let perception = perception_stage(config)?;
    let camera_pose = perception.is_some()
        && matches!(
            config.inputs.pose_source,
            PoseSource::Auto | PoseSource::Camera
        );
    let reader = if perception.is_some()
        && config.perception.estimate_shape
        && recon.body_model() == crate::body::MAKEHUMAN_MODEL_ID
    {
        Some(ShapeReader::new(
            &crate::body::BodyTemplate::load_default()
                .map_err(|e| PipelineError::Reconstruct(ReconstructError::Body(e)))?,
        )?)
    } else {
        None
    };
    let neural_frames = neural.is_some();
    let calibration = Calibration::new(
        &config.outputs.world_frame,
        reader,
        config.perception.min_visibility,
    );
    let estimator = if camera_pose {
        let mut cfg = PoseEstimatorConfig::default();
        cfg.solver.min_visibility = config.perception.min_visibility;
        Some(PoseEstimator::new(recon.template(), cfg)?)
    } else {
        None
    };
    tracing::info!(
        preset = %config.model.preset,
        weights = recon.weights(),
        points = config.model.num_points,
        input = %format!("{h}x{w}"),
        "reconstruction network ready"
    );
    let refine_news = Arc::new(std::sync::atomic::AtomicU64::new(0));
    Ok(Pipeline {
        default_person: config.person_id.clone(),
        tracking: config.tracking.enabled,
        membership: Membership::new(&config.cluster),
        persons: BTreeMap::new(),
        setup: PersonSetup {
            limits: StoreLimits::from(&config.frame_store),
            schedule: SchedulerConfig::from_debounce_ms(config.frame_store.debounce_ms),
            source: config.inputs.pose_source,
            estimator,
            publish_pose: config
                .outputs
                .camera_pose
                .then(|| config.outputs.world_frame.clone()),
        },
        network: SharedNetwork::new(recon),
        jobs: Lane::inline(),
        drawing: Lane::inline(),
        drawing_frames: false,
        drawing_preview: false,
        lanes_due: Duration::ZERO,
        preprocess: PreprocessConfig {
            out_height: h,
            out_width: w,
            ..PreprocessConfig::default()
        },
        next_frame_id: 1,
        masks: MaskPairing::new(MASKS_KEPT, Vec::new(), MASK_WAIT),
        person_mask: config.inputs.person_mask,
        shared_mask_topic: !config.inputs.mask_topic.trim().is_empty(),
        perception,
        perception_due: Duration::ZERO,
        colours_from_views: config.perception.colours_from_views,
        delight: config.perception.delight,
        refine: config.refine.enabled.then(|| jobs::RefinePlan {
            config: config.refine.fit_config(),
            news: refine_news.clone(),
            since: 0,
        }),
        refine_news,
        refine_inline: false,
        calibration,
        outputs,
        publish_masks: config.outputs.masks,
        cameras: Arc::new(cameras),
        frames: Arc::new(Mutex::new(FrameRenderer::new(rasterizer, neural))),
        neural_frames,
        render_period,
        render_rate_hz: config.outputs.render_rate_hz,
        next_render: Duration::ZERO,
        preview_period: (config.outputs.preview_rate_hz > 0.0)
            .then(|| Duration::from_secs_f64(1.0 / config.outputs.preview_rate_hz)),
        next_preview: Duration::ZERO,
        drop_debt: 0.0,
        slow_render_noted: false,
        stats: PipelineStats::default(),
        input_rejections: Rejections::default(),
        status_refresh_due: Duration::ZERO,
    })
}

/// The perception stage `config` needs: none when no camera can be routed to perception and
/// the pose does not come from the cameras; live runs perceive on a worker thread, bag
/// replays every frame in order.
fn perception_stage(config: &NodeConfig) -> Result<Option<Perception>, PerceptionError> {
    if !config.runs_perception() {
        return Ok(None);
    }
    let p = &config.perception;
    let model = p.landmark_model.model();
    let networks = Arc::new(p.networks()?);
    let live = config.replay.bag.is_empty();
    tracing::info!(
        landmark_model = model.name(),
        threads = p.threads,
        mode = if live {
            "worker, newest frame per camera"
        } else {
            "every frame, in order"
        },
        "camera-only perception ready"
    );
    let finders = if config.tracking.enabled {
        tracing::info!(
            max_persons = config.tracking.max_persons,
            cluster_members = config.cluster.members,
            cluster_index = config.cluster.index,
            "several people: MoveNet MultiPose, the landmark model per person, tracked ids"
        );
        Finders::many(networks.clone(), p.people(), config.tracking.tracker())
    } else {
        Finders::one(p.tracker(live))
    };
    Ok(Some(Perception::new(
        networks,
        finders,
        MaskSettings {
            threshold: p.mask_threshold,
            feather: p.mask_feather,
        },
        p.threads,
        live,
    )))
}
