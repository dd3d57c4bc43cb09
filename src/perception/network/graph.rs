//! The op graph a weights file carries (JSON in its safetensors metadata, written by
//! `scripts/perception/convert.py`) and its checked, typed form: every op's type and options
//! supported, every tensor it names present with the shape the graph declares, every output
//! shape what the op computes from its inputs.

use std::collections::{BTreeMap, HashMap};

use serde::Deserialize;
use serde_json::{Map, Value};

use crate::kernels::nhwc::{Activation, Padding};

use super::super::PerceptionError;

/// The graph as stored: names, shapes and ops in execution order.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GraphDef {
    /// Graph inputs (one NHWC image).
    pub inputs: Vec<TensorDef>,
    /// Graph outputs, by name.
    pub outputs: Vec<TensorDef>,
    /// The shape of every activation tensor an op reads or writes.
    pub tensors: BTreeMap<String, Vec<usize>>,
    /// The shape and storage of every weight tensor.
    pub weights: BTreeMap<String, WeightDef>,
    /// The ops, in an order where each reads only tensors written before it.
    pub ops: Vec<OpDef>,
}

impl GraphDef {
    /// Re-derives the graph for an `height × width` input: the input's shape, every activation
    /// shape and every RESIZE_BILINEAR size (each keeps its ratio of output to input side) are
    /// recomputed op by op. For fully convolutional graphs (MoveNet's) that take any input
    /// whose sides are multiples of their total stride; fails when a resize's ratio gives no
    /// whole side or an op's inputs no longer fit together (an ADD of two branches whose sides
    /// came out different).
    pub fn resize_input(&mut self, height: usize, width: usize) -> Result<(), String> {
        let [input] = self.inputs.as_mut_slice() else {
            return Err(format!(
                "{} graph inputs, expected one image",
                self.inputs.len()
            ));
        };
        let old = self.tensors.clone();
        let shape = match input.shape.as_slice() {
            [1, _, _, c] => vec![1, height, width, *c],
            s => return Err(format!("graph input shape {s:?} is not [1, H, W, C]")),
        };
        input.shape.clone_from(&shape);
        self.tensors.insert(input.name.clone(), shape);
        for (index, op) in self.ops.iter_mut().enumerate() {
            let at = |reason: String| format!("op {index} ({}): {reason}", op.op_type);
            let mut kind = parse_kind(op).map_err(at)?;
            let (n_act, _) = arity(&kind, op.inputs.len());
            let lookup = |t: &BTreeMap<String, Vec<usize>>, name: &String| {
                t.get(name)
                    .cloned()
                    .ok_or_else(|| at(format!("`{name}` is not in the tensor table")))
            };
            let ins = op.inputs[..n_act.min(op.inputs.len())]
                .iter()
                .map(|n| lookup(&self.tensors, n))
                .collect::<Result<Vec<_>, _>>()?;
            if let OpKind::Resize { size } = &mut kind {
                let (was, now) = (lookup(&old, &op.inputs[0])?, &ins[0]);
                let scale = |o: usize, w: usize, n: usize| {
                    (w > 0 && (n * o) % w == 0)
                        .then_some(n * o / w)
                        .ok_or_else(|| at(format!("resize {w}→{o} does not scale to side {n}")))
                };
                *size = (
                    scale(size.0, was[1], now[1])?,
                    scale(size.1, was[2], now[2])?,
                );
                op.options
                    .insert("size".into(), serde_json::json!([size.0, size.1]));
            }
            let ws = op.inputs[n_act.min(op.inputs.len())..]
                .iter()
                .map(|w| {
                    self.weights
                        .get(w)
                        .map(|d| d.shape.as_slice())
                        .ok_or_else(|| at(format!("weight `{w}` is not in the weight table")))
                })
                .collect::<Result<Vec<_>, _>>()?;
            let refs: Vec<&[usize]> = ins.iter().map(Vec::as_slice).collect();
            let out = out_shape(&kind, &refs, &ws).map_err(at)?;
            for o in &op.outputs {
                self.tensors.insert(o.clone(), out.clone());
            }
        }
        for o in &mut self.outputs {
            if let Some(s) = self.tensors.get(&o.name) {
                o.shape.clone_from(s);
            }
        }
        Ok(())
    }
}

