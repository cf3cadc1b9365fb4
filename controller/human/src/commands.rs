//! An operator's commands for command-driven policies (a velocity-command "joystick" policy):
//! from the keyboard of a terminal, a gamepad (`gilrs`) or UDP datagrams, each source on its own
//! thread, handed to the control loop through a triple buffer (no lock, no allocation on the
//! loop's side). What the commands mean, their ranges, ramps and key steps are the policy
//! manifest's `[commands]` section ([`CommandSpec`], in the policy's contract).
//!
//! Sources publish *targets*: the loop clamps them to the ranges, moves its commands towards them
//! no faster than the ramps allow, and falls back to the defaults when a source has been silent
//! for `timeout_s` (a dropped link does not leave the robot walking).

use std::io::Read;
use std::net::{SocketAddr, UdpSocket};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

pub use policy::commands::{AxisBinding, CommandKind, CommandSpec, MAX_COMMANDS, PadAxis};

/// The version of the UDP command message this build reads.
pub const UDP_MESSAGE_VERSION: u64 = 1;

/// What a source published last: targets for the commands, and when.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CommandTargets {
    /// Targets, the first `n` used.
    pub values: [f64; MAX_COMMANDS],
    /// When the source published them; `None` before it did.
    pub at: Option<Instant>,
    /// They stand until the source says otherwise (a keyboard holds its state): no timeout.
    pub lasting: bool,
}

impl Default for CommandTargets {
    fn default() -> Self {
        Self {
            values: [0.0; MAX_COMMANDS],
            at: None,
            lasting: false,
        }
    }
}

/// Counts a source keeps, readable from any thread.
#[derive(Debug, Default)]
pub struct CommandStats {
    /// Messages or events taken.
    pub accepted: AtomicU64,
    /// Messages that did not parse, had the wrong version or the wrong number of values.
    pub malformed: AtomicU64,
    /// Messages with a value outside its range.
    pub out_of_range: AtomicU64,
    /// Messages taken with a value clamped into its range (a twist's: counted among the
    /// accepted, not the dropped).
    pub clamped: AtomicU64,
    /// Messages older than one already taken (sequence number not above the newest).
    pub stale: AtomicU64,
    /// Datagrams beyond their sender's rate ([`SOURCE_RATE_HZ`]), dropped unread.
    pub flooded: AtomicU64,
}

/// Datagrams a second one sender may have parsed (a command source sends at 50–500 Hz); beyond
/// it they are dropped before parsing, so a flood costs the receiving thread a `recv` each, not
/// a parse, and never starves the machine's other threads.
pub const SOURCE_RATE_HZ: f64 = 1000.0;

/// Senders the limiter tells apart at once (the least recently heard gives way).
const SOURCES: usize = 16;

/// A token bucket per sender: [`SOURCE_RATE_HZ`], bursts of a tenth of a second.
#[derive(Debug)]
struct SourceLimiter {
    buckets: [(Option<SocketAddr>, f64, Instant); SOURCES],
}

impl SourceLimiter {
    fn new(now: Instant) -> Self {
        Self {
            buckets: [(None, 0.0, now); SOURCES],
        }
    }

    /// Whether a datagram from `from` at `now` may be parsed.
    fn allow(&mut self, from: SocketAddr, now: Instant) -> bool {
        let burst = SOURCE_RATE_HZ / 10.0;
        let slot = match self.buckets.iter().position(|b| b.0 == Some(from)) {
            Some(i) => i,
            None => {
                let oldest = (0..SOURCES)
                    .min_by_key(|&i| (self.buckets[i].0.is_some(), self.buckets[i].2))
                    .expect("SOURCES > 0");
                self.buckets[oldest] = (Some(from), burst, now);
                oldest
            }
        };
        let (_, tokens, last) = &mut self.buckets[slot];
        *tokens = (*tokens + now.duration_since(*last).as_secs_f64() * SOURCE_RATE_HZ).min(burst);
        *last = now;
        if *tokens >= 1.0 {
            *tokens -= 1.0;
            true
        } else {
            false
        }
    }
}

impl CommandStats {
    /// Messages dropped, for any reason.
    pub fn dropped(&self) -> u64 {
        self.malformed.load(Ordering::Relaxed)
            + self.out_of_range.load(Ordering::Relaxed)
            + self.stale.load(Ordering::Relaxed)
            + self.flooded.load(Ordering::Relaxed)
    }
}

impl std::fmt::Display for CommandStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} accepted{}, {} dropped ({} malformed, {} out of range, {} out of order",
            self.accepted.load(Ordering::Relaxed),
            match self.clamped.load(Ordering::Relaxed) {
                0 => String::new(),
                n => format!(" ({n} clamped into their ranges)"),
            },
            self.dropped(),
            self.malformed.load(Ordering::Relaxed),
            self.out_of_range.load(Ordering::Relaxed),
            self.stale.load(Ordering::Relaxed),
        )?;
        match self.flooded.load(Ordering::Relaxed) {
            0 => f.write_str(")"),
            n => write!(f, ", {n} beyond their sender's rate, unread)"),
        }
    }
}

/// The publishing half, owned by a source's thread.
#[derive(Debug)]
pub struct CommandWriter {
    input: triple_buffer::Input<CommandTargets>,
    n: usize,
}

