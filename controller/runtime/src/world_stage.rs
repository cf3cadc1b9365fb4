//! The world stage of a run: each tick it turns what the robot reported into where the robot is
//! — its kinematics, the estimator's correction from the legs, or the simulation's ground truth —
//! the one place the observation and the metrics read it from.

use robot_link::{GroundTruth, RobotState};
use robots::spatial;
use world::RobotKinematics;
use world::estimator::{Estimate, Estimator, MAX_FEET};

use crate::keypoints::track::KeypointTrack;
use crate::metrics::RunMetrics;
use crate::motion::Alignment;

/// The world stage of a run: where the robot is, from its kinematics and the estimator or the
/// simulation's ground truth, and its keypoints through the cameras.
#[derive(Debug)]
pub(crate) struct WorldStage {
    /// The robot's anchor, bodies, feet and root rate through its model (when it has feet or
    /// the policy needs them).
    pub(crate) kinematics: Option<RobotKinematics>,
    /// The state estimator, for a robot with feet.
    pub(crate) estimator: Option<Estimator>,
    /// 2D keypoint references, when the run has them; and whether this tick measured them.
    pub(crate) keypoints: Option<KeypointTrack>,
    pub(crate) keypoints_measured: bool,
    /// Its estimate this tick.
    pub(crate) estimate: Estimate,
    /// The robot's place in the world as the observation reads it: the estimate, or the
    /// simulation's ground truth with `--estimator ground-truth`; and whether it is usable.
    pub(crate) observed: GroundTruth,
    pub(crate) world_valid: bool,
    /// The policy observes the robot's place in the world (decided once, at start).
    pub(crate) reads_world: bool,
    /// Ground truth (simulation) into the estimate's world: where the estimator started, for
    /// the tracking metrics, which compare the true robot with a reference placed by the
    /// estimate.
    pub(crate) truth_to_world: Alignment,
    pub(crate) truth_mapped: bool,
    pub(crate) truth: GroundTruth,
}

impl WorldStage {
    /// The robot's place in the world this tick: the kinematics posed from the measured joints
    /// and IMU, the estimator fed every IMU sample since the last tick and corrected by the legs,
    /// then what the observation reads — the estimate, or ground truth when the run asks for it.
    pub(crate) fn update(
        &mut self,
        state: &RobotState,
        has_truth: bool,
        ground_truth: bool,
        rig_holds: bool,
        imu_stale_ticks: u32,
        metrics: &mut RunMetrics,
    ) {
        let Some(k) = &mut self.kinematics else {
            self.world_valid = has_truth;
            if has_truth {
                self.observed.clone_from(&self.truth);
            }
            return;
        };
        k.update(state.quat, &state.q, &state.qd, None);
        if let Some(e) = &mut self.estimator {
            // The first tick's read may bring no sample yet: the IMU's start-up reading starts
            // the filter then (a policy in control from tick 0 reads the estimate at tick 0).
            if state.imu_samples.is_empty() {
                e.seed_attitude(state.quat, state.gyro, state.accel);
            }
            e.hold_by_rig(rig_holds);
            for sample in &state.imu_samples {
                e.propagate(sample);
            }
            let mut legs = k.legs(&state.tau);
            // Foot switches where the robot has them (robot.toml [[contacts]], one per foot).
            if state.foot_switches.len() == k.feet() && k.feet() <= MAX_FEET {
                let mut switches = [false; MAX_FEET];
                switches[..k.feet()].copy_from_slice(&state.foot_switches);
                legs.switches = Some(switches);
            }
            self.estimate = e.correct(&legs, state.imu_missed <= imu_stale_ticks);
        }
        if ground_truth || self.estimator.is_none() {
            self.world_valid = has_truth;
            if has_truth {
                self.observed.clone_from(&self.truth);
            }
        } else {
            let (p, q) = (self.estimate.position, k.root_rotation());
            self.observed.root_pose = [p[0], p[1], p[2], q[0], q[1], q[2], q[3]];
            self.observed.base_lin_vel = self.estimate.velocity_base;
            for (c, e) in self
                .observed
                .foot_contacts
                .iter_mut()
                .zip(&self.estimate.contacts)
            {
                *c = *e;
            }
            self.observed.simulation_failed = false;
            // Held in the air, the estimate has no ground to be compared on; the filter starts
            // again on landing, and the truth is mapped into its world from there.
            let on_ground = self.estimate.valid && !self.estimate.held;
            if self.estimate.held {
                self.truth_mapped = false;
                metrics.add_held_tick();
            }
            if has_truth && on_ground && !self.truth_mapped {
                self.truth_to_world = Alignment::new(self.truth.root_pose, self.observed.root_pose, true);
                self.truth_mapped = true;
            }
            if has_truth && on_ground {
                let t = self.truth_to_world.apply(self.truth.root_pose);
                let velocity = spatial::quat_rotate([t[3], t[4], t[5], t[6]], self.truth.base_lin_vel);
                metrics.add_estimate(
                    &self.estimate,
                    [t[0], t[1], t[2]],
                    velocity,
                    &self.truth.foot_contacts,
                );
            }
            self.world_valid = self.estimate.valid;
        }
        let p = self.observed.root_pose;
        k.set_root_position(self.world_valid.then_some([p[0], p[1], p[2]]));
    }
}
