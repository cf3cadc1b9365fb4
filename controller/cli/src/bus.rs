//! `robodeploy bus scan`: every bus of a robot, compared with its robot.toml.

use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use firmware_bridge::can::CanBus;
use firmware_bridge::can::socketcan::SocketCanBus;
use firmware_bridge::can::socketcand::SocketcandClient;
use firmware_bridge::dxl::transport::{DxlTransport, SerialDxlPort};
use firmware_bridge::feetech::driver::SerialFeetechPort;
use firmware_bridge::imu::reader::ImuReader;
use firmware_bridge::serial::{ByteStream, DeviceStream};
use firmware_bridge::unitree::board::motor_bits;
use firmware_bridge::unitree::hg::{LowState, Sealed as _};
use firmware_bridge::unitree::host::LowLevelPort as _;
use firmware_bridge::unitree::wire::DdsLowLevelPort;
use firmware_bridge::{dxl, feetech, mit};
use robots::{BusKind, Robot};

/// Bus tools across a whole robot.
#[derive(Debug, Subcommand)]
pub enum BusCommand {
    /// List the devices on every bus of a robot and compare them with robot.toml: missing,
    /// unexpected and wrong-model devices, and the IMU's sample rate. Only asks (MIT motors get a
    /// torque-off frame, servos pings and reads); nothing moves.
    ///
    /// By default it opens the devices robot.toml names (the hardware); --sim serves the robot's
    /// mirror locally and scans that, over the same wires.
    Scan(ScanArgs),
}

/// Arguments of `bus scan`.
#[derive(Debug, Args)]
pub struct ScanArgs {
    /// The robot description.
    #[arg(long, default_value_os_t = robots::locate::default_robot())]
    robot: std::path::PathBuf,
    /// Scan the robot's mirror, served locally, instead of the hardware.
    #[arg(long)]
    sim: bool,
    /// How long to wait for each answer, ms.
    #[arg(long, default_value_t = 20, value_parser = crate::args::whole_within(1, 10_000))]
    timeout_ms: u64,
}

/// Runs a `bus` subcommand.
pub fn run(cmd: BusCommand) -> Result<()> {
    match cmd {
        BusCommand::Scan(args) => scan(&args),
    }
}

fn scan(args: &ScanArgs) -> Result<()> {
    let robot = Robot::load(&args.robot)?;
    let timeout = Duration::from_millis(args.timeout_ms);
    let served = if args.sim {
        let mirror = sim2real::mirror::Mirror::new(robot.clone(), sim2real::config::MirrorConfig::default())?;
        Some(sim2real::link::serve_locally(mirror).context("cannot serve the mirror")?)
    } else {
        None
    };
    let mut problems = 0;
    for bus in &robot.config.buses {
        let endpoint = served.as_ref().map(|s| s.endpoints());
        match bus.kind {
            BusKind::MitCan => {
                let found = match endpoint.and_then(|e| e.can.iter().find(|c| c.0 == bus.name)) {
                    Some((_, addr)) => scan_mit(
                        &robot,
                        &bus.name,
                        &mut SocketcandClient::connect(addr, &bus.name, Duration::from_secs(2))?,
                        timeout,
                    )?,
                    None => scan_mit(&robot, &bus.name, &mut SocketCanBus::open(&bus.device)?, timeout)?,
                };
                problems += found;
            }
            BusKind::Dynamixel => {
                let path = endpoint
                    .and_then(|e| e.dxl.iter().find(|d| d.0 == bus.name))
                    .map_or(bus.device.clone(), |d| d.1.clone());
                let mut port = SerialDxlPort::open(&path, bus.rate)
                    .with_context(|| format!("bus {}: cannot open {path}", bus.name))?;
                problems += scan_dxl(&robot, &bus.name, &mut port, timeout)?;
            }
            BusKind::Feetech => {
                let path = endpoint
                    .and_then(|e| e.feetech.iter().find(|d| d.0 == bus.name))
                    .map_or(bus.device.clone(), |d| d.1.clone());
                let port = SerialFeetechPort::open(&path, bus.rate)
                    .with_context(|| format!("bus {}: cannot open {path}", bus.name))?;
                problems += scan_feetech(&robot, &bus.name, port, timeout)?;
            }
            BusKind::UnitreeDds => {
                let config = match endpoint.and_then(|e| e.unitree.iter().find(|u| u.0 == bus.name)) {
                    Some((_, c)) => c.clone(),
                    None => dds::DdsConfig {
                        domain: bus.domain.unwrap_or(0),
                        interface: bus.device.clone(),
                    },
                };
                let port = DdsLowLevelPort::open(&config).with_context(|| {
                    format!(
                        "bus {} (robot.toml buses.device {:?}, domain {})",
                        bus.name, bus.device, config.domain
                    )
                })?;
                problems += scan_unitree(&robot, &bus.name, port, &config)?;
            }
            BusKind::ImuSerial => {
                let Some(path) = endpoint.map_or(Some(bus.device.clone()), |e| e.imu.clone()) else {
                    continue;
                };
                let stream = DeviceStream::open(&path, bus.rate)
                    .with_context(|| format!("bus {}: cannot open {path}", bus.name))?;
                problems += scan_imu(&bus.name, stream, &robot.config.imu)?;
            }
        }
    }
    if problems == 0 {
        println!("every device of {} answered as configured", robot.config.name);
        Ok(())
    } else {
        anyhow::bail!("{problems} device(s) differ from {}", robot.path.display())
    }
}

