//! Bench: Unitree's low-level link over DDS (RustDDS on loopback), at the G1's 500 Hz.
//!
//! A board stand-in (a second DDS participant in this process, on its own thread) publishes a
//! `LowState` every 2 ms and stamps every `LowCmd` it receives; the host runs the real link —
//! `HgDriver` on a `DdsLowLevelPort` — one cycle every 2 ms, as the link's bus thread does.
//! 1. Link cycle time: the host's whole cycle (seal and encode the command, hand it to the DDS
//!    thread, take and check the newest state), p50/p99/max.
//! 2. Command to wire: from the cycle's send to the board's DDS reader holding the sample
//!    (through the host's I/O thread, RustDDS and loopback UDP), p50/p99/max.
//! 3. State age at the cycle: how old the newest state the cycle takes is (half a period on
//!    average at best), p50/p99/max.
//! 4. Host CPU per cycle: the link's own work on a port that only copies (the cycle's cost with
//!    the network taken out), and the whole process (both ends, their DDS threads and RustDDS's
//!    event loops) per cycle, from the process's CPU time.
//!
//! Run: `cargo bench -p firmware-bridge --bench unitree_dds` (`cargo test --benches` runs 1 s).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use dds::mio::{Events, Poll, Token};
use dds::{DdsConfig, Delivery, Participant};
use firmware_bridge::mit::driver::{JointCommand, MitJointConfig};
use firmware_bridge::mit::models::find;
use firmware_bridge::unitree::hg::{LOW_CMD_TYPE, LOW_STATE_TYPE, LowCmd, LowState, Sealed as _};
use firmware_bridge::unitree::host::{HgDriver, LowLevelPort};
use firmware_bridge::unitree::wire::{DdsLowLevelPort, LOW_CMD_TOPIC, LOW_STATE_TOPIC};
use test_support::stats::Summary;

const PERIOD: Duration = Duration::from_millis(2);
const MOTORS: usize = 29;

/// Nanoseconds since `epoch` in two reserve words.
fn stamp(epoch: Instant) -> [u32; 2] {
    let n = epoch.elapsed().as_nanos() as u64;
    [n as u32, (n >> 32) as u32]
}

fn unstamp(words: [u32; 2]) -> Duration {
    Duration::from_nanos(u64::from(words[0]) | u64::from(words[1]) << 32)
}

fn joints() -> Vec<MitJointConfig> {
    let model = find("AK80-9").unwrap();
    (0..MOTORS)
        .map(|i| MitJointConfig::new(&format!("j{i}"), i as u8, model))
        .collect()
}

fn commands(k: usize) -> Vec<Option<JointCommand>> {
    (0..MOTORS)
        .map(|i| {
            Some(JointCommand {
                q: 0.2 * ((i + k) as f64 * 0.01).sin(),
                kp: 40.0,
                kd: 1.0,
                ..JointCommand::default()
            })
        })
        .collect()
}

/// The board's side: a state every period (stamped), every command's arrival after its stamp.
fn board(config: DdsConfig, epoch: Instant, stop: Arc<AtomicBool>, arrivals: Arc<Mutex<Vec<Duration>>>) {
    let p = Participant::join(&config).unwrap();
    let states = p
        .publication(LOW_STATE_TOPIC, LOW_STATE_TYPE, Delivery::Stream)
        .unwrap();
    let mut commands = p
        .subscription(LOW_CMD_TOPIC, LOW_CMD_TYPE, Delivery::Stream)
        .unwrap();
    let mut poll = Poll::new().unwrap();
    commands.register(poll.registry(), Token(0)).unwrap();
    let mut events = Events::with_capacity(8);
    let mut state = LowState::default();
    let mut cdr = Vec::new();
    let mut next = Instant::now();
    while !stop.load(Ordering::Acquire) {
        let _ = poll.poll(&mut events, Some(next.saturating_duration_since(Instant::now())));
        commands
            .take_all(&mut |sample| {
                let at = epoch.elapsed();
                if let Ok(c) = LowCmd::read_cdr(sample) {
                    arrivals
                        .lock()
                        .unwrap()
                        .push(at.saturating_sub(unstamp([c.reserve[0], c.reserve[1]])));
                }
            })
            .unwrap();
        if Instant::now() >= next {
            let s = stamp(epoch);
            state.reserve[0] = s[0];
            state.reserve[1] = s[1];
            state.tick = state.tick.wrapping_add(2);
            state.seal();
            state.write_cdr(&mut cdr);
            states.publish(&cdr).unwrap();
            next += PERIOD;
        }
    }
}

/// A port that only copies: the link's own cost per cycle.
#[derive(Debug)]
struct CopyPort {
    state: Vec<u8>,
    sent: usize,
}

impl LowLevelPort for CopyPort {
    fn send(&mut self, cdr: &[u8]) -> std::io::Result<()> {
        self.sent += cdr.len();
        Ok(())
    }
    fn newest_state(&mut self, out: &mut Vec<u8>) -> std::io::Result<bool> {
        out.clear();
        out.extend_from_slice(&self.state);
        Ok(true)
    }
    fn wait_state(&mut self, _: Duration) -> std::io::Result<bool> {
        Ok(true)
    }
    fn state_age(&mut self) -> Option<Duration> {
        Some(Duration::ZERO)
    }
}

/// The DDS port, each command stamped with its send time in its reserve words (after its CRC:
/// the stand-in does not check it).
#[derive(Debug)]
struct Stamped {
    inner: DdsLowLevelPort,
    epoch: Instant,
    buf: Vec<u8>,
}

