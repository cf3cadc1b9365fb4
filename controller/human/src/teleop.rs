//! Teleoperation from VR trackers, the live-IK way: the headset and controllers (VMC) are resampled
//! to the control rate and forecast when late; a T-pose at the start calibrates the user (stature,
//! device-to-joint offsets) and the retargeting map (scale, nominal offsets) onto the robot's own
//! T-pose; then each update maps the user's head and wrists into the robot's heading frame and
//! solves the robot's arms and head by inverse kinematics, the legs standing. The result is a live
//! reference for a reference-tracking policy. When the stream is lost it blends back to the
//! standby pose, and says so.
//!
//! The work runs on its own thread, woken by each tracker packet and at least once per control
//! period; the control loop takes the newest frame through a lock-free exchange ([`crate::live`]),
//! never waiting for this thread and allocating nothing in its tick.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use crate::HumanError;
use crate::body_map::{Frame, PairParams, RetargetMap, Template, UserCalibration, joint_from_device};
use robots::spatial;
use robots::{HumanBody, Robot};

use super::ik::{Ik, IkGoal};
use super::vmc::{Device, Estimate, Resampler, Tracks, VmcReceiver};
use crate::live::{LiveFrame, LiveReader, LiveWriter, TRACKER_VALUES, live_channel};

/// How teleoperation runs.
#[derive(Debug, Clone, PartialEq)]
pub struct TeleopOptions {
    /// Resampling, forecasting and when the stream counts as lost.
    pub resampler: Resampler,
    /// How long the user holds the T-pose, s.
    pub tpose_s: f64,
    /// Blend back to the standby pose over this long when the stream is lost, s.
    pub blend_s: f64,
    /// Control rate, Hz (the worker updates at least this often).
    pub rate_hz: f64,
    /// Only the headset: the arms stay in the standby pose.
    pub headset_only: bool,
    /// Body proportions the T-pose calibration assumes.
    pub template: Template,
    /// IK iterations per update.
    pub iterations: usize,
}

impl Default for TeleopOptions {
    fn default() -> Self {
        Self {
            resampler: Resampler::default(),
            tpose_s: 0.5,
            blend_s: 1.0,
            rate_hz: 50.0,
            headset_only: false,
            template: Template::default(),
            iterations: 25,
        }
    }
}

/// Where teleoperation is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// Standby pose; waiting for the user's T-pose.
    WaitingForTpose,
    /// Following the user.
    Tracking,
    /// The stream stopped: blending to the standby pose.
    Lost,
    /// Standby pose after a loss; tracking resumes when the stream does.
    Standby,
}

impl std::fmt::Display for Phase {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::WaitingForTpose => "waiting for the T-pose",
            Self::Tracking => "tracking",
            Self::Lost => "stream lost: blending to standby",
            Self::Standby => "standby",
        })
    }
}

/// A change of phase, with its time since start and why.
#[derive(Debug, Clone, PartialEq)]
pub struct PhaseChange {
    /// Since the start.
    pub at: Duration,
    /// The new phase.
    pub phase: Phase,
    /// Why.
    pub why: String,
}

/// What teleoperation reports while it runs.
#[derive(Debug, Clone, PartialEq)]
pub struct TeleopStatus {
    /// Now.
    pub phase: Phase,
    /// Every change so far.
    pub changes: Vec<PhaseChange>,
    /// The user's calibration and heading (rad), once the T-pose was taken.
    pub user: Option<(UserCalibration, f64)>,
    /// The map from the user onto the robot (pairs: head, left hand, right hand).
    pub map: Option<RetargetMap>,
    /// Updates computed.
    pub updates: u64,
    /// The robot's heading-frame origin (under its head in the T-pose, world coordinates of the
    /// IK model) and its standing root pose.
    pub robot_origin: [f64; 3],
    /// The device values of the newest frame, as the `tracker_poses` term sees them.
    pub trackers: [f64; TRACKER_VALUES],
}

/// The robot bodies teleoperation drives, in the order of the map's pairs.
pub const BODIES: [HumanBody; 3] = [HumanBody::Head, HumanBody::LeftHand, HumanBody::RightHand];

/// The running worker.
#[derive(Debug)]
pub struct Teleop {
    /// The control loop's end of the live reference (taken by the loop that tracks it).
    pub live: Option<LiveReader>,
    /// The standby pose (robot joint order) the reference starts from and returns to.
    pub standby: Vec<f64>,
    /// The standing root pose `[x, y, z, w, qx, qy, qz]`.
    pub root: [f64; 7],
    /// Phase, calibration and history.
    pub status: Arc<Mutex<TeleopStatus>>,
    pub(crate) _thread: WorkerThread,
}

