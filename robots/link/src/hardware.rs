//! The robot's own buses, opened from the devices robot.toml names: SocketCAN interfaces for the
//! MIT motors, serial devices for the Dynamixel servos and the IMU, DDS on a network interface for
//! a Unitree robot's board.

use std::time::Duration;

use firmware_bridge::can::socketcan::SocketCanBus;
use firmware_bridge::dxl::driver::DxlDriverOptions;
use firmware_bridge::dxl::transport::SerialDxlPort;
use firmware_bridge::feetech::driver::SerialFeetechPort;
use firmware_bridge::serial::DeviceStream;
use firmware_bridge::unitree::wire::DdsLowLevelPort;
use robots::{BusKind, Robot};

use crate::bus_robot::{BusPorts, BusRobot};
use crate::link::IoError;

/// The hardware robot's buses.
pub type HardwareRobot = BusRobot<DeviceStream>;

/// Opens every bus of `robot` (nothing is sent yet), its buses on their own threads. Errors name
/// the bus and device.
pub fn open(robot: &Robot) -> Result<HardwareRobot, IoError> {
    open_with(robot, || {})
}

/// [`open`], running `on_start` first on each bus thread (real-time set-up of the thread).
pub fn open_with(robot: &Robot, on_start: fn()) -> Result<HardwareRobot, IoError> {
    // Each bus cycles on its own thread, at its own rate.
    open_sequential(robot)?.parallel_with(on_start)
}

/// Opens every bus of `robot`, serviced one after another (tools that need the drivers themselves,
/// such as calibration).
pub fn open_sequential(robot: &Robot) -> Result<HardwareRobot, IoError> {
    let mut can = Vec::new();
    let mut dxl = Vec::new();
    let mut feetech = Vec::new();
    let mut unitree = Vec::new();
    let mut imu = None;
    for bus in &robot.config.buses {
        let fail = |e: &dyn std::fmt::Display| {
            IoError::Open(format!("bus {} ({}): cannot open: {e}", bus.name, bus.device))
        };
        match bus.kind {
            BusKind::MitCan => can.push((
                bus.name.clone(),
                SocketCanBus::open(&bus.device).map_err(|e| fail(&e))?,
            )),
            BusKind::Dynamixel => dxl.push((
                bus.name.clone(),
                SerialDxlPort::open(&bus.device, bus.rate).map_err(|e| fail(&e))?,
            )),
            BusKind::Feetech => feetech.push((
                bus.name.clone(),
                SerialFeetechPort::open(&bus.device, bus.rate).map_err(|e| fail(&e))?,
            )),
            BusKind::ImuSerial if bus.name == robot.config.imu.bus => {
                imu = Some(DeviceStream::open(&bus.device, bus.rate).map_err(|e| fail(&e))?);
            }
            BusKind::ImuSerial => {}
            BusKind::UnitreeDds => {
                let config = dds::DdsConfig {
                    domain: bus.domain.unwrap_or(0),
                    interface: bus.device.clone(),
                };
                let port = DdsLowLevelPort::open(&config).map_err(|e| match e {
                    dds::DdsError::Interface { .. } => IoError::Open(format!(
                        "bus {} (robot.toml buses.device = {:?}): {e}",
                        bus.name, bus.device
                    )),
                    dds::DdsError::Domain(_) => {
                        IoError::Setup(format!("bus {} (robot.toml buses.domain): {e}", bus.name))
                    }
                    e => fail(&e),
                })?;
                unitree.push((bus.name.clone(), port));
            }
        }
    }
    let imu_on_board = robot
        .bus(&robot.config.imu.bus)
        .is_some_and(|b| b.kind == BusKind::UnitreeDds);
    if imu.is_none() && !imu_on_board {
        return Err(IoError::Setup(format!(
            "IMU bus {} not found",
            robot.config.imu.bus
        )));
    }
    // USB adapters: the FTDI latency timer should be 1 ms; leave margin for it.
    let options = DxlDriverOptions {
        reply_slack: Duration::from_millis(3),
        ..DxlDriverOptions::default()
    };
    let link = BusRobot::new(
        robot,
        BusPorts {
            can,
            dxl,
            feetech,
            unitree,
            imu,
        },
        Duration::from_millis(2),
        options,
    )?;
    // Foot switches on GPIO lines, where robot.toml has them.
    Ok(match crate::contacts::GpioContacts::open(robot)? {
        Some(switches) => link.with_contacts(Box::new(switches)),
        None => link,
    })
}
