//! ONNX Runtime sessions for policies: one process-wide environment loaded from the pinned
//! library, single-threaded sessions (the control loop owns its core), and a model handle that
//! checks names and shapes once at load time so each inference is a plain call.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use ort::environment::Environment;
use ort::session::Session;
use ort::session::builder::GraphOptimizationLevel;
use ort::value::{TensorElementType, ValueType};

use crate::native;

mod bound;

/// Why a policy model could not be loaded or run.
#[derive(Debug, Clone, thiserror::Error)]
#[non_exhaustive]
pub enum OnnxError {
    /// The ONNX Runtime library is missing or of the wrong version.
    #[error("ONNX Runtime is unavailable: {0}")]
    Runtime(String),
    /// The model file does not load.
    #[error("cannot load ONNX model {path}: {reason}")]
    Load {
        /// The model file.
        path: PathBuf,
        /// ONNX Runtime's message.
        reason: String,
    },
    /// The model's inputs or outputs are not a single float vector each.
    #[error("ONNX model {path}: {what}")]
    Signature {
        /// The model file.
        path: PathBuf,
        /// What does not fit.
        what: String,
    },
    /// A buffer passed to [`OnnxModel::run`] does not match the model.
    #[error("{what} has {actual} values but the model expects {expected}")]
    BufferSize {
        /// `observation` or `action`.
        what: &'static str,
        /// The model's size.
        expected: usize,
        /// The caller's size.
        actual: usize,
    },
    /// Inference failed.
    #[error("inference failed: {0}")]
    Run(String),
}

/// Loaded once; a failure is kept and given to every caller (the library is not retried).
static ENVIRONMENT: OnceLock<Result<Environment, OnnxError>> = OnceLock::new();

/// The process-wide ONNX Runtime environment, loading the pinned library on first use.
pub fn environment() -> Result<&'static Environment, OnnxError> {
    ENVIRONMENT
        .get_or_init(|| {
            let runtime = |e: &dyn std::fmt::Display| OnnxError::Runtime(e.to_string());
            let path = native::find_onnxruntime().map_err(|e| runtime(&e))?;
            let version = native::onnxruntime_version(&path).map_err(|e| runtime(&e))?;
            if version != native::ONNXRUNTIME_VERSION {
                return Err(runtime(&format_args!(
                    "{} is ONNX Runtime {version}, but this build is pinned to {}; run `scripts/setup` to \
                     reinstall the pinned library",
                    path.display(),
                    native::ONNXRUNTIME_VERSION
                )));
            }
            ort::init_from(&path)
                .map_err(|e| {
                    runtime(&format_args!(
                        "{e}; run `scripts/setup` to reinstall the pinned library"
                    ))
                })?
                .with_name("robodeploy")
                .build()
                .map_err(|e| runtime(&e))
        })
        .as_ref()
        .map_err(Clone::clone)
}

/// The loaded ONNX Runtime's version and build description, for `doctor` and logs.
pub fn runtime_info() -> Result<String, OnnxError> {
    environment()?;
    Ok(format!("{} ({})", native::ONNXRUNTIME_VERSION, ort::info()))
}

/// A load error naming the model file.
fn load_error(path: &Path) -> impl Fn(ort::Error) -> OnnxError + '_ {
    move |e| OnnxError::Load {
        path: path.to_path_buf(),
        reason: e.to_string(),
    }
}

/// The pinned environment, after checking the file exists.
fn environment_for(path: &Path) -> Result<&'static Environment, OnnxError> {
    // A missing file is named before ONNX Runtime is loaded for nothing.
    if !path.is_file() {
        return Err(OnnxError::Load {
            path: path.to_path_buf(),
            reason: "no such file".into(),
        });
    }
    environment()
}

/// What a model file says of itself without running it: its custom metadata properties (empty
/// when it has none) and its input names.
pub fn read_facts(path: &Path) -> Result<crate::export::ModelFacts, OnnxError> {
    robots::check_regular_file(path).map_err(|reason| OnnxError::Load {
        path: path.to_path_buf(),
        reason: reason.to_string(),
    })?;
    let env = environment_for(path)?;
    let load_err = load_error(path);
    let session = Session::builder(env)
        .map_err(&load_err)?
        .commit_from_file(path)
        .map_err(&load_err)?;
    let meta = session.metadata().map_err(&load_err)?;
    let mut metadata = std::collections::BTreeMap::new();
    for key in meta.custom_keys().map_err(&load_err)? {
        if let Some(v) = meta.custom(&key) {
            metadata.insert(key, v);
        }
    }
    Ok(crate::export::ModelFacts {
        metadata,
        inputs: session.inputs().iter().map(|i| i.name().to_owned()).collect(),
    })
}