/// A named tensor and its shape.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TensorDef {
    /// Tensor name.
    pub name: String,
    /// Dimensions (NHWC for images).
    pub shape: Vec<usize>,
}

/// A weight tensor's entry in the graph.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WeightDef {
    /// Dense dimensions.
    pub shape: Vec<usize>,
    /// How the file stores it.
    pub storage: WeightStorage,
}

/// How a weight tensor is stored in the file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum WeightStorage {
    /// One F16 tensor of the dense shape, under the weight's name.
    Dense,
    /// `NAME.values` (F16, the non-zero values in row-major order) and `NAME.mask` (U8, one bit
    /// per dense element, least significant bit first).
    Bitmask,
}

/// One op as stored.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OpDef {
    /// TFLite builtin op name (`CONV_2D`, `ADD`, …).
    #[serde(rename = "type")]
    pub op_type: String,
    /// Input tensor names: activations first, then weights.
    pub inputs: Vec<String>,
    /// Output tensor names.
    pub outputs: Vec<String>,
    /// The op's options.
    #[serde(default)]
    pub options: Map<String, Value>,
}

/// TFLite's two padding modes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum PadMode {
    /// Output side `ceil(in / stride)`, zeros split around (the odd one after).
    Same,
    /// No padding.
    Valid,
}

impl PadMode {
    /// The padding of an `h×w` input under a `kernel` and `stride`.
    pub(crate) fn padding(
        self,
        (h, w): (usize, usize),
        kernel: (usize, usize),
        stride: (usize, usize),
    ) -> Padding {
        match self {
            Self::Valid => Padding::default(),
            Self::Same => {
                let (top, bottom) = Padding::same(h, kernel.0, stride.0);
                let (left, right) = Padding::same(w, kernel.1, stride.1);
                Padding {
                    top,
                    left,
                    bottom,
                    right,
                }
            }
        }
    }
}

/// A supported op with its options checked.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum OpKind {
    /// CONV_2D: inputs `x, weight [O][kh][kw][I], bias [O]`.
    Conv {
        stride: (usize, usize),
        padding: PadMode,
        act: Activation,
    },
    /// DEPTHWISE_CONV_2D (depth multiplier 1): inputs `x, weight [1][kh][kw][C], bias [C]`.
    Depthwise {
        stride: (usize, usize),
        padding: PadMode,
        act: Activation,
    },
    /// ADD of two tensors of one shape.
    Add { act: Activation },
    /// MAX_POOL_2D.
    MaxPool {
        filter: (usize, usize),
        stride: (usize, usize),
        padding: PadMode,
        act: Activation,
    },
    /// RESIZE_BILINEAR with half-pixel centres.
    Resize { size: (usize, usize) },
    /// DEPTH_TO_SPACE.
    DepthToSpace { block: usize },
    /// RESHAPE (a copy: the values keep their order) to `shape` (one −1 allowed).
    Reshape { shape: Vec<i64> },
    /// CONCATENATION along `axis`.
    Concat { axis: usize, act: Activation },
    /// PAD with zeros, `[before, after]` per dimension.
    Pad { paddings: Vec<[usize; 2]> },
    /// LOGISTIC.
    Logistic,
}

/// A checked op: its kind, activation tensor ids in, weight names and the output id.
#[derive(Debug, Clone)]
pub(crate) struct Op {
    /// What it computes.
    pub kind: OpKind,
    /// Activation inputs (tensor ids).
    pub inputs: Vec<usize>,
    /// Weight inputs (names in the file).
    pub weights: Vec<String>,
    /// The output tensor id.
    pub output: usize,
}

