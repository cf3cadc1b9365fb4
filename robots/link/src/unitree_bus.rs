//! A Unitree robot's board as one bus of joints: each cycle one `LowCmd` for all its motors and
//! the newest `LowState` taken. The board publishes states at its own rate whether commanded or
//! not, so a cycle takes the newest it has and never waits; a cycle without a fresh state (none
//! arrived, or its CRC was wrong) counts as missed for every joint, and a motor's error bits are
//! a fault. The IMU in each fresh state goes to the IMU cycle through a triple buffer.

use std::time::Duration;

use firmware_bridge::mit::driver::JointCommand;
use firmware_bridge::unitree::host::{HgDriver, LowLevelPort};
use triple_buffer::Input;

use crate::bus_robot::JointBus;
use crate::imu_cycle::BoardImu;
use crate::link::IoError;
use crate::state::{DeviceIdentity, JointTarget, RobotState};

/// How long identification waits for the board's first state.
const FIRST_STATE: Duration = Duration::from_millis(500);

/// The board's joints and, where the robot's IMU is the board's, where its samples go.
#[derive(Debug)]
pub(crate) struct HgBus<P> {
    pub(crate) driver: HgDriver<P>,
    pub(crate) joints: Vec<usize>,
    pub(crate) commands: Vec<Option<JointCommand>>,
    pub(crate) imu: Option<Input<BoardImu>>,
    /// Where the bus's states come from, for errors (`rt/lowstate on eth0, domain 0`).
    pub(crate) source: String,
}

impl<P: LowLevelPort> HgBus<P> {
    fn hand_over_imu(&mut self) {
        let Some(out) = &mut self.imu else { return };
        let (imu, count) = self.driver.imu();
        let widen = |from: &[f32], to: &mut [f64]| {
            for (t, f) in to.iter_mut().zip(from) {
                *t = f64::from(*f);
            }
        };
        let mut sample = firmware_bridge::imu::wit::ImuSample {
            temperature: f64::from(imu.temperature),
            ..Default::default()
        };
        widen(&imu.quaternion, &mut sample.quat);
        widen(&imu.gyroscope, &mut sample.gyro);
        widen(&imu.accelerometer, &mut sample.accel);
        widen(&imu.rpy, &mut sample.rpy);
        *out.input_buffer_mut() = BoardImu { sample, count };
        out.publish();
    }
}

impl<P: LowLevelPort> JointBus for HgBus<P> {
    fn identify(&mut self) -> Result<(), IoError> {
        self.commands.fill(None);
        self.driver.send(&self.commands).map_err(IoError::Dds)?;
        if !self.driver.wait_first(FIRST_STATE).map_err(IoError::Dds)? {
            let s = self.driver.stats();
            return Err(IoError::Silent(format!(
                "no LowState from the robot's board on {} within {} ms ({} with a wrong CRC, {} malformed): \
                 is the robot on, on this interface and domain?",
                self.source,
                FIRST_STATE.as_millis(),
                s.bad_crc,
                s.malformed
            )));
        }
        self.hand_over_imu();
        Ok(())
    }

    fn sample(&mut self, state: &mut RobotState) -> Result<(), IoError> {
        for (f, &i) in self.driver.feedback().iter().zip(&self.joints) {
            state.q[i] = f.q;
            state.qd[i] = f.qd;
            state.tau[i] = f.tau;
            state.missed[i] = f.missed_cycles;
            state.faulted[i] = f.faulted();
        }
        Ok(())
    }

    fn send(&mut self, targets: &[JointTarget]) -> Result<(), IoError> {
        for (c, &i) in self.commands.iter_mut().zip(&self.joints) {
            let t = targets[i];
            *c = t.enabled.then_some(JointCommand {
                q: t.q,
                qd: t.qd,
                kp: t.kp,
                kd: t.kd,
                tau: t.tau,
            });
        }
        self.driver.send(&self.commands).map_err(IoError::Dds)
    }

    fn receive(&mut self, state: &mut RobotState) -> Result<(), IoError> {
        if self.driver.receive().map_err(IoError::Dds)? {
            self.hand_over_imu();
        }
        self.sample(state)
    }

    fn torque_off(&mut self) -> Result<(), IoError> {
        self.commands.fill(None);
        self.driver.send(&self.commands).map_err(IoError::Dds)
    }

    fn identities(&mut self, bus: &str, out: &mut Vec<DeviceIdentity>) -> Result<(), IoError> {
        let version = self.driver.state().version;
        for (j, f) in self.driver.joints().iter().zip(self.driver.feedback()) {
            let answer = if f.missed_cycles > 0 {
                "no state".into()
            } else {
                format!(
                    "motor {} in the board's state: status {:#010x}, {:.0} °C (board version {}.{})",
                    j.motor_id, f.status, f.temperature, version[0], version[1]
                )
            };
            out.push(DeviceIdentity {
                joint: j.name.clone(),
                bus: bus.to_owned(),
                id: j.motor_id,
                model: j.model.name.clone(),
                answer,
                firmware: None,
                current_limit_a: None,
                torque_limit_nm: j.model.t_max,
            });
        }
        Ok(())
    }
}