/// The loop's half.
#[derive(Debug)]
pub struct CommandReader {
    output: triple_buffer::Output<CommandTargets>,
}

/// A writer and a reader for `n` commands.
pub fn command_channel(n: usize) -> (CommandWriter, CommandReader) {
    let (input, output) = triple_buffer::triple_buffer(&CommandTargets::default());
    (
        CommandWriter {
            input,
            n: n.min(MAX_COMMANDS),
        },
        CommandReader { output },
    )
}

impl CommandWriter {
    /// Publishes targets (the first `n` of `values`), stamped now; they fall back to the
    /// defaults once older than the manifest's `timeout_s` (a stream that stops is a link lost).
    pub fn publish(&mut self, values: &[f64]) {
        self.write(values, false);
    }

    /// Publishes targets that stand until the next (a keyboard's state), with no timeout.
    pub fn publish_lasting(&mut self, values: &[f64]) {
        self.write(values, true);
    }

    fn write(&mut self, values: &[f64], lasting: bool) {
        let mut t = CommandTargets {
            at: Some(Instant::now()),
            lasting,
            ..CommandTargets::default()
        };
        for (o, v) in t.values.iter_mut().zip(values.iter().take(self.n)) {
            *o = *v;
        }
        self.input.write(t);
    }
}

impl CommandReader {
    /// The newest targets. Lock- and allocation-free.
    pub fn latest(&mut self) -> CommandTargets {
        *self.output.read()
    }
}

/// The commands the loop feeds its policy: the newest targets of a source, clamped, ramped, and
/// back to the defaults when the source falls silent. Sized once; `update` does not allocate.
#[derive(Debug)]
pub struct LiveCommands {
    spec: CommandSpec,
    reader: Option<CommandReader>,
    current: Vec<f64>,
    target: Vec<f64>,
    defaults: Vec<f64>,
    /// Largest change per tick.
    step_per_tick: Vec<f64>,
    timeout: Duration,
    /// Ticks a source was silent for longer than the timeout while it had spoken before.
    pub silent_ticks: u64,
}

impl LiveCommands {
    /// Commands starting at `initial` (checked against `spec`), updated every `dt` seconds from
    /// `reader` (none: they stay at `initial`).
    pub fn new(spec: &CommandSpec, initial: &[f64], reader: Option<CommandReader>, dt: f64) -> Self {
        let n = spec.names.len();
        let ramp = spec.ramp.clone().unwrap_or_else(|| vec![f64::INFINITY; n]);
        Self {
            spec: spec.clone(),
            reader,
            current: initial.to_vec(),
            target: initial.to_vec(),
            defaults: spec.defaults(),
            step_per_tick: ramp.iter().map(|r| r * dt).collect(),
            timeout: Duration::try_from_secs_f64(spec.timeout_s).unwrap_or(Duration::from_millis(500)),
            silent_ticks: 0,
        }
    }

    /// Moves the commands one tick towards the newest targets and returns them.
    pub fn update(&mut self, now: Instant) -> &[f64] {
        if let Some(reader) = &mut self.reader {
            let t = reader.latest();
            match t.at {
                Some(at) if t.lasting || now.saturating_duration_since(at) <= self.timeout => {
                    let n = self.target.len();
                    self.target.copy_from_slice(&t.values[..n]);
                    self.spec.clamp(&mut self.target);
                }
                Some(_) => {
                    self.silent_ticks += 1;
                    self.target.copy_from_slice(&self.defaults);
                }
                None => {}
            }
        }
        for ((c, t), s) in self.current.iter_mut().zip(&self.target).zip(&self.step_per_tick) {
            *c += (t - *c).clamp(-s, *s);
        }
        &self.current
    }

    /// Puts the commands at `values` (clamped) with no source and no ramp: a replay's way to
    /// feed back what a run recorded.
    pub fn set(&mut self, values: &[f64]) {
        self.reader = None;
        for ((c, t), v) in self.current.iter_mut().zip(self.target.iter_mut()).zip(values) {
            (*c, *t) = (*v, *v);
        }
    }

    /// Holds the commands at their defaults (at rest) this tick, the targets kept: once let go
    /// they ramp to what the sources say. A harness start's way of standing the robot on its feet
    /// before it walks.
    pub fn rest(&mut self) -> &[f64] {
        self.current.copy_from_slice(&self.defaults);
        &self.current
    }

    /// Brings the commands to their defaults (at rest: zero velocity) over `ticks` updates, the
    /// sources let go: a soft stop's way to a robot standing under its policy.
    pub fn wind_down(&mut self, ticks: u32) {
        self.reader = None;
        self.target.copy_from_slice(&self.defaults);
        for ((s, c), t) in self.step_per_tick.iter_mut().zip(&self.current).zip(&self.target) {
            *s = ((t - c).abs() / f64::from(ticks.max(1))).max(f64::MIN_POSITIVE);
        }
    }

    /// The commands of the last update.
    pub fn current(&self) -> &[f64] {
        &self.current
    }

    /// What the commands mean.
    pub fn spec(&self) -> &CommandSpec {
        &self.spec
    }
}

// ---- Keyboard ------------------------------------------------------------------------------

/// What a key does.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum KeyAction {
    /// Adds `sign ×` its step to command `index`.
    Nudge {
        /// The command.
        index: usize,
        /// +1 or −1.
        sign: f64,
    },
    /// Every command back to its default.
    Reset,
}

