//! The host side of a mirror in lockstep: the real bus drivers of `firmware-bridge` on the mirror's
//! ports, set up from the robot description. Tests, benches and bench-top tools use it to drive
//! the mirror exactly as the controller drives hardware.

use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use firmware_bridge::can::virtual_bus::{LockstepCanPort, SimWorld};
use firmware_bridge::dxl::driver::{DxlBusDriver, DxlCommand, DxlDriverOptions, DxlError};
use firmware_bridge::dxl::transport::LockstepDxlPort;
use firmware_bridge::imu::reader::ImuReader;
use firmware_bridge::mit::driver::{JointCommand, MitBusDriver, MitError};
use firmware_bridge::serial::LockstepStream;
use robots::{Robot, drivers};

use crate::config::MirrorConfig;
use crate::mirror::{Mirror, MirrorError};

/// Why the host side could not start.
#[derive(Debug, thiserror::Error)]
pub enum HostError {
    /// The mirror could not be built.
    #[error(transparent)]
    Mirror(#[from] MirrorError),
    /// A CAN driver failed.
    #[error("CAN")]
    Mit(#[from] MitError),
    /// A Dynamixel driver failed.
    #[error("Dynamixel")]
    Dxl(#[from] DxlError),
}

/// Drivers on every bus of a mirror, with the policy index of each driver's joints.
#[derive(Debug)]
pub struct MirrorHost {
    /// The mirror, shared with the ports.
    pub world: Arc<Mutex<Mirror>>,
    /// One MIT driver per CAN bus.
    pub mit: Vec<(MitBusDriver<LockstepCanPort<Mirror>>, Vec<usize>)>,
    /// One Dynamixel driver per serial bus.
    pub dxl: Vec<(DxlBusDriver<LockstepDxlPort<Mirror>>, Vec<usize>)>,
    /// The IMU reader.
    pub imu: ImuReader<LockstepStream<Mirror>>,
    mit_commands: Vec<Vec<JointCommand>>,
    dxl_commands: Vec<Vec<DxlCommand>>,
}

impl MirrorHost {
    /// Builds the mirror of `robot`, and the drivers on its buses; checks, configures and enables
    /// every actuator.
    pub fn start(robot: Robot, config: MirrorConfig) -> Result<Self, HostError> {
        let world = Arc::new(Mutex::new(Mirror::new(robot.clone(), config)?));
        let ports = Mirror::host_ports(&world);
        let mut mit = Vec::new();
        for (name, port) in ports.can {
            let (idx, joints): (Vec<_>, Vec<_>) = robot
                .joints_on(&name)
                .map(|(i, j)| (i, drivers::mit_joint(j)))
                .unzip();
            let mut d = MitBusDriver::new(port, joints, Duration::from_millis(2))?;
            d.enable_all()?;
            mit.push((d, idx));
        }
        let mut dxl = Vec::new();
        for (name, port) in ports.dxl {
            let (idx, joints): (Vec<_>, Vec<_>) = robot
                .joints_on(&name)
                .map(|(i, j)| (i, drivers::dxl_joint(j)))
                .unzip();
            let options = DxlDriverOptions {
                expected_return_delay: Duration::ZERO,
                ..DxlDriverOptions::default()
            };
            let mut d = DxlBusDriver::new(port, joints, options)?;
            d.configure()?;
            d.enable()?;
            dxl.push((d, idx));
        }
        let mit_commands = mit
            .iter()
            .map(|(_, idx)| vec![JointCommand::default(); idx.len()])
            .collect();
        let dxl_commands = dxl
            .iter()
            .map(|(_, idx)| vec![DxlCommand::default(); idx.len()])
            .collect();
        Ok(Self {
            world,
            mit,
            dxl,
            imu: ImuReader::new(ports.imu),
            mit_commands,
            dxl_commands,
        })
    }

    /// One control tick: sends every joint its target `q` (policy order) with the robot's PD
    /// gains, reads every bus and the IMU.
    pub fn command_positions(&mut self, robot: &Robot, q: &[f64]) -> Result<(), HostError> {
        let joints = &robot.config.joints;
        for ((d, idx), cmds) in self.mit.iter_mut().zip(&mut self.mit_commands) {
            for (c, &i) in cmds.iter_mut().zip(idx.iter()) {
                *c = JointCommand {
                    q: q[i],
                    qd: 0.0,
                    kp: joints[i].kp,
                    kd: joints[i].kd,
                    tau: 0.0,
                };
            }
            d.cycle(cmds)?;
        }
        for ((d, idx), cmds) in self.dxl.iter_mut().zip(&mut self.dxl_commands) {
            for (c, &i) in cmds.iter_mut().zip(idx.iter()) {
                let model = firmware_bridge::dxl::models::find(&joints[i].model);
                *c = DxlCommand {
                    q: q[i],
                    // Current-sensing servos run current-based position control: cap at the limit.
                    current: model.map_or(0.0, |m| drivers::goal_current_for(joints[i].torque_limit, m)),
                };
            }
            d.cycle(cmds)?;
        }
        // A failing IMU read leaves the last sample in place; the caller sees its age.
        let _ = self.imu.poll();
        Ok(())
    }

    /// Runs the mirror until `period` after `since` (the rest of a control tick).
    pub fn wait_until(&self, deadline: firmware_bridge::time::SimInstant) {
        let mut w = self.world.lock().unwrap_or_else(PoisonError::into_inner);
        while w.now() < deadline {
            w.step_until(deadline);
        }
    }

    /// The mirror's clock.
    pub fn now(&self) -> firmware_bridge::time::SimInstant {
        self.world.lock().unwrap_or_else(PoisonError::into_inner).now()
    }
}
