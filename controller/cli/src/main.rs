//! `robodeploy`: run motion-tracking policies on a robot or its mirrored simulator.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};

mod args;
mod batch;
mod bundle;
mod bus;
mod calibrate;
mod can;
mod commands;
mod console;
mod dxl;
mod exit;
mod feetech;
mod layout;
mod logging;
mod motion_files;
mod play;
mod project;
mod retarget;
mod schema;
mod sim;
mod soak;
mod teleop;

/// Run motion-tracking policies on a real robot, or on its mirrored MuJoCo simulator.
///
/// The controller reads the robot's state over its CAN and serial buses, builds the policy's
/// observation exactly as in training, runs the ONNX policy, limits the commands and writes them
/// back to the servos, at the policy rate.
const EXIT_STATUSES: &str = "\
Exit status:
  0  finished: the run or command did what it was asked
  1  failed for another reason (the message says why)
  2  bad input: a file, flag or value is wrong; nothing moved
  3  safety stop: a fault stopped the robot (stale feedback, device fault, NaN, tilt or fall,
     tracking error, overruns, bus failure, a diverging mirror)
  4  stopped by the operator: SIGINT/SIGTERM or the e-stop
  5  I/O failure: a bus, device or file could not be used
A run prints how it ended as its last line (`result: …`).";

/// The version and the commit the binary was built from (what every recording names).
const VERSION: &str = concat!(
    env!("CARGO_PKG_VERSION"),
    " (commit ",
    env!("ROBODEPLOY_COMMIT"),
    ")"
);