/// The keys: W/S and ↑/↓ drive command 0 (forward), A/D command 1 (left/right), Q/E and ←/→
/// command 2 (turn left/right), space resets. Parses a byte stream as a terminal sends it
/// (arrows as `ESC [ A…D`).
#[derive(Debug, Default)]
pub struct KeyParser {
    escape: u8,
}

impl KeyParser {
    /// The action of the next byte, if it completes one.
    pub fn feed(&mut self, byte: u8) -> Option<KeyAction> {
        let nudge = |index, sign| Some(KeyAction::Nudge { index, sign });
        match (self.escape, byte) {
            (0, 0x1b) => {
                self.escape = 1;
                None
            }
            (1, b'[' | b'O') => {
                self.escape = 2;
                None
            }
            (2, arrow) => {
                self.escape = 0;
                match arrow {
                    b'A' => nudge(0, 1.0),
                    b'B' => nudge(0, -1.0),
                    b'D' => nudge(2, 1.0),
                    b'C' => nudge(2, -1.0),
                    _ => None,
                }
            }
            (_, key) => {
                self.escape = 0;
                match key.to_ascii_lowercase() {
                    b'w' => nudge(0, 1.0),
                    b's' => nudge(0, -1.0),
                    b'a' => nudge(1, 1.0),
                    b'd' => nudge(1, -1.0),
                    b'q' => nudge(2, 1.0),
                    b'e' => nudge(2, -1.0),
                    b' ' => Some(KeyAction::Reset),
                    _ => None,
                }
            }
        }
    }
}

/// The keyboard's targets: each key press moves one command by its step, within its range.
#[derive(Debug)]
pub struct KeyboardTeleop {
    spec: CommandSpec,
    steps: Vec<f64>,
    targets: Vec<f64>,
    parser: KeyParser,
}

impl KeyboardTeleop {
    /// Starting from `initial`.
    pub fn new(spec: &CommandSpec, initial: &[f64]) -> Self {
        Self {
            spec: spec.clone(),
            steps: spec.steps(),
            targets: initial.to_vec(),
            parser: KeyParser::default(),
        }
    }

    /// Takes one byte; returns the new targets when it changed them.
    pub fn feed(&mut self, byte: u8) -> Option<&[f64]> {
        match self.parser.feed(byte)? {
            KeyAction::Nudge { index, sign } => {
                let step = *self.steps.get(index)?;
                self.targets[index] += sign * step;
            }
            KeyAction::Reset => self.targets.copy_from_slice(&self.spec.defaults()),
        }
        self.spec.clamp(&mut self.targets);
        Some(&self.targets)
    }
}

/// The terminal put into cbreak mode (keys arrive one by one, unechoed; Ctrl-C still signals and
/// output still ends lines properly), restored when dropped.
#[derive(Debug)]
pub struct TerminalGuard {
    saved: Option<rustix::termios::Termios>,
}

impl TerminalGuard {
    /// Cbreak mode on standard input when it is a terminal (otherwise nothing to do).
    pub fn cbreak() -> Self {
        use rustix::termios::{LocalModes, OptionalActions, isatty, tcgetattr, tcsetattr};
        let stdin = rustix::stdio::stdin();
        if !isatty(stdin) {
            return Self { saved: None };
        }
        let Ok(saved) = tcgetattr(stdin) else {
            return Self { saved: None };
        };
        let mut raw = saved.clone();
        raw.local_modes.remove(LocalModes::ICANON | LocalModes::ECHO);
        if tcsetattr(stdin, OptionalActions::Now, &raw).is_err() {
            return Self { saved: None };
        }
        Self { saved: Some(saved) }
    }
}

impl Drop for TerminalGuard {
    fn drop(&mut self) {
        if let Some(saved) = &self.saved {
            let _ = rustix::termios::tcsetattr(
                rustix::stdio::stdin(),
                rustix::termios::OptionalActions::Now,
                saved,
            );
        }
    }
}

/// Reads keys from `input` on a thread of its own and publishes the targets they set.
pub fn spawn_keyboard(
    spec: &CommandSpec,
    initial: &[f64],
    mut writer: CommandWriter,
    mut input: impl Read + Send + 'static,
    stats: Arc<CommandStats>,
) -> std::io::Result<std::thread::JoinHandle<()>> {
    let mut teleop = KeyboardTeleop::new(spec, initial);
    writer.publish_lasting(initial);
    std::thread::Builder::new()
        .name("keyboard".into())
        .spawn(move || {
            let mut byte = [0u8; 1];
            // A keyboard holds its state: its targets stand until the next key.
            while let Ok(1) = input.read(&mut byte) {
                if let Some(t) = teleop.feed(byte[0]) {
                    stats.accepted.fetch_add(1, Ordering::Relaxed);
                    writer.publish_lasting(t);
                }
            }
        })
}

// ---- Gamepad -------------------------------------------------------------------------------

/// What a gamepad reports.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PadEvent {
    /// An axis moved to a value in [−1, 1].
    Axis(PadAxis, f32),
    /// The pad's south button (A / cross): every command back to its default.
    Reset,
    /// The pad is gone.
    Disconnected,
}

