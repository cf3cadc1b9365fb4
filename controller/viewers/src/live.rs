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
        let server = context
            .websocket_server()
            .name(name)
            .bind(addr.ip().to_string(), addr.port())
            .listener(Arc::clone(&subscriptions) as Arc<dyn ServerListener>)
            .start_blocking()
            .map_err(|e| LiveError {
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
