//! Batch validation: many clips × seeds on the mirror in lockstep, spread over the cores, summed up
//! per clip (success rate, tracking RMSE, governor saturation).

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

use robots::Robot;
use sim2real::config::MirrorConfig;

use controller::clip::{Clip, Reference};
use controller::player::{PlayOptions, PlaySummary};
use controller::sim::run_on_mirror;
use policy::PolicyLayout;

use crate::AnalysisError;

/// One run's outcome.
#[derive(Debug, Clone)]
pub struct BatchRun {
    /// Clip index.
    pub clip: usize,
    /// Seed.
    pub seed: u64,
    /// The run's summary, or why it could not run (the error's whole message, for the table).
    pub result: Result<PlaySummary, String>,
}

/// One run of a batch as a table row: what a distributed run ships back and what `batch --json`
/// writes, one JSON object per line. Only what a lockstep run determines (no wall-clock times), so
/// the same clip, seed and mirror file give the same row on any machine, bit for bit.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RunRow {
    /// The clip, as given.
    pub clip: String,
    /// The seed.
    pub seed: u64,
    /// Why the run could not run at all, if it could not.
    pub error: Option<String>,
    /// No fall, no safety stop, played to the end, the root's height and tilt within a tracking
    /// trainer's episode bounds (the report's criterion, `controller::metrics::tracking_success`).
    pub success: bool,
    /// The base fell while in control.
    pub fell: bool,
    /// How it ended: `finished`, `stopped by the operator …`, `safety stop …`.
    pub outcome: String,
    /// Ticks run.
    pub ticks: u64,
    /// Share of the reference played.
    pub played: f64,
    /// Joint tracking RMSE, deg (none when the run never reached the clip).
    pub joint_rmse_deg: Option<f64>,
    /// Root position RMSE, cm.
    pub root_rmse_cm: Option<f64>,
    /// Largest root position (cm) and orientation (deg) error.
    pub root_max_error: Option<(f64, f64)>,
    /// Policy ticks where the governor limited a command.
    pub limited_ticks: u64,
}

impl RunRow {
    /// The row of `run`, whose clip is `clip`.
    pub fn of(run: &BatchRun, clip: &std::path::Path) -> Self {
        let clip = clip.display().to_string();
        match &run.result {
            Ok(s) => Self {
                clip,
                seed: run.seed,
                error: None,
                success: s.success(),
                fell: s.fell,
                outcome: s.outcome().to_string(),
                ticks: s.ticks,
                played: s.played,
                joint_rmse_deg: s.joint_rmse.is_finite().then(|| s.joint_rmse.to_degrees()),
                root_rmse_cm: s.root_rmse.map(|r| r * 100.0),
                root_max_error: s.root_max_error.map(|(d, a)| (d * 100.0, a.to_degrees())),
                limited_ticks: s.limited_ticks,
            },
            Err(e) => Self {
                clip,
                seed: run.seed,
                error: Some(e.clone()),
                success: false,
                fell: false,
                outcome: "error".into(),
                ticks: 0,
                played: 0.0,
                joint_rmse_deg: None,
                root_rmse_cm: None,
                root_max_error: None,
                limited_ticks: 0,
            },
        }
    }
}

/// Per-clip totals.
#[derive(Debug, Clone, PartialEq)]
pub struct ClipTotals {
    /// The clip.
    pub clip: PathBuf,
    /// Runs.
    pub runs: usize,
    /// Runs that did not fall and ended without a fault.
    pub successes: usize,
    /// Mean joint RMSE, deg.
    pub joint_rmse_deg: f64,
    /// Mean root RMSE, cm.
    pub root_rmse_cm: f64,
    /// Ticks where the governor limited a command, summed over runs.
    pub limited_ticks: u64,
    /// Runs that could not run (with the first reason).
    pub errors: Vec<String>,
}

