//! A tick record as the recording's typed messages (`telemetry-schema`, protobuf), built on the
//! telemetry thread. One message per channel is kept and overwritten each tick: names are set
//! once, only values change.

use foxglove::schemas as fg;
use telemetry_schema as pb;

use super::{MODE_NAMES, RecordingInfo, TickRecord};
use crate::generator::PlanStatus;
use robot_link::CycleRecord;
use viewers::fg_time;

/// `[x, y, z]` as a message vector.
pub(super) fn vec3(v: [f64; 3]) -> Option<pb::Vector3> {
    Some(pb::Vector3 {
        x: v[0],
        y: v[1],
        z: v[2],
    })
}

/// A pose `[x, y, z, w, qx, qy, qz]` (the loop's order) as a message pose.
pub(super) fn pose(p: [f64; 7]) -> Option<pb::Pose> {
    Some(pb::Pose {
        position: vec3([p[0], p[1], p[2]]),
        orientation: Some(pb::Quaternion {
            x: p[4],
            y: p[5],
            z: p[6],
            w: p[3],
        }),
    })
}

/// The name of item `i`, or a stand-in past the names given.
fn name(names: &[String], i: usize, what: &str) -> String {
    names.get(i).cloned().unwrap_or_else(|| format!("{what}{i}"))
}

/// A message element that carries its own name (a joint, a command, a body, a bus, a foot).
trait Named: Default {
    fn name_mut(&mut self) -> &mut String;
}

macro_rules! named {
    ($($t:ty => $field:ident),* $(,)?) => {
        $(impl Named for $t {
            fn name_mut(&mut self) -> &mut String {
                &mut self.$field
            }
        })*
    };
}

named!(
    pb::JointState => name,
    pb::JointCommand => name,
    pb::NamedValue => name,
    pb::BodyError => name,
    pb::BusTime => bus,
    pb::Foot => name,
    pb::KeypointError => view,
);

/// `items` at length `n`, each named from `names` once (a stand-in `{what}{i}` past them).
fn named<'a, T: Named>(items: &'a mut Vec<T>, n: usize, names: &[String], what: &str) -> &'a mut [T] {
    items.resize_with(n, T::default);
    for (i, item) in items.iter_mut().enumerate() {
        let slot = item.name_mut();
        if slot.is_empty() {
            *slot = name(names, i, what);
        }
    }
    items
}

/// The typed messages of the tick channels, reused tick after tick.
pub(super) struct Messages {
    joint_state: pb::JointStates,
    command: pb::JointCommands,
    policy: pb::PolicyStep,
    imu: pb::ImuReading,
    timing: pb::TickTiming,
    estimate: pb::StateEstimate,
    /// One per bus, its joints named.
    buses: Vec<pb::BusCycle>,
    joint_names: Vec<String>,
    motion_bodies: Vec<String>,
    anchor: Option<usize>,
    command_names: Vec<String>,
    foot_names: Vec<String>,
    bus_names: Vec<String>,
    keypoint_views: Vec<String>,
    last_mode: u8,
    /// The harness phase of the last record.
    last_harness: crate::options::HarnessPhase,
    last_generated: Option<PlanStatus>,
}

impl Messages {
    pub(super) fn new(info: &RecordingInfo) -> Self {
        let joint_names = info.joint_names.clone();
        let buses = info
            .bus_cycles
            .iter()
            .flatten()
            .map(|joints| pb::BusCycle {
                joints: joints
                    .iter()
                    .take(robot_link::MAX_RECORDED_JOINTS)
                    .map(|&i| pb::BusJoint {
                        name: name(&joint_names, i, "joint"),
                        ..Default::default()
                    })
                    .collect(),
                ..Default::default()
            })
            .collect();
        Self {
            joint_state: pb::JointStates::default(),
            command: pb::JointCommands::default(),
            policy: pb::PolicyStep::default(),
            imu: pb::ImuReading::default(),
            timing: pb::TickTiming::default(),
            estimate: pb::StateEstimate::default(),
            buses,
            joint_names,
            motion_bodies: info.motion_bodies.clone(),
            anchor: info.anchor,
            command_names: info.commands.iter().map(|(n, _)| n.clone()).collect(),
            foot_names: info.foot_names.clone(),
            bus_names: info.bus_names.clone(),
            keypoint_views: info.keypoint_views.clone(),
            last_mode: u8::MAX,
            last_harness: crate::options::HarnessPhase::None,
            last_generated: None,
        }
    }

