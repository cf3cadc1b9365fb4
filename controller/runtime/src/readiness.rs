//! What a machine offers the real-time loop (`robodeploy doctor --realtime`): the kernel, the
//! permissions the loop's set-up asks for, the CPU frequency governor, isolated cores, serial
//! adapters' latency timers, SocketCAN interfaces — each read from `/proc` and `/sys` under a root
//! (`/`, or another machine's captured files), each with a verdict and what to change when it falls
//! short — and the timer's wake-up latency measured beside the loop's budget. Nothing is changed.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// How an item stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// As the loop wants it.
    Good,
    /// Falls short: the fix says what to change.
    Short,
    /// Could not be told (the file is not there).
    Unknown,
}

impl std::fmt::Display for Verdict {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // `pad`: a width in the format string lines the verdicts up.
        f.pad(match self {
            Self::Good => "ok",
            Self::Short => "SHORT",
            Self::Unknown => "unknown",
        })
    }
}

/// One thing the machine offers.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Item {
    /// What it is.
    pub name: &'static str,
    /// What was found.
    pub found: String,
    /// How it stands.
    pub verdict: Verdict,
    /// What to change, when it falls short.
    pub fix: Option<String>,
}

impl Item {
    fn new(name: &'static str, found: String, verdict: Verdict, fix: impl Into<Option<String>>) -> Self {
        let fix = if verdict == Verdict::Good {
            None
        } else {
            fix.into()
        };
        Self {
            name,
            found,
            verdict,
            fix,
        }
    }
}

/// The SCHED_FIFO priority the loop's `--realtime` set-up asks for (its bus threads ask 85).
pub const LOOP_PRIORITY: u64 = 80;
/// Locked memory the set-up needs to lock everything it maps: more than a run's working set.
pub const MEMLOCK_NEEDED: u64 = 1 << 30;

/// The most of a `/proc` or `/sys` file read, bytes: they hold a line or a table.
const MOST_READ: u64 = 64 * 1024;

/// A `/proc` or `/sys` file's text: a regular file only (a FIFO, a device or a link to one under
/// a captured root is skipped: opened without waiting for a writer, never read), at most
/// [`MOST_READ`] bytes of it.
fn read_small(path: &Path) -> Option<String> {
    use std::io::Read as _;
    use std::os::unix::fs::OpenOptionsExt as _;
    let file = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK)
        .open(path)
        .ok()?;
    if !file.metadata().ok()?.is_file() {
        return None;
    }
    let mut text = String::new();
    file.take(MOST_READ).read_to_string(&mut text).ok()?;
    Some(text)
}

/// A soft resource limit as `/proc/self/limits` states it.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Limit {
    Unlimited,
    At(u64),
    /// Not stated, or not a number: why.
    Unknown(String),
}

impl Limit {
    fn at_least(&self, needed: u64) -> bool {
        match self {
            Self::Unlimited => true,
            Self::At(v) => *v >= needed,
            Self::Unknown(_) => false,
        }
    }

    fn shown(&self, value: impl Fn(u64) -> String) -> String {
        match self {
            Self::Unlimited => "unlimited".into(),
            Self::At(v) => value(*v),
            Self::Unknown(why) => why.clone(),
        }
    }
}

/// A machine's `/proc` and `/sys`, under `root`.
#[derive(Debug, Clone)]
pub struct Machine {
    root: PathBuf,
}

impl Machine {
    /// This machine.
    pub fn this() -> Self {
        Self::at("/")
    }

    /// The files under `root` (a captured `/proc` and `/sys`, for another machine).
    pub fn at(root: impl Into<PathBuf>) -> Self {
        Self { root: root.into() }
    }

    fn read(&self, path: &str) -> Option<String> {
        read_small(&self.root.join(path.trim_start_matches('/')))
    }

    fn entries(&self, dir: &str) -> Vec<PathBuf> {
        let mut out: Vec<PathBuf> = std::fs::read_dir(self.root.join(dir.trim_start_matches('/')))
            .into_iter()
            .flatten()
            .flatten()
            .map(|e| e.path())
            .collect();
        out.sort();
        out
    }