/// What to run.
#[derive(Debug, Clone)]
pub struct BatchSpec<'a> {
    /// The robot.
    pub robot: &'a Robot,
    /// The policy manifest.
    pub policy: &'a std::path::Path,
    /// The clips.
    pub clips: &'a [PathBuf],
    /// The seeds (each run randomises the mirror with its seed).
    pub seeds: &'a [u64],
    /// Mirror settings (randomisation, faults, gantry); the seed is replaced per run.
    pub mirror: &'a MirrorConfig,
    /// Run options.
    pub options: PlayOptions,
    /// Worker threads.
    pub jobs: usize,
}

/// Runs every clip with every seed on `spec.jobs` threads; `progress` is called after each run
/// with (done, total).
pub fn run_batch(
    spec: &BatchSpec<'_>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<(Vec<ClipTotals>, Vec<BatchRun>), AnalysisError> {
    let BatchSpec {
        robot,
        policy,
        clips,
        seeds,
        mirror,
        options,
        jobs,
    } = *spec;
    // Load and check everything before starting any run.
    let layout = PolicyLayout::load(policy, robot)?;
    let mut references = Vec::with_capacity(clips.len());
    for c in clips {
        let clip = Clip::load(c)?;
        references.push(Reference::for_policy(&clip, robot, &layout)?);
    }
    let work: Vec<(usize, u64)> = (0..clips.len())
        .flat_map(|c| seeds.iter().map(move |&s| (c, s)))
        .collect();
    let next = AtomicUsize::new(0);
    let done = AtomicUsize::new(0);
    let results = Mutex::new(Vec::with_capacity(work.len()));
    std::thread::scope(|scope| {
        for w in 0..jobs.max(1) {
            let (work, next, done, results, references, layout) =
                (&work, &next, &done, &results, &references, &layout);
            let builder = std::thread::Builder::new().name(format!("batch-{w}"));
            let spawned = builder.spawn_scoped(scope, move || {
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    let Some(&(clip, seed)) = work.get(i) else { break };
                    let config = MirrorConfig {
                        seed,
                        ..mirror.clone()
                    };
                    let result = run_on_mirror(
                        robot.clone(),
                        layout.clone(),
                        references[clip].clone(),
                        options,
                        config,
                        Arc::new(AtomicBool::new(false)),
                    )
                    .map_err(|e| robot_link::message_chain(&e));
                    results
                        .lock()
                        .unwrap_or_else(PoisonError::into_inner)
                        .push(BatchRun { clip, seed, result });
                    progress(done.fetch_add(1, Ordering::Relaxed) + 1, work.len());
                }
            });
            if let Err(e) = spawned {
                tracing::warn!("cannot start batch worker {w}: {e}");
            }
        }
    });
    let mut runs = results.into_inner().unwrap_or_else(PoisonError::into_inner);
    runs.sort_by_key(|r| (r.clip, r.seed));
    let totals = clips
        .iter()
        .enumerate()
        .map(|(c, path)| {
            let mine: Vec<&BatchRun> = runs.iter().filter(|r| r.clip == c).collect();
            let ok: Vec<&PlaySummary> = mine.iter().filter_map(|r| r.result.as_ref().ok()).collect();
            // The same criterion as the report's (controller::metrics::tracking_success).
            let clean = |s: &PlaySummary| s.success();
            let mean = |f: &dyn Fn(&PlaySummary) -> f64| {
                if ok.is_empty() {
                    f64::NAN
                } else {
                    ok.iter().map(|s| f(s)).sum::<f64>() / ok.len() as f64
                }
            };
            ClipTotals {
                clip: path.clone(),
                runs: mine.len(),
                successes: ok.iter().filter(|s| clean(s)).count(),
                joint_rmse_deg: mean(&|s| s.joint_rmse.to_degrees()),
                root_rmse_cm: mean(&|s| s.root_rmse.unwrap_or(f64::NAN) * 100.0),
                limited_ticks: ok.iter().map(|s| s.limited_ticks).sum(),
                errors: mine
                    .iter()
                    .filter_map(|r| r.result.as_ref().err().cloned())
                    .collect(),
            }
        })
        .collect();
    Ok((totals, runs))
}