/// The bus's schedule from robot.toml: what the loop will run it at, and the command timeout the
/// devices must be set to (the loop arms the Dynamixel Bus Watchdog with it; MIT motors keep
/// theirs in their firmware, set with the vendor's tool).
pub(crate) fn schedule(robot: &Robot, bus: &str) -> Option<String> {
    let t = robot.bus_timing(bus)?;
    if robot.bus(bus)?.kind == BusKind::ImuSerial {
        return Some(format!(
            "polled at {} Hz (the IMU streams at {} Hz)",
            robots::num(t.rate_hz),
            robots::num(robot.config.imu.rate_hz)
        ));
    }
    let mut line = format!(
        "cycles at {} Hz ({:.2} ms of {:.2} ms on the wire, {:.0} % load{})",
        robots::num(t.rate_hz),
        t.wire_time.as_secs_f64() * 1e3,
        t.period.as_secs_f64() * 1e3,
        t.load() * 100.0,
        if robot.bus(bus)?.fast_reads {
            ", state by fast sync read"
        } else {
            ""
        },
    );
    if robot.joints_on(bus).next().is_some() {
        let timeout = if robot.bus(bus)?.kind == BusKind::Feetech {
            // STS servos have no watchdog: only the host's own stop (damping, torque off) and
            // the loss of power end a goal.
            "no device command timeout (Feetech servos hold their last goal if the host goes quiet)"
                .to_owned()
        } else {
            format!("device command timeout {} ms", t.command_timeout.as_millis())
        };
        line.push_str(&format!(
            ", targets {} between policy ticks, {timeout}",
            match t.interpolation {
                robots::Interpolation::Hold => "held",
                robots::Interpolation::Linear => "ramped",
            },
        ));
    }
    Some(line)
}

fn print_timing(robot: &Robot, bus: &str) {
    if let Some(line) = schedule(robot, bus) {
        println!("     {line}");
    }
}

