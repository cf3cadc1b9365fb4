//! References from an online motion generator: an autoregressive ONNX model on its own worker
//! thread turns the last N frames into the next K (at its own frame rate, one step per K frames),
//! and the control loop samples the newest plan at its own rate without locks or allocation.
//!
//! The worker keeps a window of the generated stream (the frames already played, the plan ahead)
//! and publishes it whole through the lock-free exchange teleoperation uses
//! ([`human::live::live_channel`]); it steps when the loop (whose time it reads from an atomic)
//! has entered the newest step, so plans are ready one step ahead of need. When the loop's time
//! runs past the plan — a late, failed or stalled step — the reference is carried on by the
//! forecast teleoperation uses ([`human::live::carry_forward`]) for at most `forecast_s`, then
//! blends to the standby pose over `blend_s`; a fresh plan blends back the same way. Every change
//! is counted and kept with its time (in a list sized once), never logged from the loop.
//!
//! A generator is described by a TOML file beside its ONNX file ([`GeneratorDescription`]): the
//! input and output names, N, K, the frame rate, the joints in the model's order, and the clip
//! whose first N frames seed the history.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use human::live::{LiveReader, LiveWriter, carry_forward, live_channel};
use robots::{FileError, Robot};

use crate::clip::{Clip, Reference};
use crate::histogram::Histogram;
use policy::onnx::{OnnxError, OnnxModel};

/// Most frames of history or horizon a description may ask for.
pub const MAX_FRAMES: usize = 256;

/// Changes of the generated reference kept per run (the first ones; later ones are counted).
pub const MAX_EVENTS: usize = 64;

