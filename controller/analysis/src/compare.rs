//! The observation contract diff: two observation traces (from runs, or a training export) compared
//! term by term, to find where and by how much the policy's inputs first diverge — the usual reason
//! a policy that works in training fails on the robot.

use std::path::Path;

use controller::npy::NpyArray;
use controller::options::RunMetadata;

use crate::AnalysisError;
use policy::PolicyLayout;

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
    let unreadable = |e| AnalysisError::recording(path, e);
    let bytes = crate::recording::read(path).map_err(unreadable)?;
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
        let v = <telemetry_schema::PolicyStep as prost::Message>::decode(m.data)
            .map_err(|e| crate::recording::RecordingError::decode("/policy", e))?;
        if !v.running {
            return Ok(());
        }
        trace.steps.push(v.observation);
        trace.ticks.push(v.tick);
        Ok(())
    })
    .map_err(unreadable)?;
    let bad = |m: String| AnalysisError::file(path, m);
    if trace.steps.is_empty() {
        return Err(bad("no Running ticks with observations".to_owned()));
    }
    let run = run
        .get("run")
        .ok_or_else(|| bad("the recording does not say how it was run".to_owned()))
        .and_then(|json| RunMetadata::from_json(json).map_err(|e| bad(format!("run metadata: {e}"))))?
        .resolved_from(path.parent().unwrap_or(Path::new(".")));
    Ok((trace, run))
}

/// Reads an observation export: `.npz` with an `obs` array (steps × values), or CSV with one
/// observation per row (a header row is skipped).
pub fn trace_from_export(path: &Path) -> Result<ObsTrace, AnalysisError> {
    let bad = |m: &dyn std::fmt::Display| AnalysisError::file(path, m);
    let steps: Vec<Vec<f32>> = if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("npz")) {
        let arrays = controller::npy::read_npz(path).map_err(|e| bad(&e.message))?;
        match arrays.get("obs") {
            Some(NpyArray::Numbers { shape, data }) if shape.len() == 2 && shape[0] > 0 && shape[1] > 0 => {
                data.chunks(shape[1])
                    .map(|r| r.iter().map(|&x| x as f32).collect())
                    .collect()
            }
            Some(_) => {
                return Err(bad(&"obs must be a steps × values number array"));
            }
            None => return Err(bad(&"no obs array")),
        }
    } else {
        let text = robots::read_text(path).map_err(|e| bad(&e))?;
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
                Err(_) => return Err(bad(&format_args!("line {}: not numbers", i + 1))),
            }
        }
        rows
    };
    if steps.is_empty() {
        return Err(bad(&"no observations (one row per step, one column per value)"));
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
    /// First step (of the first trace) where some value differs by more than the tolerance.
    pub first_step: Option<usize>,
    /// Largest difference over all steps.
    pub max_abs: f64,
    /// RMS difference over all steps and values.
    pub rms: f64,
    /// The buses' resolution of what the term observes, in observation units (its largest value
    /// over the term): `None` for terms no bus measures (commands, actions, phase, references).
    pub quantum: Option<f64>,
}

impl TermDiff {
    /// Whether the difference is within what the buses can tell apart: two readings of the same
    /// quantity each rounded to the device's step differ by at most one step, two when the term
    /// is derived from several readings.
    pub fn within_quantisation(&self) -> Option<bool> {
        self.quantum.map(|q| self.max_abs <= 2.0 * q + 1e-7)
    }
}

/// Which steps of the second trace meet which of the first: step `k` of the first against step
/// `k + offset` of the second, at most `steps` of them.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Alignment {
    /// The second trace's shift, steps (negative: it starts later).
    pub offset: i64,
    /// Compare at most this many steps.
    pub steps: Option<usize>,
}

impl Alignment {
    /// How many steps of traces `a` and `b` steps long it compares.
    pub fn steps_compared(&self, a: usize, b: usize) -> usize {
        self.pairs(a, b).count()
    }

    /// The pairs of step indices compared: (first trace, second trace).
    fn pairs(&self, a: usize, b: usize) -> impl Iterator<Item = (usize, usize)> {
        let start = if self.offset < 0 {
            self.offset.unsigned_abs() as usize
        } else {
            0
        };
        let offset = self.offset;
        (start..a)
            .map(move |k| (k, (k as i64 + offset) as usize))
            .take_while(move |&(_, j)| j < b)
            .take(self.steps.unwrap_or(usize::MAX))
    }
}

/// Shifts the alignment may search, steps either way.
pub const MAX_SHIFT: i64 = 500;

/// Steps two traces must share for an automatic alignment to count.
pub const MIN_OVERLAP: usize = 10;

