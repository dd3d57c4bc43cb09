//! Runs a converted TFLite graph (MediaPipe's BlazePose networks) on the crate's CPU kernels.
//!
//! A weights file (see `assets/perception/README.md`) is a safetensors file with the graph as
//! JSON metadata. Loading checks it throughout — format version, every op type and option
//! supported, every tensor an op names present with the shape the graph declares, every
//! output shape what the op computes — and compiles it into steps over one f32 arena
//! ([`plan`]: zero PADs folded into the convolutions after them, ADDs into the op producing
//! an operand). [`Network::run`] takes an NHWC f32 image and returns every graph output by name.
//!
//! `run` takes `&self` and may be called from several threads at once: each call borrows an
//! arena from the network's pool (or makes one when all are busy) and returns it, so a
//! network allocates one arena per concurrent caller and, per call, only its outputs. The
//! kernels split each op over the current rayon pool; run the network inside
//! `ThreadPool::install` to choose the thread count.

mod file;
mod graph;
mod plan;
mod run;

use std::path::Path;
use std::sync::Mutex;
use std::time::Duration;

pub use file::{FORMAT, FORMAT_VERSION};
pub use graph::{GraphDef, OpDef, TensorDef, WeightDef, WeightStorage};

use super::PerceptionError;
use plan::Plan;

/// A loaded, checked network ready to run.
#[derive(Debug)]
pub struct Network {
    origin: String,
    source_file: String,
    source_sha256: String,
    plan: Plan,
    input_shape: [usize; 4],
    /// Arenas not in use (each [`Plan::arena_len`] floats plus alignment room).
    arenas: Mutex<Vec<Vec<f32>>>,
}

/// One graph output: its name, shape and values.
#[derive(Debug, Clone, PartialEq)]
pub struct OutputTensor {
    /// The graph's name for it.
    pub name: String,
    /// Its dimensions.
    pub shape: Vec<usize>,
    /// Its values, row-major.
    pub data: Vec<f32>,
}

/// The outputs of one [`Network::run`], in the graph's order.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct NetworkOutputs {
    /// The outputs.
    pub tensors: Vec<OutputTensor>,
}

impl NetworkOutputs {
    /// The values of output `name`.
    pub fn get(&self, name: &str) -> Option<&[f32]> {
        self.tensor(name).map(|t| t.data.as_slice())
    }

    /// The shape of output `name`.
    pub fn shape(&self, name: &str) -> Option<&[usize]> {
        self.tensor(name).map(|t| t.shape.as_slice())
    }

    /// Output `name`.
    pub fn tensor(&self, name: &str) -> Option<&OutputTensor> {
        self.tensors.iter().find(|t| t.name == name)
    }
}

/// The wall time one step of a profiled run took.
#[derive(Debug, Clone)]
pub struct StepTime {
    /// What the step computes (op, kernel, channels, output size, fused residual).
    pub label: String,
    /// Its time.
    pub time: Duration,
}

impl Network {
    /// Loads a network from the bytes of a weights file; `origin` names it in errors.
    pub fn from_bytes(bytes: &[u8], origin: &str) -> Result<Self, PerceptionError> {
        Self::from_bytes_edited(bytes, origin, |_| {})
    }

