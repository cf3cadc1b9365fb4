//! `robodeploy sim …`: the mirrored simulator of a robot, served in real time behind real wires.

use std::io::Write as _;
use std::net::IpAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use robots::Robot;
use sim2real::config::MirrorConfig;
use sim2real::mirror::Mirror;
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
}

/// Arguments of `sim serve`.
#[derive(Debug, Args)]
pub struct ServeArgs {
    /// The robot description.
    #[arg(long, default_value_os_t = robots::reference_robot_path())]
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
    /// Stop after this many seconds (default: run until interrupted).
    #[arg(long)]
    seconds: Option<u64>,
}

/// Reads mirror settings from a TOML file; errors name the file and the line.
pub fn load_mirror_config(path: &Path) -> Result<MirrorConfig> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    toml::from_str(&text).with_context(|| format!("{}: invalid mirror settings", path.display()))
}

/// Runs a `sim` subcommand.
pub fn run(cmd: SimCommand) -> Result<()> {
    match cmd {
        SimCommand::Serve(args) => serve(&args),
    }
}

fn serve(args: &ServeArgs) -> Result<()> {
    let robot = Robot::load(&args.robot)?;
    let mut config = match &args.mirror {
        Some(p) => load_mirror_config(p)?,
        None => MirrorConfig::default(),
    };
    config.gantry |= args.gantry;
    if let Some(seed) = args.seed {
        config.seed = seed;
    }
    let name = robot.config.name.clone();
    let mirror = Mirror::new(robot, config).context("cannot build the mirror")?;
    let served =
        ServedMirror::start(mirror, args.listen, args.port).context("cannot open the mirror's wires")?;
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
    let _ = writeln!(out, "  imu  {:<6} {}", "", ep.imu);
    let _ = out.flush();
    drop(out);
    match args.seconds {
        Some(s) => std::thread::sleep(Duration::from_secs(s)),
        None => loop {
            std::thread::sleep(Duration::from_secs(3600));
        },
    }
    let stats = served
        .world
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
        .stats();
    let _ = writeln!(
        std::io::stdout(),
        "stopping: {} physics steps, {} IMU outputs, {} faults applied",
        stats.physics_steps,
        stats.imu_outputs,
        stats.faults_applied
    );
    Ok(())
}
