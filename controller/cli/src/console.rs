//! The person at the terminal during calibration: each step explained and confirmed with Enter,
//! progress as a bar.

use std::io::{BufRead, Write as _};

use calibration::operator::{Aborted, Operator, Request};

/// The person at the terminal: each step is explained and confirmed with Enter (`q` aborts);
/// `yes` answers every question (allowed in the mirror only).
#[derive(Debug)]
pub struct ConsoleOperator {
    yes: bool,
    bar: Option<(String, indicatif::ProgressBar)>,
}

impl ConsoleOperator {
    /// A console operator; `yes` confirms everything without asking.
    pub fn new(yes: bool) -> Self {
        Self { yes, bar: None }
    }

    fn ask(&mut self, prompt: &str) -> Result<(), Aborted> {
        self.finish_bar();
        if self.yes {
            println!("{prompt} [--yes]");
            return Ok(());
        }
        print!("{prompt} [Enter: go on, q: abort] ");
        let _ = std::io::stdout().flush();
        let mut line = String::new();
        match std::io::stdin().lock().read_line(&mut line) {
            Ok(n) if n > 0 && !matches!(line.trim(), "q" | "Q" | "n" | "N" | "no" | "abort") => Ok(()),
            Ok(0) => {
                println!(
                    "\nstandard input ended: nobody is there to answer (run it at a terminal, or pipe the answers; \
                     on the mirror --yes answers for you)"
                );
                Err(Aborted)
            }
            _ => Err(Aborted),
        }
    }

    fn finish_bar(&mut self) {
        if let Some((_, bar)) = self.bar.take() {
            bar.finish_and_clear();
        }
    }
}

impl Operator for ConsoleOperator {
    fn request(&mut self, request: Request<'_>) -> Result<(), Aborted> {
        match request {
            Request::Confirm { what } => self.ask(&format!("\n{what}.\nGo ahead?")),
            Request::ClampJig { label, joints, pose } => {
                let mut text = format!("Clamp the robot in jig setting {label}:");
                for (name, q) in joints.iter().zip(pose) {
                    text.push_str(&format!("\n  {name:<20} {:>8.2}°", q.to_degrees()));
                }
                self.ask(&format!("{text}\nEvery joint clamped?"))
            }
            Request::ReleaseJig => self.ask("Take the robot out of the jig; it hangs on its stand. Done?"),
            Request::Watch { joint, .. } => self.ask(&format!(
                "Watch {joint}: it will move slowly under low torque until it rests on its stops. Ready?"
            )),
            Request::HoldBase { label, rpy_deg } => self.ask(&format!(
                "Hold the robot's base still {label} (roll {:.0}°, pitch {:.0}°, yaw {:.0}°). Still?",
                rpy_deg[0], rpy_deg[1], rpy_deg[2]
            )),
        }
    }

    fn direction_seen(&mut self, _index: usize, joint: &str) -> Result<f64, Aborted> {
        self.finish_bar();
        if self.yes {
            // Nobody answers for the person here: only the mirror's hands can see.
            return Err(Aborted);
        }
        loop {
            print!("Did {joint} turn in its positive direction (the model's axis)? [+/-, q: abort] ");
            let _ = std::io::stdout().flush();
            let mut line = String::new();
            match std::io::stdin().lock().read_line(&mut line) {
                Ok(n) if n > 0 => match line.trim() {
                    "+" | "y" | "yes" => return Ok(1.0),
                    "-" | "n" | "no" => return Ok(-1.0),
                    "q" | "abort" => return Err(Aborted),
                    _ => continue,
                },
                _ => return Err(Aborted),
            }
        }
    }

    fn say(&mut self, line: &str) {
        self.finish_bar();
        println!("{line}");
    }

    fn progress(&mut self, step: &str, done: f64) {
        if self.bar.as_ref().is_none_or(|(s, _)| s != step) {
            self.finish_bar();
            let bar = indicatif::ProgressBar::new(100).with_message(step.to_owned());
            bar.set_style(
                indicatif::ProgressStyle::with_template("  {msg:<14} [{bar:30}] {percent:>3}%")
                    .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
            );
            self.bar = Some((step.to_owned(), bar));
        }
        if let Some((_, bar)) = &self.bar {
            bar.set_position((done * 100.0).round() as u64);
        }
    }
}

