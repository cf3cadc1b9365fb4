//! Whole-body teleoperation: the operator's whole body (VMC bones) retargeted live onto the
//! policy's robot by the same step offline retargeting takes ([`Retargeter`]), into a general
//! tracker's live reference — the root's pose and velocities, every joint. A T-pose held at the
//! start calibrates the map on this operator; a lost stream blends to the robot standing where it
//! is, and tracking resumes when the stream does.
//!
//! The work runs on its own thread, woken by each packet and at least once per control period; the
//! control loop takes the newest frame through the lock-free exchange of [`crate::live`].

use std::collections::VecDeque;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use crate::HumanError;
use crate::body_map::{HumanPose, Template, UserCalibration};
use crate::ik::Ik;
use crate::live::{LiveFrame, LiveWriter, TRACKER_VALUES, live_channel};
use crate::retarget::{Nominal, RetargetOptions, Retargeter, RetargeterOptions};
pub use crate::sparse::Wearing;
use crate::sparse::{Devices, SparseBody};
use crate::teleop::{Phase, PhaseChange, Teleop, TeleopOptions, TeleopStatus, WorkerThread, change};
use crate::vmc::{Device, Estimate, Tracks, VmcReceiver};
use robots::{Robot, spatial};

/// The window over which the reference's velocities are taken, s: a tracker's millimetres of
/// noise over one 90 Hz sample would be tenths of a metre per second.
pub const VELOCITY_WINDOW_S: f64 = 0.1;

struct Worker {
    robot: Robot,
    options: TeleopOptions,
    wearing: Wearing,
    /// The five-point operator's whole body, once calibrated.
    sparse: Option<SparseBody>,
    retargeter: Option<Retargeter>,
    standby: Vec<f64>,
    standing_height: f64,
    tpose_since: Option<Instant>,
    /// Arrivals of the skeletons seen while the T-pose is held (the stream's rate).
    tpose_inputs: Vec<Instant>,
    /// The newest input stepped, and the outputs of the last [`VELOCITY_WINDOW_S`].
    stepped: Option<Instant>,
    history: VecDeque<(Instant, [f64; 7], Vec<f64>)>,
    frame: LiveFrame,
    lost: Option<(Instant, LiveFrame)>,
    /// The worn devices last said to be missing while waiting for the T-pose.
    missing_said: Option<Vec<&'static str>>,
}

/// Starts whole-body teleoperation of `robot` (its `[retarget]` map pairs the human bodies) on
/// what `receiver` hears of an operator `wearing` a skeleton or five devices: the same handle as
/// head-and-hands teleoperation, the live reference carrying the whole robot.
pub fn start(
    robot: &Robot,
    receiver: &VmcReceiver,
    options: TeleopOptions,
    wearing: Wearing,
) -> Result<Teleop, HumanError> {
    if robot.config.retarget.is_none() {
        return Err(HumanError::map(format!(
            "{}: no [retarget] section: which robot body stands for which human one?",
            robot.path.display()
        )));
    }
    let standby: Vec<f64> = robot.config.joints.iter().map(|j| j.default_position).collect();
    let root = Ik::new(robot, &[], true, &[])?.standing_root(&standby);
    let period = Duration::try_from_secs_f64(1.0 / options.rate_hz)
        .map_err(|_| HumanError::map(format!("control rate {} Hz is not a rate", options.rate_hz)))?;
    let still = LiveFrame::still(standby.clone(), root);
    let (writer, live) = live_channel(still.clone());
    let status = Arc::new(Mutex::new(TeleopStatus {
        phase: Phase::WaitingForTpose,
        changes: vec![PhaseChange {
            at: Duration::ZERO,
            phase: Phase::WaitingForTpose,
            why: match wearing {
                Wearing::WholeBody => "waiting for the operator's T-pose (whole body)".into(),
                Wearing::FivePoint => {
                    "waiting for the operator's T-pose (headset, two controllers, two foot trackers; the rest of the body estimated)".into()
                }
            },
        }],
        user: None,
        map: None,
        updates: 0,
        robot_origin: [root[0], root[1], 0.0],
        trackers: [0.0; TRACKER_VALUES],
    }));
    let worker = Worker {
        robot: robot.clone(),
        options,
        wearing,
        sparse: None,
        retargeter: None,
        standing_height: root[2],
        standby: standby.clone(),
        tpose_since: None,
        tpose_inputs: Vec::new(),
        stepped: None,
        history: VecDeque::new(),
        frame: still,
        lost: None,
        missing_said: None,
    };
    let (mut out, st) = (writer, Arc::clone(&status));
    let mut worker = worker;
    let thread = WorkerThread::spawn("body-teleop", receiver, period, move |t, now, start| {
        worker.update(t, now, now - start, &mut out, &st);
    })?;
    Ok(Teleop {
        live: Some(live),
        standby,
        root,
        status,
        _thread: thread,
    })
}

