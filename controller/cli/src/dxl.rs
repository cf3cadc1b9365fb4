//! `robodeploy dxl …`: emulated Dynamixel servos on a pseudo-terminal, and scanning a serial bus.

use std::io::Write as _;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use anyhow::{Context, Result};

use crate::args::FlagError;
use clap::{Args, Subcommand};
use firmware_bridge::dxl::driver::{hardware_error_names, scan};
use firmware_bridge::dxl::models;
use firmware_bridge::dxl::transport::SerialDxlPort;
use firmware_bridge::dxl::wire::{DxlRig, WireTiming, code_of_baud};
use firmware_bridge::serial::PtyServer;

/// Serial bus tools for Dynamixel X-series servos (Protocol 2.0).
#[derive(Debug, Subcommand)]
pub enum DxlCommand {
    /// Serve emulated X-series servos on a pseudo-terminal, in real time.
    ///
    /// Each servo runs its firmware (control table, position PID at 2 kHz, watchdog, thermal
    /// model and protections) against a small inertia. Open the printed device path with any
    /// Dynamixel client (this tool's `dxl scan`, ROBOTIS's dynamixel-sdk, Dynamixel Wizard
    /// through a serial bridge) at the same baud rate.
    Emulate(EmulateArgs),
    /// List the servos that answer on a serial bus: model, firmware, position, temperature and
    /// hardware errors. Only pings and reads; nothing is written.
    Scan(ScanArgs),
}

/// Arguments of `dxl emulate`.
#[derive(Debug, Args)]
pub struct EmulateArgs {
    /// A servo as ID:MODEL (repeat), e.g. --servo 1:XM430-W350 --servo 2:XL430-W250.
    #[arg(long = "servo", required = true, value_parser = parse_servo)]
    servos: Vec<(u8, String)>,
    /// Line speed, bit/s (one of the X-series rates: 57600, 115200, 1000000, 2000000, 3000000,
    /// 4000000, 4500000).
    #[arg(long, default_value_t = 1_000_000)]
    baud: u32,
    /// Return Delay Time of the servos, µs (factory: 500).
    #[arg(long, default_value_t = 500, value_parser = crate::args::whole_within(0, 508))]
    return_delay_us: u64,
    /// USB adapter latency added to every answer, µs (FTDI default 16000; tuned adapters 1000).
    #[arg(long, default_value_t = 0, value_parser = crate::args::whole_within(0, 100_000))]
    usb_latency_us: u64,
    /// Stop after this many seconds (default: run until interrupted).
    #[arg(long, value_parser = crate::args::whole_within(1, 31_536_000))]
    seconds: Option<u64>,
}

/// Arguments of `dxl scan`.
#[derive(Debug, Args)]
pub struct ScanArgs {
    /// Serial device, e.g. /dev/ttyUSB0 or the path `dxl emulate` printed.
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
    crate::args::id_and_model(s, "servo", 0..=252, &known)
}

fn parse_ids(s: &str) -> Result<(u8, u8), String> {
    crate::args::id_range(s, 252)
}

/// Runs a `dxl` subcommand.
pub fn run(cmd: DxlCommand) -> Result<()> {
    match cmd {
        DxlCommand::Emulate(args) => emulate(&args),
        DxlCommand::Scan(args) => scan_cmd(&args),
    }
}

fn emulate(args: &EmulateArgs) -> Result<()> {
    let stop = crate::args::StopSignal::install()?;
    if code_of_baud(args.baud).is_none() {
        return Err(FlagError::new(
            "baud",
            format!(
                " {}: X-series servos support 9600, 57600, 115200, 1000000, 2000000, 3000000, 4000000 and 4500000",
                args.baud
            ),
        )
        .into());
    }
    let mut servos = Vec::new();
    for (id, name) in &args.servos {
        if args.servos.iter().filter(|(other, _)| other == id).count() > 1 {
            return Err(FlagError::new("servo", format!(": servo ID {id} is given twice")).into());
        }
        servos.push((*id, models::find(name).context("model checked by the parser")?));
    }
    let timing = WireTiming {
        baud: args.baud,
        usb_latency: Duration::from_micros(args.usb_latency_us),
    };
    let rig = Arc::new(Mutex::new(DxlRig::bench(
        &servos,
        timing,
        Duration::from_micros(args.return_delay_us),
    )));
    let pty = PtyServer::spawn(Arc::clone(&rig), 0, Duration::from_micros(200))
        .context("cannot open a pseudo-terminal pair")?;
    // As with `can emulate`: a closed stdout must not take the servos down mid-run.
    let mut out = std::io::stdout().lock();
    let _ = writeln!(
        out,
        "dynamixel: serving {} emulated servo(s) on {} at {} bit/s",
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
        "stopping: {} packets, {} CRC errors, {} malformed, {} junk bytes",
        stats.packets,
        stats.crc_errors,
        stats.malformed,
        stats.junk_bytes
    );
    Ok(())
}

fn scan_cmd(args: &ScanArgs) -> Result<()> {
    let mut port = SerialDxlPort::open(&args.port, args.baud)
        .with_context(|| format!("cannot open serial port {} at {} bit/s", args.port, args.baud))?;
    let hits = scan(
        &mut port,
        args.ids.0..=args.ids.1,
        Duration::from_millis(args.timeout_ms),
    )
    .with_context(|| format!("serial port {}", args.port))?;
    println!(
        "{:>4} {:>12} {:>5} {:>9} {:>8}  hardware error",
        "id", "model", "fw", "position", "temp °C"
    );
    for h in &hits {
        let name = models::find_by_number(h.model_number)
            .map_or_else(|| format!("#{}", h.model_number), |m| m.name.clone());
        println!(
            "{:>4} {:>12} {:>5} {:>9} {:>8}  {}",
            h.id,
            name,
            h.firmware,
            crate::bus::or_dash(h.position),
            crate::bus::or_dash(h.temperature),
            match h.hardware_error {
                None => "not read: its reply came late or garbled".to_owned(),
                Some(0) => "0x00".to_owned(),
                Some(e) => format!("{e:#04x} {}", hardware_error_names(e)),
            }
        );
    }
    println!(
        "{} servo(s) answered out of {} asked",
        hits.len(),
        u16::from(args.ids.1 - args.ids.0) + 1
    );
    Ok(())
}
