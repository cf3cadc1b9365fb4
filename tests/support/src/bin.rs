//! The `robodeploy` binary for whole-path tests, started as a user starts it.
//!
//! Integration tests of another package cannot name a binary through `CARGO_BIN_EXE_*`, so the
//! binary is found beside the test executable (`target/<profile>/deps/..`). Under cargo it is
//! first brought up to date, once per test process, so a test never runs an old build.

use std::path::PathBuf;
use std::process::Command;
use std::sync::OnceLock;

/// The path of the `robodeploy` binary of this build profile, built if cargo is at hand.
///
/// # Panics
/// When the binary cannot be built or found, with the command that builds it.
pub fn robodeploy_path() -> PathBuf {
    static PATH: OnceLock<PathBuf> = OnceLock::new();
    PATH.get_or_init(|| {
        let exe = std::env::current_exe().expect("the test executable has a path");
        let mut dir = exe
            .parent()
            .expect("the test executable is in a folder")
            .to_path_buf();
        if dir.ends_with("deps") {
            dir.pop();
        }
        if let Some(cargo) = std::env::var_os("CARGO") {
            let profile = match dir.file_name().and_then(|n| n.to_str()) {
                Some("debug") | None => "dev".to_owned(),
                Some(other) => other.to_owned(),
            };
            let status = Command::new(cargo)
                .args([
                    "build",
                    "--quiet",
                    "-p",
                    "robodeploy",
                    "--bin",
                    "robodeploy",
                    "--profile",
                ])
                .arg(&profile)
                .status()
                .expect("cargo runs");
            assert!(status.success(), "cargo build -p robodeploy failed");
        }
        let path = dir.join("robodeploy");
        assert!(
            path.is_file(),
            "{} is missing: build it with `cargo build -p robodeploy` (scripts/dev test does)",
            path.display()
        );
        path
    })
    .clone()
}

/// A command that runs `robodeploy`.
pub fn robodeploy() -> Command {
    Command::new(robodeploy_path())
}

/// A command that runs `program` as a user on the robot's computer would: from `home` (an
/// unpacked bundle), in an empty environment (`env -i`), with the checkout these tests were built
/// in hidden under an empty tmpfs in a mount namespace of the command's own (its `.local/lib`,
/// robots and policies unreachable). Arguments added go to `program`.
pub fn with_checkout_hidden(home: &std::path::Path, program: &std::path::Path) -> Command {
    let mut command = Command::new("unshare");
    command
        .args(["--mount", "--propagation", "private", "--", "sh", "-c"])
        .arg(r#"mount -t tmpfs none "$1" && test ! -e "$1/Cargo.toml" && shift && exec env -i "$@""#)
        .arg("sh")
        .arg(crate::fixtures::workspace_root())
        .arg(program)
        .current_dir(home);
    command
}

/// A `robodeploy` process whose output is read line by line as it comes: a test waits for the
/// line that says the process is ready (never a fixed sleep), and both pipes are always drained,
/// so the process never blocks on a full pipe.
#[derive(Debug)]
pub struct Running {
    child: std::process::Child,
    lines: std::sync::mpsc::Receiver<(Stream, String)>,
    seen: Vec<(Stream, String)>,
    readers: Vec<std::thread::JoinHandle<()>>,
}

/// Which pipe a line came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stream {
    /// Standard output.
    Stdout,
    /// Standard error.
    Stderr,
}

/// What a finished process said.
#[derive(Debug)]
pub struct Finished {
    /// Its exit status.
    pub status: std::process::ExitStatus,
    /// Everything it wrote to standard output.
    pub stdout: String,
    /// Everything it wrote to standard error.
    pub stderr: String,
}

impl Running {
    /// Starts `robodeploy ARGS` with both pipes read.
    ///
    /// # Panics
    /// When the process cannot start.
    pub fn start<S: AsRef<std::ffi::OsStr>>(args: &[S]) -> Self {
        Self::spawn(args, false)
    }

    /// Starts `robodeploy ARGS` with a pipe on its standard input ([`Self::stdin`]), for
    /// processes that read keys.
    ///
    /// # Panics
    /// When the process cannot start.
    pub fn start_with_stdin<S: AsRef<std::ffi::OsStr>>(args: &[S]) -> Self {
        Self::spawn(args, true)
    }

    /// The pipe to the process's standard input (processes started with
    /// [`Self::start_with_stdin`]).
    ///
    /// # Panics
    /// When the process was started without one.
    pub fn stdin(&mut self) -> &mut std::process::ChildStdin {
        self.child.stdin.as_mut().expect("started with start_with_stdin")
    }

    fn spawn<S: AsRef<std::ffi::OsStr>>(args: &[S], stdin: bool) -> Self {
        use std::io::BufRead;
        use std::process::Stdio;
        let mut child = robodeploy()
            .args(args)
            .stdin(if stdin { Stdio::piped() } else { Stdio::null() })
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("robodeploy starts");
        // Bounded: the readers wait for the test (and the process for them) past this many lines.
        let (tx, lines) = std::sync::mpsc::sync_channel(1 << 16);
        let mut readers = Vec::new();
        let out = child
            .stdout
            .take()
            .map(|p| (Stream::Stdout, Box::new(p) as Box<dyn std::io::Read + Send>));
        let err = child
            .stderr
            .take()
            .map(|p| (Stream::Stderr, Box::new(p) as Box<dyn std::io::Read + Send>));
        for (stream, pipe) in [out, err].into_iter().flatten() {
            let tx = tx.clone();
            readers.push(
                std::thread::Builder::new()
                    .name(format!("{stream:?}"))
                    .spawn(move || {
                        for line in std::io::BufReader::new(pipe).lines() {
                            let Ok(line) = line else { break };
                            if tx.send((stream, line)).is_err() {
                                break;
                            }
                        }
                    })
                    .expect("a reader thread starts"),
            );
        }
        Self {
            child,
            lines,
            seen: Vec::new(),
            readers,
        }
    }

