//! `robodeploy can …`: emulated MIT motors behind socketcand, and scanning a CAN bus for motors.

use std::io::Write as _;
use std::net::SocketAddr;
use std::time::Duration;

use anyhow::{Context, Result};

use crate::args::FlagError;
use clap::{Args, Subcommand};
use firmware_bridge::can::socketcan::SocketCanBus;
use firmware_bridge::can::socketcand::{SocketcandClient, SocketcandServer};
use firmware_bridge::can::virtual_bus::VirtualCanBus;
use firmware_bridge::mit::driver::scan;
use firmware_bridge::mit::firmware::MitFirmwareConfig;
use firmware_bridge::mit::models;
use firmware_bridge::mit::rig::MitRig;
use firmware_bridge::plant::InertiaPlant;
use firmware_bridge::time::WallClockRunner;

/// CAN bus tools for MIT-mode motors (CubeMars AK, DaMiao DM-J).
#[derive(Debug, Subcommand)]
pub enum CanCommand {
    /// Serve emulated MIT motors over the socketcand protocol, in real time.
    ///
    /// Each motor runs its firmware (PD law at 2 kHz, command timeout, thermal model) against a
    /// small inertia. Point a controller, `robodeploy can scan`, or python-can's socketcand
    /// interface at the printed address. Binds to 127.0.0.1 unless --listen says otherwise.
    Emulate(EmulateArgs),
    /// List the motors that answer on a bus.
    ///
    /// Sends each ID a *disable* frame (torque off, safe when the robot is not running) and
    /// prints position, velocity, torque, temperature and fault of every motor that answers.
    Scan(ScanArgs),
}

/// Arguments of `can emulate`.
#[derive(Debug, Args)]
pub struct EmulateArgs {
    /// Address to listen on.
    #[arg(long, default_value = "127.0.0.1:29536")]
    listen: SocketAddr,
    /// Bus name clients open.
    #[arg(long, default_value = "can0")]
    bus: String,
    /// A motor as ID:MODEL (repeat), e.g. --motor 1:AK80-9 --motor 2:DM-J4310.
    #[arg(long = "motor", required = true, value_parser = parse_motor)]
    motors: Vec<(u8, String)>,
    /// Bus bitrate, bit/s (frames take their wire time at this rate).
    #[arg(long, default_value_t = 1_000_000, value_parser = clap::value_parser!(u32).range(10_000..=1_000_000))]
    bitrate: u32,
    /// Stop after this many seconds (default: run until interrupted).
    #[arg(long, value_parser = crate::args::whole_within(1, 31_536_000))]
    seconds: Option<u64>,
}

/// Arguments of `can scan`.
#[derive(Debug, Args)]
pub struct ScanArgs {
    /// A socketcand server to scan through (HOST:PORT), e.g. one started by `can emulate`.
    #[arg(long, conflicts_with = "socketcan", required_unless_present = "socketcan")]
    socketcand: Option<SocketAddr>,
    /// A SocketCAN interface to scan (e.g. can0), which must be up.
    #[arg(long)]
    socketcan: Option<String>,
    /// Bus name to open on the socketcand server.
    #[arg(long, default_value = "can0")]
    bus: String,
    /// Motor model, to decode replies (AK80-9, AK10-9, DM-J4310, DM-J4340).
    #[arg(long, default_value = "AK80-9")]
    model: String,
    /// First and last ID to ask, e.g. 1-16.
    #[arg(long, default_value = "1-16", value_parser = parse_range)]
    ids: (u8, u8),
    /// How long to wait for each answer, ms.
    #[arg(long, default_value_t = 20, value_parser = crate::args::whole_within(1, 10_000))]
    timeout_ms: u64,
}

fn parse_motor(s: &str) -> Result<(u8, String), String> {
    let known: Vec<&str> = models::builtin().iter().map(|m| m.name.as_str()).collect();
    crate::args::id_and_model(s, "motor", 1..=127, &known)
}