/// Why a generator could not be loaded or started.
#[derive(Debug, thiserror::Error)]
pub enum GeneratorError {
    /// The description file.
    #[error(transparent)]
    File(#[from] FileError),
    /// The model.
    #[error(transparent)]
    Onnx(#[from] OnnxError),
    /// The seed clip.
    #[error(transparent)]
    Clip(#[from] crate::clip::ClipError),
    /// The model's shapes disagree with the description.
    #[error("generator {}: {message}", .path.display())]
    Shape {
        /// The model file.
        path: PathBuf,
        /// What disagrees.
        message: String,
    },
    /// Options out of their ranges.
    #[error("generator options: {0}")]
    Options(String),
    /// A command value out of its range.
    #[error("command: {0}")]
    Command(#[from] CommandValueError),
    /// The policy observes what a generator does not give.
    #[error("{}: observes {observes}: a motion generator gives joint angles only", .policy.display())]
    PolicyNeedsMore {
        /// The policy manifest.
        policy: PathBuf,
        /// The terms (or "motion bodies") it would lack.
        observes: String,
    },
    /// The worker thread could not start.
    #[error("cannot start the generator's worker: {0}")]
    Thread(std::io::Error),
}

/// A generator's description: what its ONNX model takes and gives (`generator.toml`).
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct GeneratorDescription {
    /// What the model is (and is not).
    pub description: String,
    /// The ONNX file, relative to this file.
    pub onnx: PathBuf,
    /// The input that takes the last `history` frames, `[1, history, joints]`.
    #[serde(default = "history_input")]
    pub input: String,
    /// The output that gives the next `horizon` frames, `[1, horizon, joints]`.
    #[serde(default = "frames_output")]
    pub output: String,
    /// N: frames the model looks back (1–256).
    pub history: usize,
    /// K: frames one step produces (1–256).
    pub horizon: usize,
    /// Frames per second of the model's frames (1–1000); it steps at `frame_hz / horizon`.
    pub frame_hz: f64,
    /// Joint names (the robot's) in the model's order: a frame's values, rad.
    pub joints: Vec<String>,
    /// The clip whose first `history` frames seed the model (relative to this file).
    pub seed_clip: PathBuf,
    /// A second input the model takes beside its history: a command such as a target velocity
    /// or a style index, `[1, values]`.
    #[serde(default)]
    pub command: Option<GeneratorCommand>,
}

/// A generator's command input (`[command]` of its description).
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct GeneratorCommand {
    /// The input's name.
    pub input: String,
    /// What each value means (1–16 of them).
    pub names: Vec<String>,
    /// The values unless the run says otherwise (finite, within ±1000).
    pub values: Vec<f64>,
}

/// Command values that do not fit a generator's command.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CommandValueError {
    /// Not one value per name.
    #[error("{given} values for {} ({})", names.len(), names.join(", "))]
    Count {
        /// Values given.
        given: usize,
        /// The command's names.
        names: Vec<String>,
    },
    /// A value not finite or beyond ±1000.
    #[error("{name} = {value}: a finite value within ±1000")]
    OutOfRange {
        /// Its name.
        name: String,
        /// The value.
        value: f64,
    },
}

impl GeneratorCommand {
    /// Checks `values` against the command: one per name, finite, within ±1000.
    pub fn check(&self, values: &[f64]) -> Result<(), CommandValueError> {
        if values.len() != self.names.len() {
            return Err(CommandValueError::Count {
                given: values.len(),
                names: self.names.clone(),
            });
        }
        if let Some((name, &value)) = self
            .names
            .iter()
            .zip(values)
            .find(|(_, v)| !(v.is_finite() && v.abs() <= 1000.0))
        {
            return Err(CommandValueError::OutOfRange {
                name: name.clone(),
                value,
            });
        }
        Ok(())
    }
}

impl GeneratorDescription {
    /// Parses `text` (the file `path`) and checks what needs no robot or model: N and K within
    /// 1–256, the frame rate within 1–1000 Hz, joints named once each. Errors name the field.
    pub fn from_str(path: &Path, text: &str) -> Result<Self, FileError> {
        let d: Self = toml::from_str(text).map_err(|e| FileError::new(path, e.to_string()))?;
        let bad = |field: &str, m: String| FileError::new(path, format!("{field}: {m}"));
        for (field, v) in [("history", d.history), ("horizon", d.horizon)] {
            if !(1..=MAX_FRAMES).contains(&v) {
                return Err(bad(field, format!("{v} frames: 1–{MAX_FRAMES}")));
            }
        }
        if !(d.frame_hz.is_finite() && (1.0..=1000.0).contains(&d.frame_hz)) {
            return Err(bad("frame_hz", format!("{}: 1–1000 Hz", d.frame_hz)));
        }
        if d.joints.is_empty() {
            return Err(bad(
                "joints",
                "empty: name the model's joints in its order".into(),
            ));
        }
        if let Some((i, name)) = d
            .joints
            .iter()
            .enumerate()
            .find(|(i, n)| d.joints[..*i].contains(n))
        {
            return Err(bad("joints", format!("{name:?} twice (entry {i})")));
        }
        if let Some(c) = &d.command {
            if !(1..=16).contains(&c.names.len()) {
                return Err(bad("command.names", format!("{} names: 1–16", c.names.len())));
            }
            c.check(&c.values)
                .map_err(|e| bad("command.values", e.to_string()))?;
            if c.input == d.input {
                return Err(bad(
                    "command.input",
                    format!("{:?} is the history's input", c.input),
                ));
            }
        }
        Ok(d)
    }
}

fn history_input() -> String {
    "history".into()
}

fn frames_output() -> String {
    "frames".into()
}

/// How a generated reference copes with a late generator, and faults to inject.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct GeneratorOptions {
    /// Carry the reference on by its recent velocity for at most this long past the plan, s.
    pub forecast_s: f64,
    /// Then blend to the standby pose over this long (and back to a fresh plan as long), s.
    pub blend_s: f64,
    /// Fault injection: the worker stops producing once it has generated this far, s.
    pub stall_after_s: Option<f64>,
}

impl Default for GeneratorOptions {
    fn default() -> Self {
        Self {
            forecast_s: 0.2,
            blend_s: 1.0,
            stall_after_s: None,
        }
    }
}

impl GeneratorOptions {
    /// Checks the ranges: forecast 0–2 s, blend 0.05–10 s, stall ≥ 0 s.
    pub fn check(&self) -> Result<(), GeneratorError> {
        let out_of_range = |m: String| Err(GeneratorError::Options(m));
        if !(self.forecast_s.is_finite() && (0.0..=2.0).contains(&self.forecast_s)) {
            return out_of_range(format!("forecast {} s: 0–2 s", self.forecast_s));
        }
        if !(self.blend_s.is_finite() && (0.05..=10.0).contains(&self.blend_s)) {
            return out_of_range(format!("blend {} s: 0.05–10 s", self.blend_s));
        }
        if let Some(s) = self.stall_after_s
            && !(s.is_finite() && s >= 0.0)
        {
            return out_of_range(format!("stall after {s} s: a time ≥ 0"));
        }
        Ok(())
    }
}

/// Whether `layout` can track a generated reference: joint angles and velocities only (no
/// reference bodies, anchor or embedded motion, which a generator does not produce).
pub fn check_policy(layout: &policy::PolicyLayout) -> Result<(), GeneratorError> {
    use policy::Term;
    let unsupported: Vec<&str> = layout
        .slots
        .iter()
        .filter(|s| s.term.needs_anchor() || matches!(s.term, Term::RefBodyPos { .. } | Term::TimeStep(_)))
        .map(|s| s.term.name())
        .collect();
    if unsupported.is_empty() && layout.manifest.motion_bodies.is_empty() {
        Ok(())
    } else {
        Err(GeneratorError::PolicyNeedsMore {
            policy: layout.path.clone(),
            observes: if unsupported.is_empty() {
                "motion bodies".to_owned()
            } else {
                unsupported.join(", ")
            },
        })
    }
}

/// A loaded, checked generator: its model, description and seed.
#[derive(Debug)]
pub struct Generator {
    /// The description file.
    pub path: PathBuf,
    /// What it says.
    pub description: GeneratorDescription,
    model: OnnxModel,
    /// Robot joint of each model joint.
    robot_index: Vec<usize>,
    /// The first `history` frames of the seed clip, model order, `history × joints`.
    seed: Vec<f64>,
    /// The seed clip's first root pose (the generated reference's root).
    root: [f64; 7],
    /// The command values the model gets (the description's unless set).
    command: Vec<f64>,
}

impl Generator {
    /// Loads `path` (the description) for `robot`: every field in range, the joints the robot's,
    /// the model's input and output shaped as described, the seed clip long enough.
    pub fn load(path: &Path, robot: &Robot) -> Result<Self, GeneratorError> {
        let text = robots::read_text(path).map_err(|m| FileError::new(path, m))?;
        let d = GeneratorDescription::from_str(path, &text)?;
        let bad = |field: &str, m: String| FileError::new(path, format!("{field}: {m}"));
        let mut robot_index = Vec::with_capacity(d.joints.len());
        for name in &d.joints {
            let Some(r) = robot.config.joints.iter().position(|j| &j.name == name) else {
                return Err(bad(
                    "joints",
                    format!("{name:?} is not a joint of {}", robot.config.name),
                )
                .into());
            };
            robot_index.push(r);
        }
        let dir = path.parent().unwrap_or(Path::new("."));
        let onnx = dir.join(&d.onnx);
        let model = OnnxModel::load_tensors(&onnx)?;
        let j = d.joints.len() as i64;
        let want = [
            (d.input.as_str(), "input", [1, d.history as i64, j], "history"),
            (d.output.as_str(), "output", [1, d.horizon as i64, j], "horizon"),
        ];
        let shapes = model.shapes();
        let (inputs, output) = shapes.split_at(shapes.len() - 1);
        let shape_err = |message: String| GeneratorError::Shape {
            path: onnx.clone(),
            message,
        };
        for (name, kind, dims, field) in want {
            let found = if kind == "input" { inputs } else { output };
            let Some((_, shape)) = found.iter().find(|(n, _)| n == name) else {
                return Err(shape_err(format!(
                    "has no {kind} named {name:?} ({kind}s: {}); {} names it",
                    found
                        .iter()
                        .map(|(n, _)| n.as_str())
                        .collect::<Vec<_>>()
                        .join(", "),
                    path.display()
                )));
            };
            if shape.as_slice() != dims {
                return Err(shape_err(format!(
                    "{kind} {name:?} has shape {shape:?}, but {} says {field} = {} frames of {} joints: {dims:?}",
                    path.display(),
                    dims[1],
                    dims[2]
                )));
            }
        }
        if let Some(c) = &d.command {
            let width = [1, c.names.len() as i64];
            match inputs.iter().find(|(n, _)| n == &c.input) {
                Some((_, shape)) if shape.as_slice() == width => {}
                Some((_, shape)) => {
                    return Err(shape_err(format!(
                        "input {:?} has shape {shape:?}, but {} says the command has {} values: {width:?}",
                        c.input,
                        path.display(),
                        c.names.len()
                    )));
                }
                None => {
                    return Err(shape_err(format!(
                        "has no input named {:?}, the command {} names",
                        c.input,
                        path.display()
                    )));
                }
            }
        }
        let wanted = 1 + usize::from(d.command.is_some());
        if inputs.len() != wanted {
            return Err(shape_err(format!(
                "has {} inputs ({}); {} describes {wanted}: its history{}",
                inputs.len(),
                inputs
                    .iter()
                    .map(|(n, _)| n.as_str())
                    .collect::<Vec<_>>()
                    .join(", "),
                path.display(),
                if wanted == 2 {
                    " and its command"
                } else {
                    " (a [command] section names a second)"
                }
            )));
        }
        let clip = Clip::load(&dir.join(&d.seed_clip))?;
        let seed_reference = Reference::from_clip(&clip, robot, d.frame_hz)?;
        if seed_reference.len() < d.history {
            return Err(bad(
                "seed_clip",
                format!(
                    "{} has {} frames at {} Hz; the history needs {}",
                    clip.path.display(),
                    seed_reference.len(),
                    d.frame_hz,
                    d.history
                ),
            )
            .into());
        }
        let seed = (0..d.history)
            .flat_map(|k| robot_index.iter().map(move |&r| (k, r)))
            .map(|(k, r)| seed_reference.q_at(k)[r])
            .collect();
        Ok(Self {
            path: path.to_path_buf(),
            root: seed_reference.root[0],
            command: d.command.as_ref().map_or_else(Vec::new, |c| c.values.clone()),
            description: d,
            model,
            robot_index,
            seed,
        })
    }

    /// Sets the command the model gets (one value per the description's `command.names`).
    pub fn set_command(&mut self, values: &[f64]) -> Result<(), GeneratorError> {
        let c =
            self.description.command.as_ref().ok_or_else(|| {
                GeneratorError::Options(format!("{} takes no command", self.path.display()))
            })?;
        c.check(values)?;
        self.command = values.to_vec();
        Ok(())
    }

    /// The command the model gets: names and values (empty without one).
    pub fn command(&self) -> (Vec<String>, Vec<f64>) {
        (
            self.description
                .command
                .as_ref()
                .map_or_else(Vec::new, |c| c.names.clone()),
            self.command.clone(),
        )
    }

    /// The root pose the generated reference holds (the seed clip's first).
    pub fn root(&self) -> [f64; 7] {
        self.root
    }

    /// Starts the worker. `standby` (robot order) is where the reference blends to when the
    /// generator is late; `lookahead_s` how far ahead of its time the loop reads the plan.
    pub fn start(
        self,
        standby: &[f64],
        options: GeneratorOptions,
        lookahead_s: f64,
    ) -> Result<(GeneratorWorker, PlanReader), GeneratorError> {
        options.check()?;
        let d = &self.description;
        let (j, n, k) = (d.joints.len(), d.history, d.horizon);
        // What the loop may need: frames it played for the forecast's velocity, up to three steps
        // ahead of it (the worker runs at most two steps ahead of the loop's look-ahead).
        let width = n.max(4) + 3 * k + (lookahead_s * d.frame_hz).ceil() as usize;
        let mut frames = vec![0.0; width * j];
        frames[..n * j].copy_from_slice(&self.seed);
        let initial = Plan {
            first: -(n as i64),
            count: n,
            frames,
            joints: j,
            step: 0,
            latency_s: 0.0,
        };
        let (writer, reader) = live_channel(initial.clone());
        let shared = Arc::new(Shared::new(d.frame_hz));
        let mut plan_reader = PlanReader::new(
            reader,
            Arc::clone(&shared),
            self.robot_index.clone(),
            d.frame_hz,
            options,
            standby,
        );
        // The model's inputs in its order, concatenated: the history's place, the command's values.
        let mut input = Vec::with_capacity(n * j + self.command.len());
        let mut history_at = 0;
        for (name, _) in &self.model.shapes()[..self.model.inputs().len()] {
            if *name == d.input {
                history_at = input.len();
                input.resize(input.len() + n * j, 0.0);
            } else {
                input.extend(self.command.iter().map(|&v| v as f32));
            }
        }
        let worker = Worker {
            model: self.model,
            writer,
            shared: Arc::clone(&shared),
            plan: initial,
            input,
            history_at,
            history_len: n,
            next: vec![0.0; k * j],
            horizon: k,
            frame_hz: d.frame_hz,
            lookahead_s,
            stall_after: options.stall_after_s,
        };
        let thread = std::thread::Builder::new()
            .name("motion-generator".into())
            .spawn(move || worker.run())
            .map_err(GeneratorError::Thread)?;
        plan_reader.worker = Some(thread.thread().clone());
        Ok((
            GeneratorWorker {
                shared,
                thread: Some(thread),
            },
            plan_reader,
        ))
    }
}

/// A window of the generated stream: frames `first .. first + count` (frame `i` is at `i /
/// frame_hz` s of generator time; the seed is at negative indices), `joints` values each.
#[derive(Debug, Clone)]
pub struct Plan {
    first: i64,
    count: usize,
    frames: Vec<f64>,
    joints: usize,
    /// The step that made it (0: the seed), and its inference time, s.
    step: u64,
    latency_s: f64,
}

impl Plan {
    fn frame(&self, k: usize) -> &[f64] {
        &self.frames[k * self.joints..(k + 1) * self.joints]
    }
}

impl Shared {
    fn new(frame_hz: f64) -> Self {
        Self {
            loop_time: AtomicU64::new(0f64.to_bits()),
            // Nothing generated yet: the seed's last frame is at −1 frame.
            generated_until: AtomicU64::new((-1.0 / frame_hz).to_bits()),
            wake_at: AtomicU64::new(f64::INFINITY.to_bits()),
            stop: AtomicBool::new(false),
            stats: Mutex::new(WorkerStats::default()),
        }
    }
}

#[derive(Debug)]
struct Shared {
    /// The generator time the loop has reached, s (f64 bits).
    loop_time: AtomicU64,
    /// How far the worker has generated: the time of its newest frame, s (f64 bits).
    generated_until: AtomicU64,
    /// The loop time from which the worker wants to step again, s (f64 bits; infinite while it
    /// works): the loop wakes it then, so it sleeps between steps instead of polling.
    wake_at: AtomicU64,
    stop: AtomicBool,
    /// The worker's own counts (only the worker and the end of the run touch them).
    stats: Mutex<WorkerStats>,
}

/// What the worker did.
#[derive(Debug, Clone, Default)]
pub struct WorkerStats {
    /// Steps published.
    pub steps: u64,
    /// Steps whose inference failed or gave non-finite frames (not published).
    pub failed: u64,
    /// The injected stall began (generator time, s).
    pub stalled_at: Option<f64>,
    /// Each step's inference time.
    pub latency: Histogram,
}

struct Worker {
    model: OnnxModel,
    writer: LiveWriter<Plan>,
    shared: Arc<Shared>,
    /// The worker's copy of the window it publishes.
    plan: Plan,
    /// The model's inputs (history, and the command's values, in the model's order) and output,
    /// `f32` as the model wants them.
    input: Vec<f32>,
    /// Where the history starts in `input`, and its frames.
    history_at: usize,
    history_len: usize,
    next: Vec<f32>,
    horizon: usize,
    frame_hz: f64,
    lookahead_s: f64,
    stall_after: Option<f64>,
}

impl Worker {
    fn run(mut self) {
        // A model failing every step would write a line per step: one a second, with the count.
        let mut failure_log = firmware_bridge::ratelimit::RateLimit::per_second();
        let (j, k) = (self.plan.joints, self.horizon);
        let n = self.history_len;
        while !self.shared.stop.load(Ordering::Relaxed) {
            let loop_t = f64::from_bits(self.shared.loop_time.load(Ordering::Relaxed));
            let end = self.plan.first + self.plan.count as i64;
            let needed = (loop_t + self.lookahead_s) * self.frame_hz;
            // Two steps ahead of what the loop reads: a step late by a whole period still lands
            // before it is needed.
            if end as f64 - needed > (2 * k) as f64 {
                // Asleep until the loop reaches the time this test turns, woken by it (or a
                // stop); the timeout is only a backstop.
                let wake = (end - (2 * k) as i64) as f64 / self.frame_hz - self.lookahead_s;
                self.shared.wake_at.store(wake.to_bits(), Ordering::Relaxed);
                std::thread::park_timeout(Duration::from_millis(50));
                self.shared
                    .wake_at
                    .store(f64::INFINITY.to_bits(), Ordering::Relaxed);
                continue;
            }
            let generated_s = end as f64 / self.frame_hz;
            if let Some(at) = self.stall_after.filter(|&at| generated_s >= at) {
                let mut stats = self.shared.stats.lock().unwrap_or_else(PoisonError::into_inner);
                stats.stalled_at.get_or_insert(at);
                drop(stats);
                std::thread::park_timeout(Duration::from_millis(5));
                continue;
            }
            // The model's history: the newest `n` frames of the stream.
            let from = self.plan.count - n;
            let history = &mut self.input[self.history_at..self.history_at + n * j];
            for (h, v) in history
                .iter_mut()
                .zip(&self.plan.frames[from * j..self.plan.count * j])
            {
                *h = *v as f32;
            }
            let t0 = Instant::now();
            let ran = self.model.run(&self.input, &mut self.next);
            let took = t0.elapsed();
            let mut stats = self.shared.stats.lock().unwrap_or_else(PoisonError::into_inner);
            stats.latency.record(took);
            if let Err(e) = ran.map_err(|e| e.to_string()).and_then(|()| {
                self.next
                    .iter()
                    .all(|x| x.is_finite())
                    .then_some(())
                    .ok_or_else(|| "non-finite frames".to_owned())
            }) {
                stats.failed += 1;
                drop(stats);
                if let Some(left_out) = failure_log.allow(Instant::now()) {
                    tracing::warn!(
                        left_out,
                        "motion generator step at {generated_s:.2} s failed: {e}"
                    );
                }
                std::thread::park_timeout(Duration::from_millis(5));
                continue;
            }
            stats.steps += 1;
            self.plan.step = stats.steps;
            self.plan.latency_s = took.as_secs_f64();
            drop(stats);
            self.append();
            let plan = &self.plan;
            self.writer.publish(|p| {
                p.first = plan.first;
                p.count = plan.count;
                p.frames.copy_from_slice(&plan.frames);
                p.step = plan.step;
                p.latency_s = plan.latency_s;
            });
            let newest = (plan.first + plan.count as i64 - 1) as f64 / self.frame_hz;
            self.shared
                .generated_until
                .store(newest.to_bits(), Ordering::Relaxed);
        }
    }

    /// Appends the step's frames to the window, dropping the oldest ones that no longer fit.
    fn append(&mut self) {
        let (j, k) = (self.plan.joints, self.horizon);
        let width = self.plan.frames.len() / j;
        let drop = (self.plan.count + k).saturating_sub(width);
        if drop > 0 {
            self.plan.frames.copy_within(drop * j..self.plan.count * j, 0);
            self.plan.first += drop as i64;
            self.plan.count -= drop;
        }
        let at = self.plan.count * j;
        for (f, v) in self.plan.frames[at..at + k * j].iter_mut().zip(&self.next) {
            *f = f64::from(*v);
        }
        self.plan.count += k;
    }
}

/// The running worker; stops it when dropped.
#[derive(Debug)]
pub struct GeneratorWorker {
    shared: Arc<Shared>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl GeneratorWorker {
    /// How far the worker has generated: the generator time of its newest published frame, s.
    pub fn generated_until_s(&self) -> f64 {
        f64::from_bits(self.shared.generated_until.load(Ordering::Relaxed))
    }

    /// Stops the worker and returns what it did.
    pub fn finish(mut self) -> WorkerStats {
        self.stop();
        self.shared
            .stats
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .clone()
    }

    fn stop(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            t.thread().unpark();
            let _ = t.join();
        }
    }
}

impl Drop for GeneratorWorker {
    fn drop(&mut self) {
        self.stop();
    }
}

/// Where the generated reference stands at a tick.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PlanStatus {
    /// Inside the newest plan.
    Fresh,
    /// Past the plan, carried on by its recent velocity.
    Forecast,
    /// Past the forecast's bound: blending to (or holding) the standby pose.
    Standby,
}

impl PlanStatus {
    /// The status of a tick record's code (`as u8`).
    pub fn from_code(code: u8) -> Option<Self> {
        [Self::Fresh, Self::Forecast, Self::Standby]
            .get(usize::from(code))
            .copied()
    }