    /// Every item, in the order a person fixes them.
    pub fn audit(&self) -> Vec<Item> {
        let mut items = vec![self.kernel()];
        items.extend(self.limits());
        items.push(self.governor());
        items.push(self.isolated());
        items.push(self.serial_latency());
        items.push(self.can());
        items
    }

    fn kernel(&self) -> Item {
        let version = self.read("proc/version").unwrap_or_default();
        let realtime = self.read("sys/kernel/realtime").is_some_and(|s| s.trim() == "1")
            || version.contains("PREEMPT_RT")
            || version.contains("PREEMPT RT");
        let release = version.split_whitespace().nth(2).unwrap_or("?").to_owned();
        if version.is_empty() {
            return Item::new("kernel", "no /proc/version".into(), Verdict::Unknown, None);
        }
        Item::new(
            "kernel",
            format!("{release}{}", if realtime { " (PREEMPT_RT)" } else { " (not PREEMPT_RT)" }),
            if realtime { Verdict::Good } else { Verdict::Short },
            "boot a PREEMPT_RT kernel: Debian's linux-image-rt-amd64 or linux-image-rt-arm64, Raspberry Pi OS's \
             rt kernel, NVIDIA's real-time kernel for a Jetson"
                .to_owned(),
        )
    }

    /// The soft limit of `name` in `/proc/self/limits`.
    fn limit(&self, name: &str) -> Limit {
        let Some(limits) = self.read("proc/self/limits") else {
            return Limit::Unknown("no /proc/self/limits".into());
        };
        let Some(line) = limits.lines().find(|l| l.starts_with(name)) else {
            return Limit::Unknown(format!("no \"{name}\" line in /proc/self/limits"));
        };
        match line[name.len()..].split_whitespace().next() {
            Some("unlimited") => Limit::Unlimited,
            Some(soft) => soft.parse().map_or_else(
                |_| Limit::Unknown(format!("\"{name}\" reads {soft:?}, not a number")),
                Limit::At,
            ),
            None => Limit::Unknown(format!("\"{name}\" has no value")),
        }
    }

    fn is_root(&self) -> bool {
        self.read("proc/self/status").is_some_and(|s| {
            s.lines()
                .find(|l| l.starts_with("Uid:"))
                .and_then(|l| l.split_whitespace().nth(2))
                == Some("0")
        })
    }

    fn limits(&self) -> [Item; 2] {
        let root = self.is_root();
        let who = if root { " (root)" } else { "" };
        let rtprio = match self.limit("Max realtime priority") {
            Limit::Unknown(why) => Item::new("SCHED_FIFO", why, Verdict::Unknown, None),
            limit => {
                let ok = root || limit.at_least(LOOP_PRIORITY);
                Item::new(
                    "SCHED_FIFO",
                    format!("realtime priority limit {}{who}", limit.shown(|p| p.to_string())),
                    if ok { Verdict::Good } else { Verdict::Short },
                    format!(
                        "allow priority {LOOP_PRIORITY}+: a line `<user> - rtprio 95` in /etc/security/limits.d/robodeploy.conf \
                         (log in again), or give the binary CAP_SYS_NICE (setcap cap_sys_nice+ep robodeploy)"
                    ),
                )
            }
        };
        let memlock = match self.limit("Max locked memory") {
            Limit::Unknown(why) => Item::new("memory locking", why, Verdict::Unknown, None),
            limit => {
                let ok = root || limit.at_least(MEMLOCK_NEEDED);
                Item::new(
                    "memory locking",
                    format!(
                        "locked memory limit {}{who}",
                        limit.shown(|b| format!("{} KiB", b / 1024))
                    ),
                    if ok { Verdict::Good } else { Verdict::Short },
                    "allow locking all memory: a line `<user> - memlock unlimited` in \
                     /etc/security/limits.d/robodeploy.conf (log in again), or CAP_IPC_LOCK"
                        .to_owned(),
                )
            }
        };
        [rtprio, memlock]
    }