/// A loaded model with float vector inputs (one or several, named), a float vector output of
/// actions (batch 1) and, beside it, any other float outputs of fixed shape (e.g. the reference
/// motion a tracking export carries), read after each run with [`OnnxModel::extra_output`].
#[derive(Debug)]
pub struct OnnxModel {
    session: Session,
    path: PathBuf,
    inputs: Vec<(String, usize)>,
    input_len: usize,
    output_name: String,
    output_len: usize,
    /// The other outputs with their shapes (batch dimension included), in the model's order.
    extra_outputs: Vec<(String, Vec<i64>)>,
    /// Every input's shape, then the output's (batch included).
    shapes: Vec<(String, Vec<i64>)>,
    bound: bound::BoundTensors,
}

/// The name of the action output when a model has several outputs.
pub const ACTION_OUTPUT: &str = "actions";

/// Why a model's input or output is not the tensor it must be.
#[derive(Debug, thiserror::Error)]
enum ShapeError {
    #[error("is {0}, not a tensor")]
    NotTensor(String),
    #[error("has element type {0:?}, expected float32")]
    NotFloat(TensorElementType),
    #[error("has shape {dims:?}, expected {expected}")]
    Shape { dims: Vec<i64>, expected: &'static str },
}

/// A float tensor's dimensions, or why it is not one.
fn float_dims(dtype: &ValueType) -> Result<&[i64], ShapeError> {
    let (Some(shape), Some(ty)) = (dtype.tensor_shape(), dtype.tensor_type()) else {
        return Err(ShapeError::NotTensor(format!("{dtype:?}")));
    };
    if ty != TensorElementType::Float32 {
        return Err(ShapeError::NotFloat(ty));
    }
    Ok(shape)
}

/// The shape of a float tensor of fixed size with batch 1 (a free leading dimension counts as
/// the batch), or why it is not one.
fn fixed_shape(dtype: &ValueType) -> Result<Vec<i64>, ShapeError> {
    let dims = float_dims(dtype)?;
    let mut out = dims.to_vec();
    if let Some(first) = out.first_mut()
        && *first < 0
    {
        *first = 1;
    }
    if out.first() != Some(&1) || out.iter().any(|&d| d <= 0) || out.iter().product::<i64>() > 1 << 26 {
        return Err(ShapeError::Shape {
            dims: dims.to_vec(),
            expected: "[1, …] with fixed sizes (at most 2^26 values)",
        });
    }
    Ok(out)
}

/// The shape to bind a `[batch?, n]` or `[n]` float tensor with (the model's own rank: a rank-1
/// input fed a `[1, n]` tensor fails every inference), or why it is not one.
fn vector_shape(dtype: &ValueType) -> Result<Vec<i64>, ShapeError> {
    let dims = float_dims(dtype)?;
    let shape_error = |expected| ShapeError::Shape {
        dims: dims.to_vec(),
        expected,
    };
    let (n, rank) = match dims {
        [n] => (*n, 1),
        [b, n] if *b == 1 || *b < 0 => (*n, 2),
        _ => return Err(shape_error("[n] or [batch, n]")),
    };
    if n <= 0 {
        return Err(shape_error("a fixed feature size"));
    }
    Ok(if rank == 1 { vec![n] } else { vec![1, n] })
}

impl OnnxModel {
    /// Loads a model and checks its signature: float vector inputs; one float vector output, or
    /// several of which the one named [`ACTION_OUTPUT`] holds the actions and the others are
    /// float tensors of fixed shape.
    pub fn load(path: &Path) -> Result<Self, OnnxError> {
        Self::open(path, false)
    }

    /// Loads a model whose inputs and output are float tensors of any fixed shape with batch 1
    /// (e.g. a motion generator's `[1, frames, joints]`), flattened row-major into
    /// [`Self::run`]'s buffers; [`Self::shapes`] gives the shapes.
    pub fn load_tensors(path: &Path) -> Result<Self, OnnxError> {
        Self::open(path, true)
    }