    /// Its name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Fresh => "fresh",
            Self::Forecast => "forecast",
            Self::Standby => "standby",
        }
    }
}

/// Where a generated reference stood in a tick (what a recording keeps).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GeneratedTick {
    /// Fresh, forecast or standby.
    pub status: PlanStatus,
    /// How far it had blended to standby, 0–1.
    pub standby_weight: f64,
    /// Generator time past the newest plan's last frame, s (negative: time left in it).
    pub past_plan_s: f64,
    /// The step that made the newest plan (0: the seed), and its inference time, s.
    pub step: u64,
    /// (See `step`.)
    pub step_latency_s: f64,
}

/// How often the generated reference was late, in ticks and events.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct PlanCounts {
    /// Ticks inside a plan.
    pub fresh_ticks: u64,
    /// Ticks on the forecast.
    pub forecast_ticks: u64,
    /// Ticks past the forecast's bound.
    pub standby_ticks: u64,
    /// Times the plan ran out (fresh → forecast).
    pub late: u64,
    /// Times the forecast's bound passed (forecast → standby).
    pub to_standby: u64,
    /// Times a fresh plan came back after running out.
    pub recovered: u64,
    /// Changes not kept in the event list (it was full).
    pub events_dropped: u64,
}

/// The loop's end: samples the newest plan at the loop's time into robot-order joint values.
#[derive(Debug)]
pub struct PlanReader {
    /// The worker's thread, woken when the loop reaches the time it asked for.
    worker: Option<std::thread::Thread>,
    reader: LiveReader<Plan>,
    shared: Arc<Shared>,
    robot_index: Vec<usize>,
    frame_hz: f64,
    options: GeneratorOptions,
    standby: Vec<f64>,
    /// The last sample, robot order.
    q: Vec<f64>,
    qd: Vec<f64>,
    /// The forecast's scratch, model order.
    forecast: Vec<f64>,
    status: PlanStatus,
    /// How far the reference has blended to standby, 0–1.
    weight: f64,
    counts: PlanCounts,
    events: Vec<(f64, PlanStatus)>,
    /// Past the plan's end at the last tick, s; the newest plan's step and its latency, s.
    past: f64,
    step: u64,
    step_latency_s: f64,
    reached_standby: Option<f64>,
}

