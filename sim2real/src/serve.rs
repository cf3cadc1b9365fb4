//! The mirror in wall-clock time behind real wires: each CAN bus on a socketcand server, each
//! Dynamixel line and the IMU on a pseudo-terminal, each Unitree board on DDS. An unmodified
//! controller connects to it as to hardware (`robodeploy sim serve`).

use std::net::{IpAddr, SocketAddr};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use dds::DdsConfig;
use firmware_bridge::can::socketcand::SocketcandServer;
use firmware_bridge::serial::PtyServer;
use firmware_bridge::time::WallClockRunner;
use firmware_bridge::unitree::wire::BoardServer;

use crate::mirror::Mirror;

/// The interface a served mirror's DDS stays on unless told otherwise.
pub const LOOPBACK: &str = "lo";

/// Where each bus of a served mirror can be reached.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Endpoints {
    /// CAN buses: name and socketcand address.
    pub can: Vec<(String, SocketAddr)>,
    /// Dynamixel buses: name and device path.
    pub dxl: Vec<(String, String)>,
    /// Feetech buses: name and device path.
    pub feetech: Vec<(String, String)>,
    /// The IMU's device path (`None`: the IMU is a Unitree board's).
    pub imu: Option<String>,
    /// Unitree boards: name, and the interface and domain their DDS link is on.
    pub unitree: Vec<(String, DdsConfig)>,
}

/// A mirror running in real time behind its wires; stops when dropped.
#[derive(Debug)]
pub struct ServedMirror {
    /// The mirror (lock briefly: the wires step it).
    pub world: Arc<Mutex<Mirror>>,
    endpoints: Endpoints,
    // Kept for their threads; dropped (stopped) with the server.
    _runner: WallClockRunner,
    /// How long the host keeps the mirror's threads off the CPU.
    probe: firmware_bridge::time::StarvationProbe,
    _can: Vec<SocketcandServer>,
    _ptys: Vec<PtyServer>,
    _boards: Vec<BoardServer>,
}

impl ServedMirror {
    /// Serves `mirror`: socketcand servers on `ip` (ports from `first_port` up, 0 for any free
    /// port), pseudo-terminals for the serial lines, DDS for the Unitree boards on the loopback
    /// interface (each in its bus's domain).
    pub fn start(mirror: Mirror, ip: IpAddr, first_port: u16) -> std::io::Result<Self> {
        Self::start_on(mirror, ip, first_port, LOOPBACK)
    }

    /// [`Self::start`], the Unitree boards' DDS on network interface `dds_interface`.
    pub fn start_on(
        mirror: Mirror,
        ip: IpAddr,
        first_port: u16,
        dds_interface: &str,
    ) -> std::io::Result<Self> {
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
        let imu_on_board = mirror
            .robot()
            .bus(&mirror.robot().config.imu.bus)
            .is_some_and(|b| b.kind == robots::BusKind::UnitreeDds);
        let boards: Vec<_> = mirror
            .robot()
            .config
            .buses
            .iter()
            .filter_map(|b| {
                let line = mirror.unitree_line(&b.name)?;
                let config = DdsConfig {
                    domain: b.domain.unwrap_or(0),
                    interface: dds_interface.to_owned(),
                };
                Some((b.name.clone(), line, config))
            })
            .collect();
        let world = Arc::new(Mutex::new(mirror));
        let runner = WallClockRunner::spawn(Arc::clone(&world), Duration::from_micros(200))?;
        let probe = firmware_bridge::time::StarvationProbe::spawn()?;
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
        let imu = if imu_on_board {
            None
        } else {
            let imu_pty = PtyServer::spawn(Arc::clone(&world), imu_line, Duration::from_micros(500))?;
            let path = imu_pty.path().to_owned();
            ptys.push(imu_pty);
            Some(path)
        };
        let mut board_servers = Vec::new();
        let mut unitree = Vec::new();
        for (name, line, config) in boards {
            let server = BoardServer::spawn(Arc::clone(&world), line, &config)
                .map_err(|e| std::io::Error::other(format!("board {name}: {e}")))?;
            board_servers.push(server);
            unitree.push((name, config));
        }
        Ok(Self {
            world,
            endpoints: Endpoints {
                can: can_endpoints,
                dxl,
                feetech,
                imu,
                unitree,
            },
            _runner: runner,
            probe,
            _can: can,
            _ptys: ptys,
            _boards: board_servers,
        })
    }

    /// Reads how long the host keeps the mirror's threads waiting for the CPU.
    pub fn starvation(&self) -> firmware_bridge::time::StarvationReader {
        self.probe.reader()
    }

    /// Where the buses are.
    pub fn endpoints(&self) -> &Endpoints {
        &self.endpoints
    }
}