fn scan_mit<B: CanBus>(robot: &Robot, bus: &str, port: &mut B, timeout: Duration) -> Result<usize> {
    let joints: Vec<_> = robot.joints_on(bus).map(|(_, j)| j).collect();
    let last = joints
        .iter()
        .map(|j| j.id)
        .max()
        .unwrap_or(0)
        .saturating_add(2)
        .min(127);
    // Each protocol on the bus (MIT mode, Robstride's factory protocol) is asked in its own
    // frames, once, with the first model of that family.
    let mut hits = Vec::new();
    let mut asked = Vec::new();
    for j in &joints {
        let model = robot.mit_model(&j.model).context("model checked at load")?;
        if asked.contains(&model.family) {
            continue;
        }
        asked.push(model.family);
        for hit in mit::driver::scan(port, model, 1..=last, timeout)? {
            if !hits
                .iter()
                .any(|h: &mit::driver::ScanHit| h.motor_id == hit.motor_id)
            {
                hits.push(hit);
            }
        }
    }
    hits.sort_by_key(|h| h.motor_id);
    println!("can  {bus}: {} motor(s) answered among IDs 1-{last}", hits.len());
    print_timing(robot, bus);
    let mut problems = 0;
    for j in &joints {
        match hits.iter().find(|h| h.motor_id == j.id) {
            Some(h) => println!(
                "  id {:>3}  {:<20} {:<9} pos {:>7.3} rad  temp {}",
                j.id,
                j.name,
                j.model,
                h.reply.p,
                h.reply.temperature.map_or("-".into(), |t| format!("{t:.0} °C"))
            ),
            None => {
                problems += 1;
                println!("  id {:>3}  {:<20} MISSING", j.id, j.name);
            }
        }
    }
    for h in hits.iter().filter(|h| !joints.iter().any(|j| j.id == h.motor_id)) {
        problems += 1;
        println!("  id {:>3}  not in robot.toml", h.motor_id);
    }
    Ok(problems)
}

fn scan_dxl<T: DxlTransport>(robot: &Robot, bus: &str, port: &mut T, timeout: Duration) -> Result<usize> {
    let joints: Vec<_> = robot.joints_on(bus).map(|(_, j)| j).collect();
    let last = joints
        .iter()
        .map(|j| j.id)
        .max()
        .unwrap_or(0)
        .saturating_add(2)
        .min(252);
    let hits = dxl::driver::scan(port, 1..=last, timeout)?;
    println!("dxl  {bus}: {} servo(s) answered among IDs 1-{last}", hits.len());
    print_timing(robot, bus);
    let answered: Vec<_> = hits
        .iter()
        .map(|h| {
            let state = format!(
                "pos {:>5} ticks  {} °C  hw error {}",
                or_dash(h.position),
                or_dash(h.temperature),
                h.hardware_error.map_or("-".to_owned(), |e| format!("{e:#04x}"))
            );
            (h.id, h.model_number, state)
        })
        .collect();
    Ok(compare_with_file(&joints, &answered, |j| {
        robot.dxl_model(&j.model).map_or(0, |m| m.model_number)
    }))
}

/// Serial servos that answered — `(id, model number, state)` — against robot.toml's joints on the
/// bus: one line per joint (its state, a wrong model or missing) and per ID robot.toml lacks;
/// the number of differences.
fn compare_with_file(
    joints: &[&robots::JointConfig],
    answered: &[(u8, u16, String)],
    model_number: impl Fn(&robots::JointConfig) -> u16,
) -> usize {
    let mut problems = 0;
    for j in joints {
        match answered.iter().find(|h| h.0 == j.id) {
            Some((_, number, state)) if *number == model_number(j) => {
                println!("  id {:>3}  {:<20} {:<11} {state}", j.id, j.name, j.model);
            }
            Some((_, number, _)) => {
                problems += 1;
                println!(
                    "  id {:>3}  {:<20} WRONG MODEL: configured {}, answers model {number}",
                    j.id, j.name, j.model
                );
            }
            None => {
                problems += 1;
                println!("  id {:>3}  {:<20} MISSING", j.id, j.name);
            }
        }
    }
    for (id, number, _) in answered.iter().filter(|h| !joints.iter().any(|j| j.id == h.0)) {
        problems += 1;
        println!("  id {id:>3}  not in robot.toml (model {number})");
    }
    problems
}

