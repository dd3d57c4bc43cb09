//! Compiling a checked graph into steps over one buffer arena.
//!
//! Two rewrites remove memory passes before the steps are built: a zero PAD whose readers are
//! all VALID convolutions becomes their explicit padding (the PAD's output is never written),
//! and an ADD one of whose operands comes straight from a convolution, depthwise convolution or
//! bilinear resize read by nothing else becomes that op's residual epilogue. Every remaining
//! tensor then gets a range in one f32 arena, placed greedily by size so that tensors alive at
//! the same time never overlap (TFLite's own arena strategy).

use std::collections::HashMap;
use std::ops::Range;

use crate::kernels::conv_nhwc::ConvNhwc;
use crate::kernels::depthwise::Depthwise;
use crate::kernels::nhwc::{Activation, Padding, Shape};
use crate::kernels::sparse_pointwise::SparsePointwise;

use super::graph::{resolve_axis, Graph, Op, OpKind, PadMode};
use crate::perception::PerceptionError;

/// Arena ranges start on multiples of this many floats (one 64-byte cache line).
const ALIGN: usize = 16;

/// 1×1 layers whose weights are at most this share non-zero (and have at least
/// [`SPARSE_MIN_INPUTS`] input channels) multiply only their non-zero weights.
const SPARSE_MAX_DENSITY: f64 = 0.5;

/// See [`SPARSE_MAX_DENSITY`].
const SPARSE_MIN_INPUTS: usize = 32;

/// One executable step.
#[derive(Debug)]
pub(crate) struct Step {
    /// What the step computes, for profiles (op type, kernel, shapes).
    pub label: String,
    /// Tensor ids read: the main input first, then the other operands and the residual.
    pub reads: Vec<usize>,
    /// The tensor id written.
    pub write: usize,
    /// The computation.
    pub kind: StepKind,
}

/// The computation of a step.
#[derive(Debug)]
pub(crate) enum StepKind {
    /// A dense convolution with fused epilogue.
    Conv {
        conv: ConvNhwc,
        input: Shape,
        pad: Padding,
        pre: Activation,
        residual: Option<usize>,
        post: Activation,
    },
    /// A 1×1 convolution over mostly-zero weights with fused epilogue.
    SparseConv {
        conv: SparsePointwise,
        pixels: usize,
        pre: Activation,
        residual: Option<usize>,
        post: Activation,
    },
    /// A depthwise convolution with fused epilogue.
    Depthwise {
        dw: Depthwise,
        input: Shape,
        pad: Padding,
        pre: Activation,
        residual: Option<usize>,
        post: Activation,
    },
    /// `act(a + b)`.
    Add { act: Activation },
    /// Zero padding of an NHWC image.
    Pad {
        input: Shape,
        pad: Padding,
        channels: (usize, usize),
    },
    /// Max pooling.
    MaxPool {
        input: Shape,
        window: (usize, usize),
        stride: (usize, usize),
        pad: Padding,
        act: Activation,
    },
    /// Half-pixel bilinear resize, plus a residual.
    Resize {
        input: Shape,
        size: (usize, usize),
        residual: Option<usize>,
    },
    /// Depth to space.
    DepthToSpace { input: Shape, block: usize },
    /// A plain copy (RESHAPE).
    Copy,
    /// Concatenation of the reads: `outer` runs of `inners[i]` values each.
    Concat {
        outer: usize,
        inners: Vec<usize>,
        act: Activation,
    },
    /// The logistic function.
    Logistic,
}

/// The compiled graph.
#[derive(Debug)]
pub(crate) struct Plan {
    /// Steps in execution order.
    pub steps: Vec<Step>,
    /// Each tensor's arena range (`None` for tensors the rewrites removed).
    pub slots: Vec<Option<Range<usize>>>,
    /// Floats the arena needs.
    pub arena_len: usize,
    /// The graph input's id.
    pub input: usize,
    /// Tensor names, by id.
    pub names: Vec<String>,
    /// Tensor shapes, by id.
    pub shapes: Vec<Vec<usize>>,
    /// Graph output ids.
    pub outputs: Vec<usize>,
}

/// An op while the rewrites run: extra padding from a folded PAD, a fused residual.
struct Work {
    op: Op,
    pad: Padding,
    residual: Option<usize>,
    post: Activation,
}

