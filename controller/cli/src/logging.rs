//! Logging that can never hold up the robot: every thread (the control loop, bus workers, the
//! e-stop listener, servers) hands its lines to a bounded queue that one writer thread empties
//! into standard error. When nobody reads standard error and the queue is full, lines are dropped
//! and counted, never waited for.

use tracing_appender::non_blocking::{ErrorCounter, NonBlockingBuilder, WorkerGuard};

/// Lines the queue holds before it drops.
const QUEUED_LINES: usize = 16 * 1024;

/// The filter in force, to quiet routine lines while a progress bar is drawn.
static FILTER: std::sync::OnceLock<
    tracing_subscriber::reload::Handle<tracing_subscriber::EnvFilter, tracing_subscriber::Registry>,
> = std::sync::OnceLock::new();

/// Keeps the writer alive; says at exit how many lines were dropped.
#[derive(Debug)]
pub struct Logging {
    dropped: ErrorCounter,
    _writer: WorkerGuard,
}

/// Installs the subscriber (`RUST_LOG` filters; default `info`).
pub fn init() -> Logging {
    let (writer, guard) = NonBlockingBuilder::default()
        .lossy(true)
        .buffered_lines_limit(QUEUED_LINES)
        .thread_name("log")
        .finish(std::io::stderr());
    let dropped = writer.error_counter();
    // Colour only for a person at a terminal: a pipe or a file gets plain text (NO_COLOR too).
    let colour =
        std::io::IsTerminal::is_terminal(&std::io::stderr()) && std::env::var_os("NO_COLOR").is_none();
    use tracing_subscriber::layer::SubscriberExt as _;
    use tracing_subscriber::util::SubscriberInitExt as _;
    let filter =
        tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info,ort=warn".into());
    let (filter, handle) = tracing_subscriber::reload::Layer::new(filter);
    let _ = FILTER.set(handle);
    tracing_subscriber::registry()
        .with(filter)
        .with(
            tracing_subscriber::fmt::layer()
                .with_ansi(colour)
                .with_writer(writer),
        )
        .init();
    Logging {
        dropped,
        _writer: guard,
    }
}

/// Only errors from now on, unless `RUST_LOG` asked for more: for work that draws a progress bar
/// and reports every item's outcome itself (a batch's runs and their faults would cut through it).
pub fn errors_only() {
    if std::env::var_os("RUST_LOG").is_none()
        && let Some(handle) = FILTER.get()
    {
        let _ = handle.reload(tracing_subscriber::EnvFilter::new("error"));
    }
}

impl Logging {
    /// Log lines dropped so far because standard error was not read fast enough.
    pub fn dropped(&self) -> usize {
        self.dropped.dropped_lines()
    }
}

/// Writes `text` to standard error without risking a hang at exit: a helper thread writes it and
/// is waited for at most a second (when nobody reads a full pipe, the process ends anyway).
pub fn last_words(text: String) {
    let (done, finished) = std::sync::mpsc::sync_channel(1);
    let writer = std::thread::Builder::new()
        .name("last-words".into())
        .spawn(move || {
            use std::io::Write as _;
            let _ = std::io::stderr().write_all(text.as_bytes());
            let _ = done.send(());
        });
    if writer.is_ok() {
        let _ = finished.recv_timeout(std::time::Duration::from_secs(1));
    }
}