/// The user's head and wrists in their heading frame (yaw of the T-pose, origin under the head).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UserFrames {
    /// Head joint: position and the headset's orientation.
    pub head: Frame,
    /// Wrists (orientation: the heading frame's).
    pub hands: [Option<Frame>; 2],
}

/// The user's head and wrists from the devices, given the T-pose calibration and heading.
pub fn user_frames(devices: &[Option<Frame>; 3], user: &UserCalibration, heading: f64) -> Option<UserFrames> {
    let hmd = devices[0]?;
    let turn = spatial::yaw(-heading);
    let head_world = joint_from_device(&hmd, user.head);
    let local = |p: [f64; 3]| spatial::mat_apply(&turn, [p[0] - head_world[0], p[1] - head_world[1], p[2]]);
    let hand = |d: Option<Frame>, offset: [f64; 3]| {
        d.map(|d| Frame {
            pos: local(joint_from_device(&d, offset)),
            rot: spatial::IDENTITY,
        })
    };
    Some(UserFrames {
        head: Frame {
            pos: local(head_world),
            rot: spatial::mat_mul(&turn, &hmd.rot),
        },
        hands: [hand(devices[1], user.left), hand(devices[2], user.right)],
    })
}

struct Worker {
    ik: Ik,
    weights: [(f64, f64); 3],
    params: [PairParams; 3],
    standby: Vec<f64>,
    root: [f64; 7],
    targets_tpose: [Frame; 3],
    speed: Vec<f64>,
    arm_joints: [Vec<usize>; 2],
    options: TeleopOptions,
    q: Vec<f64>,
    last: Option<Instant>,
    tpose: Vec<[Frame; 3]>,
    tpose_since: Option<Instant>,
    lost: Option<(Instant, Vec<f64>)>,
    user: Option<(UserCalibration, f64)>,
    map: Option<RetargetMap>,
    /// Arrival of the newest input any published frame used.
    source: Option<Instant>,
}

impl Teleop {
    /// Starts the worker for `robot` on `receiver`'s tracks. The robot's [retarget] section must
    /// pair `head`, `left_hand` and `right_hand` with robot frames.
    pub fn start(robot: &Robot, receiver: &VmcReceiver, options: TeleopOptions) -> Result<Self, HumanError> {
        let config = robot
            .config
            .retarget
            .as_ref()
            .ok_or_else(|| HumanError::map(format!("{}: no [retarget] section", robot.path.display())))?;
        let pair = |b: HumanBody| {
            config.pairs.iter().find(|p| p.human == b).ok_or_else(|| {
                HumanError::map(format!(
                    "{}: [retarget] pairs no robot frame with {b:?}",
                    robot.path.display()
                ))
            })
        };
        let pairs = [pair(BODIES[0])?, pair(BODIES[1])?, pair(BODIES[2])?];
        let frames: Vec<String> = pairs.iter().map(|p| p.frame.clone()).collect();
        // Legs stand: only joints that move the paired frames are free.
        let ik = Ik::new(robot, &frames, false, &[])?;
        let movers = ik.joints_moving_frames();
        let locked: Vec<usize> = (0..robot.config.joints.len())
            .filter(|j| !movers.contains(j))
            .collect();
        let mut ik = Ik::new(robot, &frames, false, &locked)?;
        for (k, p) in pairs.iter().enumerate() {
            ik.set_compare(k, p.orientation_compare, p.twist_axis);
        }
        let standby: Vec<f64> = robot.config.joints.iter().map(|j| j.default_position).collect();
        let root = ik.standing_root(&standby);
        let tpose_q: Vec<f64> = robot
            .config
            .joints
            .iter()
            .map(|j| config.tpose.get(&j.name).copied().unwrap_or(j.default_position))
            .collect();
        ik.set_pose(root, &tpose_q);
        let targets_tpose = [ik.frame(0), ik.frame(1), ik.frame(2)];
        let arm = |k: usize| {
            ik.joints_moving_frame(k)
                .into_iter()
                .filter(|j| !locked.contains(j))
                .collect::<Vec<_>>()
        };
        let arm_joints = [arm(1), arm(2)];
        let dt = 1.0 / options.rate_hz;
        let period = Duration::try_from_secs_f64(dt)
            .map_err(|_| HumanError::map(format!("control rate {} Hz is not a rate", options.rate_hz)))?;
        let worker = Worker {
            weights: pairs.map(|p| (p.position_weight, p.orientation_weight)),
            params: pairs.map(|p| PairParams {
                p_pos: p.p_pos,
                p_ori: p.p_ori,
            }),
            speed: robot
                .config
                .joints
                .iter()
                .map(|j| 0.9 * j.velocity_limit)
                .collect(),
            q: standby.clone(),
            standby: standby.clone(),
            root,
            targets_tpose,
            arm_joints,
            ik,
            options: options.clone(),
            last: None,
            tpose: Vec::new(),
            tpose_since: None,
            lost: None,
            user: None,
            map: None,
            source: None,
        };
        let (writer, live) = live_channel(LiveFrame::still(standby.clone(), root));
        let status = Arc::new(Mutex::new(TeleopStatus {
            phase: Phase::WaitingForTpose,
            changes: vec![PhaseChange {
                at: Duration::ZERO,
                phase: Phase::WaitingForTpose,
                why: "waiting for the user's T-pose".into(),
            }],
            user: None,
            map: None,
            updates: 0,
            robot_origin: [targets_tpose[0].pos[0], targets_tpose[0].pos[1], 0.0],
            trackers: [0.0; TRACKER_VALUES],
        }));
        let (mut f, st) = (writer, Arc::clone(&status));
        let mut worker = worker;
        let thread = WorkerThread::spawn("teleop", receiver, period, move |t, now, start| {
            worker.update(t, now, start, &mut f, &st);
        })?;
        Ok(Self {
            live: Some(live),
            standby,
            root,
            status,
            _thread: thread,
        })
    }