impl Worker {
    fn update(
        &mut self,
        tracks: &Tracks,
        now: Instant,
        at: Duration,
        out: &mut LiveWriter,
        status: &Mutex<TeleopStatus>,
    ) {
        let lost_after = self.options.resampler.lost_after;
        let fresh = |t: &Instant| now.saturating_duration_since(*t).as_secs_f64() <= lost_after;
        // The devices worn now (resampled, forecast when late); the others are not looked at.
        let worn = self.wearing.devices();
        let devices: Devices = Device::ALL.map(|d| {
            if d as usize >= worn {
                return None;
            }
            match self.options.resampler.at(&tracks.devices[d as usize], now) {
                Estimate::Live(f) | Estimate::Forecast(f) => Some(f),
                Estimate::Missing => None,
            }
        });
        let arrived = match self.wearing {
            Wearing::WholeBody => tracks.skeleton_at.filter(fresh),
            Wearing::FivePoint => devices[..worn]
                .iter()
                .all(Option::is_some)
                .then(|| {
                    Device::ALL[..worn]
                        .iter()
                        .filter_map(|&d| tracks.devices[d as usize].newest().map(|(t, _)| t))
                        .max()
                })
                .flatten()
                .filter(fresh),
        };
        let phase = status.lock().unwrap_or_else(PoisonError::into_inner).phase;
        let mut source = None;
        match (phase, arrived) {
            (Phase::WaitingForTpose, Some(input)) => {
                let since = *self.tpose_since.get_or_insert(now);
                if self.tpose_inputs.last() != Some(&input) {
                    self.tpose_inputs.push(input);
                }
                if (now - since).as_secs_f64() >= self.options.tpose_s {
                    let options = RetargeterOptions {
                        nominal: Nominal::Tpose,
                        iterations: RetargetOptions::default().iterations,
                    };
                    let stream = self.stream();
                    let taken = self.tpose_pose(tracks, &devices).and_then(|pose| {
                        check_operator(&pose, &self.tpose_inputs, stream)?;
                        Retargeter::new(&self.robot, &pose, options).map(|r| (r, pose))
                    });
                    self.tpose_inputs.clear();
                    match taken {
                        Ok((r, pose)) => {
                            let why = format!(
                                "T-pose taken: the operator's root {:.2} m high, scale {:.3} onto {}",
                                pose.get(robots::HumanBody::Root).map_or(0.0, |r| r.pos[2]),
                                r.scale(),
                                self.robot.config.name
                            );
                            self.retargeter = Some(r);
                            change(status, at, Phase::Tracking, why);
                        }
                        Err(e) => {
                            self.sparse = None;
                            tracing::warn!("T-pose: {e}");
                            change(status, at, Phase::WaitingForTpose, format!("T-pose refused: {e}"));
                            self.tpose_since = None;
                        }
                    }
                }
            }
            (Phase::WaitingForTpose, None) => {
                self.tpose_since = None;
                self.tpose_inputs.clear();
                // Some of the devices come and some do not: say which, once.
                let worn = &Device::ALL[..self.wearing.devices()];
                if worn.iter().any(|&d| devices[d as usize].is_some()) {
                    let missing: Vec<&'static str> = worn
                        .iter()
                        .filter(|&&d| devices[d as usize].is_none())
                        .map(|&d| d.name())
                        .collect();
                    if self.missing_said.as_ref() != Some(&missing) {
                        change(
                            status,
                            at,
                            Phase::WaitingForTpose,
                            format!(
                                "waiting for {} (the operator wears {} devices; a tracker is a foot by its serial)",
                                missing.join(" and "),
                                worn.len()
                            ),
                        );
                        self.missing_said = Some(missing);
                    }
                }
            }
            (Phase::Tracking | Phase::Lost | Phase::Standby, Some(input)) => {
                if phase != Phase::Tracking {
                    change(
                        status,
                        at,
                        Phase::Tracking,
                        format!("{} stream back: tracking again", self.stream()),
                    );
                }
                self.lost = None;
                if self.stepped != Some(input) {
                    let dt = self
                        .stepped
                        .map_or(1.0 / self.options.rate_hz, |s| {
                            input.saturating_duration_since(s).as_secs_f64()
                        })
                        .clamp(1e-3, 0.1);
                    let pose = match self.wearing {
                        Wearing::WholeBody => Some(tracks.skeleton.human_pose()),
                        Wearing::FivePoint => self.sparse.as_mut().and_then(|b| b.pose(&devices, dt)),
                    };
                    if let Some(pose) = pose {
                        self.step(&pose, dt, input);
                        source = Some(input);
                    }
                }
            }
            (Phase::Tracking | Phase::Lost, None) => {
                if phase == Phase::Tracking {
                    change(
                        status,
                        at,
                        Phase::Lost,
                        format!(
                            "{} stream lost (nothing for {:.2} s): blending to standing over {:.2} s",
                            self.stream(),
                            self.options.resampler.lost_after,
                            self.options.blend_s
                        ),
                    );
                }
                if self.blend_to_standing(now) {
                    change(
                        status,
                        at,
                        Phase::Standby,
                        "standing: the operator can take over again".into(),
                    );
                }
            }
            (Phase::Standby, None) => {}
        }
        let frame = &self.frame;
        out.publish(|f| {
            f.q.copy_from_slice(&frame.q);
            f.qd.copy_from_slice(&frame.qd);
            f.root = frame.root;
            f.root_lin_vel = frame.root_lin_vel;
            f.root_ang_vel = frame.root_ang_vel;
            f.bodies.clear();
            f.bodies.extend_from_slice(&frame.bodies);
            f.source = source;
        });
        status.lock().unwrap_or_else(PoisonError::into_inner).updates += 1;
    }