impl PlanReader {
    /// A reader of `reader`'s plans for the model joints at `robot_index`, blending to
    /// `standby` (robot order).
    fn new(
        reader: LiveReader<Plan>,
        shared: Arc<Shared>,
        robot_index: Vec<usize>,
        frame_hz: f64,
        options: GeneratorOptions,
        standby: &[f64],
    ) -> Self {
        Self {
            worker: None,
            forecast: vec![0.0; robot_index.len()],
            reader,
            shared,
            robot_index,
            frame_hz,
            options,
            standby: standby.to_vec(),
            q: standby.to_vec(),
            qd: vec![0.0; standby.len()],
            status: PlanStatus::Fresh,
            weight: 0.0,
            counts: PlanCounts::default(),
            events: Vec::with_capacity(MAX_EVENTS),
            past: 0.0,
            step: 0,
            step_latency_s: 0.0,
            reached_standby: None,
        }
    }

    /// Takes the newest plan for the tick at generator time `t` (s; the loop's `dt` apart) and
    /// judges it: fresh, forecast or standby. Allocates nothing.
    pub fn begin_tick(&mut self, t: f64, dt: f64) {
        self.shared.loop_time.store(t.to_bits(), Ordering::Relaxed);
        if t >= f64::from_bits(self.shared.wake_at.load(Ordering::Relaxed))
            && let Some(worker) = &self.worker
        {
            // A futex wake: no lock, no allocation, never waits.
            worker.unpark();
        }
        let plan = self.reader.latest();
        let last = plan.first as f64 + plan.count as f64 - 1.0;
        let past = (t * self.frame_hz - last) / self.frame_hz;
        (self.past, self.step, self.step_latency_s) = (past, plan.step, plan.latency_s);
        let status = if past <= 0.0 {
            PlanStatus::Fresh
        } else if past <= self.options.forecast_s {
            PlanStatus::Forecast
        } else {
            PlanStatus::Standby
        };
        let step = dt / self.options.blend_s;
        self.weight = if status == PlanStatus::Standby {
            (self.weight + step).min(1.0)
        } else {
            (self.weight - step).max(0.0)
        };
        if self.weight >= 1.0 && self.reached_standby.is_none() {
            self.reached_standby = Some(t);
        }
        let c = &mut self.counts;
        match status {
            PlanStatus::Fresh => c.fresh_ticks += 1,
            PlanStatus::Forecast => c.forecast_ticks += 1,
            PlanStatus::Standby => c.standby_ticks += 1,
        }
        if status != self.status {
            match (self.status, status) {
                (PlanStatus::Fresh, _) => c.late += 1,
                (_, PlanStatus::Fresh) => c.recovered += 1,
                _ => {}
            }
            if status == PlanStatus::Standby {
                c.to_standby += 1;
            }
            if self.events.len() < MAX_EVENTS {
                self.events.push((t, status));
            } else {
                c.events_dropped += 1;
            }
            self.status = status;
        }
    }