    fn governor(&self) -> Item {
        let mut governors: Vec<(String, String)> = Vec::new();
        for cpu in self.entries("sys/devices/system/cpu") {
            let name = cpu
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            if !name
                .strip_prefix("cpu")
                .is_some_and(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()))
            {
                continue;
            }
            if let Ok(g) = read_small(&cpu.join("cpufreq/scaling_governor")).ok_or(()) {
                governors.push((name, g.trim().to_owned()));
            }
        }
        if governors.is_empty() {
            return Item::new(
                "CPU governor",
                "no cpufreq (a fixed clock, or a virtual machine)".into(),
                Verdict::Unknown,
                None,
            );
        }
        let slow: Vec<String> = governors
            .iter()
            .filter(|(_, g)| g != "performance")
            .map(|(c, g)| format!("{c} {g}"))
            .collect();
        Item::new(
            "CPU governor",
            if slow.is_empty() {
                format!("performance on all {} CPUs", governors.len())
            } else {
                slow.join(", ")
            },
            if slow.is_empty() {
                Verdict::Good
            } else {
                Verdict::Short
            },
            "run the CPUs at full speed: cpupower frequency-set -g performance (or write performance to \
             /sys/devices/system/cpu/cpu*/cpufreq/scaling_governor)"
                .to_owned(),
        )
    }

    fn isolated(&self) -> Item {
        let isolated = self.read("sys/devices/system/cpu/isolated").unwrap_or_default();
        let isolated = isolated.trim();
        let cmdline = self.read("proc/cmdline").unwrap_or_default();
        let nohz = cmdline
            .split_whitespace()
            .find_map(|w| w.strip_prefix("nohz_full="))
            .map(str::to_owned);
        let found = match (isolated.is_empty(), &nohz) {
            (true, _) => "no isolated CPU".to_owned(),
            (false, Some(n)) => format!("isolated CPUs {isolated}, nohz_full={n}"),
            (false, None) => format!("isolated CPUs {isolated}, no nohz_full"),
        };
        Item::new(
            "isolated cores",
            found,
            if isolated.is_empty() { Verdict::Short } else { Verdict::Good },
            "keep a core for the loop: isolcpus=N nohz_full=N rcu_nocbs=N on the kernel command line (the last \
             core; play --realtime pins the loop to it)"
                .to_owned(),
        )
    }

    fn serial_latency(&self) -> Item {
        let mut timers = Vec::new();
        for dev in self.entries("sys/bus/usb-serial/devices") {
            if let Ok(t) = read_small(&dev.join("latency_timer")).ok_or(()) {
                let name = dev
                    .file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default();
                timers.push((name, t.trim().parse::<u32>().unwrap_or(u32::MAX)));
            }
        }
        if timers.is_empty() {
            return Item::new(
                "serial latency",
                "no USB serial adapter with a latency timer".into(),
                Verdict::Good,
                None,
            );
        }
        let found: Vec<String> = timers.iter().map(|(d, ms)| format!("{d} {ms} ms")).collect();
        let slow: Vec<&str> = timers
            .iter()
            .filter(|(_, ms)| *ms > 1)
            .map(|(d, _)| d.as_str())
            .collect();
        Item::new(
            "serial latency",
            found.join(", "),
            if slow.is_empty() {
                Verdict::Good
            } else {
                Verdict::Short
            },
            format!(
                "1 ms latency timer on {}: echo 1 > /sys/bus/usb-serial/devices/<dev>/latency_timer, kept by a udev rule \
                 (ATTR{{latency_timer}}=\"1\")",
                slow.join(", ")
            ),
        )
    }

    fn can(&self) -> Item {
        let mut found = Vec::new();
        let mut down = Vec::new();
        for iface in self.entries("sys/class/net") {
            // ARPHRD_CAN.
            if read_small(&iface.join("type"))
                .ok_or(())
                .is_ok_and(|t| t.trim() == "280")
            {
                let name = iface
                    .file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default();
                let up = read_small(&iface.join("operstate"))
                    .ok_or(())
                    .is_ok_and(|s| s.trim() != "down");
                let bitrate = if self.root == Path::new("/") {
                    can_bitrate(&name)
                } else {
                    None
                };
                found.push(format!(
                    "{name} {}{}",
                    if up { "up" } else { "down" },
                    bitrate.map_or(String::new(), |b| format!(" at {b} bit/s"))
                ));
                if !up {
                    down.push(name);
                }
            }
        }
        if found.is_empty() {
            return Item::new("SocketCAN", "no CAN interface".into(), Verdict::Good, None);
        }
        Item::new(
            "SocketCAN",
            found.join(", "),
            if down.is_empty() {
                Verdict::Good
            } else {
                Verdict::Short
            },
            format!(
                "bring {} up at the robot's bit rate: ip link set <can> up type can bitrate 1000000 (robot.toml's `rate`)",
                down.join(", ")
            ),
        )
    }
}