    /// What the operator's stream carries, for messages.
    fn stream(&self) -> &'static str {
        match self.wearing {
            Wearing::WholeBody => "skeleton",
            Wearing::FivePoint => "tracker",
        }
    }

    /// The operator's body in the T-pose: the skeleton, or the devices' estimate of it (which
    /// calibrates the five-point body).
    fn tpose_pose(&mut self, tracks: &Tracks, devices: &Devices) -> Result<HumanPose, HumanError> {
        match self.wearing {
            Wearing::WholeBody => Ok(tracks.skeleton.human_pose()),
            Wearing::FivePoint => {
                let missing: Vec<&str> = Device::ALL[..self.wearing.devices()]
                    .iter()
                    .filter(|&&d| devices[d as usize].is_none())
                    .map(|&d| d.name())
                    .collect();
                if !missing.is_empty() {
                    return Err(HumanError::Calibration(format!(
                        "not seen in the T-pose: {} (the operator wears {} devices)",
                        missing.join(", "),
                        self.wearing.devices()
                    )));
                }
                let [Some(hmd), Some(left), Some(right), ..] = devices else {
                    unreachable!("the worn devices were all seen")
                };
                let user = UserCalibration::from_tpose(hmd, left, right, &Template::default())?;
                let mut body = SparseBody::new(user, devices)
                    .ok_or_else(|| HumanError::Calibration("no headset in the T-pose".into()))?;
                let pose = body
                    .pose(devices, 1.0 / self.options.rate_hz)
                    .ok_or_else(|| HumanError::Calibration("no headset in the T-pose".into()))?;
                self.sparse = Some(body);
                Ok(pose)
            }
        }
    }

    /// Retargets the operator's body now; velocities over the last [`VELOCITY_WINDOW_S`] of output.
    fn step(&mut self, pose: &HumanPose, dt: f64, input: Instant) {
        let Some(r) = self.retargeter.as_mut() else {
            return;
        };
        r.step(pose, dt);
        self.stepped = Some(input);
        let (root, q) = (r.root(), r.joints());
        while self
            .history
            .front()
            .is_some_and(|(t, ..)| input.saturating_duration_since(*t).as_secs_f64() > VELOCITY_WINDOW_S)
        {
            self.history.pop_front();
        }
        let f = &mut self.frame;
        match self.history.front() {
            Some((t, r0, q0)) => {
                let span = input.saturating_duration_since(*t).as_secs_f64().max(1e-3);
                f.root_lin_vel = [0, 1, 2].map(|i| (root[i] - r0[i]) / span);
                let turn = spatial::quat_mul(
                    [root[3], root[4], root[5], root[6]],
                    spatial::quat_conj([r0[3], r0[4], r0[5], r0[6]]),
                );
                f.root_ang_vel = spatial::scale(spatial::quat_log(turn), 1.0 / span);
                for ((v, a), b) in f.qd.iter_mut().zip(q).zip(q0) {
                    *v = (a - b) / span;
                }
            }
            None => {
                f.root_lin_vel = [0.0; 3];
                f.root_ang_vel = [0.0; 3];
                f.qd.fill(0.0);
            }
        }
        f.q.copy_from_slice(q);
        f.root = root;
        r.operator_in_root(&mut f.bodies);
        self.history.push_back((input, root, q.to_vec()));
    }

    /// Blends from the last tracked frame to the default pose standing where the robot is (its
    /// heading kept, level, at its standing height); true once there.
    fn blend_to_standing(&mut self, now: Instant) -> bool {
        let (since, from) = self.lost.get_or_insert_with(|| (now, self.frame.clone())).clone();
        let a = if self.options.blend_s > 0.0 {
            ((now - since).as_secs_f64() / self.options.blend_s).min(1.0)
        } else {
            1.0
        };
        let w = a * a * (3.0 - 2.0 * a);
        let f = &mut self.frame;
        for ((v, a), b) in f.q.iter_mut().zip(&from.q).zip(&self.standby) {
            *v = a + (b - a) * w;
        }
        let heading = spatial::heading_of_quat([from.root[3], from.root[4], from.root[5], from.root[6]]);
        let level = spatial::quat_of_rpy(0.0, 0.0, heading);
        let q = spatial::slerp([from.root[3], from.root[4], from.root[5], from.root[6]], level, w);
        f.root = [
            from.root[0],
            from.root[1],
            from.root[2] + (self.standing_height - from.root[2]) * w,
            q[0],
            q[1],
            q[2],
            q[3],
        ];
        f.qd.fill(0.0);
        f.root_lin_vel = [0.0; 3];
        f.root_ang_vel = [0.0; 3];
        f.bodies.clear();
        self.history.clear();
        a >= 1.0
    }
}