#[derive(Debug, Parser)]
#[command(name = "robodeploy", version = VERSION, about, long_about, after_long_help = EXIT_STATUSES)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// CAN bus tools: emulated MIT-mode motors behind socketcand, and bus scans.
    #[command(subcommand)]
    #[command(display_order = 13)]
    Can(can::CanCommand),
    /// Calibrate a robot without risking it: identity check, joint zeros and directions from a
    /// jig (torque off), IMU bias and mounting, and a gentle verification. Results go to
    /// calibration.toml beside robot.toml, which every later run merges.
    #[command(subcommand)]
    #[command(display_order = 11)]
    Calibrate(calibrate::CalibrateCommand),
    /// Tools over every bus of a robot: scan and compare with robot.toml.
    #[command(subcommand)]
    #[command(display_order = 12)]
    Bus(bus::BusCommand),
    /// Dynamixel serial bus tools: emulated X-series servos on a pseudo-terminal, and bus scans.
    #[command(subcommand)]
    #[command(display_order = 14)]
    Dxl(dxl::DxlCommand),
    /// Pack what a run needs into one tarball for the robot's computer: the binary, its two
    /// native libraries, the robot's folder, the policy's folder and clips. This machine's
    /// architecture, or a 64-bit ARM computer with `--target aarch64-unknown-linux-gnu`.
    ///
    /// Unpacked anywhere, `bin/robodeploy` finds its libraries beside itself; the README.txt
    /// inside says how to run it. `scripts/dev bundle [--target …] ARGS` builds the release
    /// binary to pack and runs this.
    #[command(display_order = 18)]
    Bundle(bundle::BundleArgs),
    /// Feetech serial bus tools: emulated STS servos on a pseudo-terminal, and bus scans.
    #[command(subcommand)]
    #[command(display_order = 15)]
    Feetech(feetech::FeetechCommand),
    /// Write the Foxglove layout for a robot: the robot in 3D, a tracking plot per joint with its
    /// limits (a tab per bus), the safety timeline and log, tick timing. Import it in Foxglove
    /// (Layouts → Import from file), then open a recording or connect to `play --live`.
    #[command(display_order = 17)]
    Layout(layout::LayoutArgs),
    /// See a 3D clip through cameras as 2D keypoints (robot.toml's [keypoints] map, cameras in a
    /// TOML file), or measure it against 2D keypoint references — a pose estimator's COCO JSON or
    /// keypoints written here: reprojection error per view (px), frames over 100 px, and with two
    /// views or more the triangulated 3D error (mm).
    #[command(display_order = 10)]
    Project(project::ProjectArgs),
    /// Play a clip through a policy: on the mirrored robot (default, lockstep), in real time over
    /// real wires (--wall), or on the hardware (--hardware).
    ///
    /// The loop reads every bus and the IMU, builds the observation the policy manifest declares,
    /// runs the ONNX policy, maps actions to joint targets, passes them through the safety governor
    /// (position limits with margin, speed limits, torque bounds) and writes them. The state machine
    /// goes Off → Ready → SoftStart → Running → Stopping → Damped → Off; faults (stale feedback,
    /// device faults, NaN, tilt, overruns) and SIGINT/SIGTERM take the short way to Damped.
    #[command(display_order = 1)]
    Play(Box<play::PlayArgs>),
    /// Motion files: what one holds and how it maps onto a robot (`motion info FILE --robot …`).
    #[command(subcommand)]
    #[command(display_order = 9)]
    Motion(motion_files::MotionCommand),
    /// Retarget a human BVH recording onto the robot: the retargeting map of robot.toml (scale
    /// and nominal offsets from a T-pose or the first frame), inverse kinematics on the robot's
    /// MuJoCo model within the joints' limits, soles kept out of the floor; writes a clip (CSV)
    /// and checks it as `check --clip` does.
    #[command(display_order = 9)]
    Retarget(retarget::RetargetArgs),
    /// Drive the robot live from VR trackers or a motion-capture suit sending VMC (OSC over UDP,
    /// 127.0.0.1:39539 by default). A T-pose calibrates the user. With a headset and two
    /// controllers (`--body devices`) the head and hands are solved by inverse kinematics into a
    /// reference follower's live reference, legs standing; with the whole skeleton (`--body full`)
    /// every body is retargeted onto the robot frame by frame, root and joints, for a general
    /// tracker such as TWIST2, and the summary says how far the robot's key bodies stayed from the
    /// operator's. Late packets are forecast; a lost stream blends back to standing; malformed
    /// packets are dropped and counted. Mirror by default.
    #[command(display_order = 7)]
    Teleop(teleop::TeleopArgs),
    /// VR tools: stream a recorded session as a headset and controllers, or as a whole skeleton.
    #[command(subcommand)]
    #[command(display_order = 8)]
    Vr(teleop::VrCommand),
    /// Run many clips × seeds on the mirror in lockstep, in parallel over the cores, and print one
    /// table per clip: success rate, tracking RMSE, governor saturation.
    #[command(display_order = 5)]
    Batch(batch::BatchArgs),
    /// Validate a robot, a policy manifest with its ONNX file, and a clip, moving nothing: prints
    /// the resolved observation layout and the clip's length, or the first problem with its place.
    #[command(display_order = 0)]
    Check(play::CheckArgs),
    /// Replay a recorded run (the MCAP `play` writes) through the same controller code: feeds the
    /// recorded bus readings, IMU, ground truth and stop requests tick by tick and reports the first
    /// command that differs from the recording, bit for bit.
    #[command(display_order = 3)]
    Replay {
        /// The recording.
        log: PathBuf,
    },
    /// Compare the observations of two runs, or of a run and an export from training (NPZ with an
    /// `obs` array, or CSV rows), term by term: which term diverges first, at which step, by how
    /// much. The first file must be a run (its manifest names the terms).
    ///
    /// The traces are paired step by step from their first policy steps, or shifted (`--offset`,
    /// or `--align TERM` to find the shift that makes one term agree best), for `--steps` steps at
    /// most. Each term's difference is judged against what the buses can resolve of it (encoder
    /// ticks, the MIT fields' steps, the IMU's output steps, through the term's scale): within
    /// quantisation, or beyond it.
    #[command(display_order = 4)]
    Compare {
        /// A recorded run (MCAP from `play`).
        run: PathBuf,
        /// Another run, or a training export (.npz / .csv).
        other: PathBuf,
        /// Differences up to this are equal.
        #[arg(long, default_value_t = 1e-3, value_parser = crate::args::within(0.0, 1e6))]
        tolerance: f64,
        /// Step k of RUN meets step k + OFFSET of OTHER (−500 to 500).
        #[arg(long, allow_hyphen_values = true, conflicts_with = "align", value_parser = clap::value_parser!(i64).range(-500..=500))]
        offset: Option<i64>,
        /// Find the offset (within ±500 steps) at which this term agrees best, e.g. joint_pos.
        #[arg(long, value_name = "TERM")]
        align: Option<String>,
        /// Compare at most this many steps (1 to 10 000 000).
        #[arg(long, value_parser = crate::args::whole_within(1, 10_000_000))]
        steps: Option<u64>,
    },
    /// Write the report of a recorded run: tracking plots, root error, success, RMSE, jitter,
    /// timing, bus misses, safety events (report.html with plots, summary.md, summary.json).
    #[command(display_order = 2)]
    Report {
        /// A recorded run (MCAP from `play`).
        run: PathBuf,
        /// Folder to write into.
        #[arg(long, default_value = "out/report")]
        out: PathBuf,
    },
    /// The mirrored simulator: a robot's MuJoCo model behind emulated firmware on its buses.
    #[command(subcommand)]
    #[command(display_order = 16)]
    Sim(sim::SimCommand),
    /// Soak the stack on the mirror: episodes of random clips with random device faults, checking
    /// commands against the limits, fault reaction times and lost records (exit 3 if any fails).
    #[command(display_order = 6)]
    Soak(soak::SoakArgs),
    /// Check the native libraries and load a MuJoCo model and an ONNX model, moving nothing.
    ///
    /// Prints the versions of MuJoCo and ONNX Runtime this build loads, the sizes of the MuJoCo
    /// model, and the input/output of the ONNX model with one timed inference on zeros. With
    /// --realtime, also what the machine offers the real-time loop, each item with a verdict and
    /// what to change when it falls short (exit 1 if any does): the kernel (PREEMPT_RT), permission
    /// for SCHED_FIFO and memory locking, the CPU governor, isolated cores, USB serial adapters'
    /// latency timers, SocketCAN interfaces, and the timer's wake-up latency measured under the
    /// loop's real-time set-up. Reads only; changes nothing.
    #[command(display_order = 19)]
    Doctor {
        /// MJCF model to load (default: the reference robot's).
        #[arg(long, default_value_os_t = robots::locate::default_robot().with_file_name("biped.xml"))]
        mjcf: PathBuf,
        /// ONNX policy to load (default: the reference policy).
        #[arg(long, default_value_os_t = robots::locate::default_robot().with_file_name("policies/reference_follower.onnx"))]
        onnx: PathBuf,
        /// Also check what the machine offers the real-time loop.
        #[arg(long)]
        realtime: bool,
        /// With --realtime: how long to measure the timer's wake-up latency, s (0: not at all).
        #[arg(long, default_value_t = 10, requires = "realtime", value_parser = crate::args::whole_within(0, 600))]
        seconds: u64,
        /// With --realtime: read /proc and /sys under DIR instead of this machine's (files captured
        /// from a robot's computer); no measurement is made.
        #[arg(long, value_name = "DIR", requires = "realtime")]
        root: Option<PathBuf>,
    },
    /// Write the JSON Schema of robot.toml, a policy manifest, a mirror file or calibration.toml,
    /// generated from the types robodeploy reads them with: `robodeploy schema robot --out
    /// robot.schema.json`, then a first line `#:schema ./robot.schema.json` in robot.toml lets
    /// taplo and VS Code (Even Better TOML) check and complete it as you type. `--format markdown`
    /// writes the reference page the user guide carries.
    #[command(display_order = 98)]
    Schema(schema::SchemaArgs),
    /// Write shell completions for robodeploy to stdout: `robodeploy completions bash >
    /// ~/.local/share/bash-completion/completions/robodeploy` (zsh: a file `_robodeploy` on
    /// `$fpath`; fish: `~/.config/fish/completions/robodeploy.fish`).
    #[command(display_order = 99)]
    Completions {
        /// The shell.
        #[arg(value_enum)]
        shell: clap_complete::Shell,
    },
}