    /// `/joint_state`.
    pub(super) fn joint_state(&mut self, r: &TickRecord, stamp: u64) -> &pb::JointStates {
        let n = usize::from(r.joints);
        let m = &mut self.joint_state;
        m.timestamp = Some(pb::timestamp(stamp));
        for (i, j) in named(&mut m.joints, n, &self.joint_names, "joint")
            .iter_mut()
            .enumerate()
        {
            j.position = r.q[i];
            j.velocity = r.qd[i];
            j.effort = r.tau[i];
            j.missed = r.missed[i];
            j.stale = r.stale[i];
            j.age_ms = r.age_ms[i];
            j.faulted = r.faulted[i];
        }
        m
    }

    /// `/joint_states` (ROS 2's `sensor_msgs/msg/JointState`, CDR) into `buf`: each joint by
    /// name, measured position, velocity and torque.
    pub(super) fn joint_states_cdr(&self, r: &TickRecord, stamp: u64, buf: &mut Vec<u8>) {
        let n = usize::from(r.joints);
        let names = (0..n).map(|i| self.joint_names.get(i).map_or("", String::as_str));
        telemetry_schema::ros2::encode_joint_state(
            buf,
            stamp,
            "",
            names,
            r.q[..n].iter().copied(),
            r.qd[..n].iter().copied(),
            r.tau[..n].iter().copied(),
        );
    }

    /// `/command`.
    pub(super) fn command(&mut self, r: &TickRecord, stamp: u64) -> &pb::JointCommands {
        let n = usize::from(r.joints);
        let m = &mut self.command;
        m.timestamp = Some(pb::timestamp(stamp));
        for (i, j) in named(&mut m.joints, n, &self.joint_names, "joint")
            .iter_mut()
            .enumerate()
        {
            let [q, qd, kp, kd, tau] = r.target[i];
            (j.position, j.velocity, j.kp, j.kd, j.effort) = (q, qd, kp, kd, tau);
            j.enabled = r.enabled[i];
            j.reference = f64::from(r.reference_q[i]);
        }
        m.reference_root = pose(r.reference_root);
        m.tracking = r.tracking;
        m
    }

    /// `/policy`.
    pub(super) fn policy(&mut self, r: &TickRecord, obs: &[f32], stamp: u64) -> &pb::PolicyStep {
        let m = &mut self.policy;
        m.timestamp = Some(pb::timestamp(stamp));
        m.tick = r.tick;
        m.running = usize::from(r.mode) == MODE_NAMES.iter().position(|&n| n == "Running").unwrap_or(3);
        m.policy_ran = r.policy_ran;
        m.observation.clear();
        m.observation.extend_from_slice(obs);
        m.action.clear();
        m.action.extend_from_slice(&r.action[..usize::from(r.joints)]);
        let c = usize::from(r.command_count);
        for (i, v) in named(&mut m.commands, c, &self.command_names, "command")
            .iter_mut()
            .enumerate()
        {
            v.value = r.commands[i];
        }
        (m.robot_anchor, m.reference_anchor) = match r.anchors {
            Some((robot, reference)) => (pose(robot), pose(reference)),
            None => (None, None),
        };
        let b = usize::from(r.bodies);
        for (i, e) in named(&mut m.body_errors, b, &self.motion_bodies, "body")
            .iter_mut()
            .enumerate()
        {
            e.anchor = self.anchor == Some(i);
            e.error_m = f64::from(r.body_errors[i]);
        }
        m.generated = r.generated.map(|g| pb::GeneratedReference {
            status: g.status.name().into(),
            standby_weight: g.standby_weight,
            past_plan_s: g.past_plan_s,
            step: g.step,
            step_latency_s: g.step_latency_s,
        });
        let views = usize::from(r.keypoint_views);
        for (i, e) in named(&mut m.keypoint_errors, views, &self.keypoint_views, "view")
            .iter_mut()
            .enumerate()
        {
            let [mean, max, du, dv, compared] = r.keypoint_errors[i];
            (e.mean_px, e.max_px, e.mean_du_px, e.mean_dv_px) =
                (f64::from(mean), f64::from(max), f64::from(du), f64::from(dv));
            e.compared = compared as u32;
            e.failed = f64::from(max) > crate::keypoints::FAILURE_PX;
        }
        m.triangulated_mm = (!r.triangulated_mm.is_nan()).then_some(f64::from(r.triangulated_mm));
        m
    }

