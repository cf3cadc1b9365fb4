//! `robodeploy sim …`: the mirrored simulator of a robot, served in real time behind real wires.

use std::io::Write as _;
use std::net::IpAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use robots::Robot;
use sim2real::config::MirrorConfig;
use sim2real::host::MirrorHost;
use sim2real::mirror::Mirror;
use sim2real::render::CameraSpec;
use sim2real::serve::ServedMirror;

/// The mirrored MuJoCo simulator.
#[derive(Debug, Subcommand)]
pub enum SimCommand {
    /// Serve a robot's mirror in real time: its CAN buses on socketcand servers, its Dynamixel
    /// buses and IMU on pseudo-terminals.
    ///
    /// Behind every bus sits the emulated firmware of the real part (MIT-mode motors, X-series
    /// servos, a WIT-protocol AHRS) driving MuJoCo. Point a controller (or `robodeploy can scan`,
    /// `robodeploy dxl scan`, python-can, dynamixel-sdk) at the printed endpoints. Binds to
    /// 127.0.0.1 unless --listen says otherwise.
    Serve(ServeArgs),
    /// Stand the robot in its default pose in lockstep through its real drivers, and render the
    /// run to PNG frames (CPU ray casting; no GPU needed).
    ///
    /// Faults and randomisation from --mirror apply, so this shows what a fault does to the robot.
    Stand(StandArgs),
}

/// Arguments of `sim stand`.
#[derive(Debug, Args)]
pub struct StandArgs {
    /// The robot description.
    #[arg(long, default_value_os_t = robots::locate::default_robot())]
    robot: PathBuf,
    /// Mirror settings (TOML: seed, gantry, randomization, faults …).
    #[arg(long)]
    mirror: Option<PathBuf>,
    /// Hold the robot on a gantry.
    #[arg(long)]
    gantry: bool,
    /// Simulated seconds.
    #[arg(long, default_value_t = 3.0, value_parser = crate::args::within(0.001, 3600.0))]
    seconds: f64,
    /// Folder for the frames (frame_0000.png …); none when absent.
    #[arg(long)]
    frames: Option<PathBuf>,
    /// Frames per simulated second.
    #[arg(long, default_value_t = 10.0, value_parser = crate::args::within(0.1, 100.0))]
    fps: f64,
    /// Frame size, px.
    #[arg(long, default_value = "480x360", value_parser = parse_size)]
    size: (u32, u32),
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once('x')
        .ok_or_else(|| format!("'{s}': expected WIDTHxHEIGHT, e.g. 480x360"))?;
    let parse = |v: &str| v.parse::<u32>().ok().filter(|v| (16..=4096).contains(v));
    match (parse(w), parse(h)) {
        (Some(w), Some(h)) => Ok((w, h)),
        _ => Err(format!("'{s}': width and height must be 16-4096")),
    }
}

/// Arguments of `sim serve`.
#[derive(Debug, Args)]
pub struct ServeArgs {
    /// The robot description.
    #[arg(long, default_value_os_t = robots::locate::default_robot())]
    robot: PathBuf,
    /// Mirror settings (TOML: seed, gantry, randomization, faults …).
    #[arg(long)]
    mirror: Option<PathBuf>,
    /// Hold the robot on a gantry (overrides the settings file).
    #[arg(long)]
    gantry: bool,
    /// Random seed (overrides the settings file).
    #[arg(long)]
    seed: Option<u64>,
    /// Address for the socketcand servers.
    #[arg(long, default_value = "127.0.0.1")]
    listen: IpAddr,
    /// First socketcand port (one per CAN bus, counting up; 0: any free port).
    #[arg(long, default_value_t = 29536)]
    port: u16,
    /// Network interface the Unitree boards' DDS link is served on (each in its bus's domain).
    #[arg(long, default_value = sim2real::serve::LOOPBACK)]
    dds_interface: String,
    /// Stop after this many seconds (default: run until interrupted).
    #[arg(long, value_parser = crate::args::whole_within(1, 31_536_000))]
    seconds: Option<u64>,
}

/// Reads mirror settings from a TOML file for `robot`: errors name the file and the line or field.
pub fn load_mirror_config(path: &Path, robot: &Robot) -> Result<MirrorConfig> {
    let text = robots::read_text(path).map_err(|m| robots::FileError::new(path, m))?;
    let config: MirrorConfig =
        toml::from_str(&text).map_err(|e| robots::FileError::new(path, e.to_string()))?;
    config
        .check(robot)
        .map_err(|(field, m)| robots::FileError::new(path, format!("{field}: {m}")))?;
    Ok(config)
}

/// Runs a `sim` subcommand.
pub fn run(cmd: SimCommand) -> Result<()> {
    match cmd {
        SimCommand::Serve(args) => serve(&args),
        SimCommand::Stand(args) => stand(&args),
    }
}