/// The checked graph: tensor table, ops, input and outputs.
#[derive(Debug, Clone)]
pub(crate) struct Graph {
    /// Activation tensor names, by id.
    pub names: Vec<String>,
    /// Activation tensor shapes, by id.
    pub shapes: Vec<Vec<usize>>,
    /// The ops in execution order.
    pub ops: Vec<Op>,
    /// The graph input's id.
    pub input: usize,
    /// The graph outputs' ids, in file order.
    pub outputs: Vec<usize>,
    /// Every weight's dense shape, by name.
    pub weight_shapes: HashMap<String, Vec<usize>>,
}

/// Checks `def` and gives its typed form; `origin` names the file in errors.
pub(crate) fn check(def: &GraphDef, origin: &str) -> Result<Graph, PerceptionError> {
    let fail = |reason: String| PerceptionError::format(origin, reason);
    let mut ids: HashMap<&str, usize> = HashMap::new();
    let mut names = Vec::new();
    let mut shapes = Vec::new();
    for (name, shape) in &def.tensors {
        if def.weights.contains_key(name) {
            return Err(fail(format!("`{name}` is both an activation and a weight")));
        }
        ids.insert(name, names.len());
        names.push(name.clone());
        shapes.push(shape.clone());
    }
    let [input] = def.inputs.as_slice() else {
        return Err(fail(format!(
            "{} graph inputs, expected one image",
            def.inputs.len()
        )));
    };
    let &input_id = ids.get(input.name.as_str()).ok_or_else(|| {
        fail(format!(
            "graph input `{}` is not in the tensor table",
            input.name
        ))
    })?;
    if input.shape.len() != 4 || input.shape[0] != 1 || shapes[input_id] != input.shape {
        return Err(fail(format!(
            "graph input `{}` has shape {:?} (table {:?}), expected [1, H, W, C]",
            input.name, input.shape, shapes[input_id]
        )));
    }
    let mut defined = vec![false; names.len()];
    defined[input_id] = true;
    let mut ops = Vec::with_capacity(def.ops.len());
    for (index, op) in def.ops.iter().enumerate() {
        let at = |reason: String| fail(format!("op {index} ({}): {reason}", op.op_type));
        let kind = parse_kind(op).map_err(at)?;
        let (n_act, n_weights) = arity(&kind, op.inputs.len());
        if op.inputs.len() != n_act + n_weights || op.outputs.len() != 1 {
            return Err(at(format!(
                "{} inputs and {} outputs, expected {} and 1",
                op.inputs.len(),
                op.outputs.len(),
                n_act + n_weights
            )));
        }
        let mut inputs = Vec::with_capacity(n_act);
        for name in &op.inputs[..n_act] {
            let &id = ids.get(name.as_str()).ok_or_else(|| {
                at(format!(
                    "input `{name}` is not an activation tensor of the graph"
                ))
            })?;
            if !defined[id] {
                return Err(at(format!(
                    "input `{name}` is read before any op writes it"
                )));
            }
            inputs.push(id);
        }
        let weights: Vec<String> = op.inputs[n_act..].to_vec();
        for name in &weights {
            if !def.weights.contains_key(name) {
                return Err(at(format!(
                    "weight `{name}` is not in the file's weight table"
                )));
            }
        }
        let out_name = &op.outputs[0];
        let &output = ids
            .get(out_name.as_str())
            .ok_or_else(|| at(format!("output `{out_name}` is not in the tensor table")))?;
        if defined[output] {
            return Err(at(format!("output `{out_name}` is written twice")));
        }
        let in_shapes: Vec<&[usize]> = inputs.iter().map(|&i| shapes[i].as_slice()).collect();
        let w_shapes: Vec<&[usize]> = weights
            .iter()
            .map(|w| def.weights[w].shape.as_slice())
            .collect();
        let want = out_shape(&kind, &in_shapes, &w_shapes).map_err(at)?;
        if want != shapes[output] {
            return Err(at(format!(
                "output `{out_name}` is declared {:?}, the op computes {want:?}",
                shapes[output]
            )));
        }
        defined[output] = true;
        ops.push(Op {
            kind,
            inputs,
            weights,
            output,
        });
    }
    let mut outputs = Vec::new();
    for o in &def.outputs {
        let &id = ids.get(o.name.as_str()).ok_or_else(|| {
            fail(format!(
                "graph output `{}` is not in the tensor table",
                o.name
            ))
        })?;
        if !defined[id] || shapes[id] != o.shape {
            return Err(fail(format!(
                "graph output `{}` ({:?}) is never written or has table shape {:?}",
                o.name, o.shape, shapes[id]
            )));
        }
        outputs.push(id);
    }
    Ok(Graph {
        names,
        shapes,
        ops,
        input: input_id,
        outputs,
        weight_shapes: def
            .weights
            .iter()
            .map(|(n, w)| (n.clone(), w.shape.clone()))
            .collect(),
    })
}