impl LowLevelPort for Stamped {
    fn send(&mut self, cdr: &[u8]) -> std::io::Result<()> {
        let mut cmd = LowCmd::read_cdr(cdr).map_err(std::io::Error::other)?;
        let s = stamp(self.epoch);
        cmd.reserve[0] = s[0];
        cmd.reserve[1] = s[1];
        cmd.write_cdr(&mut self.buf);
        self.inner.send(&self.buf)
    }
    fn newest_state(&mut self, out: &mut Vec<u8>) -> std::io::Result<bool> {
        self.inner.newest_state(out)
    }
    fn wait_state(&mut self, within: Duration) -> std::io::Result<bool> {
        self.inner.wait_state(within)
    }
    fn state_age(&mut self) -> Option<Duration> {
        self.inner.state_age()
    }
}

/// CPU time of every thread of this process so far (the scheduler's own count, ns).
fn cpu_time() -> Duration {
    let mut total = 0u64;
    for task in std::fs::read_dir("/proc/self/task")
        .into_iter()
        .flatten()
        .flatten()
    {
        if let Ok(text) = std::fs::read_to_string(task.path().join("schedstat")) {
            total += text
                .split_whitespace()
                .next()
                .and_then(|n| n.parse::<u64>().ok())
                .unwrap_or(0);
        }
    }
    Duration::from_nanos(total)
}

fn main() {
    // `cargo bench` passes --bench; `cargo test --benches` (the smoke run) does not.
    let quick = !std::env::args().any(|a| a == "--bench");
    let seconds = if quick { 1 } else { 10 };
    let cycles = seconds * 500;
    println!("Unitree low-level link over DDS (RustDDS, loopback), {MOTORS} motors, 500 Hz, {seconds} s");

    // 4a. The link's own work per cycle.
    let mut state = LowState::default();
    state.seal();
    let mut cdr = Vec::new();
    state.write_cdr(&mut cdr);
    let mut driver = HgDriver::new(CopyPort { state: cdr, sent: 0 }, joints(), PERIOD).unwrap();
    let cmds = commands(0);
    let mut own = Vec::with_capacity(20_000);
    for _ in 0..if quick { 500 } else { 20_000 } {
        let t = Instant::now();
        driver.send(&cmds).unwrap();
        driver.receive().unwrap();
        own.push(t.elapsed());
    }
    let own = Summary::of(&mut own).unwrap();

    let config = DdsConfig {
        domain: 42,
        interface: "lo".into(),
    };
    let epoch = Instant::now();
    let stop = Arc::new(AtomicBool::new(false));
    let arrivals = Arc::new(Mutex::new(Vec::with_capacity(cycles)));
    let peer = {
        let (config, stop, arrivals) = (config.clone(), Arc::clone(&stop), Arc::clone(&arrivals));
        std::thread::Builder::new()
            .name("board-stand-in".into())
            .spawn(move || board(config, epoch, stop, arrivals))
            .unwrap()
    };
    let port = Stamped {
        inner: DdsLowLevelPort::open(&config).unwrap(),
        epoch,
        buf: Vec::with_capacity(LowCmd::CDR_LEN),
    };
    let mut driver = HgDriver::new(port, joints(), PERIOD).unwrap();
    // Discovery: until states flow.
    assert!(
        driver.wait_first(Duration::from_secs(10)).unwrap(),
        "no state from the board stand-in"
    );
    let mut cycle_times = Vec::with_capacity(cycles);
    let mut ages = Vec::with_capacity(cycles);
    let mut cmds = commands(0);
    let cpu_start = cpu_time();
    let mut next = Instant::now();
    for k in 0..cycles {
        std::thread::sleep(next.saturating_duration_since(Instant::now()));
        next += PERIOD;
        let t = Instant::now();
        for (i, c) in cmds.iter_mut().enumerate() {
            if let Some(c) = c {
                c.q = 0.2 * ((i + k) as f64 * 0.01).sin();
            }
        }
        driver.send(&cmds).unwrap();
        driver.receive().unwrap();
        cycle_times.push(t.elapsed());
        let s = driver.state();
        ages.push(
            epoch
                .elapsed()
                .saturating_sub(unstamp([s.reserve[0], s.reserve[1]])),
        );
    }
    let cpu = cpu_time() - cpu_start;
    stop.store(true, Ordering::Release);
    peer.join().unwrap();
    let stats = driver.stats();
    drop(driver);
    let mut arrivals = arrivals.lock().unwrap().clone();
    let received = arrivals.len();
    let us = |d: Duration| d.as_secs_f64() * 1e6;
    let show = |name: &str, s: Option<Summary>| match s {
        Some(s) => println!("  {name:<32} {s}"),
        None => println!("  {name:<32} no samples"),
    };
    show("link cycle (host)", Summary::of(&mut cycle_times));
    show("command to the board's reader", Summary::of(&mut arrivals));
    show("state age at the cycle", Summary::of(&mut ages));
    show("link's own work per cycle", Some(own));
    println!(
        "  whole process CPU per cycle (both ends, DDS threads): {:.1} µs  ({:.1} % of one core)",
        us(cpu) / cycles as f64,
        100.0 * cpu.as_secs_f64() / (cycles as f64 * PERIOD.as_secs_f64())
    );
    println!(
        "  cycles with a fresh state: {} of {cycles}; phase slips forgiven keep the rest from counting as missed",
        stats.states
    );
    println!(
        "  commands received {} of {cycles}; states taken {} with a right CRC, {} wrong, {} malformed",
        received, stats.states, stats.bad_crc, stats.malformed
    );
}