/// The rates a whole-body stream may come at, Hz: slower, the reference jumps between frames;
/// motion-capture suits and VR runtimes send 30–240 Hz.
pub const STREAM_RATES_HZ: [f64; 2] = [20.0, 1000.0];
/// Where an operator's hips may stand in the T-pose, m (statures of about 1.1–2.3 m).
pub const HIP_HEIGHTS_M: [f64; 2] = [0.55, 1.3];

/// Refuses, by name, an operator the map cannot be calibrated on: hips out of a standing adult's
/// range, or a stream at a rate out of [`STREAM_RATES_HZ`] (from the skeletons' arrivals while the
/// T-pose was held).
fn check_operator(pose: &HumanPose, arrivals: &[Instant], stream: &str) -> Result<(), HumanError> {
    if let (Some(first), Some(last)) = (arrivals.first(), arrivals.last())
        && arrivals.len() >= 2
    {
        let span = last.saturating_duration_since(*first).as_secs_f64();
        let rate = (arrivals.len() - 1) as f64 / span.max(1e-9);
        if !(STREAM_RATES_HZ[0]..=STREAM_RATES_HZ[1]).contains(&rate) {
            return Err(HumanError::map(format!(
                "the {stream} stream arrives at {rate:.1} Hz; whole-body teleoperation takes {:.0}–{:.0} Hz",
                STREAM_RATES_HZ[0], STREAM_RATES_HZ[1]
            )));
        }
    } else {
        return Err(HumanError::map(format!(
            "one {stream} sample in the whole T-pose: the stream is too slow to follow"
        )));
    }
    let hips = pose.get(robots::HumanBody::Root).map_or(f64::NAN, |r| r.pos[2]);
    if !(HIP_HEIGHTS_M[0]..=HIP_HEIGHTS_M[1]).contains(&hips) {
        return Err(HumanError::map(format!(
            "the operator's hips {hips:.2} m above the floor are not a standing adult's ({:.2}–{:.2} m): stand up straight, feet on the floor, for the T-pose",
            HIP_HEIGHTS_M[0], HIP_HEIGHTS_M[1]
        )));
    }
    Ok(())
}
