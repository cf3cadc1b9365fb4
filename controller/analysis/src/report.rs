//! Run reports, made from a run's MCAP: tracking per joint over time, root position and orientation
//! error, the ReActor success criterion (failure when the root is more than 1 m or 45° off), RMSE of
//! root position (cm), root orientation (deg) and joints (deg), jitter (mean |d³q/dt³|), loop timing,
//! bus misses and safety events. Written as `report.html` (inline SVG plots), `summary.md` and
//! `summary.json`.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use controller::metrics::{root_error, tracking_success};

use crate::AnalysisError;
use telemetry_schema as pb;

/// The headline numbers of a run.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RunSummary {
    /// Ticks recorded.
    pub ticks: usize,
    /// Ticks tracking the clip (the metrics' window).
    pub tracking_ticks: usize,
    /// Joint RMSE per joint, deg.
    pub joint_rmse_deg: BTreeMap<String, f64>,
    /// Joint RMSE over all joints, deg.
    pub joints_rmse_deg: f64,
    /// Root position RMSE, cm (simulation runs).
    pub root_position_rmse_cm: Option<f64>,
    /// Root orientation RMSE, deg (simulation runs).
    pub root_orientation_rmse_deg: Option<f64>,
    /// Whether the base fell (tilt beyond the run's limit; simulation runs).
    pub fell: Option<bool>,
    /// Whether a fault stopped the run.
    pub safety_stop: bool,
    /// Share of the reference played (when the recording says how long it was).
    pub played: Option<f64>,
    /// Success: no fall, no safety stop, the reference played to its end, and (simulation) the
    /// root never more than 1 m or 45° from the reference's — [`tracking_success`].
    pub success: bool,
    /// Mean magnitude of the third time derivative of joint positions, rad/s³.
    pub jitter: f64,
    /// Ticks where some joint's feedback was missing.
    pub bus_miss_ticks: usize,
    /// Safety transitions: tick, mode, cause.
    pub safety_events: Vec<(u64, String, String)>,
    /// Bus I/O per tick: p50, p99, max, µs.
    pub io_us: [f64; 3],
    /// Compute per tick: p50, p99, max, µs.
    pub compute_us: [f64; 3],
    /// Position RMSE of each tracked motion body over the tracking window, cm (simulation runs
    /// of policies that track bodies).
    pub body_rmse_cm: BTreeMap<String, f64>,
    /// The anchor body's, cm.
    pub anchor_rmse_cm: Option<f64>,
    /// The state estimate against the truth over the whole run (simulation runs with an
    /// estimator).
    pub estimator: Option<EstimatorFigures>,
    /// A command-driven run (no clip): where the robot went against its commands, while the
    /// policy was in control (simulation runs). Such a run has no clip-tracking numbers.
    pub locomotion: Option<controller::metrics::LocomotionSummary>,
}

/// How well the state estimate followed the simulation's truth, from a recording's `/estimator`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct EstimatorFigures {
    /// Ticks with a valid estimate and the truth beside it.
    pub ticks: usize,
    /// Base velocity RMSE (base axes), m/s.
    pub velocity_rmse: f64,
    /// Base height RMSE, mm.
    pub height_rmse_mm: f64,
    /// Base position error at the end, cm.
    pub final_position_error_cm: f64,
    /// Share of foot-ticks whose contact agreed with the truth, %.
    pub contact_agreement_pct: f64,
}

/// One tick of the estimate against the truth.
#[derive(Debug, Clone, Copy)]
struct EstimateTick {
    time: f64,
    /// Base velocity error, m/s.
    velocity: f64,
    /// Height error (estimate − truth), m.
    height: f64,
    /// Position error, m.
    position: f64,
    /// Feet whose contact agreed, of those compared.
    agree: usize,
    compared: usize,
}