    fn open(path: &Path, tensors: bool) -> Result<Self, OnnxError> {
        robots::check_regular_file(path).map_err(|reason| OnnxError::Load {
            path: path.to_path_buf(),
            reason: reason.to_string(),
        })?;
        let env = environment_for(path)?;
        let load_err = load_error(path);
        let builder_err = |e: ort::Error<_>| load_err(e.into());
        let session = Session::builder(env)
            .map_err(&load_err)?
            .with_intra_threads(1)
            .map_err(builder_err)?
            .with_inter_threads(1)
            .map_err(builder_err)?
            .with_optimization_level(GraphOptimizationLevel::All)
            .map_err(builder_err)?
            .commit_from_file(path)
            .map_err(&load_err)?;
        let signature = |what: String| OnnxError::Signature {
            path: path.to_path_buf(),
            what,
        };
        let output = match session.outputs() {
            [o] => o,
            [] => return Err(signature("has no outputs".into())),
            many => many.iter().find(|o| o.name() == ACTION_OUTPUT).ok_or_else(|| {
                signature(format!(
                    "has {} outputs ({}) and none is named {ACTION_OUTPUT:?}, the actions",
                    many.len(),
                    many.iter().map(|o| o.name()).collect::<Vec<_>>().join(", ")
                ))
            })?,
        };
        if session.inputs().is_empty() {
            return Err(signature("has no inputs".into()));
        }
        let shape_of = |dtype: &ValueType| {
            if tensors {
                fixed_shape(dtype)
            } else {
                vector_shape(dtype)
            }
        };
        let mut input_shapes = Vec::with_capacity(session.inputs().len());
        for input in session.inputs() {
            let shape =
                shape_of(input.dtype()).map_err(|w| signature(format!("input '{}' {w}", input.name())))?;
            input_shapes.push((input.name().to_owned(), shape));
        }
        let inputs: Vec<(String, usize)> = input_shapes
            .iter()
            .map(|(name, shape)| (name.clone(), shape.iter().product::<i64>() as usize))
            .collect();
        let output_shape =
            shape_of(output.dtype()).map_err(|w| signature(format!("output '{}' {w}", output.name())))?;
        let output_len = output_shape.iter().product::<i64>() as usize;
        let mut extra_outputs = Vec::new();
        for o in session.outputs().iter().filter(|o| o.name() != output.name()) {
            let shape =
                fixed_shape(o.dtype()).map_err(|w| signature(format!("output '{}' {w}", o.name())))?;
            extra_outputs.push((o.name().to_owned(), shape));
        }
        let mut bound_outputs = vec![(output.name().to_owned(), output_shape)];
        bound_outputs.extend(extra_outputs.iter().cloned());
        let bound = bound::BoundTensors::new(&input_shapes, &bound_outputs).map_err(|e| OnnxError::Load {
            path: path.to_path_buf(),
            reason: e.to_string(),
        })?;
        Self {
            shapes: input_shapes
                .into_iter()
                .chain(std::iter::once((
                    output.name().to_owned(),
                    bound_outputs[0].1.clone(),
                )))
                .collect(),
            bound,
            extra_outputs,
            input_len: inputs.iter().map(|i| i.1).sum(),
            inputs,
            output_name: output.name().to_owned(),
            output_len,
            path: path.to_path_buf(),
            session,
        }
        .tried()
    }

    /// The model after one inference on zeros: what ONNX Runtime refuses only when it runs (a
    /// rank, an operator's shape rule) is a load error, before anything moves.
    fn tried(mut self) -> Result<Self, OnnxError> {
        let (obs, mut actions) = (vec![0.0; self.input_len], vec![0.0; self.output_len]);
        self.run(&obs, &mut actions).map_err(|e| OnnxError::Load {
            path: self.path.clone(),
            reason: format!("one inference on zeros failed: {e}"),
        })?;
        Ok(self)
    }

    /// The model file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Name and total length of the inputs (the first input's name).
    pub fn input(&self) -> (&str, usize) {
        (&self.inputs[0].0, self.input_len)
    }

    /// Every input, in the model's order, with its length. [`Self::run`] takes their
    /// concatenation in this order.
    pub fn inputs(&self) -> &[(String, usize)] {
        &self.inputs
    }

    /// Every input's name and shape (batch included), in the model's order, then the output's.
    pub fn shapes(&self) -> &[(String, Vec<i64>)] {
        &self.shapes
    }

    /// Name and length of the output vector.
    pub fn output(&self) -> (&str, usize) {
        (&self.output_name, self.output_len)
    }

    /// The outputs other than the actions, with their shapes (batch included), in the model's
    /// order; [`Self::extra_output`] takes an index into this list.
    pub fn extra_outputs(&self) -> &[(String, Vec<i64>)] {
        &self.extra_outputs
    }

    /// The values of extra output `k` as the last [`Self::run`] left them (zeros before).
    pub fn extra_output(&self, k: usize) -> &[f32] {
        self.bound.output(k + 1)
    }

    /// Runs one inference: `obs` (the inputs concatenated in the model's order) in, `actions` out.
    /// Allocates nothing: the tensors are bound to buffers made at load time.
    pub fn run(&mut self, obs: &[f32], actions: &mut [f32]) -> Result<(), OnnxError> {
        let check = |what, expected, actual| {
            if expected == actual {
                Ok(())
            } else {
                Err(OnnxError::BufferSize {
                    what,
                    expected,
                    actual,
                })
            }
        };
        check("observation", self.input_len, obs.len())?;
        check("action", self.output_len, actions.len())?;
        self.bound
            .run(&mut self.session, obs, actions)
            .map_err(|e| OnnxError::Run(e.to_string()))
    }
}