/// (activation inputs, weight inputs) of an op kind.
fn arity(kind: &OpKind, given: usize) -> (usize, usize) {
    match kind {
        OpKind::Conv { .. } | OpKind::Depthwise { .. } => (1, 2),
        OpKind::Add { .. } => (2, 0),
        OpKind::Concat { .. } => (given.max(1), 0),
        _ => (1, 0),
    }
}

fn parse_kind(op: &OpDef) -> Result<OpKind, String> {
    let o = Options(&op.options);
    let kind = match op.op_type.as_str() {
        "CONV_2D" | "DEPTHWISE_CONV_2D" => {
            if o.pair("dilation")? != (1, 1) {
                return Err("dilated convolutions are not supported".into());
            }
            let (stride, padding, act) = (o.pair("stride")?, o.padding()?, o.activation()?);
            if op.op_type == "CONV_2D" {
                o.only(&["stride", "padding", "activation", "dilation"])?;
                OpKind::Conv {
                    stride,
                    padding,
                    act,
                }
            } else {
                o.only(&[
                    "stride",
                    "padding",
                    "activation",
                    "dilation",
                    "depth_multiplier",
                ])?;
                if o.usize("depth_multiplier")? != 1 {
                    return Err("depth multipliers other than 1 are not supported".into());
                }
                OpKind::Depthwise {
                    stride,
                    padding,
                    act,
                }
            }
        }
        "ADD" => {
            o.only(&["activation"])?;
            OpKind::Add {
                act: o.activation()?,
            }
        }
        "MAX_POOL_2D" => {
            o.only(&["stride", "filter", "padding", "activation"])?;
            OpKind::MaxPool {
                filter: o.pair("filter")?,
                stride: o.pair("stride")?,
                padding: o.padding()?,
                act: o.activation()?,
            }
        }
        "RESIZE_BILINEAR" => {
            o.only(&["align_corners", "half_pixel_centers", "size"])?;
            if o.bool("align_corners")? || !o.bool("half_pixel_centers")? {
                return Err("only half_pixel_centers without align_corners is supported".into());
            }
            OpKind::Resize {
                size: o.pair("size")?,
            }
        }
        "DEPTH_TO_SPACE" => {
            o.only(&["block_size"])?;
            OpKind::DepthToSpace {
                block: o.usize("block_size")?,
            }
        }
        "RESHAPE" => {
            o.only(&["shape"])?;
            let shape = o
                .get("shape")?
                .as_array()
                .and_then(|a| a.iter().map(|v| v.as_i64().filter(|&d| d >= -1)).collect())
                .ok_or("option `shape`: expected a list of dimensions")?;
            OpKind::Reshape { shape }
        }
        "CONCATENATION" => {
            o.only(&["axis", "activation"])?;
            let axis = o
                .get("axis")?
                .as_i64()
                .ok_or("option `axis`: expected an integer")?;
            // a negative axis counts from the end; resolved against the rank in `out_shape`
            let axis = if axis < 0 {
                usize::MAX - (-axis - 1) as usize
            } else {
                axis as usize
            };
            OpKind::Concat {
                axis,
                act: o.activation()?,
            }
        }
        "PAD" => {
            o.only(&["paddings"])?;
            let pairs = o
                .get("paddings")?
                .as_array()
                .ok_or("option `paddings`: expected a list of pairs")?;
            let mut paddings = Vec::new();
            for p in pairs {
                let pair = p
                    .as_array()
                    .filter(|p| p.len() == 2)
                    .ok_or("option `paddings`: expected pairs")?;
                let b = pair[0]
                    .as_u64()
                    .ok_or("option `paddings`: negative or not an integer")?;
                let a = pair[1]
                    .as_u64()
                    .ok_or("option `paddings`: negative or not an integer")?;
                paddings.push([b as usize, a as usize]);
            }
            OpKind::Pad { paddings }
        }
        "LOGISTIC" => {
            o.only(&[])?;
            OpKind::Logistic
        }
        other => return Err(format!("op type {other} is not supported")),
    };
    Ok(kind)
}

