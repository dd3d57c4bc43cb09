//! Per-person pose state: One-Euro filtering of the landmarks, the solver, and what hidden
//! segments do.
//!
//! A segment ([`Segment`]) whose landmarks are not all visible (visibility below
//! [`SolverConfig::min_visibility`]) keeps its last solved rotations for
//! [`PoseEstimatorConfig::hold_s`] seconds, then eases back to rest (identity local
//! rotations; the identity root rotation for the root) over
//! [`PoseEstimatorConfig::ease_s`] seconds along a smoothstep; a segment never seen stays at
//! rest. Its children are still solved from their own landmarks, against the held parent.

use super::ik::{PoseSolver, SolverConfig};
use super::one_euro::{OneEuroConfig, OneEuroFilter};
use super::rotation::smoothstep;
use super::segment::{BoneRotations, Segment};
use super::PoseSolveError;
use crate::body::{BodyTemplate, Pose};
use crate::perception::{Landmark, BODY_LANDMARKS};
use glam::{Quat, Vec3};

/// Estimator settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseEstimatorConfig {
    /// Solver settings (axes, root translation, visibility threshold, limits).
    pub solver: SolverConfig,
    /// One-Euro filter on landmark positions; `None` for raw landmarks.
    pub filter: Option<OneEuroConfig>,
    /// How long a hidden segment keeps its last rotation, seconds.
    pub hold_s: f64,
    /// How long it then takes to ease back to rest, seconds.
    pub ease_s: f64,
}

impl Default for PoseEstimatorConfig {
    fn default() -> Self {
        Self {
            solver: SolverConfig::default(),
            filter: Some(OneEuroConfig::default()),
            hold_s: 0.5,
            ease_s: 1.0,
        }
    }
}

/// The live pose of one tracked person.
#[derive(Debug, Clone)]
pub struct PoseEstimator {
    solver: PoseSolver,
    config: PoseEstimatorConfig,
    /// One filter per landmark, when filtering.
    filters: Option<Vec<OneEuroFilter>>,
    last_good: BoneRotations,
    last_good_time: [Option<f64>; Segment::COUNT],
    last_solved: [bool; Segment::COUNT],
}

impl PoseEstimator {
    /// An estimator posing `template`'s skeleton (MakeHuman or SMPL-X).
    pub fn new(
        template: &BodyTemplate,
        config: PoseEstimatorConfig,
    ) -> Result<Self, PoseSolveError> {
        let solver = PoseSolver::new(template, config.solver)?;
        Ok(Self::with_solver(solver, config))
    }

    /// An estimator around an existing solver (its settings replace `config.solver`).
    pub fn with_solver(solver: PoseSolver, mut config: PoseEstimatorConfig) -> Self {
        config.solver = *solver.config();
        Self {
            filters: config
                .filter
                .map(|f| vec![OneEuroFilter::new(f); BODY_LANDMARKS]),
            last_good: BoneRotations::rest(solver.bone_count()),
            last_good_time: [None; Segment::COUNT],
            last_solved: [false; Segment::COUNT],
            solver,
            config,
        }
    }

    /// The solver.
    pub fn solver(&self) -> &PoseSolver {
        &self.solver
    }

    /// Which segments the last update solved from landmarks ([`Segment::index`]).
    pub fn last_solved(&self) -> [bool; Segment::COUNT] {
        self.last_solved
    }

    /// Forgets the person: filters restart and every segment is at rest.
    pub fn reset(&mut self) {
        for filter in self.filters.iter_mut().flatten() {
            filter.reset();
        }
        self.last_good = BoneRotations::rest(self.solver.bone_count());
        self.last_good_time = [None; Segment::COUNT];
        self.last_solved = [false; Segment::COUNT];
    }

    /// The pose at time `t` (seconds, increasing) from this frame's world landmarks
    /// (camera axes, metres, hip-centred).
    pub fn update(&mut self, t: f64, world: &[Landmark; BODY_LANDMARKS]) -> Pose {
        let min_visibility = self.config.solver.min_visibility;
        let visible: [bool; BODY_LANDMARKS] = std::array::from_fn(|i| {
            world[i].visibility >= min_visibility && world[i].position.is_finite()
        });
        let positions: [Vec3; BODY_LANDMARKS] = std::array::from_fn(|i| {
            let raw = world[i].position;
            match &mut self.filters {
                Some(filters) if visible[i] => filters[i].filter(t, raw),
                _ => raw,
            }
        });
        let fallback = self.fallback(t);
        let solved = self.solver.solve(&positions, &visible, &fallback);
        for segment in Segment::ALL {
            if !solved.solved[segment.index()] {
                continue;
            }
            self.last_good_time[segment.index()] = Some(t);
            if segment == Segment::Root {
                self.last_good.root = solved.rotations.root;
            }
            for &b in self.solver.segment_bones(segment) {
                self.last_good.locals[b] = solved.rotations.locals[b];
            }
        }
        self.last_solved = solved.solved;
        self.solver.to_pose(&solved.rotations)
    }

    /// How far (0 = held, 1 = at rest) a segment last solved at `since` has eased at `t`.
    fn ease(&self, since: Option<f64>, t: f64) -> f32 {
        let Some(since) = since else { return 1.0 };
        let age = t - since - self.config.hold_s;
        if age <= 0.0 {
            0.0
        } else if self.config.ease_s <= 0.0 {
            1.0
        } else {
            smoothstep((age / self.config.ease_s) as f32)
        }
    }

    /// Rotations for segments that cannot be solved at `t`.
    fn fallback(&self, t: f64) -> BoneRotations {
        let mut out = BoneRotations::rest(self.solver.bone_count());
        for segment in Segment::ALL {
            let e = self.ease(self.last_good_time[segment.index()], t);
            if segment == Segment::Root {
                out.root = self.last_good.root.slerp(Quat::IDENTITY, e);
            }
            for &b in self.solver.segment_bones(segment) {
                out.locals[b] = self.last_good.locals[b].slerp(Quat::IDENTITY, e);
            }
        }
        out
    }
}