    /// A copy of the status.
    pub fn status(&self) -> TeleopStatus {
        self.status.lock().unwrap_or_else(PoisonError::into_inner).clone()
    }
}

/// A teleoperation worker's thread: woken by each tracker packet and at least once per period,
/// it hands the newest tracks to `update` (with the time and the thread's start) until dropped.
#[derive(Debug)]
pub(crate) struct WorkerThread {
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl WorkerThread {
    pub(crate) fn spawn(
        name: &str,
        receiver: &VmcReceiver,
        period: Duration,
        mut update: impl FnMut(&Tracks, Instant, Instant) + Send + 'static,
    ) -> Result<Self, HumanError> {
        let stop = Arc::new(AtomicBool::new(false));
        let (tracks, arrivals) = (Arc::clone(&receiver.tracks), receiver.arrivals.clone());
        let s = Arc::clone(&stop);
        let thread = std::thread::Builder::new()
            .name(name.into())
            .spawn(move || {
                let start = Instant::now();
                while !s.load(Ordering::Relaxed) {
                    let _ = arrivals.recv_timeout(period);
                    let t = *tracks.lock().unwrap_or_else(PoisonError::into_inner);
                    update(&t, Instant::now(), start);
                }
            })
            .map_err(|e| HumanError::io("cannot start the teleoperation thread", e))?;
        Ok(Self {
            stop,
            thread: Some(thread),
        })
    }
}

impl Drop for WorkerThread {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Records a change of phase (or a new reason in the same phase) and logs it.
pub(crate) fn change(status: &Mutex<TeleopStatus>, at: Duration, phase: Phase, why: String) {
    let mut s = status.lock().unwrap_or_else(PoisonError::into_inner);
    if s.phase != phase || s.changes.last().is_some_and(|c| c.why != why) {
        match phase {
            Phase::Lost => tracing::warn!(phase = ?phase, "{why}"),
            _ => tracing::info!(phase = ?phase, "{why}"),
        }
        s.phase = phase;
        s.changes.push(PhaseChange { at, phase, why });
    }
}

impl Worker {
    fn update(
        &mut self,
        tracks: &Tracks,
        now: Instant,
        start: Instant,
        frame: &mut LiveWriter,
        status: &Mutex<TeleopStatus>,
    ) {
        let at = now - start;
        let estimates =
            Device::HEAD_AND_HANDS.map(|d| self.options.resampler.at(&tracks.devices[d as usize], now));
        let frames = estimates.map(|e| match e {
            Estimate::Live(f) | Estimate::Forecast(f) => Some(f),
            Estimate::Missing => None,
        });
        let newest = Device::HEAD_AND_HANDS
            .iter()
            .filter_map(|&d| tracks.devices[d as usize].newest().map(|(t, _)| t))
            .max();
        let phase = status.lock().unwrap_or_else(PoisonError::into_inner).phase;
        let wanted = if self.options.headset_only { 1 } else { 3 };
        let live = estimates[..wanted].iter().all(|e| matches!(e, Estimate::Live(_)));
        let (q, source) = match phase {
            Phase::WaitingForTpose => {
                if live {
                    let since = *self.tpose_since.get_or_insert(now);
                    self.tpose.push(frames.map(|f| {
                        f.unwrap_or(Frame {
                            pos: [0.0; 3],
                            rot: spatial::IDENTITY,
                        })
                    }));
                    if (now - since).as_secs_f64() >= self.options.tpose_s {
                        match self.calibrate() {
                            Ok(why) => {
                                let mut s = status.lock().unwrap_or_else(PoisonError::into_inner);
                                s.user = self.user;
                                s.map = self.map.clone();
                                drop(s);
                                change(status, at, Phase::Tracking, why);
                            }
                            Err(why) => {
                                tracing::warn!("T-pose: {why}");
                                self.tpose.clear();
                                self.tpose_since = None;
                            }
                        }
                    }
                } else {
                    self.tpose.clear();
                    self.tpose_since = None;
                }
                (self.standby.clone(), None)
            }
            Phase::Tracking | Phase::Standby if frames[0].is_some() => {
                if phase == Phase::Standby {
                    change(
                        status,
                        at,
                        Phase::Tracking,
                        "tracker stream back: tracking again".into(),
                    );
                }
                self.lost = None;
                (self.track(&frames), newest)
            }
            Phase::Tracking | Phase::Lost => {
                let (since, from) = self.lost.get_or_insert_with(|| (now, self.q.clone())).clone();
                if phase == Phase::Tracking {
                    change(
                        status,
                        at,
                        Phase::Lost,
                        format!(
                            "tracker stream lost (nothing for {:.2} s): blending to standby over {:.1} s",
                            self.options.resampler.lost_after, self.options.blend_s
                        ),
                    );
                }
                let a = ((now - since).as_secs_f64() / self.options.blend_s).min(1.0);
                let w = a * a * (3.0 - 2.0 * a);
                if a >= 1.0 {
                    change(status, at, Phase::Standby, "standby pose reached".into());
                }
                (
                    from.iter()
                        .zip(&self.standby)
                        .map(|(f, s)| f + (s - f) * w)
                        .collect(),
                    None,
                )
            }
            Phase::Standby => (self.standby.clone(), None),
        };
        let trackers = self.tracker_values(&frames);
        self.publish(q, source, trackers, now, frame);
        let mut s = status.lock().unwrap_or_else(PoisonError::into_inner);
        s.updates += 1;
        s.trackers = trackers;
    }