    /// The reference at generator time `t` (this tick's, or ahead of it), robot order: the plan
    /// interpolated, or its forecast, blended to standby by this tick's weight. Joints the model
    /// does not drive stay at standby.
    pub fn sample(&mut self, t: f64) -> (&[f64], &[f64]) {
        let plan = self.reader.latest();
        let x = t * self.frame_hz - plan.first as f64;
        let last = plan.count - 1;
        let a = (self.weight * self.weight * (3.0 - 2.0 * self.weight)).clamp(0.0, 1.0);
        let (q, qd) = (&mut self.q, &mut self.qd);
        if x <= last as f64 {
            let x = x.max(0.0);
            let i = (x.floor() as usize).min(last.saturating_sub(1));
            let (f0, f1) = (plan.frame(i), plan.frame((i + 1).min(last)));
            let s = x - i as f64;
            for (m, &r) in self.robot_index.iter().enumerate() {
                let g = f0[m] + (f1[m] - f0[m]) * s;
                q[r] = g + (self.standby[r] - g) * a;
                qd[r] = (f1[m] - f0[m]) * self.frame_hz * (1.0 - a);
            }
        } else {
            let back = last.min(3);
            let span = back as f64 / self.frame_hz;
            let age = (x - last as f64) / self.frame_hz;
            carry_forward(
                plan.frame(last),
                plan.frame(last - back),
                span,
                age,
                self.options.forecast_s,
                &mut self.forecast,
            );
            let moving = age < self.options.forecast_s;
            for (m, &r) in self.robot_index.iter().enumerate() {
                let g = self.forecast[m];
                q[r] = g + (self.standby[r] - g) * a;
                let velocity = if moving && span > 0.0 {
                    (plan.frame(last)[m] - plan.frame(last - back)[m]) / span
                } else {
                    0.0
                };
                qd[r] = velocity * (1.0 - a);
            }
        }
        (&self.q, &self.qd)
    }