/// The output shape an op computes from its input and weight shapes.
fn out_shape(kind: &OpKind, ins: &[&[usize]], ws: &[&[usize]]) -> Result<Vec<usize>, String> {
    let image = |s: &[usize]| -> Result<(usize, usize, usize), String> {
        match s {
            [1, h, w, c] => Ok((*h, *w, *c)),
            _ => Err(format!("input shape {s:?} is not [1, H, W, C]")),
        }
    };
    match kind {
        OpKind::Conv {
            stride, padding, ..
        }
        | OpKind::Depthwise {
            stride, padding, ..
        } => {
            let (h, w, c) = image(ins[0])?;
            let depthwise = matches!(kind, OpKind::Depthwise { .. });
            let (o, kh, kw) = match ws[0] {
                [o, kh, kw, i] if !depthwise && *i == c => (*o, *kh, *kw),
                [1, kh, kw, i] if depthwise && *i == c => (c, *kh, *kw),
                s => {
                    return Err(format!(
                        "weight shape {s:?} does not fit {c} input channels"
                    ))
                }
            };
            if ws[1] != [o] {
                return Err(format!("bias shape {:?}, expected [{o}]", ws[1]));
            }
            if stride.0 == 0 || stride.1 == 0 || kh == 0 || kw == 0 {
                return Err("zero stride or kernel".into());
            }
            let p = padding.padding((h, w), (kh, kw), *stride);
            let oh = Padding::out_side(h, p.top, p.bottom, kh, stride.0);
            let ow = Padding::out_side(w, p.left, p.right, kw, stride.1);
            Ok(vec![1, oh, ow, o])
        }
        OpKind::Add { .. } => {
            if ins[0] != ins[1] {
                return Err(format!(
                    "adds {:?} and {:?} (broadcasting is not supported)",
                    ins[0], ins[1]
                ));
            }
            Ok(ins[0].to_vec())
        }
        OpKind::MaxPool {
            filter,
            stride,
            padding,
            ..
        } => {
            let (h, w, c) = image(ins[0])?;
            if stride.0 == 0 || stride.1 == 0 || filter.0 == 0 || filter.1 == 0 {
                return Err("zero stride or filter".into());
            }
            let p = padding.padding((h, w), *filter, *stride);
            let oh = Padding::out_side(h, p.top, p.bottom, filter.0, stride.0);
            let ow = Padding::out_side(w, p.left, p.right, filter.1, stride.1);
            Ok(vec![1, oh, ow, c])
        }
        OpKind::Resize { size } => {
            let (h, w, c) = image(ins[0])?;
            if h == 0 || w == 0 {
                return Err("empty input".into());
            }
            Ok(vec![1, size.0, size.1, c])
        }
        OpKind::DepthToSpace { block } => {
            let (h, w, c) = image(ins[0])?;
            if *block == 0 || c % (block * block) != 0 {
                return Err(format!(
                    "{c} channels do not split into {block}×{block} blocks"
                ));
            }
            Ok(vec![1, h * block, w * block, c / (block * block)])
        }
        OpKind::Reshape { shape } => {
            let count: usize = ins[0].iter().product();
            let known: usize = shape
                .iter()
                .filter(|&&d| d >= 0)
                .map(|&d| d as usize)
                .product();
            let free = shape.iter().filter(|&&d| d < 0).count();
            let fill = match free {
                0 if known == count => 0,
                1 if known > 0 && count % known == 0 => count / known,
                _ => return Err(format!("cannot reshape {:?} to {shape:?}", ins[0])),
            };
            Ok(shape
                .iter()
                .map(|&d| if d < 0 { fill } else { d as usize })
                .collect())
        }
        OpKind::Concat { axis, .. } => {
            let rank = ins[0].len();
            let axis = resolve_axis(*axis, rank)?;
            let mut out = ins[0].to_vec();
            out[axis] = 0;
            for s in ins {
                let same = s.len() == rank && (0..rank).all(|d| d == axis || s[d] == ins[0][d]);
                if !same {
                    return Err(format!(
                        "concatenates {s:?} with {:?} along axis {axis}",
                        ins[0]
                    ));
                }
                out[axis] += s[axis];
            }
            Ok(out)
        }
        OpKind::Pad { paddings } => {
            if paddings.len() != ins[0].len() {
                return Err(format!(
                    "{} padding pairs for rank {}",
                    paddings.len(),
                    ins[0].len()
                ));
            }
            Ok(ins[0]
                .iter()
                .zip(paddings)
                .map(|(d, p)| d + p[0] + p[1])
                .collect())
        }
        OpKind::Logistic => Ok(ins[0].to_vec()),
    }
}