    /// The devices as the sparse-input observation wants them: in the user's heading frame (origin
    /// on the floor under the headset), at the map's scale, position and the rotation's first two
    /// columns; zeros for a missing device or before the T-pose.
    fn tracker_values(&self, devices: &[Option<Frame>; 3]) -> [f64; TRACKER_VALUES] {
        let mut out = [0.0; TRACKER_VALUES];
        let (Some((_, heading)), Some(map), Some(hmd)) = (&self.user, &self.map, devices[0]) else {
            return out;
        };
        let turn = spatial::yaw(-heading);
        for (k, d) in devices.iter().enumerate() {
            let Some(d) = d else { continue };
            let rel = [d.pos[0] - hmd.pos[0], d.pos[1] - hmd.pos[1], d.pos[2]];
            let p = spatial::scale(spatial::mat_apply(&turn, rel), map.scale);
            let r = spatial::mat_mul(&turn, &d.rot);
            let v = &mut out[9 * k..9 * k + 9];
            v[..3].copy_from_slice(&p);
            for row in 0..3 {
                v[3 + row] = r[row][0];
                v[6 + row] = r[row][1];
            }
        }
        out
    }

    /// Averages the T-pose samples, calibrates the user and builds the map.
    fn calibrate(&mut self) -> Result<String, HumanError> {
        let n = self.tpose.len() as f64;
        let mean = |k: usize| {
            let mut f = self.tpose[self.tpose.len() - 1][k];
            f.pos = self.tpose.iter().fold([0.0; 3], |acc, s| {
                spatial::add(acc, spatial::scale(s[k].pos, 1.0 / n))
            });
            f
        };
        let (hmd, left, right) = (mean(0), mean(1), mean(2));
        let user = if self.options.headset_only {
            // Only the headset: stature and head; the hands are not used.
            let fake = |side: f64| Frame {
                pos: spatial::add(hmd.pos, [0.0, side, 0.0]),
                rot: spatial::IDENTITY,
            };
            UserCalibration::from_tpose(&hmd, &fake(1.0), &fake(-1.0), &self.options.template)?
        } else {
            UserCalibration::from_tpose(&hmd, &left, &right, &self.options.template)?
        };
        let heading = spatial::heading(&hmd.rot);
        let frames = user_frames(&[Some(hmd), Some(left), Some(right)], &user, heading)
            .ok_or_else(|| HumanError::Calibration("no headset".into()))?;
        let head_height = frames.head.pos[2];
        let source = [
            frames.head,
            frames.hands[0].unwrap_or(frames.head),
            frames.hands[1].unwrap_or(frames.head),
        ];
        // The robot's T-pose in its heading frame (origin under the head, like the user's).
        let origin = self.targets_tpose[0].pos;
        let target = self.targets_tpose.map(|f| Frame {
            pos: [f.pos[0] - origin[0], f.pos[1] - origin[1], f.pos[2]],
            rot: f.rot,
        });
        let map = RetargetMap::nominal(head_height, target[0].pos[2], &source, &target, &self.params, 0.0)?;
        let why = format!(
            "T-pose taken: stature {:.2} m, scale {:.3}; tracking",
            user.stature, map.scale
        );
        self.user = Some((user, heading));
        self.map = Some(map);
        Ok(why)
    }