/// Compiles `graph` with its dense `weights`; `origin` names the file in errors.
pub(crate) fn compile(
    graph: Graph,
    weights: &HashMap<String, Vec<f32>>,
    origin: &str,
) -> Result<Plan, PerceptionError> {
    let mut work: Vec<Option<Work>> = graph
        .ops
        .iter()
        .cloned()
        .map(|op| {
            Some(Work {
                op,
                pad: Padding::default(),
                residual: None,
                post: Activation::None,
            })
        })
        .collect();
    fold_pads(&graph, &mut work);
    fuse_adds(&graph, &mut work);
    let mut steps = Vec::new();
    for w in work.into_iter().flatten() {
        steps.push(build_step(&graph, w, weights, origin)?);
    }
    let (slots, arena_len) = place(&graph, &steps);
    for (i, s) in steps.iter().enumerate() {
        let out = slots[s.write].as_ref().expect("written tensors have slots");
        for &r in &s.reads {
            let r = slots[r].as_ref().expect("read tensors have slots");
            if r.start < out.end && out.start < r.end {
                return Err(PerceptionError::format(
                    origin,
                    format!("internal: step {i} ({}) writes over its own input", s.label),
                ));
            }
        }
    }
    Ok(Plan {
        steps,
        slots,
        arena_len,
        input: graph.input,
        names: graph.names,
        shapes: graph.shapes,
        outputs: graph.outputs,
    })
}

/// For each tensor, the indices of the (live) ops that read it.
fn readers(graph: &Graph, work: &[Option<Work>]) -> Vec<Vec<usize>> {
    let mut r = vec![Vec::new(); graph.names.len()];
    for (i, w) in work.iter().enumerate() {
        if let Some(w) = w {
            for &t in w.op.inputs.iter().chain(&w.residual) {
                r[t].push(i);
            }
        }
    }
    r
}

/// Removes zero PADs of H and W whose readers are all VALID (depthwise) convolutions reading
/// it as their image, moving the padding into those convolutions.
fn fold_pads(graph: &Graph, work: &mut [Option<Work>]) {
    for i in 0..work.len() {
        let Some(Work {
            op:
                Op {
                    kind: OpKind::Pad { paddings },
                    inputs,
                    output,
                    ..
                },
            ..
        }) = &work[i]
        else {
            continue;
        };
        let (src, out) = (inputs[0], *output);
        let spatial_only = paddings.len() == 4 && paddings[0] == [0, 0] && paddings[3] == [0, 0];
        if !spatial_only || graph.outputs.contains(&out) {
            continue;
        }
        let pad = Padding {
            top: paddings[1][0],
            left: paddings[2][0],
            bottom: paddings[1][1],
            right: paddings[2][1],
        };
        let users = &readers(graph, work)[out];
        let foldable = !users.is_empty()
            && users.iter().all(|&u| {
                let w = work[u].as_ref().expect("readers are live");
                let valid_conv = matches!(
                    w.op.kind,
                    OpKind::Conv {
                        padding: PadMode::Valid,
                        ..
                    } | OpKind::Depthwise {
                        padding: PadMode::Valid,
                        ..
                    }
                );
                valid_conv
                    && w.op.inputs[0] == out
                    && w.residual != Some(out)
                    && w.pad == Padding::default()
            });
        if !foldable {
            continue;
        }
        for &u in users {
            let w = work[u].as_mut().expect("readers are live");
            w.op.inputs[0] = src;
            w.pad = pad;
        }
        work[i] = None;
    }
}

/// Moves ADDs into the op producing one of their operands (see the module docs).
fn fuse_adds(graph: &Graph, work: &mut [Option<Work>]) {
    let mut producer = vec![usize::MAX; graph.names.len()];
    for (i, w) in work.iter().enumerate() {
        if let Some(w) = w {
            producer[w.op.output] = i;
        }
    }
    for i in 0..work.len() {
        let Some(Work {
            op:
                Op {
                    kind: OpKind::Add { act },
                    inputs,
                    output,
                    ..
                },
            ..
        }) = &work[i]
        else {
            continue;
        };
        let (act, a, b, out) = (*act, inputs[0], inputs[1], *output);
        let users = readers(graph, work);
        for (x, other) in [(a, b), (b, a)] {
            let p = producer[x];
            if p == usize::MAX || users[x] != [i] || graph.outputs.contains(&x) {
                continue;
            }
            // the other operand must exist when the producer runs
            let ready = other == graph.input || producer[other] < p;
            let w = work[p].as_ref().expect("producers are live");
            let fusable = match w.op.kind {
                OpKind::Conv { .. } | OpKind::Depthwise { .. } => true,
                OpKind::Resize { .. } => act == Activation::None,
                _ => false,
            };
            if !ready || !fusable || w.residual.is_some() || other == x {
                continue;
            }
            let w = work[p].as_mut().expect("producers are live");
            w.residual = Some(other);
            w.post = act;
            w.op.output = out;
            producer[out] = p;
            work[i] = None;
            break;
        }
    }
}