fn scan_feetech(robot: &Robot, bus: &str, port: SerialFeetechPort, timeout: Duration) -> Result<usize> {
    let joints: Vec<_> = robot.joints_on(bus).map(|(_, j)| j).collect();
    let last = joints
        .iter()
        .map(|j| j.id)
        .max()
        .unwrap_or(0)
        .saturating_add(2)
        .min(253);
    let hits = feetech::driver::scan(port, 1..=last, timeout)?;
    println!("sts  {bus}: {} servo(s) answered among IDs 1-{last}", hits.len());
    print_timing(robot, bus);
    let answered: Vec<_> = hits
        .iter()
        .map(|h| {
            let state = format!(
                "pos {:>5} ticks  {} °C  firmware {}.{}  status {}",
                or_dash(h.position),
                or_dash(h.temperature),
                h.firmware[0],
                h.firmware[1],
                h.status.map_or("-".to_owned(), |s| format!("{s:#04x}"))
            );
            (h.id, h.model_number, state)
        })
        .collect();
    Ok(compare_with_file(&joints, &answered, |j| {
        robot.feetech_model(&j.model).map_or(0, |m| m.model_number)
    }))
}

/// Listens to a Unitree board's states for half a second (sending nothing): their rate and CRC,
/// and each configured joint's motor in them (mode, status bits, temperature).
fn scan_unitree(
    robot: &Robot,
    bus: &str,
    mut port: DdsLowLevelPort,
    config: &dds::DdsConfig,
) -> Result<usize> {
    let listen = Duration::from_millis(500);
    let mut cdr = Vec::new();
    let (mut good, mut bad_crc, mut malformed) = (0u32, 0u32, 0u32);
    let mut newest = None;
    let start = Instant::now();
    while start.elapsed() < listen {
        port.wait_state(Duration::from_millis(5))?;
        if port.newest_state(&mut cdr)? {
            match LowState::read_cdr(&cdr) {
                Ok(s) if s.crc_ok() => {
                    good += 1;
                    newest = Some(s);
                }
                Ok(_) => bad_crc += 1,
                Err(_) => malformed += 1,
            }
        }
    }
    println!(
        "unitree {bus}: {good} states with a right CRC in {:.1} s on {} (domain {}), {bad_crc} with a wrong one, {malformed} malformed",
        listen.as_secs_f64(),
        config.interface,
        config.domain
    );
    let Some(state) = newest else {
        println!("  no state from the robot's board: is it on, on this interface and domain?");
        return Ok(robot.joints_on(bus).count().max(1));
    };
    let rate = robot.bus_timing(bus).map_or(500.0, |t| t.rate_hz);
    println!(
        "  board version {}.{}, mode_machine {}, mode_pr {}; about {:.0} states/s (robot.toml: {})",
        state.version[0],
        state.version[1],
        state.mode_machine,
        state.mode_pr,
        f64::from(good) / listen.as_secs_f64(),
        robots::num(rate)
    );
    let mut problems = 0;
    for (_, j) in robot.joints_on(bus) {
        let m = &state.motor_state[usize::from(j.id)];
        let verdict = if m.motorstate & !motor_bits::COMMAND_TIMEOUT != 0 {
            problems += 1;
            "FAULT"
        } else {
            "ok"
        };
        println!(
            "  motor {:>2} {:<28} mode {} status {:#010x} {:>3} °C  {verdict}",
            j.id, j.name, m.mode, m.motorstate, m.temperature[0]
        );
    }
    Ok(problems)
}

fn scan_imu<S: ByteStream>(bus: &str, stream: S, imu: &robots::ImuConfig) -> Result<usize> {
    let rate_hz = imu.rate_hz;
    let mut reader = ImuReader::speaking_at(imu.protocol, stream, rate_hz);
    let start = Instant::now();
    let mut last = None;
    let mut samples = 0u32;
    while start.elapsed() < Duration::from_millis(500) {
        if let Some(r) = reader.poll()?
            && Some(r.received_at) != last
        {
            last = Some(r.received_at);
            samples += 1;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    let stats = reader.stats();
    println!(
        "imu  {bus}: {} samples in 0.5 s ({} packets, {} checksum errors)",
        stats.samples, stats.packets, stats.checksum_errors
    );
    let expected = rate_hz * 0.5;
    Ok(usize::from(
        (stats.samples as f64) < 0.5 * expected || samples == 0,
    ))
}

/// A scan's reading, or "-" where its reply came late or garbled.
pub fn or_dash<T: std::fmt::Display>(v: Option<T>) -> String {
    v.map_or("-".to_owned(), |v| v.to_string())
}
