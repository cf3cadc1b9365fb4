//! `play --keyboard | --gamepad | --command-udp`: where a command-driven policy's live commands
//! come from, each source on its own thread.

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, Result};
use clap::Args;
use human::commands::{self, CommandReader, CommandSpec, CommandStats, GilrsPad, TerminalGuard};

/// Where live commands come from (the policy manifest's `[commands]` says what they mean).
#[derive(Debug, Args)]
#[group(multiple = false)]
#[command(next_help_heading = "Operator commands")]
pub struct CommandArgs {
    /// Live commands from this terminal's keyboard: W/S or ↑/↓ forward and back, A/D sideways,
    /// Q/E or ←/→ turn, space back to the defaults; each press moves a command by the manifest's
    /// `step`, within its `ranges`, ramped by its `ramp`.
    #[arg(long)]
    pub keyboard: bool,
    /// Live commands from the first gamepad (gilrs): left stick walks, right stick turns, A
    /// (south) resets; full deflection is the end of a command's range. A pad silent longer
    /// than the manifest's `timeout_s` (a dropped link) hands back to the defaults.
    #[arg(long)]
    pub gamepad: bool,
    /// Live commands from UDP datagrams on ADDR (default 127.0.0.1:9870; another address only
    /// when given): one JSON object each, {"version": 1, "seq": N, "command": [..]}, seq rising
    /// (optionally "session": S — a sender that starts over sends a new one; a seq more than
    /// 1024 behind the newest also counts as starting over), one value per manifest command
    /// within its range. Malformed, out-of-range, late and repeated datagrams are dropped and
    /// counted; silence longer than `timeout_s` hands back to the defaults.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = "127.0.0.1:9870")]
    pub command_udp: Option<SocketAddr>,
    /// Live commands from ROS 2's /cmd_vel (geometry_msgs/msg/Twist, as a joystick node or a
    /// navigation stack sends it), on --ros2's interface and domain: linear x → forward speed,
    /// linear y → leftward, angular z → turning (by the manifest's command kinds), each clamped to
    /// its range; silence longer than `timeout_s` hands back to the defaults.
    #[arg(long, requires = "ros2")]
    pub cmd_vel: bool,
    /// Live commands from the viewer: Foxglove's *Teleop* panel (or any client of the live
    /// connection) publishing geometry_msgs/Twist on /cmd_vel (JSON), mapped as --cmd-vel maps
    /// it. Needs --live.
    #[arg(long, requires = "live_view")]
    pub viewer_commands: bool,
}

impl CommandArgs {
    /// The source named, as the recording's metadata says it.
    pub fn source(&self) -> Option<String> {
        if self.keyboard {
            Some("keyboard".into())
        } else if self.gamepad {
            Some("gamepad".into())
        } else if self.cmd_vel {
            Some("ros2 /cmd_vel".into())
        } else if self.viewer_commands {
            Some("viewer /cmd_vel".into())
        } else {
            self.command_udp.map(|a| format!("udp {a}"))
        }
    }
}

/// A running command source: its counts, and what to stop or restore when it is dropped.
#[derive(Debug)]
pub struct CommandSource {
    /// Accepted and dropped messages.
    pub stats: Arc<CommandStats>,
    /// Where the live view hands the viewer's twists (`--viewer-commands`).
    pub viewer: Option<std::sync::mpsc::SyncSender<[f64; 6]>>,
    stop: Arc<AtomicBool>,
    _terminal: Option<TerminalGuard>,
}

impl Drop for CommandSource {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

/// Starts the source `args` names for commands `spec` starting at `initial`, with the reader the
/// loop takes; `None` when no source is named.
pub fn start(
    args: &CommandArgs,
    spec: Option<&CommandSpec>,
    initial: &[f64],
    ros2: Option<&dds::DdsConfig>,
) -> Result<Option<(CommandReader, CommandSource)>> {
    let Some(name) = args.source() else {
        return Ok(None);
    };
    let Some(spec) = spec else {
        let flag = match name.as_str() {
            "keyboard" | "gamepad" => name.clone(),
            _ if args.cmd_vel => "cmd-vel".into(),
            _ if args.viewer_commands => "viewer-commands".into(),
            _ => "command-udp".into(),
        };
        return Err(crate::args::FlagError::new(
            flag,
            ": the policy's manifest has no [commands] section to take live commands",
        )
        .into());
    };
    let (writer, reader) = commands::command_channel(spec.names.len());
    let stats = Arc::new(CommandStats::default());
    let stop = Arc::new(AtomicBool::new(false));
    let mut terminal = None;
    let mut viewer = None;
    if args.viewer_commands {
        let (tx, rx) = std::sync::mpsc::sync_channel(64);
        commands::spawn_twists(spec, rx, writer, Arc::clone(&stats), Arc::clone(&stop))
            .context("cannot start the viewer's command thread")?;
        viewer = Some(tx);
        println!("commands: the viewer's /cmd_vel (geometry_msgs/Twist, JSON: Foxglove's Teleop panel)");
    } else if args.keyboard {
        terminal = Some(TerminalGuard::cbreak());
        commands::spawn_keyboard(spec, initial, writer, std::io::stdin(), Arc::clone(&stats))
            .context("cannot start the keyboard thread")?;
        println!(
            "commands: keyboard — W/S ↑/↓ forward, A/D sideways, Q/E ←/→ turn, space resets; Ctrl-C stops"
        );
    } else if args.gamepad {
        let pad = GilrsPad::open()?;
        let pads = pad.connected();
        if pads.is_empty() {
            println!(
                "commands: gamepad — none connected yet; the commands stay at their defaults until one speaks"
            );
        } else {
            println!("commands: gamepad — {}", pads.join(", "));
        }
        commands::spawn_gamepad(spec, writer, pad, Arc::clone(&stats), Arc::clone(&stop))
            .context("cannot start the gamepad thread")?;
    } else if let (true, Some(config)) = (args.cmd_vel, ros2) {
        commands::spawn_cmd_vel(spec, config, writer, Arc::clone(&stats), Arc::clone(&stop))
            .context("--cmd-vel: cannot subscribe /cmd_vel")?;
        println!(
            "commands: ROS 2 /cmd_vel (geometry_msgs/msg/Twist) on {}, domain {}",
            config.interface, config.domain
        );
    } else if let Some(addr) = args.command_udp {
        let (local, _) = commands::spawn_udp(spec, addr, writer, Arc::clone(&stats), Arc::clone(&stop))
            .with_context(|| format!("--command-udp: cannot listen on {addr}"))?;
        println!("commands: send to udp://{local}");
    }
    Ok(Some((
        reader,
        CommandSource {
            stats,
            viewer,
            stop,
            _terminal: terminal,
        },
    )))
}