/// A CAN interface's bit rate as the kernel has it (`ip -details -json link show`).
fn can_bitrate(iface: &str) -> Option<u64> {
    let out = std::process::Command::new("ip")
        .args(["-details", "-json", "link", "show", "dev", iface])
        .output()
        .ok()?;
    let text = String::from_utf8_lossy(&out.stdout);
    let at = text.find("\"bitrate\":")? + "\"bitrate\":".len();
    text[at..]
        .trim_start()
        .split(|c: char| !c.is_ascii_digit())
        .next()?
        .parse()
        .ok()
}

/// Timer wake-up lateness over a run: how late a thread that sleeps until a deadline wakes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WakeLatency {
    /// Wake-ups measured.
    pub samples: usize,
    /// Median lateness.
    pub p50: Duration,
    /// 99th percentile.
    pub p99: Duration,
    /// Worst.
    pub max: Duration,
}

/// Sleeps until a deadline every `period` for `run`, on the calling thread (set it up first as the
/// loop would be), and measures how late each wake-up is.
pub fn measure_wake_latency(run: Duration, period: Duration) -> WakeLatency {
    let n = (run.as_nanos() / period.as_nanos().max(1)) as usize;
    let mut late = Vec::with_capacity(n);
    let mut next = Instant::now() + period;
    for _ in 0..n {
        std::thread::sleep(next.saturating_duration_since(Instant::now()));
        late.push(Instant::now().saturating_duration_since(next));
        next += period;
    }
    late.sort_unstable();
    let at = |q: f64| {
        late.get(((q * late.len() as f64).ceil() as usize).saturating_sub(1))
            .copied()
            .unwrap_or_default()
    };
    WakeLatency {
        samples: late.len(),
        p50: at(0.5),
        p99: at(0.99),
        max: late.last().copied().unwrap_or_default(),
    }
}

/// The verdict on a wake-up latency against the fastest period the loop's threads keep (a bus
/// cycle): its 99th percentile within a tenth of the period, its worst within half of it.
pub fn judge_wake_latency(w: &WakeLatency, fastest_period: Duration) -> Item {
    let us = |d: Duration| d.as_secs_f64() * 1e6;
    let ok = w.p99 <= fastest_period / 10 && w.max <= fastest_period / 2;
    Item::new(
        "timer wake-up",
        format!(
            "late by p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs over {} wake-ups (a {:.1} ms bus cycle allows p99 {:.0} µs, max {:.0} µs)",
            us(w.p50),
            us(w.p99),
            us(w.max),
            w.samples,
            fastest_period.as_secs_f64() * 1e3,
            us(fastest_period / 10),
            us(fastest_period / 2)
        ),
        if ok { Verdict::Good } else { Verdict::Short },
        "the items above that fall short (a PREEMPT_RT kernel, an isolated core, the performance governor) are what \
         shortens it; run with play --realtime"
            .to_owned(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_wake_up_verdict_weighs_the_tail_against_the_fastest_cycle() {
        let us = Duration::from_micros;
        let w = |p99, max| WakeLatency {
            samples: 1000,
            p50: us(20),
            p99: us(p99),
            max: us(max),
        };
        let cycle = Duration::from_millis(2);
        assert_eq!(judge_wake_latency(&w(150, 800), cycle).verdict, Verdict::Good);
        assert_eq!(judge_wake_latency(&w(250, 800), cycle).verdict, Verdict::Short);
        let long_tail = judge_wake_latency(&w(150, 1500), cycle);
        assert_eq!(long_tail.verdict, Verdict::Short);
        assert!(
            long_tail.fix.is_some() && long_tail.found.contains("max 1500 µs"),
            "{long_tail:?}"
        );
    }

    #[test]
    fn a_measurement_counts_every_wake_up_of_its_run() {
        // What is checked is the count and order, not the times (the machine may be busy).
        let w = measure_wake_latency(Duration::from_millis(30), Duration::from_millis(1));
        assert_eq!(w.samples, 30);
        assert!(w.p50 <= w.p99 && w.p99 <= w.max);
    }
}