    /// Waits (up to a minute) for the line an emulator prints when it serves on a
    /// pseudo-terminal (`… on /dev/pts/N at …`) and returns the terminal's path.
    ///
    /// # Panics
    /// When no such line comes, with everything the process printed.
    pub fn wait_for_pty(&mut self) -> String {
        let line = self.wait_for("/dev/pts/", std::time::Duration::from_secs(60));
        line.split(" on ")
            .nth(1)
            .and_then(|s| s.split(' ').next())
            .filter(|p| p.starts_with("/dev/pts/"))
            .unwrap_or_else(|| panic!("no pseudo-terminal in: {line}"))
            .to_owned()
    }

    /// The process id.
    pub fn id(&self) -> u32 {
        self.child.id()
    }

    /// Waits (up to `timeout`) for a line on either pipe that contains `needle`, and returns it.
    ///
    /// # Panics
    /// When the process ends or the time runs out first, with everything it printed.
    pub fn wait_for(&mut self, needle: &str, timeout: std::time::Duration) -> String {
        let give_up = std::time::Instant::now() + timeout;
        loop {
            let left = give_up.saturating_duration_since(std::time::Instant::now());
            match self.lines.recv_timeout(left) {
                Ok((stream, line)) => {
                    let hit = line.contains(needle);
                    self.seen.push((stream, line.clone()));
                    if hit {
                        return line;
                    }
                }
                Err(e) => panic!("no line with {needle:?} ({e:?}); so far:\n{}", self.transcript()),
            }
        }
    }

    /// The first line seen so far that starts (after indentation) with `prefix`.
    pub fn seen(&self, prefix: &str) -> Option<&str> {
        self.seen
            .iter()
            .map(|(_, l)| l.as_str())
            .find(|l| l.trim_start().starts_with(prefix))
    }

    fn transcript(&self) -> String {
        self.seen.iter().map(|(_, l)| format!("{l}\n")).collect()
    }

    /// Waits for the process to end and returns all it printed.
    ///
    /// # Panics
    /// When waiting fails.
    pub fn finish(mut self) -> Finished {
        let status = self.drain_and_wait();
        self.finish_with(status)
    }

    fn drain_and_wait(&mut self) -> std::process::ExitStatus {
        // Read until both pipes close (the process ended), then reap it.
        while let Ok(line) = self.lines.recv() {
            self.seen.push(line);
        }
        for r in self.readers.drain(..) {
            let _ = r.join();
        }
        self.child.wait().expect("the process can be waited for")
    }

    fn finish_with(mut self, status: std::process::ExitStatus) -> Finished {
        while let Ok(line) = self.lines.recv() {
            self.seen.push(line);
        }
        for r in self.readers.drain(..) {
            let _ = r.join();
        }
        let text = |s: Stream| {
            self.seen
                .iter()
                .filter(|(k, _)| *k == s)
                .map(|(_, l)| format!("{l}\n"))
                .collect()
        };
        Finished {
            status,
            stdout: text(Stream::Stdout),
            stderr: text(Stream::Stderr),
        }
    }
}

impl Running {
    /// Waits for the process to end (its output closes) within `limit`: all it printed, or, when
    /// it is still running then, `Err` with what it printed before it was killed.
    ///
    /// # Panics
    /// When waiting fails.
    pub fn finish_within(mut self, limit: std::time::Duration) -> Result<Finished, Finished> {
        let give_up = std::time::Instant::now() + limit;
        loop {
            let left = give_up.saturating_duration_since(std::time::Instant::now());
            match self.lines.recv_timeout(left) {
                Ok(line) => self.seen.push(line),
                Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => return Ok(self.finish()),
                Err(std::sync::mpsc::RecvTimeoutError::Timeout) => return Err(self.kill()),
            }
        }
    }

    /// Stops the process (a server, say) and returns all it printed.
    pub fn kill(mut self) -> Finished {
        let _ = self.child.kill();
        self.finish()
    }
}

/// Runs `robodeploy ARGS` to the end: whether it succeeded, its stdout and its stderr.
///
/// # Panics
/// When the process cannot start.
pub fn run<S: AsRef<std::ffi::OsStr>>(args: &[S]) -> (bool, String, String) {
    let out = robodeploy().args(args).output().expect("robodeploy starts");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Runs `robodeploy ARGS` to the end within `limit`: its exit code (`None`: killed by a signal),
/// stdout and stderr.
///
/// # Panics
/// When the process cannot start, or is still running after `limit` (then it is killed): a hang.
pub fn run_within<S: AsRef<std::ffi::OsStr>>(
    args: &[S],
    limit: std::time::Duration,
) -> (Option<i32>, String, String) {
    match Running::start(args).finish_within(limit) {
        Ok(out) => (out.status.code(), out.stdout, out.stderr),
        Err(out) => panic!("robodeploy hung for {limit:?}:\n{}{}", out.stdout, out.stderr),
    }
}