/// Where gamepad events come from: `gilrs` on a real machine, a script in tests.
pub trait PadEvents: Send {
    /// The next event, waiting at most `timeout`.
    fn next(&mut self, timeout: Duration) -> Option<PadEvent>;
}

/// Gamepads through `gilrs` (udev/evdev on Linux): the first pad that speaks.
pub struct GilrsPad {
    gilrs: gilrs::Gilrs,
}

impl std::fmt::Debug for GilrsPad {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GilrsPad").finish_non_exhaustive()
    }
}

impl GilrsPad {
    /// Opens the gamepad subsystem; the error says why it cannot.
    pub fn open() -> Result<Self, crate::HumanError> {
        let gilrs = gilrs::Gilrs::new().map_err(|e| crate::HumanError::Gamepad(e.to_string()))?;
        Ok(Self { gilrs })
    }

    /// Names of the gamepads connected now.
    pub fn connected(&self) -> Vec<String> {
        self.gilrs.gamepads().map(|(_, g)| g.name().to_owned()).collect()
    }
}

impl PadEvents for GilrsPad {
    fn next(&mut self, timeout: Duration) -> Option<PadEvent> {
        use gilrs::{Axis, Button, EventType};
        let ev = self.gilrs.next_event_blocking(Some(timeout))?;
        match ev.event {
            EventType::AxisChanged(axis, v, _) => {
                let axis = match axis {
                    Axis::LeftStickX => PadAxis::LeftX,
                    Axis::LeftStickY => PadAxis::LeftY,
                    Axis::RightStickX => PadAxis::RightX,
                    Axis::RightStickY => PadAxis::RightY,
                    _ => return None,
                };
                Some(PadEvent::Axis(axis, v))
            }
            EventType::ButtonPressed(Button::South, _) => Some(PadEvent::Reset),
            EventType::Disconnected => Some(PadEvent::Disconnected),
            _ => None,
        }
    }
}

/// Stick deflection below which an axis reads zero (worn sticks rest a little off centre).
pub const STICK_DEADZONE: f32 = 0.08;

/// The gamepad's targets: each bound axis scales its command between the range's ends (full
/// deflection = the end of the range in that direction), outside a small dead zone.
#[derive(Debug)]
pub struct GamepadTeleop {
    spec: CommandSpec,
    bindings: Vec<Option<AxisBinding>>,
    targets: Vec<f64>,
}

impl GamepadTeleop {
    /// Starting at the defaults.
    pub fn new(spec: &CommandSpec) -> Self {
        Self {
            spec: spec.clone(),
            bindings: spec.gamepad_bindings(),
            targets: spec.defaults(),
        }
    }

    /// Takes one event; returns the targets.
    pub fn apply(&mut self, event: PadEvent) -> &[f64] {
        match event {
            PadEvent::Axis(axis, raw) => {
                let a = if raw.abs() < STICK_DEADZONE || !raw.is_finite() {
                    0.0
                } else {
                    f64::from(raw.clamp(-1.0, 1.0))
                };
                let defaults = self.spec.defaults();
                for (((t, b), [lo, hi]), d) in self
                    .targets
                    .iter_mut()
                    .zip(&self.bindings)
                    .zip(&self.spec.ranges)
                    .zip(defaults)
                {
                    let Some(b) = b.filter(|b| b.axis == axis) else {
                        continue;
                    };
                    let a = if b.invert { -a } else { a };
                    *t = if a >= 0.0 {
                        d + a * (hi - d)
                    } else {
                        d + a * (d - lo)
                    };
                }
            }
            PadEvent::Reset | PadEvent::Disconnected => self.targets = self.spec.defaults(),
        }
        &self.targets
    }
}

/// How often the gamepad's thread re-publishes its targets while the sticks rest (pads report
/// changes only; the loop's timeout must not take a held stick for a lost pad).
pub const PAD_REPUBLISH: Duration = Duration::from_millis(50);

/// Reads `pad` on a thread of its own and publishes the targets it sets until `stop`.
pub fn spawn_gamepad(
    spec: &CommandSpec,
    mut writer: CommandWriter,
    mut pad: impl PadEvents + 'static,
    stats: Arc<CommandStats>,
    stop: Arc<AtomicBool>,
) -> std::io::Result<std::thread::JoinHandle<()>> {
    let mut teleop = GamepadTeleop::new(spec);
    std::thread::Builder::new().name("gamepad".into()).spawn(move || {
        let mut connected = true;
        while !stop.load(Ordering::Relaxed) {
            match pad.next(PAD_REPUBLISH) {
                Some(PadEvent::Disconnected) => {
                    tracing::warn!("gamepad disconnected: commands fall back to their defaults");
                    teleop.apply(PadEvent::Disconnected);
                    connected = false;
                }
                Some(e) => {
                    stats.accepted.fetch_add(1, Ordering::Relaxed);
                    let t = teleop.apply(e);
                    writer.publish(t);
                    connected = true;
                }
                // Quiet: the sticks rest where they are.
                None if connected => writer.publish(&teleop.targets),
                None => {}
            }
        }
    })
}

// ---- UDP -----------------------------------------------------------------------------------

