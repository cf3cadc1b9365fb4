//! The robot link: the one interface through which the loop, calibration and replay reach a robot.

use std::time::Duration;

use firmware_bridge::dxl::driver::DxlError;
use firmware_bridge::mit::driver::MitError;

use crate::clock::TickClock;
use crate::cycle::{BusStats, CycleRecord};
use crate::state::{DeviceIdentity, JointTarget, RobotState};

/// Why the buses failed as a whole (single-device trouble shows in [`RobotState`]).
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// A CAN bus failed.
    #[error("CAN")]
    Mit(#[from] MitError),
    /// A Dynamixel bus failed.
    #[error("Dynamixel")]
    Dxl(#[from] DxlError),
    /// A Feetech bus failed.
    #[error("Feetech")]
    Feetech(#[from] firmware_bridge::feetech::driver::FeetechError),
    /// The IMU stream failed.
    #[error("IMU")]
    Imu(#[from] std::io::Error),
    /// A Unitree board's DDS link failed.
    #[error("Unitree DDS link")]
    Dds(#[source] std::io::Error),
    /// A device did not answer when the buses were set up.
    #[error("{0}")]
    Silent(String),
    /// The robot description and the ports do not fit.
    #[error("{0}")]
    Setup(String),
    /// A bus's device could not be opened.
    #[error("{0}")]
    Open(String),
}

/// The robot as the loop drives it: identify, read, write, torque off. [`BusRobot`] is the real
/// thing (on hardware or a mirror); a replay feeds a recording through the same loop.
pub trait RobotLink: std::fmt::Debug {
    /// Checks every device answers with the right identity; leaves them limp.
    fn identify(&mut self) -> Result<(), IoError>;
    /// Reads every bus and the IMU into `state`.
    fn read(&mut self, state: &mut RobotState) -> Result<(), IoError>;
    /// Sends every joint its target (robot order).
    fn write(&mut self, targets: &[JointTarget]) -> Result<(), IoError>;
    /// Lets time pass until `deadline` on `clock` (the links whose buses cycle in the loop's own
    /// thread serve them on the way); returns whether the deadline had passed already.
    fn wait_until(&mut self, clock: &mut dyn TickClock, deadline: Duration) -> bool {
        clock.wait_until(deadline)
    }
    /// Torque off everywhere.
    fn torque_off(&mut self) -> Result<(), IoError>;
    /// Who each device says it is (after [`Self::identify`]), robot bus order.
    fn identities(&mut self) -> Result<Vec<DeviceIdentity>, IoError> {
        Err(IoError::Setup(
            "this link cannot ask its devices who they are".into(),
        ))
    }
    /// Bus names, in the order of [`Self::bus_times`].
    fn bus_names(&self) -> &[String] {
        &[]
    }
    /// Time each bus's newest cycle took.
    fn bus_times(&self) -> &[Duration] {
        &[]
    }
    /// What each bus did so far (cycles, overruns, cycle times, self-damping), as of the last read.
    fn bus_stats(&self) -> &[BusStats] {
        &[]
    }
    /// Cycles in a row a joint may stay silent before its bus damps itself (default
    /// [`crate::STALE_CYCLES`]; at least 1).
    fn set_stale_cycles(&mut self, _cycles: u32) {}
    /// Asks every bus to record each of its cycles for telemetry, keeping up to `capacity` per
    /// bus until [`Self::drain_cycles`] takes them (before the devices are identified); false
    /// when this link has no bus cycles to record.
    fn record_cycles(&mut self, _capacity: usize) -> bool {
        false
    }
    /// Hands each cycle recorded since the last call to `sink`; returns the records lost so far
    /// because they were not taken in time.
    fn drain_cycles(&mut self, _sink: &mut dyn FnMut(&CycleRecord)) -> u64 {
        0
    }
}

/// What kind of failure an error is: what the safety layer and the exit status go by.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ErrorKind {
    /// A file, flag or value is wrong; nothing was moved.
    BadInput,
    /// A bus, wire, socket or file system failed.
    Io,
    /// A device is missing, faulted, or not the configured model.
    Device,
    /// Something the run needs is not there (a native library, a thread).
    Unavailable,
}

impl IoError {
    /// What kind of failure this is.
    pub fn kind(&self) -> ErrorKind {
        use firmware_bridge::dxl::driver::DxlError as D;
        use firmware_bridge::feetech::driver::FeetechError as F;
        use firmware_bridge::mit::driver::MitError as M;
        match self {
            Self::Mit(M::NoReply { .. })
            | Self::Dxl(D::Fault(_) | D::Scan(_))
            | Self::Feetech(F::NoReply { .. } | F::WrongModel { .. }) => ErrorKind::Device,
            Self::Mit(M::Config { .. } | M::Command { .. } | M::CommandCount { .. })
            | Self::Dxl(D::Config(_))
            | Self::Feetech(F::Config { .. } | F::NotFinite { .. } | F::CommandCount { .. }) => {
                ErrorKind::BadInput
            }
            Self::Silent(_) => ErrorKind::Device,
            Self::Mit(_) | Self::Dxl(_) | Self::Feetech(_) | Self::Imu(_) | Self::Dds(_) | Self::Open(_) => {
                ErrorKind::Io
            }
            Self::Setup(_) => ErrorKind::BadInput,
        }
    }
}

/// The message of an error and of every error under it, joined by ": ".
pub fn message_chain(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut source = e.source();
    while let Some(inner) = source {
        s.push_str(": ");
        s.push_str(&inner.to_string());
        source = inner.source();
    }
    s
}