/// The shift of `b` against `a` (within ±`MAX_SHIFT`) that makes term `term` agree best (least RMS
/// difference over at least `MIN_OVERLAP` shared steps), and that RMS.
pub fn best_offset(
    a: &ObsTrace,
    b: &ObsTrace,
    layout: &PolicyLayout,
    term: &str,
) -> Result<(i64, f64), AnalysisError> {
    let slot = layout
        .slots
        .iter()
        .find(|s| s.term.name() == term || layout.slot_label(s) == term)
        .ok_or_else(|| {
            let names: Vec<&str> = layout.slots.iter().map(|s| s.term.name()).collect();
            AnalysisError::Mismatch(format!(
                "--align {term}: not a term of the policy (its terms: {})",
                names.join(", ")
            ))
        })?;
    let mut best: Option<(i64, f64)> = None;
    for offset in -MAX_SHIFT..=MAX_SHIFT {
        let align = Alignment { offset, steps: None };
        let (mut sq, mut n, mut steps) = (0.0f64, 0usize, 0usize);
        for (i, j) in align.pairs(a.steps.len(), b.steps.len()) {
            let (x, y) = (
                a.steps[i].get(slot.range.clone()),
                b.steps[j].get(slot.range.clone()),
            );
            let (Some(x), Some(y)) = (x, y) else { continue };
            for (p, q) in x.iter().zip(y) {
                let d = f64::from(*p) - f64::from(*q);
                sq += if d.is_finite() { d * d } else { 1e12 };
                n += 1;
            }
            steps += 1;
        }
        if steps < MIN_OVERLAP || n == 0 {
            continue;
        }
        let rms = (sq / n as f64).sqrt();
        // Ties go to the smallest shift.
        if best.is_none_or(|(o, r)| rms < r - 1e-12 || (rms <= r + 1e-12 && offset.abs() < o.abs())) {
            best = Some((offset, rms));
        }
    }
    best.ok_or_else(|| {
        AnalysisError::Mismatch(format!(
            "--align {term}: the traces ({} and {} steps) share fewer than {MIN_OVERLAP} steps at any shift",
            a.steps.len(),
            b.steps.len()
        ))
    })
}

/// The buses' resolution of each observation value, in observation units (`None` where no bus
/// measures it): joint positions and velocities from each joint's device, the IMU's outputs by
/// its protocol (WIT, BNO08x RVC, BNO055).
pub fn quanta(layout: &PolicyLayout, robot: &robots::Robot) -> Vec<Option<f64>> {
    use policy::Term;
    let imu = robot.config.imu.protocol.resolution();
    let mut out = vec![None; layout.obs_len];
    for slot in &layout.slots {
        let sh = slot.term.shaping();
        let joint = |p: usize, which: usize| {
            layout
                .robot_index
                .get(p)
                .and_then(|&r| robot.joint_resolution(r))
                .map(|res| res[which])
        };
        let raw: Vec<Option<f64>> = (0..slot.width)
            .map(|i| match &slot.term {
                Term::JointPos { .. } => joint(i, 0),
                Term::JointVel(_) => joint(i, 1),
                // The robot's own IMU, by its protocol's resolution.
                Term::Gyro(_) | Term::BaseAngVel(_) => Some(imu.gyro),
                Term::Accelerometer(_) => Some(imu.accel),
                // Gravity and orientation come from the quaternion: a step of each component.
                Term::ProjectedGravity(_) | Term::BaseOrientation(_) => Some(2.0 * imu.quaternion),
                _ => None,
            })
            .collect();
        // Every history step of the term alike.
        for chunk in out[slot.range.clone()].chunks_mut(slot.width) {
            for (i, (o, r)) in chunk.iter_mut().zip(&raw).enumerate() {
                let scale = sh.scales.as_ref().map_or(sh.scale, |v| v[i]);
                *o = r.map(|r| r * scale.abs());
            }
        }
    }
    out
}

/// Compares `a` and `b` as `align` pairs their steps, term by term (with `quanta` per value, from
/// [`quanta`]); terms in the order they first diverge (never-diverging terms last).
pub fn compare(
    a: &ObsTrace,
    b: &ObsTrace,
    layout: &PolicyLayout,
    tolerance: f64,
    align: Alignment,
    quanta: &[Option<f64>],
) -> Result<Vec<TermDiff>, AnalysisError> {
    let pairs: Vec<(usize, usize)> = align.pairs(a.steps.len(), b.steps.len()).collect();
    if pairs.is_empty() {
        return Err(AnalysisError::Mismatch(format!(
            "nothing to compare: the traces have {} and {} steps, offset {}",
            a.steps.len(),
            b.steps.len(),
            align.offset
        )));
    }
    for (name, t, side) in [("first", a, 0), ("second", b, 1)] {
        let len = |&(i, j): &(usize, usize)| t.steps[if side == 0 { i } else { j }].len();
        if let Some(s) = pairs.iter().map(len).find(|&l| l != layout.obs_len) {
            return Err(AnalysisError::Mismatch(format!(
                "the {name} trace has {s} values per step; the policy's observation has {}",
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
            for &(i, j) in &pairs {
                let (x, y) = (&a.steps[i][slot.range.clone()], &b.steps[j][slot.range.clone()]);
                for (p, q) in x.iter().zip(y) {
                    let d = (f64::from(*p) - f64::from(*q)).abs();
                    let d = if d.is_nan() { f64::INFINITY } else { d };
                    max_abs = max_abs.max(d);
                    sq += if d.is_finite() { d * d } else { 0.0 };
                    count += 1;
                    if d > tolerance && first.is_none() {
                        first = Some(i);
                    }
                }
            }
            let quantum = quanta
                .get(slot.range.clone())
                .and_then(|q| q.iter().copied().collect::<Option<Vec<f64>>>())
                .and_then(|q| q.into_iter().reduce(f64::max));
            TermDiff {
                term: layout.slot_label(slot),
                range: slot.range.clone(),
                first_step: first,
                max_abs,
                rms: if count > 0 {
                    (sq / count as f64).sqrt()
                } else {
                    0.0
                },
                quantum,
            }
        })
        .collect();
    out.sort_by_key(|d| d.first_step.unwrap_or(usize::MAX));
    Ok(out)
}