/// The UDP command message, version 1: one JSON object per datagram,
/// `{"version": 1, "seq": 17, "command": [0.3, 0.0, 0.0]}` — `seq` rising (a datagram whose
/// `seq` is at most [`SEQ_WINDOW`] behind the newest taken is dropped as late or repeated; one
/// further behind is a sender that started over, and is taken), `session` optional (a sender
/// that starts over may say so with a new one: its `seq` then starts afresh), `command` one
/// value per manifest command, in its order and within its range (a message outside is dropped
/// whole).
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct UdpCommand {
    /// Message version: [`UDP_MESSAGE_VERSION`].
    pub version: u64,
    /// Sequence number, rising.
    pub seq: u64,
    /// The sender's session (default 0): a new one restarts the sequence.
    #[serde(default)]
    pub session: u64,
    /// The commands.
    pub command: Vec<f64>,
}

/// How far behind the newest taken a datagram's `seq` may be and still count as late or
/// repeated (dropped); further behind, the sender started over (taken). One datagram with a
/// huge `seq` thus cannot lock the commands out for the rest of the run.
pub const SEQ_WINDOW: u64 = 1024;

/// The newest datagram taken: its session and sequence number.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Newest {
    /// Its session.
    pub session: u64,
    /// Its sequence number.
    pub seq: u64,
}

impl UdpCommand {
    /// This message as the newest taken.
    pub fn newest(&self) -> Newest {
        Newest {
            session: self.session,
            seq: self.seq,
        }
    }
}

/// Largest datagram read; anything longer is malformed.
pub const MAX_DATAGRAM: usize = 1024;

/// Why a datagram was dropped.
#[derive(Debug, Clone, PartialEq)]
pub enum Dropped {
    /// Not a version-1 message with the right number of values.
    Malformed(String),
    /// A value outside its range.
    OutOfRange(policy::commands::CommandValuesError),
    /// Late or repeated: at most [`SEQ_WINDOW`] behind the newest taken, or equal to it.
    OutOfOrder,
}

/// Checks one datagram against `spec` and the newest sequence number taken.
pub fn parse_datagram(
    spec: &CommandSpec,
    bytes: &[u8],
    newest: Option<Newest>,
) -> Result<UdpCommand, Dropped> {
    let m: UdpCommand = serde_json::from_slice(bytes).map_err(|e| Dropped::Malformed(e.to_string()))?;
    if m.version != UDP_MESSAGE_VERSION {
        return Err(Dropped::Malformed(format!(
            "version {} (this build reads {UDP_MESSAGE_VERSION})",
            m.version
        )));
    }
    if m.command.len() != spec.names.len() {
        return Err(Dropped::Malformed(format!(
            "{} values for {} commands",
            m.command.len(),
            spec.names.len()
        )));
    }
    spec.check_values(&m.command).map_err(Dropped::OutOfRange)?;
    let late =
        newest.is_some_and(|n| n.session == m.session && m.seq <= n.seq && n.seq - m.seq <= SEQ_WINDOW);
    if late {
        return Err(Dropped::OutOfOrder);
    }
    Ok(m)
}

/// Binds `addr` (loopback unless configured otherwise by the caller) and publishes every valid
/// datagram's commands on a thread of its own until `stop`; returns the bound address.
pub fn spawn_udp(
    spec: &CommandSpec,
    addr: SocketAddr,
    mut writer: CommandWriter,
    stats: Arc<CommandStats>,
    stop: Arc<AtomicBool>,
) -> std::io::Result<(SocketAddr, std::thread::JoinHandle<()>)> {
    let socket = UdpSocket::bind(addr)?;
    socket.set_read_timeout(Some(Duration::from_millis(50)))?;
    let local = socket.local_addr()?;
    let spec = spec.clone();
    let handle = std::thread::Builder::new()
        .name("udp-commands".into())
        .spawn(move || {
            let mut buf = [0u8; MAX_DATAGRAM + 1];
            let mut newest = None;
            let mut limiter = SourceLimiter::new(Instant::now());
            while !stop.load(Ordering::Relaxed) {
                let Ok((len, from)) = socket.recv_from(&mut buf) else {
                    continue;
                };
                if !limiter.allow(from, Instant::now()) {
                    if stats.flooded.fetch_add(1, Ordering::Relaxed) == 0 {
                        tracing::warn!(%from, "udp commands: a sender beyond {SOURCE_RATE_HZ} datagrams/s; the rest are dropped unread");
                    }
                    continue;
                }
                let counted = if len > MAX_DATAGRAM {
                    Err(Dropped::Malformed(format!("longer than {MAX_DATAGRAM} bytes")))
                } else {
                    parse_datagram(&spec, &buf[..len], newest)
                };
                match counted {
                    Ok(m) => {
                        newest = Some(m.newest());
                        stats.accepted.fetch_add(1, Ordering::Relaxed);
                        writer.publish(&m.command);
                    }
                    Err(why) => {
                        let counter = match &why {
                            Dropped::Malformed(_) => &stats.malformed,
                            Dropped::OutOfRange(_) => &stats.out_of_range,
                            Dropped::OutOfOrder => &stats.stale,
                        };
                        // The first of each kind is worth a line; a flood is counted.
                        if counter.fetch_add(1, Ordering::Relaxed) == 0 {
                            tracing::warn!("udp command dropped: {why:?}");
                        }
                    }
                }
            }
        })?;
    Ok((local, handle))
}

// ---- ROS 2 /cmd_vel -------------------------------------------------------------------------