#[derive(Debug, Default)]
struct Series {
    time: Vec<f64>,
    q: Vec<Vec<f64>>,
    reference_q: Vec<Vec<f64>>,
    reference_root: Vec<[f64; 7]>,
    tracking: Vec<bool>,
    base_pose: Vec<[f64; 7]>,
    missed: Vec<bool>,
    io: Vec<f64>,
    compute: Vec<f64>,
    safety: Vec<(u64, String, String)>,
    joints: Vec<String>,
    /// A safety transition had a fault as its cause.
    faulted: bool,
    /// Ticks of the reference, when the recording says.
    reference_ticks: Option<usize>,
    /// The run's tilt limit, rad (the default when the recording does not say).
    tilt_limit: f64,
    /// Each tick with a valid estimate and the truth beside it.
    estimator: Vec<EstimateTick>,
    /// Tracked motion bodies, their anchor, and their position errors per tick (m).
    motion_bodies: Vec<String>,
    anchor_body: Option<String>,
    body_errors: Vec<Vec<f64>>,
    /// The run played no clip (a command-driven policy).
    command_driven: bool,
    /// What its commands mean, and per `/policy` message whether the policy ran and the commands.
    command_kinds: Vec<controller::metrics::CommandKind>,
    running: Vec<bool>,
    commands: Vec<Vec<f64>>,
}

fn floats(v: &serde_json::Value) -> Vec<f64> {
    v.as_array().map_or_else(Vec::new, |a| {
        a.iter().map(|x| x.as_f64().unwrap_or(f64::NAN)).collect()
    })
}

/// A typed message of `m`'s channel.
fn decode<M: prost::Message + Default>(m: &crate::recording::Message<'_>) -> Result<M, String> {
    M::decode(m.data).map_err(|e| format!("{}: {e}", m.topic))
}

/// `[x, y, z]` of a message vector (NaN when absent).
fn xyz(v: Option<&pb::Vector3>) -> [f64; 3] {
    v.map_or([f64::NAN; 3], |v| [v.x, v.y, v.z])
}

/// `[x, y, z, w, qx, qy, qz]` of a message pose (NaN when absent).
fn pose7(p: Option<&pb::Pose>) -> [f64; 7] {
    let Some(p) = p else { return [f64::NAN; 7] };
    let [x, y, z] = xyz(p.position.as_ref());
    let q = p.orientation.unwrap_or_default();
    [x, y, z, q.w, q.x, q.y, q.z]
}

fn read(path: &Path) -> Result<Series, AnalysisError> {
    read_series(path).map_err(|m| AnalysisError::file(path, m))
}

