//! `robodeploy batch`: many clips × seeds on the mirror, in parallel, one table at the end.

use std::path::PathBuf;

use analysis::batch::{BatchSpec, run_batch};
use anyhow::{Context, Result};
use clap::Args;
use controller::player::PlayOptions;
use robots::Robot;

use crate::sim::load_mirror_config;

/// Arguments of `batch`.
#[derive(Debug, Args)]
pub struct BatchArgs {
    /// The robot description.
    #[arg(long, default_value_os_t = robots::locate::default_robot())]
    robot: PathBuf,
    /// The policy manifest.
    /// Default: the policy robot.toml names (`policy = "policies/…"`).
    #[arg(long)]
    policy: Option<PathBuf>,
    /// Clips to run (CSV or NPZ).
    #[arg(long, num_args = 1.., required = true)]
    clips: Vec<PathBuf>,
    /// Seeds, as FIRST-LAST (each seed randomises the mirror per --mirror).
    #[arg(long, default_value = "0-3", value_parser = parse_seeds)]
    seeds: (u64, u64),
    /// Mirror settings (randomisation, faults, gantry), TOML.
    #[arg(long)]
    mirror: Option<PathBuf>,
    /// How much of the robot the mirror is (default: the --mirror file's `fidelity`, else
    /// wires): wires — every device's firmware behind its bus protocol; direct — the trainer's
    /// actuator law applied to MuJoCo, no buses: the physics floor, for validating a motion
    /// library fast.
    #[arg(long, value_enum)]
    fidelity: Option<crate::args::FidelityArg>,
    /// Parallel runs, 1–256 (default: the number of cores).
    #[arg(long, value_parser = crate::args::jobs)]
    jobs: Option<usize>,
    /// Also write every run as one JSON object per line here (clip, seed, success, fall, outcome,
    /// RMSEs, limited ticks): only what the lockstep run determines, bit for bit the same on any
    /// machine. What `robodeploy-ray` gathers from its workers.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Also write every run as a row of a CSV table here (the same fields as --json).
    #[arg(long, value_name = "FILE")]
    csv: Option<PathBuf>,
}

fn parse_seeds(s: &str) -> Result<(u64, u64), String> {
    let (a, b) = s.split_once('-').unwrap_or((s, s));
    let parse = |x: &str| {
        x.trim()
            .parse::<u64>()
            .map_err(|_| format!("'{s}': expected FIRST-LAST, e.g. 0-7"))
    };
    let (a, b) = (parse(a)?, parse(b)?);
    if a > b || b - a >= 10_000 {
        return Err(format!("'{s}': need FIRST <= LAST and at most 10000 seeds"));
    }
    Ok((a, b))
}