fn mirror_config(path: Option<&Path>, gantry: bool, robot: &Robot) -> Result<MirrorConfig> {
    let mut config = match path {
        Some(p) => load_mirror_config(p, robot)?,
        None => MirrorConfig::default(),
    };
    config.gantry |= gantry;
    Ok(config)
}

fn stand(args: &StandArgs) -> Result<()> {
    if !(args.seconds.is_finite() && args.seconds > 0.0 && args.fps > 0.0 && args.fps <= 100.0) {
        return Err(crate::args::FlagError::new("seconds", " must be positive and --fps in (0, 100]").into());
    }
    let robot = Robot::load(&args.robot)?;
    let config = mirror_config(args.mirror.as_deref(), args.gantry, &robot)?;
    let mut host =
        MirrorHost::start(robot.clone(), config).context("cannot start the mirror and its drivers")?;
    if let Some(dir) = &args.frames {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    let pose: Vec<f64> = robot.config.joints.iter().map(|j| j.default_position).collect();
    let tick = Duration::from_nanos((1e9 / robot.config.control_rate_hz).round() as u64);
    let ticks = (args.seconds * robot.config.control_rate_hz).round() as u64;
    let frame_every = (robot.config.control_rate_hz / args.fps).round().max(1.0) as u64;
    let camera = CameraSpec {
        width: args.size.0,
        height: args.size.1,
        ..CameraSpec::default()
    };
    let bar = indicatif::ProgressBar::new(ticks).with_message("standing");
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} ticks {elapsed}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let start = host.now();
    let mut frames = 0;
    for k in 0..ticks {
        host.command_positions(&robot, &pose)?;
        host.wait_until(start + tick * (k as u32 + 1));
        if let Some(dir) = &args.frames
            && k % frame_every == 0
        {
            let image = host
                .world
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .render(&camera);
            let path = dir.join(format!("frame_{frames:04}.png"));
            image
                .save_png(&path)
                .with_context(|| format!("cannot write {}", path.display()))?;
            frames += 1;
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    let w = host
        .world
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    let root = w.root_pose();
    let up = 1.0 - 2.0 * (root[4] * root[4] + root[5] * root[5]);
    println!(
        "{}: {:.1} s standing; pelvis height {:.3} m, uprightness {:.3}, {} physics steps, {} faults applied",
        robot.config.name,
        args.seconds,
        root[2],
        up,
        w.stats().physics_steps,
        w.stats().faults_applied
    );
    if let Some(dir) = &args.frames {
        println!("{frames} frames in {}", dir.display());
    }
    Ok(())
}

fn serve(args: &ServeArgs) -> Result<()> {
    let stop = crate::args::StopSignal::install()?;
    let robot = Robot::load(&args.robot)?;
    let mut config = mirror_config(args.mirror.as_deref(), args.gantry, &robot)?
        // Served like a run's: nothing falls before a controller drives it.
        .for_run(&robot, robot.config.start.mode);
    if let Some(seed) = args.seed {
        config.seed = seed;
    }
    let name = robot.config.name.clone();
    let mirror = Mirror::new(robot, config).context("cannot build the mirror")?;
    let served = ServedMirror::start_on(mirror, args.listen, args.port, &args.dds_interface)
        .context("cannot open the mirror's wires")?;
    let ep = served.endpoints();
    // As with the other servers: a closed stdout must not stop the robot mid-run.
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "mirror of {name} running in real time");
    for (bus, addr) in &ep.can {
        let _ = writeln!(out, "  can  {bus:<6} socketcand {addr}");
    }
    for (bus, path) in &ep.dxl {
        let _ = writeln!(out, "  dxl  {bus:<6} {path}");
    }
    for (bus, c) in &ep.unitree {
        let _ = writeln!(
            out,
            "  unitree {bus:<6} DDS rt/lowstate, rt/lowcmd on {} domain {}",
            c.interface, c.domain
        );
    }
    match &ep.imu {
        Some(path) => {
            let _ = writeln!(out, "  imu  {:<6} {path}", "");
        }
        None => {
            let _ = writeln!(out, "  imu  in the board's rt/lowstate");
        }
    }
    let _ = out.flush();
    drop(out);
    let why = stop.wait(args.seconds);
    let _ = writeln!(std::io::stdout(), "stopped ({why})");
    let world = served
        .world
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    let stats = world.stats();
    for (bus, _) in &ep.unitree {
        if let Some(b) = world.unitree_line(bus).and_then(|l| world.unitree_board(l)) {
            let s = b.stats();
            let _ = writeln!(
                std::io::stdout(),
                "unitree {bus}: {} states published, {} commands taken, {} refused for their CRC, {} malformed",
                s.states,
                s.accepted,
                s.bad_crc,
                s.malformed
            );
        }
    }
    let _ = writeln!(
        std::io::stdout(),
        "stopping: {} physics steps, {} IMU outputs, {} faults applied",
        stats.physics_steps,
        stats.imu_outputs,
        stats.faults_applied
    );
    Ok(())
}
