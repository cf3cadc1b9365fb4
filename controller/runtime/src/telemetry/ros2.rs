//! ROS 2 topics from a run (`play --ros2`): what the recording carries, published on DDS under
//! ROS 2's names (`rt/joint_states`, `sensor_msgs::msg::dds_::JointState_`, …), from the telemetry
//! thread — never the loop's. `/joint_states` and `/robot_description` are the recording's own
//! bytes; `/tf` the recording's link frames in `tf2_msgs/msg/TFMessage`; `/diagnostics` the loop's
//! and each bus's health once a second and at every change of mode; `/clock` a lockstep run's
//! simulated time, every tick.

use dds::ros2::{Level, Status, Transform};
use dds::{DdsConfig, DdsError, Delivery, Participant, Publication};

use super::{MODE_NAMES, TickRecord};

/// Where a run's ROS 2 topics go.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Ros2Config {
    /// The DDS domain (ROS 2's `ROS_DOMAIN_ID`) and network interface.
    pub dds: DdsConfig,
    /// The robot's name, the hardware id of its diagnostics.
    pub robot: String,
}

/// Ticks between two `/diagnostics` (one second at 50 Hz).
const DIAGNOSTICS_EVERY: u64 = 50;

/// The run's ROS 2 topics. Field order is drop order: the topics before their participant.
pub(crate) struct Ros2Topics {
    joint_states: Publication,
    tf: Publication,
    /// Frames that never change, once (transient local, as robot_state_publisher offers them).
    tf_static: Publication,
    /// Their child frames' names, and whether they went out.
    fixed: Vec<String>,
    static_sent: bool,
    robot_description: Publication,
    diagnostics: Publication,
    /// `/clock`, for a run in simulated time.
    clock: Option<Publication>,
    robot: String,
    bus_names: Vec<String>,
    last_mode: Option<u8>,
    buf: Vec<u8>,
    warned: bool,
    _participant: Participant,
}

impl std::fmt::Debug for Ros2Topics {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Ros2Topics")
            .field("robot", &self.robot)
            .finish_non_exhaustive()
    }
}

fn topic(
    participant: &Participant,
    name: &str,
    ros_type: &str,
    delivery: Delivery,
) -> Result<Publication, DdsError> {
    participant.publication(
        &dds::names::ros2_topic(name),
        &dds::names::ros2_type(ros_type),
        delivery,
    )
}

impl Ros2Topics {
    /// Joins `config`'s domain on its interface and declares the topics; with `simulated`, the
    /// run's time is the simulation's and `/clock` carries it.
    pub(crate) fn open(config: &Ros2Config, bus_names: &[String], simulated: bool) -> Result<Self, DdsError> {
        let p = Participant::join(&config.dds)?;
        Ok(Self {
            // ROS 2's default profile (reliable): what tf2 listeners, RViz and
            // diagnostic_aggregator subscribe with; best-effort readers match it too.
            joint_states: topic(
                &p,
                "/joint_states",
                "sensor_msgs/msg/JointState",
                Delivery::Reliable,
            )?,
            tf: topic(&p, "/tf", "tf2_msgs/msg/TFMessage", Delivery::Reliable)?,
            tf_static: topic(&p, "/tf_static", "tf2_msgs/msg/TFMessage", Delivery::Latched)?,
            fixed: Vec::new(),
            static_sent: false,
            // Transient local, as robot_state_publisher offers it: a late subscriber gets it.
            robot_description: topic(&p, "/robot_description", "std_msgs/msg/String", Delivery::Latched)?,
            diagnostics: topic(
                &p,
                "/diagnostics",
                "diagnostic_msgs/msg/DiagnosticArray",
                Delivery::Reliable,
            )?,
            // What a simulator offers (Gazebo, Isaac): nodes with use_sim_time follow it; the
            // run's messages are stamped in the same time.
            clock: match simulated {
                true => Some(topic(
                    &p,
                    "/clock",
                    "rosgraph_msgs/msg/Clock",
                    Delivery::Reliable,
                )?),
                false => None,
            },
            robot: config.robot.clone(),
            bus_names: bus_names.to_vec(),
            last_mode: None,
            buf: Vec::with_capacity(4096),
            warned: false,
            _participant: p,
        })
    }

    /// A failed publication is said once; the run and its recording go on.
    fn check(&mut self, what: &str, r: Result<(), DdsError>) {
        if let Err(e) = r
            && !std::mem::replace(&mut self.warned, true)
        {
            tracing::warn!("--ros2: {what}: {e} (further failures not reported)");
        }
    }

    /// `/joint_states`: the recording's CDR.
    pub(crate) fn joint_states(&mut self, cdr: &[u8]) {
        let r = self.joint_states.publish(cdr);
        self.check("/joint_states", r);
    }

    /// `/clock` at the tick's time `t` (simulated runs only).
    pub(crate) fn clock(&mut self, t: u64) {
        let Some(clock) = &self.clock else { return };
        dds::ros2::encode_clock(&mut self.buf, t);
        let r = clock.publish(&self.buf);
        self.check("/clock", r);
    }

    /// `/robot_description`: the recording's CDR of the URDF.
    pub(crate) fn robot_description(&mut self, cdr: &[u8]) {
        let r = self.robot_description.publish(cdr);
        self.check("/robot_description", r);
    }