    /// `/log`, when a generated reference changed status this tick.
    /// A line on `/log` as a harness start's phase begins.
    pub(super) fn harness_log(&mut self, r: &TickRecord, stamp: u64) -> Option<fg::Log> {
        if r.harness == self.last_harness {
            return None;
        }
        self.last_harness = r.harness;
        Some(fg::Log {
            timestamp: fg_time(stamp),
            level: fg::log::Level::Info as i32,
            message: format!("tick {}: harness: {}", r.tick, r.harness),
            name: "harness".into(),
            ..Default::default()
        })
    }

    pub(super) fn generated_log(&mut self, r: &TickRecord, stamp: u64) -> Option<fg::Log> {
        let g = r.generated?;
        let (status, past) = (g.status, g.past_plan_s);
        let before = self.last_generated.replace(status);
        if before == Some(status) || (before.is_none() && status == PlanStatus::Fresh) {
            return None;
        }
        let (level, message) = match status {
            PlanStatus::Fresh => (
                fg::log::Level::Info,
                format!("tick {}: generated reference fresh again", r.tick),
            ),
            PlanStatus::Forecast => (
                fg::log::Level::Warning,
                format!(
                    "tick {}: generator late ({past:.3} s past its plan): forecasting",
                    r.tick
                ),
            ),
            PlanStatus::Standby => (
                fg::log::Level::Warning,
                format!("tick {}: generator {past:.3} s late: blending to standby", r.tick),
            ),
        };
        Some(fg::Log {
            timestamp: fg_time(stamp),
            level: level as i32,
            message,
            name: "generator".into(),
            ..Default::default()
        })
    }

    /// `/safety` and `/log`, when the mode changed this tick.
    pub(super) fn safety(&mut self, r: &TickRecord, stamp: u64) -> Option<(pb::SafetyTransition, fg::Log)> {
        if r.mode == self.last_mode {
            return None;
        }
        self.last_mode = r.mode;
        let mode = MODE_NAMES.get(usize::from(r.mode)).copied().unwrap_or("?");
        let cause = std::str::from_utf8(&r.cause[..usize::from(r.cause_len)]).unwrap_or("?");
        let log = fg::Log {
            timestamp: fg_time(stamp),
            level: if r.cause_fault {
                fg::log::Level::Error
            } else {
                fg::log::Level::Info
            } as i32,
            message: if cause.is_empty() {
                format!("tick {}: {mode}", r.tick)
            } else {
                format!("tick {}: {mode} ({cause})", r.tick)
            },
            name: "safety".into(),
            ..Default::default()
        };
        let transition = pb::SafetyTransition {
            timestamp: Some(pb::timestamp(stamp)),
            tick: r.tick,
            mode: mode.into(),
            cause: cause.into(),
            fault: r.cause_fault,
        };
        Some((transition, log))
    }