/// Takes twists `[linear xyz, angular xyz]` from `twists` (a viewer's /cmd_vel) and publishes
/// them as the manifest's commands ([`twist_commands`]), until `stop` or the sender goes.
pub fn spawn_twists(
    spec: &CommandSpec,
    twists: std::sync::mpsc::Receiver<[f64; 6]>,
    mut writer: CommandWriter,
    stats: Arc<CommandStats>,
    stop: Arc<AtomicBool>,
) -> std::io::Result<std::thread::JoinHandle<()>> {
    let spec = spec.clone();
    let kinds = spec.kinds();
    std::thread::Builder::new()
        .name("viewer-commands".into())
        .spawn(move || {
            let mut values = spec.defaults();
            while !stop.load(Ordering::Relaxed) {
                match twists.recv_timeout(Duration::from_millis(50)) {
                    Ok(twist) => take_twist(
                        &spec,
                        &kinds,
                        twist,
                        &mut values,
                        &stats,
                        &mut writer,
                        "the viewer's /cmd_vel",
                    ),
                    Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {}
                    Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => break,
                }
            }
        })
}

/// The largest speed or turning rate a twist may carry, m/s or rad/s: beyond it the message is
/// no velocity command (a blob read as a Twist), dropped as malformed rather than clamped.
pub const TWIST_LIMIT: f64 = 100.0;

/// Takes one twist from `source`: a plausible one becomes the commands (clamped into their
/// ranges, counted as such) and is published; any other is dropped as malformed, said once.
fn take_twist(
    spec: &CommandSpec,
    kinds: &[CommandKind],
    twist: [f64; 6],
    values: &mut [f64],
    stats: &CommandStats,
    writer: &mut CommandWriter,
    source: &str,
) {
    if !twist.iter().all(|v| v.is_finite() && v.abs() <= TWIST_LIMIT) {
        if stats.malformed.fetch_add(1, Ordering::Relaxed) == 0 {
            tracing::warn!(
                "{source}: a twist beyond ±{TWIST_LIMIT} dropped: {twist:?} (further ones not reported)"
            );
        }
        return;
    }
    if twist_commands(spec, kinds, twist, values) > 0 {
        stats.clamped.fetch_add(1, Ordering::Relaxed);
    }
    stats.accepted.fetch_add(1, Ordering::Relaxed);
    writer.publish(values);
}

/// A `geometry_msgs/msg/Twist` as the manifest's commands: linear x → the forward speed command,
/// linear y → the leftward one, angular z → the turning rate (by each command's kind), every
/// other command at its default; each clamped to its range. Returns how many were clamped.
pub fn twist_commands(spec: &CommandSpec, kinds: &[CommandKind], twist: [f64; 6], out: &mut [f64]) -> usize {
    let mut clamped = 0;
    let defaults = spec.defaults();
    for (((o, kind), range), default) in out.iter_mut().zip(kinds).zip(&spec.ranges).zip(defaults) {
        let v = match kind {
            CommandKind::LinVelX => twist[0],
            CommandKind::LinVelY => twist[1],
            CommandKind::AngVelZ => twist[5],
            CommandKind::Other => default,
        };
        // NaN goes to the default: a command is never not a number.
        let v = if v.is_finite() { v } else { default };
        *o = v.clamp(range[0], range[1]);
        clamped += usize::from(*o != v);
    }
    clamped
}