fn image(shape: &[usize]) -> Shape {
    Shape::new(shape[1], shape[2], shape[3])
}

fn build_step(
    graph: &Graph,
    w: Work,
    weights: &HashMap<String, Vec<f32>>,
    origin: &str,
) -> Result<Step, PerceptionError> {
    let Work {
        op,
        pad: extra,
        residual,
        post,
    } = w;
    let in_shape = &graph.shapes[op.inputs[0]];
    let out_shape = &graph.shapes[op.output];
    let weight = |n: usize| -> Result<&Vec<f32>, PerceptionError> {
        weights.get(&op.weights[n]).ok_or_else(|| {
            PerceptionError::format(origin, format!("weight `{}` has no values", op.weights[n]))
        })
    };
    let mut reads = op.inputs.clone();
    reads.extend(residual);
    let dims = |s: &[usize]| {
        s.iter()
            .map(|d| d.to_string())
            .collect::<Vec<_>>()
            .join("×")
    };
    let res_label = if residual.is_some() { " +res" } else { "" };
    let (label, kind) = match &op.kind {
        OpKind::Conv {
            stride,
            padding,
            act,
        }
        | OpKind::Depthwise {
            stride,
            padding,
            act,
        } => {
            let input = image(in_shape);
            let kernel = kernel_of(graph, &op);
            let own = padding.padding((input.height, input.width), kernel, *stride);
            let pad = Padding {
                top: own.top + extra.top,
                left: own.left + extra.left,
                bottom: own.bottom + extra.bottom,
                right: own.right + extra.right,
            };
            let pointwise = kernel == (1, 1) && *stride == (1, 1) && pad == Padding::default();
            let sparse = pointwise && input.channels >= SPARSE_MIN_INPUTS && {
                let w = weight(0)?;
                let nonzero = w.iter().filter(|v| **v != 0.0).count();
                (nonzero as f64) <= SPARSE_MAX_DENSITY * w.len() as f64
            };
            if matches!(op.kind, OpKind::Conv { .. }) && sparse {
                let conv =
                    SparsePointwise::new(weight(0)?, input.channels, out_shape[3], weight(1)?);
                (
                    format!(
                        "conv 1×1 sparse {:.0}% {}→{} @{}{res_label}",
                        100.0 * conv.density(),
                        input.channels,
                        out_shape[3],
                        dims(&out_shape[1..3])
                    ),
                    StepKind::SparseConv {
                        conv,
                        pixels: input.pixels(),
                        pre: *act,
                        residual,
                        post,
                    },
                )
            } else if let OpKind::Conv { .. } = op.kind {
                let conv = ConvNhwc::new(
                    weight(0)?,
                    weight(1)?,
                    out_shape[3],
                    kernel,
                    input.channels,
                    *stride,
                );
                (
                    format!(
                        "conv {}×{} s{} {}→{} @{}{res_label}",
                        kernel.0,
                        kernel.1,
                        stride.0,
                        input.channels,
                        out_shape[3],
                        dims(&out_shape[1..3])
                    ),
                    StepKind::Conv {
                        conv,
                        input,
                        pad,
                        pre: *act,
                        residual,
                        post,
                    },
                )
            } else {
                let dw = Depthwise::new(weight(0)?, weight(1)?, kernel, input.channels, *stride);
                (
                    format!(
                        "depthwise {}×{} s{} {} @{}{res_label}",
                        kernel.0,
                        kernel.1,
                        stride.0,
                        input.channels,
                        dims(&out_shape[1..3])
                    ),
                    StepKind::Depthwise {
                        dw,
                        input,
                        pad,
                        pre: *act,
                        residual,
                        post,
                    },
                )
            }
        }
        OpKind::Add { act } => (
            format!("add @{}", dims(out_shape)),
            StepKind::Add { act: *act },
        ),
        OpKind::MaxPool {
            filter,
            stride,
            padding,
            act,
        } => {
            let input = image(in_shape);
            let pad = padding.padding((input.height, input.width), *filter, *stride);
            (
                format!("max pool {}×{} @{}", filter.0, filter.1, dims(out_shape)),
                StepKind::MaxPool {
                    input,
                    window: *filter,
                    stride: *stride,
                    pad,
                    act: *act,
                },
            )
        }
        OpKind::Resize { size } => (
            format!("resize →{}{res_label}", dims(out_shape)),
            StepKind::Resize {
                input: image(in_shape),
                size: *size,
                residual,
            },
        ),
        OpKind::DepthToSpace { block } => (
            format!("depth to space @{}", dims(out_shape)),
            StepKind::DepthToSpace {
                input: image(in_shape),
                block: *block,
            },
        ),
        OpKind::Reshape { .. } => (format!("reshape →{}", dims(out_shape)), StepKind::Copy),
        OpKind::Concat { axis, act } => {
            let axis = resolve_axis(*axis, in_shape.len())
                .map_err(|e| PerceptionError::format(origin, e))?;
            let outer: usize = in_shape[..axis].iter().product();
            let inners = op
                .inputs
                .iter()
                .map(|&t| graph.shapes[t][axis..].iter().product())
                .collect();
            (
                format!("concat →{}", dims(out_shape)),
                StepKind::Concat {
                    outer,
                    inners,
                    act: *act,
                },
            )
        }
        OpKind::Pad { paddings } => {
            let image_pad = paddings.len() == 4 && paddings[0] == [0, 0];
            if !image_pad {
                return Err(PerceptionError::format(
                    origin,
                    format!("PAD {paddings:?}: only H, W and C of one NHWC image can be padded"),
                ));
            }
            (
                format!("pad →{}", dims(out_shape)),
                StepKind::Pad {
                    input: image(in_shape),
                    pad: Padding {
                        top: paddings[1][0],
                        left: paddings[2][0],
                        bottom: paddings[1][1],
                        right: paddings[2][1],
                    },
                    channels: (paddings[3][0], paddings[3][1]),
                },
            )
        }
        OpKind::Logistic => (format!("logistic @{}", dims(out_shape)), StepKind::Logistic),
    };
    Ok(Step {
        label,
        reads,
        write: op.output,
        kind,
    })
}