    /// Loads the weights file at `path`.
    pub fn load(path: &Path) -> Result<Self, PerceptionError> {
        let bytes = std::fs::read(path).map_err(|source| PerceptionError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_bytes(&bytes, &path.display().to_string())
    }

    /// [`Network::from_bytes`] for an `height × width` input instead of the size the file was
    /// written for ([`GraphDef::resize_input`]): for fully convolutional networks such as
    /// MoveNet, which take any input whose sides are multiples of their total stride.
    pub fn from_bytes_resized(
        bytes: &[u8],
        origin: &str,
        height: usize,
        width: usize,
    ) -> Result<Self, PerceptionError> {
        Self::from_bytes_try_edit(bytes, origin, |g| {
            g.resize_input(height, width)
                .map_err(|e| format!("for a {height}×{width} input: {e}"))
        })
    }

    /// [`Network::from_bytes`] with `edit` applied to the graph before it is checked: for
    /// tests that plant a wiring mistake and show that parity then fails.
    #[doc(hidden)]
    pub fn from_bytes_edited(
        bytes: &[u8],
        origin: &str,
        edit: impl FnOnce(&mut GraphDef),
    ) -> Result<Self, PerceptionError> {
        Self::from_bytes_try_edit(bytes, origin, |g| {
            edit(g);
            Ok(())
        })
    }

    fn from_bytes_try_edit(
        bytes: &[u8],
        origin: &str,
        edit: impl FnOnce(&mut GraphDef) -> Result<(), String>,
    ) -> Result<Self, PerceptionError> {
        let mut file = file::read(bytes, origin)?;
        edit(&mut file.graph).map_err(|e| PerceptionError::format(origin, e))?;
        let graph = graph::check(&file.graph, origin)?;
        let input_shape: [usize; 4] = graph.shapes[graph.input]
            .clone()
            .try_into()
            .expect("the graph input is rank 4 (checked)");
        let plan = plan::compile(graph, &file.weights, origin)?;
        Ok(Self {
            origin: origin.to_string(),
            source_file: file.source_file,
            source_sha256: file.source_sha256,
            plan,
            input_shape,
            arenas: Mutex::new(Vec::new()),
        })
    }

    /// The input image's shape, `[1, H, W, C]`.
    pub fn input_shape(&self) -> [usize; 4] {
        self.input_shape
    }

    /// The graph output names, in order.
    pub fn output_names(&self) -> Vec<&str> {
        self.plan
            .outputs
            .iter()
            .map(|&t| self.plan.names[t].as_str())
            .collect()
    }

    /// Where the network was loaded from.
    pub fn origin(&self) -> &str {
        &self.origin
    }

    /// The name and sha256 of the model file the weights were converted from.
    pub fn source(&self) -> (&str, &str) {
        (&self.source_file, &self.source_sha256)
    }

    /// Runs the network on an NHWC image of [`Network::input_shape`].
    pub fn run(&self, input: &[f32]) -> Result<NetworkOutputs, PerceptionError> {
        let mut out = NetworkOutputs::default();
        self.run_into(input, &mut out)?;
        Ok(out)
    }

    /// [`Network::run`] writing into `outputs`, reusing its buffers.
    pub fn run_into(
        &self,
        input: &[f32],
        outputs: &mut NetworkOutputs,
    ) -> Result<(), PerceptionError> {
        self.execute(input, outputs, None)
    }

    /// [`Network::run`] that also times every step.
    pub fn run_profiled(
        &self,
        input: &[f32],
    ) -> Result<(NetworkOutputs, Vec<StepTime>), PerceptionError> {
        let mut times = vec![Duration::ZERO; self.plan.steps.len()];
        let mut out = NetworkOutputs::default();
        self.execute(input, &mut out, Some(&mut times))?;
        let steps = self
            .plan
            .steps
            .iter()
            .zip(times)
            .map(|(s, time)| StepTime {
                label: s.label.clone(),
                time,
            })
            .collect();
        Ok((out, steps))
    }

    fn execute(
        &self,
        input: &[f32],
        outputs: &mut NetworkOutputs,
        times: Option<&mut [Duration]>,
    ) -> Result<(), PerceptionError> {
        let want: usize = self.input_shape.iter().product();
        if input.len() != want {
            return Err(PerceptionError::Input {
                what: format!("{} input", self.origin),
                expected: format!("{want} values ({:?})", self.input_shape),
                got: format!("{} values", input.len()),
            });
        }
        let mut buffer = self
            .arenas
            .lock()
            .expect("arena pool lock")
            .pop()
            .unwrap_or_else(|| vec![0.0; self.plan.arena_len + 16]);
        // start the arena on a 64-byte boundary
        let skew = buffer.as_ptr().align_offset(64).min(16);
        let arena = &mut buffer[skew..skew + self.plan.arena_len];
        let slot = |t: usize| {
            self.plan.slots[t]
                .clone()
                .expect("graph tensors have slots")
        };
        arena[slot(self.plan.input)].copy_from_slice(input);
        self.plan.execute(arena, times);
        outputs
            .tensors
            .resize_with(self.plan.outputs.len(), || OutputTensor {
                name: String::new(),
                shape: Vec::new(),
                data: Vec::new(),
            });
        for (o, &t) in outputs.tensors.iter_mut().zip(&self.plan.outputs) {
            if o.name != self.plan.names[t] {
                o.name.clone_from(&self.plan.names[t]);
            }
            o.shape.clone_from(&self.plan.shapes[t]);
            o.data.clear();
            o.data.extend_from_slice(&arena[slot(t)]);
        }
        self.arenas.lock().expect("arena pool lock").push(buffer);
        Ok(())
    }

    /// The number of steps after the rewrites (for tests and profiles).
    #[doc(hidden)]
    pub fn step_count(&self) -> usize {
        self.plan.steps.len()
    }
}

#[cfg(test)]
mod tests {
    use crate::perception::weights::{self, LandmarkModel};

    /// The networks give the same values on one thread and as a team of three: every split of
    /// a layer computes each output value with the same operations in the same order.
    #[test]
    fn team_runs_equal_single_thread_runs() {
        for net in [
            weights::pose_detector().unwrap(),
            LandmarkModel::Lite.load(None).unwrap(),
        ] {
            let n: usize = net.input_shape().iter().product();
            let input: Vec<f32> = (0..n).map(|i| ((i * 7919) % 255) as f32 / 255.0).collect();
            let run = |threads: usize| {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap()
                    .install(|| net.run(&input).unwrap())
            };
            let one = run(1);
            assert_eq!(one, run(3), "{}", net.origin());
            assert_eq!(one, run(2), "{}", net.origin());
        }
    }
}