/// Subscribes ROS 2's `/cmd_vel` (`geometry_msgs/msg/Twist`, as ROS 2 names it on DDS) on
/// `config`'s domain and interface and publishes each message's commands ([`twist_commands`]) on
/// a thread of its own until `stop`. A message that is not a Twist is dropped and counted;
/// silence hands back to the defaults after the manifest's `timeout_s`, as with UDP.
pub fn spawn_cmd_vel(
    spec: &CommandSpec,
    config: &dds::DdsConfig,
    mut writer: CommandWriter,
    stats: Arc<CommandStats>,
    stop: Arc<AtomicBool>,
) -> Result<std::thread::JoinHandle<()>, dds::DdsError> {
    let participant = dds::Participant::join(config)?;
    let mut subscription = participant.subscription(
        &dds::names::ros2_topic("/cmd_vel"),
        &dds::names::ros2_type("geometry_msgs/msg/Twist"),
        dds::Delivery::Stream,
    )?;
    let io = |e: std::io::Error| dds::DdsError::Middleware(format!("/cmd_vel: {e}"));
    let mut poll = dds::mio::Poll::new().map_err(io)?;
    subscription
        .register(poll.registry(), dds::mio::Token(0))
        .map_err(io)?;
    let spec = spec.clone();
    let kinds = spec.kinds();
    std::thread::Builder::new()
        .name("cmd-vel".into())
        .spawn(move || {
            let mut events = dds::mio::Events::with_capacity(4);
            let mut values = spec.defaults();
            while !stop.load(Ordering::Relaxed) {
                let _ = poll.poll(&mut events, Some(Duration::from_millis(50)));
                let taken = subscription.take_all(&mut |sample| match dds::ros2::decode_twist(sample) {
                    Ok(twist) => {
                        take_twist(&spec, &kinds, twist, &mut values, &stats, &mut writer, "/cmd_vel");
                    }
                    Err(e) => {
                        if stats.malformed.fetch_add(1, Ordering::Relaxed) == 0 {
                            tracing::warn!("/cmd_vel: a message that is not a Twist dropped: {e}");
                        }
                    }
                });
                if let Err(e) = taken {
                    tracing::warn!("/cmd_vel: {e}");
                    break;
                }
            }
            // The topic before its participant.
            drop(subscription);
            drop(participant);
        })
        .map_err(io)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn walk() -> CommandSpec {
        toml::from_str(
            r#"
            names = ["lin_vel_x", "lin_vel_y", "ang_vel_z"]
            ranges = [[-0.2, 0.4], [-0.2, 0.2], [-1.0, 1.0]]
            ramp = [0.5, 0.5, 2.0]
            "#,
        )
        .unwrap()
    }

    #[test]
    fn a_flooding_sender_is_cut_to_its_rate_and_another_sender_still_gets_through() {
        let t0 = Instant::now();
        let mut limiter = SourceLimiter::new(t0);
        let (flood, operator): (SocketAddr, SocketAddr) = (
            "127.0.0.1:4000".parse().unwrap(),
            "127.0.0.1:4001".parse().unwrap(),
        );
        // 70 000 datagrams within one millisecond: its burst (a tenth of a second's worth) passes.
        let passed = (0..70_000)
            .filter(|&k| limiter.allow(flood, t0 + Duration::from_nanos(k * 14)))
            .count();
        let burst = SOURCE_RATE_HZ / 10.0;
        assert!((burst..=burst + 1.0).contains(&(passed as f64)), "{passed}");
        // The operator, meanwhile, at 100 Hz: every datagram taken.
        let at = t0 + Duration::from_millis(1);
        assert!((0..100).all(|k| limiter.allow(operator, at + Duration::from_millis(10 * k))));
        // A second later the flood has its rate again, not its backlog.
        let later = t0 + Duration::from_secs(1);
        let passed = (0..10_000).filter(|_| limiter.allow(flood, later)).count();
        assert_eq!(passed as f64, SOURCE_RATE_HZ / 10.0);
    }

    #[test]
    fn a_twist_drives_the_commands_of_its_kinds_clamped_to_their_ranges() {
        let spec = walk();
        let kinds = spec.kinds();
        let mut out = [0.0; 3];
        // Forward 1 m/s (range to 0.4), leftward 0.1, turning 0.5; linear z and angular x ignored.
        let clamped = twist_commands(&spec, &kinds, [1.0, 0.1, 9.0, 9.0, 0.0, 0.5], &mut out);
        assert_eq!((out, clamped), ([0.4, 0.1, 0.5], 1));
        let clamped = twist_commands(&spec, &kinds, [f64::NAN, -5.0, 0.0, 0.0, 0.0, 0.0], &mut out);
        assert_eq!((out, clamped), ([0.0, -0.2, 0.0], 1));
    }

    #[test]
    fn a_clamped_twist_is_taken_and_said_so_and_an_absurd_one_is_dropped_as_malformed() {
        let spec = walk();
        let kinds = spec.kinds();
        let (mut writer, mut reader) = command_channel(3);
        let stats = CommandStats::default();
        let mut values = spec.defaults();
        // 1 m/s forward: clamped to the range's 0.4, applied, not dropped.
        take_twist(
            &spec,
            &kinds,
            [1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            &mut values,
            &stats,
            &mut writer,
            "t",
        );
        assert_eq!(reader.latest().values[0], 0.4);
        // A blob's doubles: no velocity, dropped, the commands as they were.
        take_twist(
            &spec,
            &kinds,
            [1e300, 0.0, 0.0, 0.0, 0.0, 0.0],
            &mut values,
            &stats,
            &mut writer,
            "t",
        );
        take_twist(
            &spec,
            &kinds,
            [0.1, f64::NAN, 0.0, 0.0, 0.0, 0.0],
            &mut values,
            &stats,
            &mut writer,
            "t",
        );
        assert_eq!(reader.latest().values[0], 0.4);
        assert_eq!(
            stats.to_string(),
            "1 accepted (1 clamped into their ranges), 2 dropped (2 malformed, 0 out of range, 0 out of order)"
        );
    }

    #[test]
    fn keys_nudge_within_the_ranges_and_space_resets() {
        let spec = walk();
        spec.check().unwrap();
        let mut k = KeyboardTeleop::new(&spec, &spec.defaults());
        for _ in 0..3 {
            k.feed(b'w');
        }
        // A tenth of the larger end, three times: 3 × 0.04.
        assert!((k.targets[0] - 0.12).abs() < 1e-12, "{:?}", k.targets);
        for _ in 0..20 {
            k.feed(b'w');
        }
        assert_eq!(k.targets[0], 0.4);
        // ← is ESC [ D: turn left.
        for b in [0x1b, b'[', b'D'] {
            k.feed(b);
        }
        assert!((k.targets[2] - 0.1).abs() < 1e-12, "{:?}", k.targets);
        assert_eq!(k.feed(b'x'), None);
        assert_eq!(k.feed(b' ').unwrap(), &[0.0, 0.0, 0.0]);
    }

    #[test]
    fn the_loop_ramps_to_targets_and_falls_back_when_a_source_goes_silent() {
        let spec = walk();
        let (mut w, r) = command_channel(3);
        let mut live = LiveCommands::new(&spec, &spec.defaults(), Some(r), 0.02);
        w.publish(&[9.0, 0.1, -1.0]);
        let now = Instant::now();
        // 0.5 m/s² × 0.02 s per tick.
        assert_eq!(live.update(now)[0], 0.01);
        for _ in 0..100 {
            live.update(now);
        }
        // Clamped to the range.
        assert_eq!(live.current(), &[0.4, 0.1, -1.0]);
        // Silent past the timeout: back to the defaults, ramped.
        let later = now + Duration::from_secs(2);
        live.update(later);
        assert!(live.current()[0] < 0.4 && live.silent_ticks == 1);
        for _ in 0..100 {
            live.update(later);
        }
        assert_eq!(live.current(), &[0.0, 0.0, 0.0]);
    }

    #[test]
    fn a_stick_spans_each_range_from_the_default_and_is_still_within_its_dead_zone() {
        let spec = walk();
        let mut pad = GamepadTeleop::new(&spec);
        assert_eq!(pad.apply(PadEvent::Axis(PadAxis::LeftY, 1.0))[0], 0.4);
        assert_eq!(pad.apply(PadEvent::Axis(PadAxis::LeftY, -0.5))[0], -0.1);
        assert_eq!(pad.apply(PadEvent::Axis(PadAxis::LeftY, 0.05))[0], 0.0);
        // Stick right: rightward, a negative lin_vel_y; right stick right turns right.
        assert_eq!(pad.apply(PadEvent::Axis(PadAxis::LeftX, 1.0))[1], -0.2);
        assert_eq!(pad.apply(PadEvent::Axis(PadAxis::RightX, 1.0))[2], -1.0);
        assert_eq!(pad.apply(PadEvent::Reset), &[0.0, 0.0, 0.0]);
    }

    #[test]
    fn a_huge_seq_or_a_sender_that_starts_over_does_not_lock_the_commands_out() {
        let spec = walk();
        let msg = |seq: u64, session: u64| {
            format!(r#"{{"version": 1, "seq": {seq}, "session": {session}, "command": [0.1, 0.0, 0.0]}}"#)
        };
        let at = |seq, session| Some(Newest { session, seq });
        // After seq 2^64 − 1, a sender's seq 1: far behind, it started over: taken.
        assert!(parse_datagram(&spec, msg(1, 0).as_bytes(), at(u64::MAX, 0)).is_ok());
        // Late or repeated within the window: dropped.
        assert_eq!(
            parse_datagram(&spec, msg(99, 0).as_bytes(), at(100, 0)),
            Err(Dropped::OutOfOrder)
        );
        assert_eq!(
            parse_datagram(&spec, msg(100, 0).as_bytes(), at(100, 0)),
            Err(Dropped::OutOfOrder)
        );
        assert_eq!(
            parse_datagram(&spec, msg(5000 - SEQ_WINDOW, 0).as_bytes(), at(5000, 0)),
            Err(Dropped::OutOfOrder)
        );
        assert!(parse_datagram(&spec, msg(5000 - SEQ_WINDOW - 1, 0).as_bytes(), at(5000, 0)).is_ok());
        // A new session starts its sequence afresh.
        assert!(parse_datagram(&spec, msg(0, 7).as_bytes(), at(100, 6)).is_ok());
        // Without a session field, session 0.
        let plain = br#"{"version": 1, "seq": 3, "command": [0.1, 0.0, 0.0]}"#;
        assert_eq!(parse_datagram(&spec, plain, None).unwrap().session, 0);
    }

    #[test]
    fn datagrams_outside_the_contract_are_named_and_dropped() {
        let spec = walk();
        let ok = br#"{"version": 1, "seq": 5, "command": [0.3, 0.0, 0.5]}"#;
        assert_eq!(parse_datagram(&spec, ok, None).unwrap().command, [0.3, 0.0, 0.5]);
        let after = |seq| Some(Newest { session: 0, seq });
        assert_eq!(parse_datagram(&spec, ok, after(5)), Err(Dropped::OutOfOrder));
        let far = br#"{"version": 1, "seq": 6, "command": [0.9, 0.0, 0.5]}"#;
        assert!(
            matches!(parse_datagram(&spec, far, None), Err(Dropped::OutOfRange(e)) if e.to_string().contains("lin_vel_x = 0.9"))
        );
        for bad in [
            &br#"{"version": 2, "seq": 6, "command": [0.1, 0.0, 0.5]}"#[..],
            br#"{"version": 1, "seq": 6, "command": [0.1, 0.0]}"#,
            br#"{"version": 1, "seq": 6, "command": [0.1, 0.0, 0.5], "extra": 1}"#,
            b"\xff\xfe",
            b"ESTOP",
        ] {
            assert!(
                matches!(parse_datagram(&spec, bad, None), Err(Dropped::Malformed(_))),
                "{bad:?}"
            );
        }
    }

    #[test]
    fn a_spec_with_inverted_ranges_or_mismatched_lists_is_named() {
        let mut spec = walk();
        spec.ranges[1] = [0.2, -0.2];
        let (field, m) = spec.check().unwrap_err();
        assert_eq!(field, "commands.ranges");
        assert!(m.contains("lin_vel_y"), "{m}");
        let mut spec = walk();
        spec.ramp = Some(vec![1.0]);
        assert_eq!(spec.check().unwrap_err().0, "commands.ramp");
    }
}