fn main() -> std::process::ExitCode {
    // Errors are for the person at the terminal: the message chain, not a backtrace; the exit
    // status says what kind of failure it was (see `exit`).
    match run() {
        Ok(code) => code,
        Err(e) => {
            logging::last_words(format!("error: {e:#}\n"));
            exit::of_error(&e)
        }
    }
}

fn run() -> Result<std::process::ExitCode> {
    let log = logging::init();
    let result = dispatch(Cli::parse().command);
    if log.dropped() > 0 {
        logging::last_words(format!(
            "log: {} lines dropped (standard error was not read fast enough)\n",
            log.dropped()
        ));
    }
    result
}

/// `play` and `teleop` end with their `result:` line also when they fail before the run (a bus
/// that cannot open, a file refused): scripts read the last line whatever happened.
fn with_result_line(result: Result<std::process::ExitCode>) -> Result<std::process::ExitCode> {
    if let Err(e) = &result {
        let status = exit::status_of_error(e);
        println!("result: {}: {e:#}", exit::meaning(status));
    }
    result
}

fn dispatch(command: Command) -> Result<std::process::ExitCode> {
    let done = |r: Result<()>| r.map(|()| std::process::ExitCode::SUCCESS);
    match command {
        Command::Doctor {
            mjcf,
            onnx,
            realtime,
            seconds,
            root,
        } => done(doctor(&mjcf, &onnx).and_then(|()| {
            if realtime {
                doctor_realtime(root.as_deref(), seconds)
            } else {
                Ok(())
            }
        })),
        Command::Completions { shell } => {
            use clap::CommandFactory;
            // Written whole into memory first: the generator panics on a failed write (a closed
            // pipe), and a failure here is an error, never a panic.
            let mut script = Vec::new();
            clap_complete::generate(shell, &mut Cli::command(), "robodeploy", &mut script);
            std::io::Write::write_all(&mut std::io::stdout(), &script).context("writing the completions")?;
            Ok(std::process::ExitCode::SUCCESS)
        }
        Command::Schema(args) => done(schema::run(&args)),
        Command::Can(cmd) => done(can::run(cmd)),
        Command::Dxl(cmd) => done(dxl::run(cmd)),
        Command::Feetech(cmd) => done(feetech::run(cmd)),
        Command::Bundle(args) => done(bundle::run(&args)),
        Command::Layout(args) => done(layout::run(&args)),
        Command::Project(args) => done(project::run(&args)),
        Command::Bus(cmd) => done(bus::run(cmd)),
        Command::Calibrate(cmd) => done(calibrate::run(cmd)),
        Command::Sim(cmd) => done(sim::run(cmd)),
        Command::Play(args) => with_result_line(play::play(&args)),
        Command::Check(args) => done(play::check(&args)),
        Command::Batch(args) => done(batch::run(&args)),
        Command::Retarget(args) => done(retarget::run(&args)),
        Command::Motion(cmd) => done(motion_files::run(cmd)),
        Command::Teleop(args) => with_result_line(teleop::teleop(&args)),
        Command::Soak(args) => soak::run(&args),
        Command::Vr(cmd) => done(teleop::vr(cmd)),
        Command::Compare {
            run,
            other,
            tolerance,
            offset,
            align,
            steps,
        } => done(compare(&run, &other, tolerance, offset, align.as_deref(), steps)),
        Command::Report { run, out } => {
            let s = analysis::report::write_report(&run, &out)?;
            let headline = match &s.locomotion {
                Some(l) => format!(
                    "{:.2} m travelled, heading {:+.1}°",
                    l.distance_m,
                    l.heading_change.to_degrees()
                ),
                None => format!("joint RMSE {:.2}°", s.joints_rmse_deg),
            };
            println!(
                "report in {}: {headline}, {} safety events; success: {}",
                out.display(),
                s.safety_events.len(),
                if s.success {
                    "yes".to_owned()
                } else {
                    format!("NO ({})", s.failures.join("; "))
                }
            );
            Ok(std::process::ExitCode::SUCCESS)
        }
        Command::Replay { log } => {
            let report = analysis::replay::replay(&log)?;
            println!("{report}");
            if report.first_difference.is_some() {
                anyhow::bail!("the replay does not reproduce the recording");
            }
            Ok(std::process::ExitCode::SUCCESS)
        }
    }
}