/// How often a progress line is written where no bar can be drawn.
const LINE_EVERY: std::time::Duration = std::time::Duration::from_secs(5);

/// Progress of long work for the person waiting: on a terminal a bar with the time left
/// (standard error); elsewhere (a pipe, a log file) a plain line at once and then every few
/// seconds, so a piped run is never silent. Standard output keeps only the results.
#[derive(Debug)]
pub struct Progress {
    what: String,
    unit: &'static str,
    total: Option<u64>,
    bar: Option<indicatif::ProgressBar>,
    started: std::time::Instant,
    last_line: std::sync::Mutex<Option<std::time::Instant>>,
}

impl Progress {
    /// Progress of `what`, counted in `unit`, out of `total` when known.
    pub fn new(what: &str, unit: &'static str, total: Option<u64>) -> Self {
        use std::io::IsTerminal as _;
        let bar = std::io::stderr().is_terminal().then(|| {
            let (bar, template) = match total {
                Some(n) => (
                    indicatif::ProgressBar::new(n),
                    format!("{{msg}} [{{bar:30}}] {{pos}}/{{len}} {unit} {{elapsed}}, about {{eta}} left"),
                ),
                None => (
                    indicatif::ProgressBar::new_spinner(),
                    format!("{{msg}} {{spinner}} {{pos}} {unit} {{elapsed}}"),
                ),
            };
            bar.set_style(
                indicatif::ProgressStyle::with_template(&template)
                    .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
            );
            bar.set_message(what.to_owned());
            bar
        });
        let progress = Self {
            what: what.to_owned(),
            unit,
            total,
            bar,
            started: std::time::Instant::now(),
            last_line: std::sync::Mutex::new(None),
        };
        progress.set(0);
        progress
    }

    /// `done` of the total now.
    pub fn set(&self, done: u64) {
        if let Some(bar) = &self.bar {
            bar.set_position(done);
            return;
        }
        let Ok(mut last) = self.last_line.lock() else {
            return;
        };
        if last.is_none_or(|t| t.elapsed() >= LINE_EVERY) {
            *last = Some(std::time::Instant::now());
            eprintln!("{}", self.line(done));
        }
    }

    /// The plain line: how far, how long so far, and how long left at the rate so far.
    fn line(&self, done: u64) -> String {
        let elapsed = self.started.elapsed().as_secs_f64();
        match self.total {
            Some(total) if total > 0 => {
                let share = done as f64 / total as f64;
                let left = if done > 0 {
                    format!(", about {:.0} s left", elapsed * (1.0 - share) / share)
                } else {
                    String::new()
                };
                format!(
                    "{}: {done}/{total} {} ({:.0} %), {elapsed:.0} s{left}",
                    self.what,
                    self.unit,
                    100.0 * share
                )
            }
            _ => format!("{}: {done} {}, {elapsed:.0} s", self.what, self.unit),
        }
    }

    /// The work is done: the bar goes (the results follow on standard output).
    pub fn finish(self) {
        if let Some(bar) = self.bar {
            bar.finish_and_clear();
        }
    }
}

/// A progress display that follows a counter another thread publishes (a run's tick), on its
/// own thread; dropping it stops and clears it.
#[derive(Debug)]
pub struct Watch {
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Watch {
    /// Shows `counter` in `progress` until dropped.
    pub fn start(counter: std::sync::Arc<std::sync::atomic::AtomicU64>, progress: Progress) -> Self {
        use std::sync::atomic::Ordering;
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let flag = std::sync::Arc::clone(&stop);
        let thread = std::thread::Builder::new()
            .name("progress".into())
            .spawn(move || {
                while !flag.load(Ordering::Relaxed) {
                    progress.set(counter.load(Ordering::Relaxed));
                    std::thread::park_timeout(std::time::Duration::from_millis(250));
                }
                progress.finish();
            })
            .ok();
        Self { stop, thread }
    }
}

impl Drop for Watch {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            t.thread().unpark();
            let _ = t.join();
        }
    }
}