fn parse_range(s: &str) -> Result<(u8, u8), String> {
    crate::args::id_range(s, 127)
}

/// Runs a `can` subcommand.
pub fn run(cmd: CanCommand) -> Result<()> {
    match cmd {
        CanCommand::Emulate(args) => emulate(&args),
        CanCommand::Scan(args) => scan_cmd(&args),
    }
}

fn emulate(args: &EmulateArgs) -> Result<()> {
    let stop = crate::args::StopSignal::install()?;
    let bus = VirtualCanBus::new(&args.bus, args.bitrate);
    let mut rig = MitRig::new(vec![bus.clone()], Duration::from_micros(500));
    for (id, name) in &args.motors {
        if args.motors.iter().filter(|(other, _)| other == id).count() > 1 {
            return Err(FlagError::new("motor", format!(": motor ID {id} is given twice")).into());
        }
        let model = models::find(name).context("model checked by the parser")?;
        rig.add_motor(
            0,
            MitFirmwareConfig::new(*id, model),
            InertiaPlant::new(0.01, 0.05, 0.01, 0.0),
        );
    }
    let runner = WallClockRunner::spawn(rig.shared(), Duration::from_micros(200))?;
    let start = std::time::Instant::now();
    let server = SocketcandServer::spawn(args.listen, &args.bus, bus.attach(), move || start.elapsed())
        .with_context(|| format!("cannot listen on {}", args.listen))?;
    // A server must outlive whoever reads its output: a closed stdout (a pipe to `head`, a test
    // that read the address and left) is ignored instead of killing the motors mid-run.
    let mut out = std::io::stdout().lock();
    let _ = writeln!(
        out,
        "socketcand: serving bus {} with {} emulated motor(s) on {}",
        args.bus,
        args.motors.len(),
        server.local_addr()
    );
    for (id, model) in &args.motors {
        let _ = writeln!(out, "  motor {id:>3}  {model}");
    }
    let _ = out.flush();
    drop(out);
    let why = stop.wait(args.seconds);
    let _ = writeln!(std::io::stdout(), "stopped ({why})");
    let _ = writeln!(
        std::io::stdout(),
        "stopping after {:.1} s; malformed input received: {}",
        runner.elapsed().as_secs_f64(),
        server.malformed()
    );
    Ok(())
}

fn scan_cmd(args: &ScanArgs) -> Result<()> {
    let model = models::find(&args.model).with_context(|| format!("unknown motor model '{}'", args.model))?;
    let timeout = Duration::from_millis(args.timeout_ms);
    let ids = args.ids.0..=args.ids.1;
    let hits = match (&args.socketcand, &args.socketcan) {
        (Some(addr), _) => scan(
            &mut SocketcandClient::connect(addr, &args.bus, Duration::from_secs(2))?,
            model,
            ids,
            timeout,
        )?,
        (None, Some(iface)) => scan(&mut SocketCanBus::open(iface)?, model, ids, timeout)?,
        (None, None) => {
            return Err(FlagError::new("socketcand", " HOST:PORT or --socketcan IFACE: give one").into());
        }
    };
    println!(
        "{:>4} {:>8} {:>9} {:>9} {:>8} {:>7}  fault",
        "id", "reply-id", "pos rad", "vel rad/s", "torque", "temp °C"
    );
    for h in &hits {
        let r = &h.reply;
        let temp = r.temperature.map_or("-".into(), |t| format!("{t:.0}"));
        println!(
            "{:>4} {:>#8x} {:>9.3} {:>9.3} {:>8.3} {:>7}  {}",
            h.motor_id, h.reply_id, r.p, r.v, r.t, temp, r.fault
        );
    }
    println!(
        "{} motor(s) answered out of {} asked",
        hits.len(),
        args.ids.1 - args.ids.0 + 1
    );
    Ok(())
}