fn read_series(path: &Path) -> Result<Series, String> {
    let bytes = crate::recording::read(path)?;
    let mut s = Series {
        tilt_limit: controller::safety::SafetyLimits::default().tilt,
        ..Series::default()
    };
    // Times from the run's start: a wall-clock recording's are Unix times.
    let mut t0: Option<u64> = None;
    crate::recording::for_each_message(&bytes, |m| {
        let zero = *t0.get_or_insert(m.log_time);
        let time = |log_time: u64| log_time.saturating_sub(zero) as f64 * 1e-9;
        match m.topic {
            "/joint_state" => {
                let v: pb::JointStates = decode(&m)?;
                if s.joints.is_empty() {
                    s.joints = v.joints.iter().map(|j| j.name.clone()).collect();
                }
                s.time.push(time(m.log_time));
                s.q.push(v.joints.iter().map(|j| j.position).collect());
                s.missed.push(v.joints.iter().any(|j| j.missed > 0));
            }
            "/command" => {
                let v: pb::JointCommands = decode(&m)?;
                s.reference_q.push(v.joints.iter().map(|j| j.reference).collect());
                s.reference_root.push(pose7(v.reference_root.as_ref()));
                s.tracking.push(v.tracking);
            }
            "/replay" => {
                let v: serde_json::Value =
                    serde_json::from_slice(m.data).map_err(|e| format!("{}: {e}", m.topic))?;
                if s.base_pose.is_empty() {
                    let meta = &m.metadata;
                    s.reference_ticks = meta.get("reference_ticks").and_then(|n| n.parse().ok());
                    let run = meta
                        .get("run")
                        .and_then(|j| controller::options::RunMetadata::from_json(j).ok());
                    s.tilt_limit = run.as_ref().map_or(s.tilt_limit, |r| r.options.limits.tilt);
                    s.command_driven = run.is_some_and(|r| r.clip.is_none());
                }
                let p = floats(&v["base_pose"]);
                s.base_pose
                    .push(std::array::from_fn(|i| p.get(i).copied().unwrap_or(f64::NAN)));
            }
            "/policy" => {
                let v: pb::PolicyStep = decode(&m)?;
                if s.motion_bodies.is_empty() {
                    s.motion_bodies = m
                        .metadata
                        .get("motion_bodies")
                        .map_or_else(Vec::new, |n| n.split(',').map(str::to_owned).collect());
                    s.anchor_body = m.metadata.get("anchor_body").cloned();
                    s.command_kinds = m.metadata.get("command_kinds").map_or_else(Vec::new, |k| {
                        k.split(',')
                            .map(|k| {
                                serde_json::from_value(serde_json::Value::String(k.to_owned()))
                                    .unwrap_or(controller::metrics::CommandKind::Other)
                            })
                            .collect()
                    });
                }
                s.body_errors
                    .push(v.body_errors.iter().map(|b| b.error_m).collect());
                s.running.push(v.running);
                s.commands.push(v.commands.iter().map(|c| c.value).collect());
            }
            "/estimator" => {
                let v: pb::StateEstimate = decode(&m)?;
                let Some(truth) = v.truth_position.as_ref().filter(|_| v.valid) else {
                    return Ok(());
                };
                let distance = |a: [f64; 3], b: [f64; 3]| {
                    a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>().sqrt()
                };
                let (p, t) = (xyz(v.position.as_ref()), xyz(Some(truth)));
                let compared: Vec<(bool, bool)> = v
                    .feet
                    .iter()
                    .filter_map(|f| f.truth_contact.map(|t| (f.contact, t)))
                    .collect();
                s.estimator.push(EstimateTick {
                    time: time(m.log_time),
                    velocity: distance(xyz(v.velocity_base.as_ref()), xyz(v.truth_velocity_base.as_ref())),
                    height: p[2] - t[2],
                    position: distance(p, t),
                    agree: compared.iter().filter(|(a, b)| a == b).count(),
                    compared: compared.len(),
                });
            }
            "/timing" => {
                let v: pb::TickTiming = decode(&m)?;
                s.io.push(f64::from(v.io_us));
                s.compute.push(f64::from(v.compute_us));
            }
            "/safety" => {
                let v: pb::SafetyTransition = decode(&m)?;
                s.faulted |= v.fault;
                s.safety.push((v.tick, v.mode, v.cause));
            }
            _ => {}
        }
        Ok(())
    })?;
    if s.q.is_empty() {
        return Err("no /joint_state messages".to_owned());
    }
    Ok(s)
}