fn compare(
    run: &std::path::Path,
    other: &std::path::Path,
    tolerance: f64,
    offset: Option<i64>,
    align: Option<&str>,
    steps: Option<u64>,
) -> Result<()> {
    use analysis::compare::{Alignment, best_offset, compare, quanta, trace_from_export, trace_from_run};
    let (a, meta) = trace_from_run(run)?;
    let robot = robots::Robot::load(&meta.robot)?;
    let mut layout = policy::PolicyLayout::load(&meta.policy, &robot)?;
    let model = policy::onnx::OnnxModel::load(&layout.onnx_path)?;
    layout.bind_model(model.inputs(), model.output().1)?;
    let is_run = other.extension().is_some_and(|e| e.eq_ignore_ascii_case("mcap"));
    let b = if is_run {
        trace_from_run(other)?.0
    } else {
        trace_from_export(other)?
    };
    let offset = match (offset, align) {
        (Some(o), _) => o,
        (None, Some(term)) => {
            let (o, rms) = best_offset(&a, &b, &layout, term)?;
            println!("aligned on {term}: step k of the run meets step k{o:+} of the other (RMS Δ {rms:.5})");
            o
        }
        (None, None) => 0,
    };
    let alignment = Alignment {
        offset,
        steps: steps.map(|s| s as usize),
    };
    let diffs = compare(&a, &b, &layout, tolerance, alignment, &quanta(&layout, &robot))?;
    let compared = alignment.steps_compared(a.steps.len(), b.steps.len());
    match diffs.first().filter(|d| d.first_step.is_some()) {
        Some(d) => {
            let step = d.first_step.unwrap_or(0);
            println!(
                "first divergence: term {} (obs[{}..{}]) at step {step} (tick {} of {}), max |Δ| {:.4}",
                d.term,
                d.range.start,
                d.range.end,
                a.ticks.get(step).copied().unwrap_or(0),
                run.display(),
                d.max_abs
            );
        }
        None => println!("no term differs by more than {tolerance} over {compared} steps"),
    }
    println!("compared {compared} steps, offset {offset:+}");
    // Terms shown in several blocks carry their block's name (history[t-3].joint_pos).
    let w = diffs.iter().map(|d| d.term.len()).max().unwrap_or(0).max(20);
    println!(
        "{:<w$} {:>11} {:>12} {:>12} {:>12}  verdict",
        "term", "first step", "max |Δ|", "RMS Δ", "bus step"
    );
    for d in &diffs {
        let first = d.first_step.map_or("-".to_owned(), |s| s.to_string());
        let (quantum, verdict) = match (d.quantum, d.within_quantisation()) {
            (Some(q), Some(true)) => (format!("{q:.2e}"), "within the buses' quantisation"),
            (Some(q), _) => (format!("{q:.2e}"), "BEYOND the buses' quantisation"),
            (None, _) if d.max_abs <= tolerance => ("-".to_owned(), "equal (not measured by a bus)"),
            (None, _) => ("-".to_owned(), "differs (not measured by a bus)"),
        };
        println!(
            "{:<w$} {first:>11} {:>12.5} {:>12.5} {quantum:>12}  {verdict}",
            d.term, d.max_abs, d.rms
        );
    }
    Ok(())
}

