//! Executing a [`Plan`] on one arena: each step reads its input ranges and writes its output
//! range through the NHWC kernels.

use std::time::{Duration, Instant};

use crate::kernels::nhwc::{self, Epilogue};
use crate::kernels::parallel;

use super::plan::{Plan, Step, StepKind};

impl Plan {
    /// Runs every step on `arena` (at least [`Plan::arena_len`] floats, the input already in
    /// place); with `times`, adds each step's wall time to its entry. The steps share the
    /// current rayon pool's threads as one team for the whole run ([`parallel::with_team`]).
    pub(crate) fn execute(&self, arena: &mut [f32], times: Option<&mut [Duration]>) {
        parallel::with_team(|| self.execute_steps(arena, times));
    }

    fn execute_steps(&self, arena: &mut [f32], mut times: Option<&mut [Duration]>) {
        assert!(arena.len() >= self.arena_len, "arena too small");
        let base = arena.as_mut_ptr();
        for (i, step) in self.steps.iter().enumerate() {
            let start = times.is_some().then(Instant::now);
            let read = |t: usize| -> &[f32] {
                let r = self.slots[t].as_ref().expect("read tensors have slots");
                // SAFETY: the range lies inside the arena (placed within `arena_len`), and
                // `compile` checked that no step's read range overlaps its write range; only
                // the write range is borrowed mutably while this step runs.
                unsafe { std::slice::from_raw_parts(base.add(r.start), r.len()) }
            };
            let w = self.slots[step.write]
                .as_ref()
                .expect("written tensors have slots");
            // SAFETY: inside the arena and disjoint from every range this step reads (see above).
            let out = unsafe { std::slice::from_raw_parts_mut(base.add(w.start), w.len()) };
            run_step(step, &read, out);
            if let (Some(t), Some(s)) = (times.as_deref_mut(), start) {
                t[i] += s.elapsed();
            }
        }
    }
}

fn run_step<'a>(step: &Step, read: &impl Fn(usize) -> &'a [f32], out: &mut [f32]) {
    let input = || read(step.reads[0]);
    match &step.kind {
        StepKind::Conv {
            conv,
            input: shape,
            pad,
            pre,
            residual,
            post,
        } => {
            let epi = Epilogue {
                pre: *pre,
                residual: residual.map(read),
                post: *post,
            };
            conv.run(input(), *shape, *pad, epi, out);
        }
        StepKind::SparseConv {
            conv,
            pixels,
            pre,
            residual,
            post,
        } => {
            let epi = Epilogue {
                pre: *pre,
                residual: residual.map(read),
                post: *post,
            };
            conv.run(input(), *pixels, epi, out);
        }
        StepKind::Depthwise {
            dw,
            input: shape,
            pad,
            pre,
            residual,
            post,
        } => {
            let epi = Epilogue {
                pre: *pre,
                residual: residual.map(read),
                post: *post,
            };
            dw.run(input(), *shape, *pad, epi, out);
        }
        StepKind::Add { act } => nhwc::add(input(), read(step.reads[1]), out, *act),
        StepKind::Pad {
            input: shape,
            pad,
            channels,
        } => nhwc::pad(input(), *shape, *pad, *channels, out),
        StepKind::MaxPool {
            input: shape,
            window,
            stride,
            pad,
            act,
        } => nhwc::max_pool(input(), *shape, *window, *stride, *pad, *act, out),
        StepKind::Resize {
            input: shape,
            size,
            residual,
        } => nhwc::resize_bilinear_half_pixel(input(), *shape, *size, residual.map(read), out),
        StepKind::DepthToSpace {
            input: shape,
            block,
        } => nhwc::depth_to_space(input(), *shape, *block, out),
        StepKind::Copy => out.copy_from_slice(input()),
        StepKind::Concat { outer, inners, act } => {
            let parts: Vec<(&[f32], usize)> = step.reads[..inners.len()]
                .iter()
                .zip(inners)
                .map(|(&t, &inner)| (read(t), inner))
                .collect();
            nhwc::concat(&parts, *outer, *act, out);
        }
        StepKind::Logistic => nhwc::logistic(input(), out),
    }
}