    /// Where the reference stood at the last tick.
    pub fn tick(&self) -> GeneratedTick {
        GeneratedTick {
            status: self.status,
            standby_weight: self.weight,
            past_plan_s: self.past,
            step: self.step,
            step_latency_s: self.step_latency_s,
        }
    }

    /// When the reference first stood fully at standby (generator time, s).
    pub fn reached_standby(&self) -> Option<f64> {
        self.reached_standby
    }

    /// Counts so far.
    pub fn counts(&self) -> PlanCounts {
        self.counts
    }

    /// The changes so far: generator time (s) and the new status.
    pub fn events(&self) -> &[(f64, PlanStatus)] {
        &self.events
    }
}

/// What a generated reference did over a run.
#[derive(Debug, Clone)]
pub struct GeneratorSummary {
    /// The worker's steps, failures and latency.
    pub worker: WorkerStats,
    /// The loop's view: ticks fresh, forecast and standby, and the changes.
    pub counts: PlanCounts,
    /// The changes kept: generator time (s) and the new status.
    pub events: Vec<(f64, PlanStatus)>,
    /// When the reference first stood fully at standby (generator time, s).
    pub reached_standby: Option<f64>,
    /// The generator's frame rate.
    pub frame_hz: f64,
    /// Frames per step.
    pub horizon: usize,
}