/// The MuJoCo and ONNX Runtime library files this process has mapped.
fn loaded_libraries() -> Vec<PathBuf> {
    let maps = std::fs::read_to_string("/proc/self/maps").unwrap_or_default();
    let mut found: Vec<PathBuf> = maps
        .lines()
        .filter_map(|l| l.split_whitespace().nth(5))
        .filter(|p| p.contains("libmujoco") || p.contains("libonnxruntime"))
        .map(PathBuf::from)
        .collect();
    found.sort();
    found.dedup();
    found
}

/// `doctor --realtime`: the machine's items, then (on this machine) the timer measured under the
/// loop's real-time set-up on a thread of its own.
fn doctor_realtime(root: Option<&std::path::Path>, seconds: u64) -> Result<()> {
    use controller::readiness::{self, Machine, Verdict};
    if let Some(r) = root
        && !r.is_dir()
    {
        return Err(args::FlagError::new(
            "root",
            format!(
                " {}: no such directory (a captured machine's /proc and /sys go under it)",
                r.display()
            ),
        )
        .into());
    }
    let machine = root.map_or_else(Machine::this, Machine::at);
    let mut items = machine.audit();
    println!();
    match root {
        Some(r) => println!(
            "real time: the machine whose /proc and /sys are under {}",
            r.display()
        ),
        None => println!("real time: this machine"),
    }
    if root.is_none() && seconds > 0 {
        println!(
            "  measuring the timer's wake-up latency for {seconds} s (1 ms sleeps, as the loop's thread)…"
        );
        let run = std::time::Duration::from_secs(seconds);
        let measured = std::thread::Builder::new()
            .name("wake-latency".into())
            .spawn(move || {
                let setup = controller::realtime::setup(readiness::LOOP_PRIORITY as i32, None);
                (
                    setup,
                    readiness::measure_wake_latency(run, std::time::Duration::from_millis(1)),
                )
            })?
            .join()
            .map_err(|_| anyhow::anyhow!("the measuring thread failed"))?;
        for step in &measured.0.steps {
            println!("  set-up: {step}");
        }
        // The fastest cycle the loop's threads keep: a 500 Hz bus.
        items.push(readiness::judge_wake_latency(
            &measured.1,
            std::time::Duration::from_millis(2),
        ));
    }
    let mut short = 0;
    for item in &items {
        println!("  {:<16} {:<8} {}", item.name, item.verdict, item.found);
        if let Some(fix) = &item.fix {
            println!("  {:<16} {:<8} fix: {fix}", "", "");
        }
        short += usize::from(item.verdict == Verdict::Short);
    }
    if short > 0 {
        anyhow::bail!("{short} item(s) fall short of what the real-time loop wants (each has its fix above)");
    }
    println!("  every item as the real-time loop wants it");
    Ok(())
}