    /// The child frames fixed to their parents: `/tf_static` carries them, `/tf` the rest.
    pub(crate) fn set_fixed_frames(&mut self, fixed: &[String]) {
        self.fixed = fixed.to_vec();
    }

    /// `/tf`: every moving link's frame of the tick; on the first, `/tf_static` the fixed ones.
    pub(crate) fn tf(&mut self, t: u64, frames: &foxglove::schemas::FrameTransforms) {
        let fixed = std::mem::take(&mut self.fixed);
        let is_fixed = |f: &&foxglove::schemas::FrameTransform| fixed.contains(&f.child_frame_id);
        if !std::mem::replace(&mut self.static_sent, true) && !fixed.is_empty() {
            let statics: Vec<Transform<'_>> = frames.transforms.iter().filter(is_fixed).map(as_ros).collect();
            dds::ros2::encode_tf(&mut self.buf, t, statics.into_iter());
            let r = self.tf_static.publish(&self.buf);
            self.check("/tf_static", r);
        }
        let moving = frames.transforms.iter().filter(|f| !is_fixed(f)).count();
        let transforms = frames.transforms.iter().filter(|f| !is_fixed(f)).map(as_ros);
        dds::ros2::encode_tf(&mut self.buf, t, Counted(transforms, moving));
        let r = self.tf.publish(&self.buf);
        self.fixed = fixed;
        self.check("/tf", r);
    }

    /// `/diagnostics`, once a second and when the mode changes: the loop (mode, the cause of its
    /// last change, timing, joints stale or faulted, the IMU) and each bus (its time in the tick).
    pub(crate) fn diagnostics(&mut self, t: u64, r: &TickRecord) {
        let changed = self.last_mode != Some(r.mode);
        if !changed && !r.tick.is_multiple_of(DIAGNOSTICS_EVERY) {
            return;
        }
        self.last_mode = Some(r.mode);
        let mode = MODE_NAMES.get(usize::from(r.mode)).copied().unwrap_or("?");
        let cause =
            std::str::from_utf8(&r.cause[..usize::from(r.cause_len).min(r.cause.len())]).unwrap_or("");
        let joints = usize::from(r.joints).min(r.stale.len());
        let stale = r.stale[..joints].iter().filter(|&&s| s).count();
        let faulted = r.faulted[..joints].iter().filter(|&&f| f).count();
        let level = if r.cause_fault {
            Level::Error
        } else if stale + faulted > 0 || r.imu_missed > 0 {
            Level::Warn
        } else {
            Level::Ok
        };
        let message = if cause.is_empty() {
            mode.to_owned()
        } else {
            format!("{mode}: {cause}")
        };
        let numbers = [
            r.tick.to_string(),
            format!("{:.0}", r.compute_us),
            format!("{:.0}", r.io_us),
            stale.to_string(),
            faulted.to_string(),
            r.imu_missed.to_string(),
        ];
        let values = [
            ("tick", numbers[0].as_str()),
            ("compute_us", numbers[1].as_str()),
            ("io_us", numbers[2].as_str()),
            ("stale_joints", numbers[3].as_str()),
            ("faulted_joints", numbers[4].as_str()),
            ("imu_missed_reads", numbers[5].as_str()),
        ];
        let bus_us: Vec<String> = r.bus_us[..usize::from(r.buses).min(r.bus_us.len())]
            .iter()
            .map(|us| format!("{us:.0}"))
            .collect();
        let bus_names: Vec<String> = self
            .bus_names
            .iter()
            .map(|b| format!("robodeploy: bus {b}"))
            .collect();
        let bus_values: Vec<[(&str, &str); 1]> = bus_us
            .iter()
            .map(|us| [("time_in_tick_us", us.as_str())])
            .collect();
        let mut statuses = vec![Status {
            level,
            name: "robodeploy: loop",
            message: &message,
            hardware_id: &self.robot,
            values: &values,
        }];
        for ((name, values), _) in bus_names.iter().zip(&bus_values).zip(&bus_us) {
            statuses.push(Status {
                level: Level::Ok,
                name,
                message: "cycling",
                hardware_id: &self.robot,
                values,
            });
        }
        dds::ros2::encode_diagnostics(&mut self.buf, t, &statuses);
        let r = self.diagnostics.publish(&self.buf);
        self.check("/diagnostics", r);
    }
}

/// An iterator whose length is known beforehand (a filter's is not, to the type system).
struct Counted<I>(I, usize);

impl<I: Iterator> Iterator for Counted<I> {
    type Item = I::Item;
    fn next(&mut self) -> Option<Self::Item> {
        let item = self.0.next()?;
        self.1 = self.1.saturating_sub(1);
        Some(item)
    }
    fn size_hint(&self) -> (usize, Option<usize>) {
        (self.1, Some(self.1))
    }
}

impl<I: Iterator> ExactSizeIterator for Counted<I> {}

/// A recorded frame as ROS 2's transform.
fn as_ros(f: &foxglove::schemas::FrameTransform) -> Transform<'_> {
    let v = f.translation.as_ref();
    let q = f.rotation.as_ref();
    Transform {
        parent: &f.parent_frame_id,
        child: &f.child_frame_id,
        translation: v.map_or([0.0; 3], |v| [v.x, v.y, v.z]),
        rotation: q.map_or([0.0, 0.0, 0.0, 1.0], |q| [q.x, q.y, q.z, q.w]),
    }
}