    /// `/imu`.
    pub(super) fn imu(&mut self, r: &TickRecord, stamp: u64) -> &pb::ImuReading {
        let m = &mut self.imu;
        m.timestamp = Some(pb::timestamp(stamp));
        m.angular_velocity = vec3([r.imu[0], r.imu[1], r.imu[2]]);
        m.linear_acceleration = vec3([r.imu[3], r.imu[4], r.imu[5]]);
        m.orientation = Some(pb::Quaternion {
            w: r.imu[6],
            x: r.imu[7],
            y: r.imu[8],
            z: r.imu[9],
        });
        m.age_ms = r.imu_age_ms;
        m.missed = r.imu_missed;
        m
    }

    /// `/timing`.
    pub(super) fn timing(&mut self, r: &TickRecord, stamp: u64) -> &pb::TickTiming {
        let m = &mut self.timing;
        m.timestamp = Some(pb::timestamp(stamp));
        m.io_us = r.io_us;
        m.compute_us = r.compute_us;
        let b = usize::from(r.buses);
        for (i, t) in named(&mut m.buses, b, &self.bus_names, "bus")
            .iter_mut()
            .enumerate()
        {
            t.us = r.bus_us[i];
        }
        m
    }

    /// `/estimator`, for a robot with an estimator.
    pub(super) fn estimate(&mut self, r: &TickRecord, stamp: u64) -> Option<&pb::StateEstimate> {
        let e = &r.estimate;
        if !e.present {
            return None;
        }
        let x = &e.estimate;
        let m = &mut self.estimate;
        m.timestamp = Some(pb::timestamp(stamp));
        m.valid = x.valid;
        m.held = x.held;
        m.position = vec3(x.position);
        m.velocity = vec3(x.velocity);
        m.velocity_base = vec3(x.velocity_base);
        m.position_std = vec3(x.position_std);
        m.velocity_std = vec3(x.velocity_std);
        m.accel_bias = vec3(x.accel_bias);
        for (i, f) in named(&mut m.feet, x.feet, &self.foot_names, "foot")
            .iter_mut()
            .enumerate()
        {
            f.contact = x.contacts[i];
            f.load = x.loads[i];
            f.truth_contact = e
                .truth
                .and_then(|_| (i < usize::from(r.feet)).then(|| r.foot_contacts[i]));
        }
        (m.truth_position, m.truth_velocity_base, m.truth_velocity) = match e.truth {
            Some((pose, vel)) => (
                vec3([pose[0], pose[1], pose[2]]),
                vec3(vel),
                // As the loop compares it: the base velocity turned by the mapped truth's pose.
                vec3(robots::spatial::quat_rotate(
                    [pose[3], pose[4], pose[5], pose[6]],
                    vel,
                )),
            ),
            None => (None, None, None),
        };
        Some(m)
    }

    /// `/bus/<name>` for one cycle of bus `c.bus`.
    pub(super) fn bus_cycle(&mut self, c: &CycleRecord, stamp: u64) -> Option<&pb::BusCycle> {
        let m = self.buses.get_mut(usize::from(c.bus))?;
        m.timestamp = Some(pb::timestamp(stamp));
        m.cycle = c.cycle;
        m.took_us = c.took_us;
        m.overruns = c.overruns;
        m.damped = c.damped;
        let n = usize::from(c.joints).min(m.joints.len());
        for (i, j) in m.joints[..n].iter_mut().enumerate() {
            j.position = f64::from(c.q[i]);
            j.velocity = f64::from(c.qd[i]);
            j.effort = f64::from(c.tau[i]);
            j.missed = c.missed[i];
            let [q, qd, kp, kd, tau] = c.command[i].map(f64::from);
            (
                j.command_position,
                j.command_velocity,
                j.kp,
                j.kd,
                j.command_effort,
            ) = (q, qd, kp, kd, tau);
            j.enabled = c.enabled[i];
        }
        Some(m)
    }
}