fn doctor(mjcf: &std::path::Path, onnx: &std::path::Path) -> Result<()> {
    sim2real::mujoco::check_version()?;
    println!(
        "MuJoCo        {} (mj_version {})",
        sim2real::mujoco::loaded_version_string(),
        sim2real::mujoco::loaded_version()
    );
    let info = policy::onnx::runtime_info()?;
    println!("ONNX Runtime  {info}");
    // Where the two libraries came from: beside the binary (a bundle, an install) or the checkout.
    for lib in loaded_libraries() {
        println!("              loaded {}", lib.display());
    }
    // What a unitree_dds bus's `device` or --ros2 can name on this machine.
    let interfaces: Vec<String> = dds::interfaces()
        .into_iter()
        .map(|(name, addrs)| match addrs.first() {
            Some(a) => format!("{name} {a}"),
            None => format!("{name} (no address)"),
        })
        .collect();
    println!(
        "DDS           {} — network interfaces: {}",
        dds::MIDDLEWARE,
        interfaces.join(", ")
    );

    let model = sim2real::mujoco::load_model(mjcf)?;
    let s = sim2real::mujoco::sizes(&model);
    println!(
        "MJCF          {}: nq {} nv {} nu {} bodies {} joints {} timestep {} s",
        mjcf.display(),
        s.nq,
        s.nv,
        s.nu,
        s.nbody,
        s.njnt,
        s.timestep
    );
    let mut data = model.make_data();
    let steps = (1.0 / s.timestep).round() as usize;
    let t0 = std::time::Instant::now();
    for _ in 0..steps {
        data.step();
    }
    println!(
        "              simulated 1 s ({steps} steps) in {:.1} ms",
        t0.elapsed().as_secs_f64() * 1e3
    );

    let mut policy =
        policy::onnx::OnnxModel::load(onnx).with_context(|| format!("loading {}", onnx.display()))?;
    let (in_name, in_len) = policy.input();
    let (out_name, out_len) = policy.output();
    println!(
        "ONNX          {}: input '{in_name}' [{in_len}] -> output '{out_name}' [{out_len}]",
        onnx.display()
    );
    let obs = vec![0.0f32; in_len];
    let mut act = vec![0.0f32; out_len];
    let t0 = std::time::Instant::now();
    policy.run(&obs, &mut act)?;
    println!(
        "              one inference on zeros in {:.1} µs; first actions {:?}",
        t0.elapsed().as_secs_f64() * 1e6,
        &act[..act.len().min(4)]
    );
    println!("doctor: all checks passed");
    Ok(())
}