    /// One IK update towards the mapped user.
    fn track(&mut self, devices: &[Option<Frame>; 3]) -> Vec<f64> {
        let (Some((user, heading)), Some(map)) = (&self.user, &self.map) else {
            return self.standby.clone();
        };
        let Some(u) = user_frames(devices, user, *heading) else {
            return self.q.clone();
        };
        let origin = self.targets_tpose[0].pos;
        let to_world = |f: Frame| Frame {
            pos: [f.pos[0] + origin[0], f.pos[1] + origin[1], f.pos[2]],
            rot: f.rot,
        };
        let mut q = self.q.clone();
        let mut goals = [IkGoal {
            frame: to_world(map.map(0, &u.head)),
            position_weight: self.weights[0].0,
            orientation_weight: self.weights[0].1,
        }; 3];
        for side in 0..2 {
            match (u.hands[side], self.options.headset_only) {
                (Some(h), false) => {
                    goals[side + 1] = IkGoal {
                        frame: to_world(map.map(side + 1, &h)),
                        position_weight: self.weights[side + 1].0,
                        orientation_weight: self.weights[side + 1].1,
                    };
                }
                _ => {
                    // No controller: that arm goes to the standby pose and is left alone.
                    for &j in &self.arm_joints[side] {
                        q[j] = self.standby[j];
                    }
                    goals[side + 1].position_weight = 0.0;
                    goals[side + 1].orientation_weight = 0.0;
                }
            }
        }
        self.ik.set_pose(self.root, &q);
        self.ik.solve(&goals, self.options.iterations);
        self.ik.joints(&mut q);
        q
    }

    /// Publishes `q`, within the joints' speeds since the last publication.
    fn publish(
        &mut self,
        mut q: Vec<f64>,
        source: Option<Instant>,
        trackers: [f64; TRACKER_VALUES],
        now: Instant,
        frame: &mut LiveWriter,
    ) {
        let dt = self
            .last
            .map_or(1.0 / self.options.rate_hz, |t| (now - t).as_secs_f64().max(1e-4));
        let mut qd = vec![0.0; q.len()];
        for (k, v) in q.iter_mut().enumerate() {
            let step = self.speed[k] * dt;
            *v = v.clamp(self.q[k] - step, self.q[k] + step);
            qd[k] = (*v - self.q[k]) / dt;
        }
        self.q.copy_from_slice(&q);
        self.last = Some(now);
        if source.is_some() {
            self.source = source;
        }
        frame.publish(|f| {
            f.q.copy_from_slice(&q);
            f.qd.copy_from_slice(&qd);
            f.root = self.root;
            f.source = self.source;
            f.trackers = trackers;
        });
    }
}
