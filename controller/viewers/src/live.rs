//! The run, live, in Foxglove: a WebSocket server (Foxglove's own SDK, its `foxglove.sdk.v1`
//! protocol) that serves the recording's channels as the logger writes them — the same topics,
//! schemas and metadata as the MCAP file, so a layout made on a recording works live.
//!
//! The loop never touches it: messages are encoded once on the telemetry thread and handed to
//! both the file and the server. Loopback by default; another address only when given.

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use foxglove::websocket::{ChannelView, Client, ServerListener};

/// Why the live view could not start.
#[derive(Debug, thiserror::Error)]
#[error("live view on {addr}: {message}")]
pub struct LiveError {
    /// The address asked for.
    pub addr: SocketAddr,
    /// What went wrong.
    pub message: String,
}

/// Counts viewers' subscriptions.
#[derive(Debug, Default)]
struct Subscriptions {
    count: AtomicU64,
}

impl ServerListener for Subscriptions {
    fn on_subscribe(&self, _client: Client, _channel: ChannelView<'_>) {
        self.count.fetch_add(1, Ordering::Relaxed);
    }
}

/// Messages queued per viewer before the oldest are dropped (the server's own bound): a viewer
/// that stops reading costs at most this many.
pub const VIEWER_BACKLOG: usize = 256;

/// The live server's runtime: one worker thread at the lowest priority (nice 19), so viewers —
/// however many, however slow — get what the loop and the bus threads leave of the cores.
fn runtime() -> Result<&'static tokio::runtime::Runtime, String> {
    static RUNTIME: std::sync::OnceLock<Result<tokio::runtime::Runtime, String>> = std::sync::OnceLock::new();
    RUNTIME
        .get_or_init(|| {
            tokio::runtime::Builder::new_multi_thread()
                .worker_threads(1)
                .max_blocking_threads(1)
                .thread_name("live-view")
                .on_thread_start(|| {
                    // Refused nowhere a process may lower its own priority; ignored if it is.
                    let _ = rustix::process::nice(19);
                })
                .enable_all()
                .build()
                .map_err(|e| e.to_string())
        })
        .as_ref()
        .map_err(Clone::clone)
}

/// A running live view.
pub struct LiveView {
    context: Arc<foxglove::Context>,
    server: Option<foxglove::WebSocketServerHandle>,
    addr: SocketAddr,
    subscriptions: Arc<Subscriptions>,
}

impl std::fmt::Debug for LiveView {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LiveView").field("addr", &self.addr).finish()
    }
}

impl LiveView {
    /// Starts serving on `addr` (port 0: any free port); `name` is what viewers see.
    pub fn serve(addr: SocketAddr, name: &str) -> Result<Self, LiveError> {
        let context = foxglove::Context::new();
        let subscriptions = Arc::new(Subscriptions::default());
        let runtime = runtime().map_err(|message| LiveError { addr, message })?;
        let builder = context
            .websocket_server()
            .message_backlog_size(VIEWER_BACKLOG)
            .name(name)
            .bind(addr.ip().to_string(), addr.port())
            .listener(Arc::clone(&subscriptions) as Arc<dyn ServerListener>);
        // Started inside the runtime, the server runs on it.
        let server = runtime.block_on(builder.start()).map_err(|e| LiveError {
            addr,
            message: e.to_string(),
        })?;
        let bound = SocketAddr::new(addr.ip(), server.port());
        Ok(Self {
            context,
            server: Some(server),
            addr: bound,
            subscriptions,
        })
    }

    /// Where viewers connect: `ws://ADDR`.
    pub fn url(&self) -> String {
        format!("ws://{}", self.addr)
    }

    /// The address served.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// Subscriptions made so far.
    pub fn subscriptions(&self) -> u64 {
        self.subscriptions.count.load(Ordering::Relaxed)
    }

    /// Waits until a viewer subscribes to a channel, `within` at most or until `stop` is set;
    /// whether one did.
    pub fn wait_for_viewer(&self, within: Duration, stop: &AtomicBool) -> bool {
        let until = Instant::now() + within;
        while self.subscriptions() == 0 && Instant::now() < until && !stop.load(Ordering::Relaxed) {
            // A person opening a connection in the Foxglove app: a poll every 50 ms is plenty.
            std::thread::sleep(Duration::from_millis(50));
        }
        self.subscriptions() > 0
    }

    /// A channel as the recording has it: topic, schema, message encoding, metadata.
    pub fn channel(
        &self,
        topic: &str,
        schema: &foxglove::Schema,
        encoding: &str,
        metadata: &std::collections::BTreeMap<String, String>,
    ) -> Option<Arc<foxglove::RawChannel>> {
        self.context
            .channel_builder(topic)
            .message_encoding(encoding)
            .schema(schema.clone())
            .metadata(metadata.clone())
            .build_raw()
            .map_err(|e| tracing::warn!("live view: channel {topic}: {e}"))
            .ok()
    }
}

impl Drop for LiveView {
    fn drop(&mut self) {
        if let Some(server) = self.server.take() {
            // Stops accepting and sending; the server's tasks end on their own (no waiting on a
            // viewer that stopped reading).
            server.stop().detach_all();
        }
    }
}

/// Hands an encoded message to a live channel, stamped with the recording's time.
pub fn publish(channel: &foxglove::RawChannel, data: &[u8], time_ns: u64) {
    channel.log_with_meta(data, foxglove::PartialMetadata::with_log_time(time_ns));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_live_server_runs_on_its_own_thread_at_the_lowest_priority() {
        let view = LiveView::serve("127.0.0.1:0".parse().unwrap(), "test").unwrap();
        assert!(view.addr().ip().is_loopback());
        // A task of the server's runtime, as the server's own run: on a thread named for it,
        // at nice 19.
        let runtime = runtime().unwrap();
        let (name, nice) = runtime
            .block_on(runtime.spawn(async {
                (
                    std::thread::current().name().map(str::to_owned),
                    rustix::process::getpriority_process(None),
                )
            }))
            .unwrap();
        assert_eq!(name.as_deref(), Some("live-view"));
        assert_eq!(nice.unwrap(), 19);
    }
}