impl GeneratorSummary {
    /// No tick ever tracked a generated plan (every step failed, or none came in time).
    pub fn never_came(&self) -> bool {
        self.counts.fresh_ticks == 0
    }
}

impl std::fmt::Display for GeneratorSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (w, c) = (&self.worker, &self.counts);
        let us = |p: f64| w.latency.quantile(p).as_secs_f64() * 1e6;
        writeln!(
            f,
            "generator: {} steps of {} frames at {} Hz ({} failed), step latency p50 {:.0} µs, p99 {:.0} µs",
            w.steps,
            self.horizon,
            self.frame_hz,
            w.failed,
            us(0.5),
            us(0.99)
        )?;
        writeln!(
            f,
            "  reference ticks: {} fresh, {} forecast, {} standby; plan ran out {} times, reached the standby bound {} times, recovered {} times",
            c.fresh_ticks, c.forecast_ticks, c.standby_ticks, c.late, c.to_standby, c.recovered
        )?;
        if let Some(at) = w.stalled_at {
            writeln!(f, "  fault injected: the generator stalled at {at:.2} s")?;
        }
        if let Some(at) = self.reached_standby {
            writeln!(f, "  standby pose reached at {at:.2} s")?;
        }
        for (t, s) in self.events.iter().take(8) {
            writeln!(f, "  {t:>8.2} s  {}", s.name())?;
        }
        if self.events.len() > 8 {
            writeln!(f, "  … {} more changes", self.events.len() - 8)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A loop's reader over a plan of one joint (robot joint 1 of 2), 10 frames a second.
    fn reader(values: &[f64], options: GeneratorOptions) -> (LiveWriter<Plan>, PlanReader) {
        let plan = Plan {
            first: 0,
            count: values.len(),
            frames: values.to_vec(),
            joints: 1,
            step: 1,
            latency_s: 0.0,
        };
        let (writer, reader) = live_channel(plan);
        let plans = PlanReader::new(
            reader,
            Arc::new(Shared::new(10.0)),
            vec![1],
            10.0,
            options,
            &[5.0, -1.0],
        );
        (writer, plans)
    }

    #[test]
    fn a_plan_is_interpolated_then_forecast_then_blended_to_standby_and_back() {
        let options = GeneratorOptions {
            forecast_s: 0.2,
            blend_s: 0.5,
            stall_after_s: None,
        };
        // Frames at 0, 0.1, 0.2, 0.3 s: a joint moving at 10 rad/s.
        let (mut writer, mut r) = reader(&[0.0, 1.0, 2.0, 3.0], options);
        r.begin_tick(0.15, 0.05);
        let (q, qd) = r.sample(0.15);
        assert!(
            (q[1] - 1.5).abs() < 1e-12 && (qd[1] - 10.0).abs() < 1e-12,
            "{q:?} {qd:?}"
        );
        assert_eq!(q[0], 5.0, "a joint the model does not drive stays at standby");
        assert_eq!(r.tick().status, PlanStatus::Fresh);
        // 0.1 s past the last frame: carried on at 10 rad/s.
        r.begin_tick(0.4, 0.05);
        let (q, qd) = r.sample(0.4);
        assert!(
            (q[1] - 4.0).abs() < 1e-12 && (qd[1] - 10.0).abs() < 1e-12,
            "{q:?}"
        );
        assert_eq!(r.tick().status, PlanStatus::Forecast);
        // Past the bound: the forecast stops at 0.2 s (5.0) and blends to standby (−1) over
        // 0.5 s, 0.1 a tick, smoothly.
        r.begin_tick(0.55, 0.05);
        let (q, qd) = r.sample(0.55);
        let w: f64 = 0.1 * 0.1 * (3.0 - 0.2);
        assert!(
            (q[1] - (5.0 - 6.0 * w)).abs() < 1e-12 && qd[1] == 0.0,
            "{q:?} {qd:?}"
        );
        for k in 1..=9 {
            r.begin_tick(0.55 + f64::from(k) * 0.05, 0.05);
            assert_eq!(r.reached_standby(), None, "tick {k}");
        }
        r.begin_tick(1.05, 0.05);
        assert_eq!(r.sample(1.05).0[1], -1.0);
        assert!((r.reached_standby().unwrap() - 1.05).abs() < 1e-9);
        // Plans again: fresh at once, blended back from standby as it left.
        writer.publish(|p| {
            p.first = 10;
            p.count = 4;
            p.frames.copy_from_slice(&[2.0, 2.0, 2.0, 2.0]);
        });
        r.begin_tick(1.1, 0.05);
        let (q, _) = r.sample(1.1);
        let w: f64 = 0.9 * 0.9 * (3.0 - 1.8);
        assert!((q[1] - (2.0 - 3.0 * w)).abs() < 1e-12, "{q:?}");
        let c = r.counts();
        assert_eq!((c.late, c.to_standby, c.recovered), (1, 1, 1), "{c:?}");
        assert_eq!(
            r.events().iter().map(|e| e.1).collect::<Vec<_>>(),
            [PlanStatus::Forecast, PlanStatus::Standby, PlanStatus::Fresh]
        );
    }

    #[test]
    fn options_out_of_range_are_refused() {
        let bad = |o: GeneratorOptions| o.check().unwrap_err().to_string();
        let d = GeneratorOptions::default();
        assert!(d.check().is_ok());
        assert!(bad(GeneratorOptions { forecast_s: 3.0, ..d }).contains("forecast 3 s"));
        assert!(bad(GeneratorOptions { blend_s: 0.0, ..d }).contains("blend 0 s"));
        assert!(
            bad(GeneratorOptions {
                stall_after_s: Some(f64::NAN),
                ..d
            })
            .contains("stall")
        );
    }
}
