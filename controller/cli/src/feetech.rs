//! `robodeploy feetech …`: emulated Feetech STS servos on a pseudo-terminal, and scanning a
//! serial bus.

use std::io::Write as _;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use anyhow::{Context, Result};

use crate::args::FlagError;
use clap::{Args, Subcommand};
use firmware_bridge::feetech::driver::{SerialFeetechPort, error_names, scan};
use firmware_bridge::feetech::models;
use firmware_bridge::feetech::table::{BAUDS, index_of_baud};
use firmware_bridge::feetech::wire::FeetechRig;
use firmware_bridge::serial::PtyServer;

/// Serial bus tools for Feetech STS servos.
#[derive(Debug, Subcommand)]
pub enum FeetechCommand {
    /// Serve emulated STS servos on a pseudo-terminal, in real time.
    ///
    /// Each servo runs its firmware (STS control table with its EPROM lock, position loop at
    /// 1 kHz under its torque limit, thermal model and protections) against a small inertia.
    /// Open the printed device path with any Feetech client (this tool's `feetech scan`, Feetech's
    /// Python SDK, LeRobot's motor bus) at the same baud rate.
    Emulate(EmulateArgs),
    /// List the servos that answer on a serial bus: model, firmware, position, temperature and
    /// status. Only pings and reads; nothing is written.
    Scan(ScanArgs),
}

/// Arguments of `feetech emulate`.
#[derive(Debug, Args)]
pub struct EmulateArgs {
    /// A servo as ID:MODEL (repeat), e.g. --servo 1:STS3215 --servo 2:STS3215-12V.
    #[arg(long = "servo", required = true, value_parser = parse_servo)]
    servos: Vec<(u8, String)>,
    /// Line speed, bit/s (1000000, 500000, 250000, 128000, 115200, 76800, 57600 or 38400).
    #[arg(long, default_value_t = 1_000_000)]
    baud: u32,
    /// Stop after this many seconds (default: run until interrupted).
    #[arg(long, value_parser = crate::args::whole_within(1, 31_536_000))]
    seconds: Option<u64>,
}

/// Arguments of `feetech scan`.
#[derive(Debug, Args)]
pub struct ScanArgs {
    /// Serial device, e.g. /dev/ttyACM0 or the path `feetech emulate` printed.
    #[arg(long)]
    port: String,
    /// Line speed, bit/s.
    #[arg(long, default_value_t = 1_000_000)]
    baud: u32,
    /// First and last ID to ask, e.g. 1-20.
    #[arg(long, default_value = "1-20", value_parser = parse_ids)]
    ids: (u8, u8),
    /// How long to wait for each answer, ms.
    #[arg(long, default_value_t = 20, value_parser = crate::args::whole_within(1, 10_000))]
    timeout_ms: u64,
}

fn parse_servo(s: &str) -> Result<(u8, String), String> {
    let known: Vec<&str> = models::builtin().iter().map(|m| m.name.as_str()).collect();
    crate::args::id_and_model(s, "servo", 0..=253, &known)
}

fn parse_ids(s: &str) -> Result<(u8, u8), String> {
    crate::args::id_range(s, 253)
}

/// Runs a `feetech` subcommand.
pub fn run(cmd: FeetechCommand) -> Result<()> {
    match cmd {
        FeetechCommand::Emulate(args) => emulate(&args),
        FeetechCommand::Scan(args) => scan_cmd(&args),
    }
}

fn emulate(args: &EmulateArgs) -> Result<()> {
    let stop = crate::args::StopSignal::install()?;
    if index_of_baud(args.baud).is_none() {
        return Err(FlagError::new("baud", format!(" {}: STS servos run at {BAUDS:?}", args.baud)).into());
    }
    let mut servos = Vec::new();
    for (id, name) in &args.servos {
        if args.servos.iter().filter(|(other, _)| other == id).count() > 1 {
            return Err(FlagError::new("servo", format!(": servo ID {id} is given twice")).into());
        }
        servos.push((*id, models::find(name).context("model checked by the parser")?));
    }
    let rig = Arc::new(Mutex::new(FeetechRig::bench(&servos, args.baud)));
    let pty = PtyServer::spawn(Arc::clone(&rig), 0, Duration::from_micros(200))
        .context("cannot open a pseudo-terminal pair")?;
    // A closed stdout must not take the servos down mid-run.
    let mut out = std::io::stdout().lock();
    let _ = writeln!(
        out,
        "feetech: serving {} emulated servo(s) on {} at {} bit/s",
        args.servos.len(),
        pty.path(),
        args.baud
    );
    for (id, model) in &args.servos {
        let _ = writeln!(out, "  servo {id:>3}  {model}");
    }
    let _ = out.flush();
    drop(out);
    let why = stop.wait(args.seconds);
    let _ = writeln!(std::io::stdout(), "stopped ({why})");
    let stats = rig
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
        .wire()
        .chain()
        .stats();
    let _ = writeln!(
        std::io::stdout(),
        "stopping: {} packets, {} checksum errors, {} junk bytes",
        stats.packets,
        stats.checksum_errors,
        stats.junk_bytes
    );
    Ok(())
}

fn scan_cmd(args: &ScanArgs) -> Result<()> {
    let port = SerialFeetechPort::open(&args.port, args.baud)
        .with_context(|| format!("cannot open serial port {} at {} bit/s", args.port, args.baud))?;
    let hits = scan(
        port,
        args.ids.0..=args.ids.1,
        Duration::from_millis(args.timeout_ms),
    )
    .with_context(|| format!("serial port {}", args.port))?;
    println!(
        "{:>4} {:>12} {:>6} {:>9} {:>8}  status",
        "id", "model", "fw", "position", "temp °C"
    );
    for h in &hits {
        let name = models::builtin()
            .iter()
            .find(|m| m.model_number == h.model_number)
            .map_or_else(|| format!("#{}", h.model_number), |m| m.name.clone());
        println!(
            "{:>4} {:>12} {:>6} {:>9} {:>8}  {}",
            h.id,
            name,
            format!("{}.{}", h.firmware[0], h.firmware[1]),
            crate::bus::or_dash(h.position),
            crate::bus::or_dash(h.temperature),
            h.status.map_or_else(
                || "state not read: its reply came late or garbled".to_owned(),
                |s| format!("{s:#04x} {}", error_names(s))
            )
        );
    }
    println!(
        "{} servo(s) answered out of {} asked",
        hits.len(),
        u16::from(args.ids.1 - args.ids.0) + 1
    );
    Ok(())
}