/// Runs `batch`.
pub fn run(args: &BatchArgs) -> Result<()> {
    let robot = Robot::load(&args.robot)?;
    let policy = crate::args::policy_of(args.policy.as_deref(), &robot)?;
    let mut mirror = match &args.mirror {
        Some(p) => load_mirror_config(p, &robot)?,
        None => sim2real::config::MirrorConfig::default(),
    };
    if let Some(f) = args.fidelity {
        mirror.fidelity = f.into();
    }
    let seeds: Vec<u64> = (args.seeds.0..=args.seeds.1).collect();
    let jobs = args
        .jobs
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, std::num::NonZero::get));
    let total = (args.clips.len() * seeds.len()) as u64;
    // Every run's state changes and faults would cut through the bar: the table below says how
    // each run ended (RUST_LOG brings the lines back).
    crate::logging::errors_only();
    let bar = crate::console::Progress::new("batch", "runs", Some(total));
    let spec = BatchSpec {
        robot: &robot,
        policy: &policy,
        clips: &args.clips,
        seeds: &seeds,
        mirror: &mirror,
        options: PlayOptions::default(),
        jobs,
    };
    let (totals, runs) = run_batch(&spec, &|done, _| bar.set(done as u64))?;
    bar.finish();
    println!("mirror: {}", mirror.fidelity);
    if let Some(path) = &args.json {
        let mut text = String::new();
        for r in &runs {
            let row = analysis::batch::RunRow::of(r, &args.clips[r.clip]);
            text.push_str(&serde_json::to_string(&row)?);
            text.push('\n');
        }
        std::fs::write(path, text).with_context(|| format!("--json: cannot write {}", path.display()))?;
    }
    let rows: Vec<_> = runs
        .iter()
        .map(|r| analysis::batch::RunRow::of(r, &args.clips[r.clip]))
        .collect();
    if let Some(path) = &args.csv {
        write_csv(path, &rows).with_context(|| format!("--csv: cannot write {}", path.display()))?;
    }
    println!(
        "{:<28} {:>6} {:>9} {:>13} {:>12} {:>14}  failures",
        "clip", "runs", "success", "joint RMSE °", "root RMSE cm", "limited ticks"
    );
    let number = |v: f64, digits: usize| {
        if v.is_finite() {
            format!("{v:.digits$}")
        } else {
            "—".to_owned()
        }
    };
    for (k, t) in totals.iter().enumerate() {
        let name = t.clip.file_name().map_or_else(
            || t.clip.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        );
        // Why the runs that failed did: their outcomes, counted.
        let mut why: std::collections::BTreeMap<String, usize> = std::collections::BTreeMap::new();
        for (r, row) in runs.iter().zip(&rows) {
            if r.clip == k && !row.success {
                let reason = match (&row.error, row.fell) {
                    (Some(_), _) => "could not run".to_owned(),
                    (None, true) if row.outcome == "finished" => "fell".to_owned(),
                    (None, _) => cause_of(&row.outcome),
                };
                *why.entry(reason).or_default() += 1;
            }
        }
        let failures = if why.is_empty() {
            "—".to_owned()
        } else {
            why.iter()
                .map(|(w, n)| format!("{w} ×{n}"))
                .collect::<Vec<_>>()
                .join("; ")
        };
        println!(
            "{name:<28} {:>6} {:>8.0}% {:>13} {:>12} {:>14}  {failures}",
            t.runs,
            100.0 * t.successes as f64 / t.runs.max(1) as f64,
            number(t.joint_rmse_deg, 2),
            number(t.root_rmse_cm, 1),
            t.limited_ticks
        );
        for e in t.errors.iter().take(3) {
            println!("    error: {e}");
        }
    }
    Ok(())
}

/// An outcome without its particulars, so runs that failed alike count together: `safety stop at
/// tick 75: joint left_elbow (14): no feedback for 2 bus cycles` → `safety stop: joint left_elbow (14): no
/// feedback`.
fn cause_of(outcome: &str) -> String {
    let mut parts = outcome.split(": ");
    let head = parts.next().unwrap_or(outcome);
    let head = head.split(" at tick ").next().unwrap_or(head);
    let mut out = vec![head.to_owned()];
    for p in parts {
        out.push(p.split(" for ").next().unwrap_or(p).to_owned());
    }
    out.join(": ")
}

/// The runs as a CSV table, one row each, the fields of `--json`.
fn write_csv(path: &std::path::Path, rows: &[analysis::batch::RunRow]) -> std::io::Result<()> {
    use std::fmt::Write as _;
    let opt = |v: Option<f64>| v.map_or_else(String::new, |v| v.to_string());
    let quoted = |s: &str| format!("\"{}\"", s.replace('"', "\"\""));
    let mut text = String::from(
        "clip,seed,success,fell,outcome,ticks,played,joint_rmse_deg,root_rmse_cm,limited_ticks,error\n",
    );
    for r in rows {
        let _ = writeln!(
            text,
            "{},{},{},{},{},{},{},{},{},{},{}",
            quoted(&r.clip),
            r.seed,
            r.success,
            r.fell,
            quoted(&r.outcome),
            r.ticks,
            r.played,
            opt(r.joint_rmse_deg),
            opt(r.root_rmse_cm),
            r.limited_ticks,
            r.error.as_deref().map_or_else(String::new, quoted)
        );
    }
    std::fs::write(path, text)
}
