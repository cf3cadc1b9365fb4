//! The observation contract diff: two observation traces (from runs, or a training export) compared
//! term by term, to find where and by how much the policy's inputs first diverge — the usual reason
//! a policy that works in training fails on the robot.

use std::path::Path;

use controller::npy::NpyArray;
use controller::options::RunMetadata;

use crate::AnalysisError;
use controller::policy::PolicyLayout;

/// Observations per policy step (running ticks only), and where they came from.
#[derive(Debug, Clone, PartialEq)]
pub struct ObsTrace {
    /// One observation per step.
    pub steps: Vec<Vec<f32>>,
    /// The control tick of each step (runs), or the step index (exports).
    pub ticks: Vec<u64>,
}

/// Reads the observations of a recorded run's Running ticks, and what the run was made from.
pub fn trace_from_run(path: &Path) -> Result<(ObsTrace, RunMetadata), AnalysisError> {
    run_trace(path).map_err(|m| AnalysisError::file(path, m))
}

fn run_trace(path: &Path) -> Result<(ObsTrace, RunMetadata), String> {
    let bytes = crate::recording::read(path)?;
    let mut trace = ObsTrace {
        steps: Vec::new(),
        ticks: Vec::new(),
    };
    let mut run = std::collections::BTreeMap::new();
    crate::recording::for_each_message(&bytes, |m| {
        if m.topic == "/replay" && run.is_empty() {
            run = m.metadata.clone();
        }
        if m.topic != "/policy" {
            return Ok(());
        }
        let v: serde_json::Value = serde_json::from_slice(m.data).map_err(|e| format!("/policy: {e}"))?;
        if v["running"].as_bool() != Some(true) {
            return Ok(());
        }
        let obs = v["obs"]
            .as_array()
            .ok_or_else(|| "/policy without obs".to_owned())?
            .iter()
            .map(|x| x.as_f64().map_or(f32::NAN, |x| x as f32))
            .collect();
        trace.steps.push(obs);
        trace.ticks.push(v["tick"].as_u64().unwrap_or(0));
        Ok(())
    })?;
    if trace.steps.is_empty() {
        return Err("no Running ticks with observations".to_owned());
    }
    let run = run
        .get("run")
        .ok_or_else(|| "the recording does not say how it was run".to_owned())
        .and_then(|json| RunMetadata::from_json(json).map_err(|e| format!("run metadata: {e}")))?;
    Ok((trace, run))
}

/// Reads an observation export: `.npz` with an `obs` array (steps × values), or CSV with one
/// observation per row (a header row is skipped).
pub fn trace_from_export(path: &Path) -> Result<ObsTrace, AnalysisError> {
    export_trace(path).map_err(|m| AnalysisError::file(path, m))
}

fn export_trace(path: &Path) -> Result<ObsTrace, String> {
    let steps: Vec<Vec<f32>> = if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("npz")) {
        let arrays = controller::npy::read_npz(path).map_err(|e| e.message)?;
        match arrays.get("obs") {
            Some(NpyArray::Numbers { shape, data }) if shape.len() == 2 && shape[0] > 0 && shape[1] > 0 => {
                data.chunks(shape[1])
                    .map(|r| r.iter().map(|&x| x as f32).collect())
                    .collect()
            }
            Some(_) => {
                return Err("obs must be a steps × values number array".into());
            }
            None => return Err("no obs array".into()),
        }
    } else {
        let text = robots::read_text(path)?;
        let mut rows = Vec::new();
        for (i, line) in text
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty() && !l.starts_with('#'))
        {
            let parsed: Result<Vec<f32>, _> = line.split(',').map(|x| x.trim().parse::<f32>()).collect();
            match parsed {
                Ok(row) => rows.push(row),
                Err(_) if rows.is_empty() => {} // a header
                Err(_) => return Err(format!("line {}: not numbers", i + 1)),
            }
        }
        rows
    };
    if steps.is_empty() {
        return Err("no observations (one row per step, one column per value)".into());
    }
    let n = steps.len() as u64;
    Ok(ObsTrace {
        steps,
        ticks: (0..n).collect(),
    })
}

/// How one term compares.
#[derive(Debug, Clone, PartialEq)]
pub struct TermDiff {
    /// Term name.
    pub term: String,
    /// Its observation index range.
    pub range: std::ops::Range<usize>,
    /// First step where some value differs by more than the tolerance.
    pub first_step: Option<usize>,
    /// Largest difference over all steps.
    pub max_abs: f64,
    /// RMS difference over all steps and values.
    pub rms: f64,
}

/// Compares `a` and `b` step by step over their common length, term by term; terms in the order
/// they first diverge (never-diverging terms last).
pub fn compare(
    a: &ObsTrace,
    b: &ObsTrace,
    layout: &PolicyLayout,
    tolerance: f64,
) -> Result<Vec<TermDiff>, AnalysisError> {
    let steps = a.steps.len().min(b.steps.len());
    if steps == 0 {
        return Err(AnalysisError::Mismatch(format!(
            "nothing to compare: the traces have {} and {} steps",
            a.steps.len(),
            b.steps.len()
        )));
    }
    for (name, t) in [("first", a), ("second", b)] {
        if let Some(s) = t.steps.iter().take(steps).find(|s| s.len() != layout.obs_len) {
            return Err(AnalysisError::Mismatch(format!(
                "the {name} trace has {} values per step; the policy's observation has {}",
                s.len(),
                layout.obs_len
            )));
        }
    }
    let mut out: Vec<TermDiff> = layout
        .slots
        .iter()
        .map(|slot| {
            let mut first = None;
            let (mut max_abs, mut sq, mut count) = (0.0f64, 0.0f64, 0usize);
            for k in 0..steps {
                let (x, y) = (&a.steps[k][slot.range.clone()], &b.steps[k][slot.range.clone()]);
                for (p, q) in x.iter().zip(y) {
                    let d = (f64::from(*p) - f64::from(*q)).abs();
                    let d = if d.is_nan() { f64::INFINITY } else { d };
                    max_abs = max_abs.max(d);
                    sq += if d.is_finite() { d * d } else { 0.0 };
                    count += 1;
                    if d > tolerance && first.is_none() {
                        first = Some(k);
                    }
                }
            }
            TermDiff {
                term: slot.term.name().to_owned(),
                range: slot.range.clone(),
                first_step: first,
                max_abs,
                rms: if count > 0 {
                    (sq / count as f64).sqrt()
                } else {
                    0.0
                },
            }
        })
        .collect();
    out.sort_by_key(|d| d.first_step.unwrap_or(usize::MAX));
    Ok(out)
}
