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
        // RustDDS logs its discovery's comings and goings, and its own teardown, at warn and
        // error: noise to a user (the link reports what matters); RUST_LOG=rustdds=info shows it.
        tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info,ort=warn,rustdds=off".into());
    let (filter, handle) = tracing_subscriber::reload::Layer::new(filter);
    let _ = FILTER.set(handle);
    use tracing_subscriber::Layer as _;
    tracing_subscriber::registry()
        .with(filter)
        .with(
            tracing_subscriber::fmt::layer()
                .with_ansi(colour)
                .with_writer(writer)
                .with_filter(ThrottledServers::default()),
        )
        .init();
    Logging {
        dropped,
        _writer: guard,
    }
}

/// Libraries whose lines one client can provoke at will (the live server's WebSocket stack: a
/// line per junk connection): at most one line a second from each place in their code.
const THROTTLED_TARGETS: [&str; 3] = ["foxglove", "tungstenite", "tokio_tungstenite"];

/// Rate-limits [`THROTTLED_TARGETS`]; the project's own lines rate-limit where they are written.
#[derive(Debug, Default)]
struct ThrottledServers {
    limits: std::sync::Mutex<
        std::collections::HashMap<tracing::callsite::Identifier, firmware_bridge::ratelimit::RateLimit>,
    >,
}

impl ThrottledServers {
    fn throttled(meta: &tracing::Metadata<'_>) -> bool {
        THROTTLED_TARGETS.iter().any(|t| {
            meta.target()
                .strip_prefix(t)
                .is_some_and(|rest| rest.is_empty() || rest.starts_with("::"))
        })
    }
}

impl<S> tracing_subscriber::layer::Filter<S> for ThrottledServers {
    fn enabled(&self, meta: &tracing::Metadata<'_>, _: &tracing_subscriber::layer::Context<'_, S>) -> bool {
        if !Self::throttled(meta) {
            return true;
        }
        // Never waits: a line another thread is deciding about right now is left out.
        let Ok(mut limits) = self.limits.try_lock() else {
            return false;
        };
        limits
            .entry(meta.callsite())
            .or_insert_with(firmware_bridge::ratelimit::RateLimit::per_second)
            .allow(std::time::Instant::now())
            .is_some()
    }

    fn callsite_enabled(&self, meta: &'static tracing::Metadata<'static>) -> tracing::subscriber::Interest {
        if Self::throttled(meta) {
            tracing::subscriber::Interest::sometimes()
        } else {
            tracing::subscriber::Interest::always()
        }
    }
}

/// Only errors from now on, unless `RUST_LOG` asked for more: for work that draws a progress bar
/// and reports every item's outcome itself (a batch's runs and their faults would cut through it).
pub fn errors_only() {
    if std::env::var_os("RUST_LOG").is_none()
        && let Some(handle) = FILTER.get()
    {
        let _ = handle.reload(tracing_subscriber::EnvFilter::new("error,rustdds=off"));
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

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::{Arc, Mutex};

    #[derive(Clone, Default)]
    struct Captured(Arc<Mutex<Vec<u8>>>);

    impl std::io::Write for Captured {
        fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(bytes);
            Ok(bytes.len())
        }

        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn a_flood_of_server_lines_is_one_line_and_our_own_lines_all_pass() {
        use tracing_subscriber::Layer as _;
        use tracing_subscriber::layer::SubscriberExt as _;
        let captured = Captured::default();
        let sink = captured.clone();
        let subscriber = tracing_subscriber::registry().with(
            tracing_subscriber::fmt::layer()
                .with_ansi(false)
                .with_writer(move || sink.clone())
                .with_filter(ThrottledServers::default()),
        );
        tracing::subscriber::with_default(subscriber, || {
            // What a junk client provokes in the live server, a thousand times.
            for k in 0..1000 {
                tracing::error!(target: "foxglove::websocket::server", "Dropping client 127.0.0.1:{k}: handshake failed");
            }
            for k in 0..3 {
                tracing::warn!("our own line {k}");
            }
        });
        let text = String::from_utf8(captured.0.lock().unwrap().clone()).unwrap();
        assert_eq!(text.matches("handshake failed").count(), 1, "{text}");
        assert_eq!(text.matches("our own line").count(), 3, "{text}");
    }
}