/// The kernel (rows, columns) of a convolution op, from its weight's shape in the graph.
fn kernel_of(graph: &Graph, op: &Op) -> (usize, usize) {
    graph.weight_shapes[&op.weights[0]][1..3]
        .try_into()
        .map(|s: [usize; 2]| (s[0], s[1]))
        .expect("convolution weights are rank 4 (checked)")
}

/// Arena ranges for every tensor the steps touch, and the arena's length.
fn place(graph: &Graph, steps: &[Step]) -> (Vec<Option<Range<usize>>>, usize) {
    let n = graph.names.len();
    let mut first = vec![usize::MAX; n];
    let mut last = vec![0usize; n];
    first[graph.input] = 0;
    last[graph.input] = 0;
    for (i, s) in steps.iter().enumerate() {
        first[s.write] = first[s.write].min(i);
        last[s.write] = last[s.write].max(i);
        for &r in &s.reads {
            last[r] = last[r].max(i);
        }
    }
    for &o in &graph.outputs {
        last[o] = steps.len();
    }
    let size = |t: usize| graph.shapes[t].iter().product::<usize>().div_ceil(ALIGN) * ALIGN;
    let mut order: Vec<usize> = (0..n).filter(|&t| first[t] != usize::MAX).collect();
    order.sort_by_key(|&t| (std::cmp::Reverse(size(t)), t));
    let mut slots: Vec<Option<Range<usize>>> = vec![None; n];
    let mut placed: Vec<usize> = Vec::new();
    let mut arena = 0;
    for t in order {
        let mut busy: Vec<Range<usize>> = placed
            .iter()
            .filter(|&&p| first[p] <= last[t] && first[t] <= last[p])
            .map(|&p| slots[p].clone().expect("placed"))
            .collect();
        busy.sort_by_key(|r| r.start);
        let mut at = 0;
        for r in &busy {
            if at + size(t) <= r.start {
                break;
            }
            at = at.max(r.end);
        }
        let len = graph.shapes[t].iter().product::<usize>();
        slots[t] = Some(at..at + len);
        arena = arena.max(at + size(t));
        placed.push(t);
    }
    (slots, arena)
}