fn quantiles(v: &[f64]) -> [f64; 3] {
    if v.is_empty() {
        return [0.0; 3];
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let at = |p: f64| s[((p * (s.len() - 1) as f64).round() as usize).min(s.len() - 1)];
    [at(0.5), at(0.99), s[s.len() - 1]]
}

/// A command-driven run's measure over the ticks its policy ran, and per tick the commanded and
/// achieved forward speed and turning rate: (time, commanded, achieved).
#[allow(clippy::type_complexity)]
fn locomotion_course(
    s: &Series,
) -> (
    Option<controller::metrics::LocomotionSummary>,
    Vec<(f64, [f64; 2], [f64; 2])>,
) {
    let mut l = controller::metrics::LocomotionMetrics::new(&s.command_kinds);
    let [forward, _, turning] = l.slots();
    let mut course = Vec::new();
    for k in 1..s.q.len() {
        let (Some(&pose), true) = (s.base_pose.get(k), s.running.get(k).copied().unwrap_or(false)) else {
            continue;
        };
        let dt = s.time[k] - s.time[k - 1];
        if dt.is_nan() || dt <= 0.0 || pose[0].is_nan() {
            continue;
        }
        let commands = s.commands.get(k).map_or(&[][..], Vec::as_slice);
        if let Some(a) = l.add(pose, commands, dt) {
            let c = |slot: Option<usize>| slot.and_then(|i| commands.get(i).copied()).unwrap_or(f64::NAN);
            course.push((s.time[k], [c(forward), c(turning)], [a[0], a[2]]));
        }
    }
    (l.summary(), course)
}

fn summarize(s: &Series) -> RunSummary {
    let n = s.joints.len().max(s.q.first().map_or(0, Vec::len));
    // The metrics' window: the ticks tracking the clip; for a command-driven run (no clip) the
    // ticks its policy ran, over which only the robot's own motion is measured.
    let window: Vec<usize> = (0..s.q.len())
        .filter(|&k| {
            if s.command_driven {
                s.running.get(k).copied().unwrap_or(false)
            } else {
                s.tracking.get(k).copied().unwrap_or(false)
            }
        })
        .collect();
    let reference_window: &[usize] = if s.command_driven { &[] } else { &window };
    let mut per_joint = vec![0.0; n];
    for &k in &window {
        for (j, sum) in per_joint.iter_mut().enumerate() {
            let reference = s
                .reference_q
                .get(k)
                .and_then(|r| r.get(j))
                .copied()
                .unwrap_or(f64::NAN);
            let e = s.q[k][j] - reference;
            *sum += e * e;
        }
    }
    let count = window.len().max(1) as f64;
    let joint_rmse_deg = s
        .joints
        .iter()
        .zip(&per_joint)
        .map(|(name, sq)| (name.clone(), (sq / count).sqrt().to_degrees()))
        .collect();
    let joints_rmse_deg = (per_joint.iter().sum::<f64>() / (count * n.max(1) as f64))
        .sqrt()
        .to_degrees();
    let has_truth = s.base_pose.iter().any(|p| !p[0].is_nan());
    let (mut pos_sq, mut ori_sq, mut root_max) = (0.0, 0.0, (0.0f64, 0.0f64));
    for &k in reference_window {
        let (Some(p), Some(r)) = (s.base_pose.get(k), s.reference_root.get(k)) else {
            continue;
        };
        let (d, a) = root_error(*p, *r);
        pos_sq += d * d;
        ori_sq += a * a;
        root_max = (root_max.0.max(d), root_max.1.max(a));
    }
    // Fell: the base tilted beyond the run's limit at any tick (simulation truth).
    let fell = has_truth.then(|| {
        s.base_pose
            .iter()
            .filter(|p| !p[0].is_nan())
            .any(|p| controller::safety::tilt_of([p[3], p[4], p[5], p[6]]) > s.tilt_limit)
    });
    let played = s
        .reference_ticks
        .map(|n| (window.len() as f64 / n.max(1) as f64).min(1.0));
    let success = if s.command_driven {
        !fell.unwrap_or(false) && !s.faulted
    } else {
        tracking_success(
            fell.unwrap_or(false),
            s.faulted,
            played,
            has_truth.then_some(root_max),
        )
    };
    // Jitter: third derivative by finite differences over the tracking window.
    let mut jitter = (0.0, 0usize);
    for w in window.windows(4) {
        if w[3] - w[0] != 3 {
            continue;
        }
        let dt = (s.time[w[3]] - s.time[w[0]]) / 3.0;
        if dt <= 0.0 {
            continue;
        }
        for j in 0..n {
            let d3 = (s.q[w[3]][j] - 3.0 * s.q[w[2]][j] + 3.0 * s.q[w[1]][j] - s.q[w[0]][j]) / dt.powi(3);
            jitter.0 += d3.abs();
            jitter.1 += 1;
        }
    }
    // Tracked bodies: their position errors over the window.
    let mut body_sq = vec![(0.0, 0usize); s.motion_bodies.len()];
    for &k in &window {
        for (sum, &e) in body_sq
            .iter_mut()
            .zip(s.body_errors.get(k).map_or(&[][..], Vec::as_slice))
        {
            if e.is_finite() {
                sum.0 += e * e;
                sum.1 += 1;
            }
        }
    }
    let body_rmse_cm: BTreeMap<String, f64> = s
        .motion_bodies
        .iter()
        .zip(&body_sq)
        .filter(|(_, (_, n))| *n > 0)
        .map(|(b, (sq, n))| (b.clone(), (sq / *n as f64).sqrt() * 100.0))
        .collect();
    let anchor_rmse_cm = s.anchor_body.as_ref().and_then(|a| body_rmse_cm.get(a).copied());
    let estimator = (!s.estimator.is_empty()).then(|| {
        let n = s.estimator.len() as f64;
        let rms = |f: &dyn Fn(&EstimateTick) -> f64| {
            (s.estimator.iter().map(|e| f(e).powi(2)).sum::<f64>() / n).sqrt()
        };
        let (agree, compared) = s
            .estimator
            .iter()
            .fold((0, 0), |(a, c), e| (a + e.agree, c + e.compared));
        EstimatorFigures {
            ticks: s.estimator.len(),
            velocity_rmse: rms(&|e| e.velocity),
            height_rmse_mm: 1000.0 * rms(&|e| e.height),
            final_position_error_cm: 100.0 * s.estimator.last().map_or(0.0, |e| e.position),
            contact_agreement_pct: if compared > 0 {
                100.0 * agree as f64 / compared as f64
            } else {
                100.0
            },
        }
    });
    // A command-driven run: the same measure the loop keeps, over the ticks the policy ran.
    let locomotion = (s.command_driven && has_truth)
        .then(|| locomotion_course(s).0)
        .flatten();
    RunSummary {
        locomotion,
        estimator,
        body_rmse_cm,
        anchor_rmse_cm,
        ticks: s.q.len(),
        tracking_ticks: window.len(),
        // Against a made-up reference (the default pose), joint errors mean nothing.
        joint_rmse_deg: if s.command_driven {
            BTreeMap::new()
        } else {
            joint_rmse_deg
        },
        joints_rmse_deg: if s.command_driven {
            f64::NAN
        } else {
            joints_rmse_deg
        },
        root_position_rmse_cm: (has_truth && !s.command_driven).then(|| (pos_sq / count).sqrt() * 100.0),
        root_orientation_rmse_deg: (has_truth && !s.command_driven)
            .then(|| (ori_sq / count).sqrt().to_degrees()),
        fell,
        safety_stop: s.faulted,
        played,
        success,
        jitter: if jitter.1 > 0 {
            jitter.0 / jitter.1 as f64
        } else {
            0.0
        },
        bus_miss_ticks: s.missed.iter().filter(|&&m| m).count(),
        safety_events: s.safety.clone(),
        io_us: quantiles(&s.io),
        compute_us: quantiles(&s.compute),
    }
}

/// One plotted line: label, colour, points.
type Line<'a> = (&'a str, &'a str, Vec<(f64, f64)>);

/// An SVG line plot of `series`.
fn svg_plot(title: &str, unit: &str, series: &[Line<'_>]) -> String {
    let (w, h, pad) = (560.0, 200.0, 40.0);
    let pts = series.iter().flat_map(|s| s.2.iter()).filter(|p| p.1.is_finite());
    let (mut x0, mut x1, mut y0, mut y1) =
        (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
    for &(x, y) in pts {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    if !x0.is_finite() {
        return format!("<p>{title}: no data</p>");
    }
    if (y1 - y0).abs() < 1e-9 {
        y0 -= 1.0;
        y1 += 1.0;
    }
    let (sx, sy) = ((w - 2.0 * pad) / (x1 - x0).max(1e-9), (h - 2.0 * pad) / (y1 - y0));
    let mut out = format!(
        r#"<figure><svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" style="background:#fff;border:1px solid #ccc">"#
    );
    let _ = write!(
        out,
        r#"<text x="{pad}" y="16" font-size="13" font-family="sans-serif">{title}</text>"#
    );
    let _ = write!(
        out,
        r#"<text x="4" y="{}" font-size="10" font-family="sans-serif">{y1:.3} {unit}</text><text x="4" y="{}" font-size="10" font-family="sans-serif">{y0:.3}</text><text x="{}" y="{}" font-size="10" font-family="sans-serif">t = {x1:.1} s</text>"#,
        pad - 4.0,
        h - pad + 10.0,
        w - pad - 40.0,
        h - 8.0
    );
    for (i, (label, colour, points)) in series.iter().enumerate() {
        let mut d = String::new();
        for &(x, y) in points.iter().filter(|p| p.1.is_finite()) {
            let _ = write!(
                d,
                "{}{:.1},{:.1}",
                if d.is_empty() { "M" } else { " L" },
                pad + (x - x0) * sx,
                h - pad - (y - y0) * sy
            );
        }
        let _ = write!(
            out,
            r#"<path d="{d}" fill="none" stroke="{colour}" stroke-width="1.3"/>"#
        );
        let _ = write!(
            out,
            r#"<text x="{}" y="16" font-size="11" fill="{colour}" font-family="sans-serif">{label}</text>"#,
            w - 160.0 + 80.0 * i as f64
        );
    }
    out.push_str("</svg></figure>\n");
    out
}

/// Writes the report of the run `log` into `dir`; returns the summary.
pub fn write_report(log: &Path, dir: &Path) -> Result<RunSummary, AnalysisError> {
    let s = read(log)?;
    let summary = summarize(&s);
    std::fs::create_dir_all(dir).map_err(|e| AnalysisError::write(dir, e))?;
    let json = serde_json::to_string_pretty(&summary)
        .map_err(|e| AnalysisError::write(&dir.join("summary.json"), std::io::Error::other(e)))?;
    let write =
        |name: &Path, text: &str| std::fs::write(name, text).map_err(|e| AnalysisError::write(name, e));
    write(&dir.join("summary.json"), &json)?;
    let mut md = format!("# Run report: {}\n\n", log.display());
    let _ = writeln!(md, "| metric | value |\n|---|---|");
    let _ = writeln!(
        md,
        "| ticks (tracking) | {} ({}) |",
        summary.ticks, summary.tracking_ticks
    );
    match &summary.locomotion {
        Some(l) => {
            let _ = writeln!(
                md,
                "| distance travelled / from the start | {:.2} m / {:.2} m |\n| heading turned | {:+.1}° |",
                l.distance_m,
                l.displacement_m,
                l.heading_change.to_degrees()
            );
            for (k, (name, unit)) in [("forward", "m/s"), ("leftward", "m/s"), ("turning", "rad/s")]
                .iter()
                .enumerate()
            {
                let commanded =
                    l.commanded[k].map_or("not commanded".to_owned(), |c| format!("{c:+.3} {unit}"));
                let _ = writeln!(
                    md,
                    "| {name}: commanded / achieved | {commanded} / {:+.3} {unit} |",
                    l.achieved[k]
                );
            }
        }
        None => {
            let _ = writeln!(md, "| joint RMSE | {:.2}° |", summary.joints_rmse_deg);
        }
    }
    if let (Some(p), Some(o)) = (summary.root_position_rmse_cm, summary.root_orientation_rmse_deg) {
        let _ = writeln!(
            md,
            "| root position RMSE | {p:.1} cm |\n| root orientation RMSE | {o:.1}° |"
        );
    }
    let yes = |b: bool| if b { "yes" } else { "NO" };
    if let Some(fell) = summary.fell {
        let _ = writeln!(md, "| fell | {} |", if fell { "YES" } else { "no" });
    }
    let _ = writeln!(
        md,
        "| safety stop | {} |",
        if summary.safety_stop { "YES" } else { "no" }
    );
    if summary.locomotion.is_some() {
        let _ = writeln!(
            md,
            "| success (no fall, no safety stop) | {} |",
            yes(summary.success)
        );
    } else {
        if let Some(p) = summary.played {
            let _ = writeln!(md, "| reference played | {:.0} % |", 100.0 * p);
        }
        let _ = writeln!(
            md,
            "| success (no fall, no safety stop, played to the end, root within 1 m and 45°) | {} |",
            yes(summary.success)
        );
    }
    let _ = writeln!(
        md,
        "| jitter (mean \\|d³q/dt³\\|) | {:.2} rad/s³ |",
        summary.jitter
    );
    let _ = writeln!(md, "| ticks with bus misses | {} |", summary.bus_miss_ticks);
    let _ = writeln!(
        md,
        "| bus I/O p50 / p99 / max | {:.0} / {:.0} / {:.0} µs |",
        summary.io_us[0], summary.io_us[1], summary.io_us[2]
    );
    let _ = writeln!(
        md,
        "| compute p50 / p99 / max | {:.0} / {:.0} / {:.0} µs |",
        summary.compute_us[0], summary.compute_us[1], summary.compute_us[2]
    );
    if let Some(a) = summary.anchor_rmse_cm {
        let _ = writeln!(
            md,
            "| anchor ({}) position RMSE | {a:.1} cm |",
            s.anchor_body.as_deref().unwrap_or("?")
        );
    }
    if let Some(e) = &summary.estimator {
        let _ = writeln!(
            md,
            "| state estimate vs truth | velocity RMSE {:.3} m/s, height RMSE {:.1} mm, position error {:.1} cm at the end, contacts agree {:.1} % ({} ticks) |",
            e.velocity_rmse, e.height_rmse_mm, e.final_position_error_cm, e.contact_agreement_pct, e.ticks
        );
    }
    let _ = writeln!(md, "\n## Safety events\n");
    for (tick, mode, cause) in &summary.safety_events {
        let _ = writeln!(md, "- tick {tick}: {mode} ({cause})");
    }
    if !summary.joint_rmse_deg.is_empty() {
        let _ = writeln!(md, "\n## Joint RMSE\n");
    }
    for (j, e) in &summary.joint_rmse_deg {
        let _ = writeln!(md, "- {j}: {e:.2}°");
    }
    if !summary.body_rmse_cm.is_empty() {
        let _ = writeln!(md, "\n## Tracked bodies: position RMSE\n");
        for (b, e) in &summary.body_rmse_cm {
            let _ = writeln!(md, "- {b}: {e:.1} cm");
        }
    }
    write(&dir.join("summary.md"), &md)?;

    let mut html = String::from(
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>robodeploy run report</title></head><body style=\"font-family:sans-serif;max-width:1200px\">\n",
    );
    let _ = writeln!(
        html,
        "<h1>Run report</h1><p>{}</p><pre>{}</pre>",
        log.display(),
        md.replace('<', "&lt;")
    );
    if s.command_driven {
        let (_, course) = locomotion_course(&s);
        for (k, (title, unit)) in [("forward speed", "m/s"), ("turning rate", "rad/s")]
            .iter()
            .enumerate()
        {
            let commanded = course.iter().map(|(t, c, _)| (*t, c[k])).collect();
            let achieved = course.iter().map(|(t, _, a)| (*t, a[k])).collect();
            html.push_str(&svg_plot(
                title,
                unit,
                &[("commanded", "#888", commanded), ("achieved", "#c33", achieved)],
            ));
        }
    }
    // The joints that moved most, measured against reference.
    let mut order: Vec<usize> = (0..s.joints.len()).collect();
    let span = |j: usize| {
        let v: Vec<f64> = s.reference_q.iter().filter_map(|r| r.get(j).copied()).collect();
        v.iter().copied().fold(f64::NEG_INFINITY, f64::max) - v.iter().copied().fold(f64::INFINITY, f64::min)
    };
    order.sort_by(|&a, &b| span(b).total_cmp(&span(a)));
    for &j in order.iter().take(8) {
        let measured: Vec<(f64, f64)> = s.time.iter().zip(&s.q).map(|(&t, q)| (t, q[j])).collect();
        let reference: Vec<(f64, f64)> = s
            .time
            .iter()
            .zip(&s.reference_q)
            .map(|(&t, r)| (t, r.get(j).copied().unwrap_or(f64::NAN)))
            .collect();
        html.push_str(&svg_plot(
            &format!("{} tracking", s.joints[j]),
            "rad",
            &[
                (
                    if s.command_driven {
                        "default pose"
                    } else {
                        "reference"
                    },
                    "#888",
                    reference,
                ),
                ("measured", "#c33", measured),
            ],
        ));
    }
    if summary.root_position_rmse_cm.is_some() {
        let err: Vec<(f64, f64)> = s
            .time
            .iter()
            .enumerate()
            .map(|(k, &t)| {
                let (p, r) = (s.base_pose.get(k), s.reference_root.get(k));
                (
                    t,
                    p.zip(r).map_or(f64::NAN, |(p, r)| {
                        ((p[0] - r[0]).powi(2) + (p[1] - r[1]).powi(2) + (p[2] - r[2]).powi(2)).sqrt() * 100.0
                    }),
                )
            })
            .collect();
        html.push_str(&svg_plot("root position error", "cm", &[("error", "#36c", err)]));
    }
    if !summary.body_rmse_cm.is_empty() {
        // Mean and worst body at each tick, and the anchor.
        let anchor = s
            .anchor_body
            .as_ref()
            .and_then(|a| s.motion_bodies.iter().position(|b| b == a));
        let per_tick = |f: &dyn Fn(&[f64]) -> f64| -> Vec<(f64, f64)> {
            s.time
                .iter()
                .zip(&s.body_errors)
                .map(|(&t, e)| (t, if e.is_empty() { f64::NAN } else { 100.0 * f(e) }))
                .collect()
        };
        let mut lines = vec![
            (
                "mean",
                "#36c",
                per_tick(&|e| e.iter().sum::<f64>() / e.len() as f64),
            ),
            (
                "worst",
                "#c33",
                per_tick(&|e| e.iter().copied().fold(0.0, f64::max)),
            ),
        ];
        if let Some(a) = anchor {
            lines.push((
                "anchor",
                "#393",
                per_tick(&|e| e.get(a).copied().unwrap_or(f64::NAN)),
            ));
        }
        html.push_str(&svg_plot("tracked bodies: position error", "cm", &lines));
    }
    if summary.estimator.is_some() {
        let series = |k: usize, scale: f64| -> Vec<(f64, f64)> {
            s.estimator
                .iter()
                .map(|e| (e.time, scale * [e.velocity, e.height.abs(), e.position][k]))
                .collect()
        };
        html.push_str(&svg_plot(
            "state estimate: error against the truth",
            "m/s · cm",
            &[
                ("velocity m/s", "#c33", series(0, 1.0)),
                ("height cm", "#36c", series(1, 100.0)),
                ("position cm", "#393", series(2, 100.0)),
            ],
        ));
    }
    let io: Vec<(f64, f64)> = s.time.iter().zip(&s.io).map(|(&t, &v)| (t, v)).collect();
    let compute: Vec<(f64, f64)> = s.time.iter().zip(&s.compute).map(|(&t, &v)| (t, v)).collect();
    html.push_str(&svg_plot(
        "loop timing per tick",
        "µs",
        &[("bus I/O", "#393", io), ("compute", "#c60", compute)],
    ));
    html.push_str("</body></html>\n");
    write(&dir.join("report.html"), &html)?;
    // Each plot also as its own SVG file, for documents that embed pictures.
    let plots = dir.join("plots");
    std::fs::create_dir_all(&plots).map_err(|e| AnalysisError::write(&plots, e))?;
    for (i, svg) in html.split("<figure>").skip(1).enumerate() {
        let svg = &svg[..svg.find("</figure>").unwrap_or(svg.len())];
        write(&plots.join(format!("{i:02}.svg")), svg)?;
    }
    Ok(summary)
}
