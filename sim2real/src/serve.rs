//! The mirror in wall-clock time behind real wires: each CAN bus on a socketcand server, each
//! Dynamixel line and the IMU on a pseudo-terminal. An unmodified controller connects to it as to
//! hardware (`robodeploy sim serve`).

use std::net::{IpAddr, SocketAddr};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use firmware_bridge::can::socketcand::SocketcandServer;
use firmware_bridge::serial::PtyServer;
use firmware_bridge::time::WallClockRunner;

use crate::mirror::Mirror;

/// Where each bus of a served mirror can be reached.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Endpoints {
    /// CAN buses: name and socketcand address.
    pub can: Vec<(String, SocketAddr)>,
    /// Dynamixel buses: name and device path.
    pub dxl: Vec<(String, String)>,
    /// Feetech buses: name and device path.
    pub feetech: Vec<(String, String)>,
    /// The IMU's device path.
    pub imu: String,
}

/// A mirror running in real time behind its wires; stops when dropped.
#[derive(Debug)]
pub struct ServedMirror {
    /// The mirror (lock briefly: the wires step it).
    pub world: Arc<Mutex<Mirror>>,
    endpoints: Endpoints,
    // Kept for their threads; dropped (stopped) with the server.
    _runner: WallClockRunner,
    _can: Vec<SocketcandServer>,
    _ptys: Vec<PtyServer>,
}

impl ServedMirror {
    /// Serves `mirror`: socketcand servers on `ip` (ports from `first_port` up, 0 for any free
    /// port), pseudo-terminals for the serial lines.
    pub fn start(mirror: Mirror, ip: IpAddr, first_port: u16) -> std::io::Result<Self> {
        let names: Vec<String> = mirror
            .robot()
            .config
            .buses
            .iter()
            .map(|b| b.name.clone())
            .collect();
        let can_buses: Vec<_> = names
            .iter()
            .filter_map(|n| mirror.can_bus(n).map(|b| (n.clone(), b.clone())))
            .collect();
        let dxl_lines: Vec<_> = names
            .iter()
            .filter_map(|n| mirror.dxl_line(n).map(|l| (n.clone(), l)))
            .collect();
        let feetech_lines: Vec<_> = names
            .iter()
            .filter_map(|n| mirror.feetech_line(n).map(|l| (n.clone(), l)))
            .collect();
        let imu_line = mirror.imu_line();
        let world = Arc::new(Mutex::new(mirror));
        let runner = WallClockRunner::spawn(Arc::clone(&world), Duration::from_micros(200))?;
        let start = std::time::Instant::now();
        let mut can = Vec::new();
        let mut can_endpoints = Vec::new();
        for (i, (name, bus)) in can_buses.into_iter().enumerate() {
            let port = match first_port {
                0 => 0,
                first => u16::try_from(usize::from(first) + i).map_err(|_| {
                    std::io::Error::new(
                        std::io::ErrorKind::InvalidInput,
                        format!("port {first} + {i}: the CAN buses' ports run past 65535"),
                    )
                })?,
            };
            let server =
                SocketcandServer::spawn(SocketAddr::new(ip, port), &name, bus.attach(), move || {
                    start.elapsed()
                })?;
            can_endpoints.push((name, server.local_addr()));
            can.push(server);
        }
        let mut ptys = Vec::new();
        let mut dxl = Vec::new();
        for (name, line) in dxl_lines {
            let pty = PtyServer::spawn(Arc::clone(&world), line, Duration::from_micros(200))?;
            dxl.push((name, pty.path().to_owned()));
            ptys.push(pty);
        }
        let mut feetech = Vec::new();
        for (name, line) in feetech_lines {
            let pty = PtyServer::spawn(Arc::clone(&world), line, Duration::from_micros(200))?;
            feetech.push((name, pty.path().to_owned()));
            ptys.push(pty);
        }
        let imu_pty = PtyServer::spawn(Arc::clone(&world), imu_line, Duration::from_micros(500))?;
        let imu = imu_pty.path().to_owned();
        ptys.push(imu_pty);
        Ok(Self {
            world,
            endpoints: Endpoints {
                can: can_endpoints,
                dxl,
                feetech,
                imu,
            },
            _runner: runner,
            _can: can,
            _ptys: ptys,
        })
    }

    /// Where the buses are.
    pub fn endpoints(&self) -> &Endpoints {
        &self.endpoints
    }
}