/// A concatenation axis (negative ones stored as `usize::MAX − (|axis| − 1)`) within `rank`.
pub(crate) fn resolve_axis(axis: usize, rank: usize) -> Result<usize, String> {
    let back = usize::MAX - axis;
    if axis < rank {
        Ok(axis)
    } else if back < rank {
        Ok(rank - 1 - back)
    } else {
        Err(format!("axis out of range for rank {rank}"))
    }
}

/// Typed access to an op's options.
struct Options<'a>(&'a Map<String, Value>);

impl Options<'_> {
    fn get(&self, key: &str) -> Result<&Value, String> {
        self.0
            .get(key)
            .ok_or_else(|| format!("option `{key}` is missing"))
    }

    /// Fails on any option not in `known`.
    fn only(&self, known: &[&str]) -> Result<(), String> {
        match self.0.keys().find(|k| !known.contains(&k.as_str())) {
            Some(k) => Err(format!("option `{k}` is not supported")),
            None => Ok(()),
        }
    }

    fn usize(&self, key: &str) -> Result<usize, String> {
        self.get(key)?
            .as_u64()
            .map(|v| v as usize)
            .ok_or_else(|| format!("option `{key}`: expected a non-negative integer"))
    }

    fn bool(&self, key: &str) -> Result<bool, String> {
        self.get(key)?
            .as_bool()
            .ok_or_else(|| format!("option `{key}`: expected true or false"))
    }

    fn pair(&self, key: &str) -> Result<(usize, usize), String> {
        match self.get(key)?.as_array().map(|a| a.as_slice()) {
            Some([a, b]) => match (a.as_u64(), b.as_u64()) {
                (Some(a), Some(b)) => Ok((a as usize, b as usize)),
                _ => Err(format!(
                    "option `{key}`: expected two non-negative integers"
                )),
            },
            _ => Err(format!("option `{key}`: expected two values")),
        }
    }

    fn padding(&self) -> Result<PadMode, String> {
        match self.get("padding")?.as_str() {
            Some("SAME") => Ok(PadMode::Same),
            Some("VALID") => Ok(PadMode::Valid),
            other => Err(format!("option `padding`: {other:?} is not SAME or VALID")),
        }
    }

    fn activation(&self) -> Result<Activation, String> {
        match self.get("activation")?.as_str() {
            Some("NONE") => Ok(Activation::None),
            Some("RELU") => Ok(Activation::Relu),
            Some("RELU6") => Ok(Activation::Relu6),
            other => Err(format!("fused activation {other:?} is not supported")),
        }
    }
}
