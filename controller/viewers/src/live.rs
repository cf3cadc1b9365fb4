//! The run, live, in Foxglove: a WebSocket server (Foxglove's own SDK, its `foxglove.sdk.v1`
//! protocol) that serves the recording's channels as the logger writes them — the same topics,
//! schemas and metadata as the MCAP file, so a layout made on a recording works live.
//!
//! The loop never touches it: messages are encoded once on the telemetry thread and handed to
//! both the file and the server. Loopback by default; another address only when given.
//!
//! Viewers that speak the protocol under its older name, `foxglove.websocket.v1` (Foxglove's
//! earlier apps and libraries; the messages are the same), are served too: a small front on the
//! address asked for passes every connection to the SDK's server on loopback, naming the older
//! subprotocol as the newer in the WebSocket handshake and back in its answer.

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use foxglove::websocket::{Capability, ChannelView, Client, ClientChannel, Parameter, ServerListener};

/// Why the live view could not start.
#[derive(Debug, thiserror::Error)]
#[error("live view on {addr}: {message}")]
pub struct LiveError {
    /// The address asked for.
    pub addr: SocketAddr,
    /// What went wrong.
    pub message: String,
}

/// Counts viewers' subscriptions, and answers their parameter requests with what the run is.
#[derive(Debug, Default)]
struct Subscriptions {
    count: AtomicU64,
    /// The run's description (tool version, commit, robot, policy, clip), as read-only parameters.
    about: Vec<(String, String)>,
    /// Where a viewer's `/cmd_vel` twists go, when the run takes them.
    twists: Option<std::sync::Mutex<std::sync::mpsc::SyncSender<[f64; 6]>>>,
    /// A viewer's message that was no twist was said once.
    warned: AtomicBool,
}

/// A `geometry_msgs/Twist` in JSON (`{"linear": {"x": …}, "angular": {…}}`, as Foxglove's Teleop
/// panel publishes it): `[linear xyz, angular xyz]`; missing components are 0, anything else or a
/// non-finite value is no twist.
pub fn twist_of_json(payload: &[u8]) -> Option<[f64; 6]> {
    let v: serde_json::Value = serde_json::from_slice(payload).ok()?;
    let part = |k: &str| -> Option<[f64; 3]> {
        let p = v.get(k)?;
        let c = |a: &str| match p.get(a) {
            None => Some(0.0),
            Some(x) => x.as_f64().filter(|x| x.is_finite()),
        };
        Some([c("x")?, c("y")?, c("z")?])
    };
    let (l, a) = (part("linear")?, part("angular")?);
    Some([l[0], l[1], l[2], a[0], a[1], a[2]])
}

impl ServerListener for Subscriptions {
    fn on_subscribe(&self, _client: Client, _channel: ChannelView<'_>) {
        self.count.fetch_add(1, Ordering::Relaxed);
    }

    fn on_get_parameters(
        &self,
        _client: Client,
        names: Vec<String>,
        _request_id: Option<&str>,
    ) -> Vec<Parameter> {
        self.about
            .iter()
            .filter(|(n, _)| names.is_empty() || names.contains(n))
            .map(|(n, v)| Parameter::string(n.clone(), v.clone()))
            .collect()
    }

    fn on_message_data(&self, _client: Client, channel: &ClientChannel, payload: &[u8]) {
        let Some(twists) = &self.twists else { return };
        if channel.topic != "/cmd_vel" {
            return;
        }
        match (channel.encoding == "json")
            .then(|| twist_of_json(payload))
            .flatten()
        {
            // A full queue drops the twist: the next one comes within a tick.
            Some(t) => drop(twists.lock().map(|tx| tx.try_send(t))),
            None => {
                if !self.warned.swap(true, Ordering::Relaxed) {
                    tracing::warn!(
                        "live view: a /cmd_vel message that is no JSON geometry_msgs/Twist dropped (further ones not reported)"
                    );
                }
            }
        }
    }

    /// Read-only: a viewer's change is answered with the values as they are.
    fn on_set_parameters(
        &self,
        client: Client,
        parameters: Vec<Parameter>,
        request_id: Option<&str>,
    ) -> Vec<Parameter> {
        let names = parameters.into_iter().map(|p| p.name).collect();
        self.on_get_parameters(client, names, request_id)
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
    front: Option<tokio::task::JoinHandle<()>>,
    addr: SocketAddr,
    subscriptions: Arc<Subscriptions>,
}

/// The subprotocol Foxglove's SDK serves, and the older name of the same protocol.
const SUBPROTOCOL: &str = "foxglove.sdk.v1";
const OLDER_SUBPROTOCOL: &str = "foxglove.websocket.v1";

/// The longest WebSocket handshake the front reads, and how long it waits for one.
const HANDSHAKE_BYTES: usize = 16 * 1024;
const HANDSHAKE_WAIT: Duration = Duration::from_secs(5);

/// How long a run's end waits for its viewers to get their close frames.
const CLOSE_WAIT: Duration = Duration::from_millis(500);

/// Bytes up to and including the end of an HTTP head (`\r\n\r\n`), when `buf` holds one.
fn head_end(buf: &[u8]) -> Option<usize> {
    buf.windows(4).position(|w| w == b"\r\n\r\n").map(|i| i + 4)
}

/// `head` with the value of each `Sec-WebSocket-Protocol` line rewritten by `rewrite` (header
/// names are case-insensitive); whether any line was.
fn rewrite_subprotocol(head: &str, rewrite: impl Fn(&str) -> Option<String>) -> (String, bool) {
    let mut out = String::with_capacity(head.len() + 16);
    let mut changed = false;
    for line in head.split_inclusive("\r\n") {
        let (content, end) = line.strip_suffix("\r\n").map_or((line, ""), |c| (c, "\r\n"));
        match content.split_once(':') {
            Some((name, value)) if name.trim().eq_ignore_ascii_case("sec-websocket-protocol") => {
                match rewrite(value.trim()) {
                    Some(v) => {
                        out.push_str(name);
                        out.push_str(": ");
                        out.push_str(&v);
                        changed = true;
                    }
                    None => out.push_str(content),
                }
            }
            _ => out.push_str(content),
        }
        out.push_str(end);
    }
    (out, changed)
}

/// Reads from `stream` into `buf` until it holds a whole HTTP head; its length.
async fn read_head(stream: &mut tokio::net::TcpStream, buf: &mut Vec<u8>) -> std::io::Result<usize> {
    use tokio::io::AsyncReadExt;
    let mut chunk = [0u8; 2048];
    loop {
        if let Some(end) = head_end(buf) {
            return Ok(end);
        }
        if buf.len() >= HANDSHAKE_BYTES {
            return Err(std::io::Error::other("handshake too long"));
        }
        let n = stream.read(&mut chunk).await?;
        if n == 0 {
            return Err(std::io::ErrorKind::UnexpectedEof.into());
        }
        buf.extend_from_slice(&chunk[..n]);
    }
}

/// One viewer's connection through the front: its handshake passed on (the older subprotocol
/// named as the newer), the server's answer passed back (named as the viewer asked), then the
/// bytes both ways.
async fn pass_on(mut viewer: tokio::net::TcpStream, server: SocketAddr) -> std::io::Result<()> {
    use tokio::io::AsyncWriteExt;
    let mut request = Vec::with_capacity(1024);
    let end = tokio::time::timeout(HANDSHAKE_WAIT, read_head(&mut viewer, &mut request))
        .await
        .map_err(|_| std::io::Error::from(std::io::ErrorKind::TimedOut))??;
    let head = String::from_utf8_lossy(&request[..end]).into_owned();
    // Only a viewer that offers the older name alone is translated; one that offers the newer
    // gets it as it is.
    let (head, older) = rewrite_subprotocol(&head, |offered| {
        let names: Vec<&str> = offered.split(',').map(str::trim).collect();
        (names.contains(&OLDER_SUBPROTOCOL) && !names.contains(&SUBPROTOCOL)).then(|| SUBPROTOCOL.to_owned())
    });
    let mut upstream = tokio::net::TcpStream::connect(server).await?;
    upstream.set_nodelay(true)?;
    viewer.set_nodelay(true)?;
    upstream.write_all(head.as_bytes()).await?;
    upstream.write_all(&request[end..]).await?;
    let mut answer = Vec::with_capacity(512);
    let end = tokio::time::timeout(HANDSHAKE_WAIT, read_head(&mut upstream, &mut answer))
        .await
        .map_err(|_| std::io::Error::from(std::io::ErrorKind::TimedOut))??;
    let head = String::from_utf8_lossy(&answer[..end]).into_owned();
    let head = if older {
        rewrite_subprotocol(&head, |given| {
            (given == SUBPROTOCOL).then(|| OLDER_SUBPROTOCOL.to_owned())
        })
        .0
    } else {
        head
    };
    viewer.write_all(head.as_bytes()).await?;
    viewer.write_all(&answer[end..]).await?;
    tokio::io::copy_bidirectional(&mut viewer, &mut upstream).await?;
    Ok(())
}

/// Accepts viewers on `listener` and passes each to the server at `server`.
async fn front(listener: tokio::net::TcpListener, server: SocketAddr) {
    loop {
        match listener.accept().await {
            Ok((viewer, _)) => {
                tokio::spawn(async move {
                    // A viewer that leaves or sends no handshake ends only its own connection.
                    let _ = pass_on(viewer, server).await;
                });
            }
            // Out of descriptors and the like: try again shortly rather than spin.
            Err(_) => tokio::time::sleep(Duration::from_millis(50)).await,
        }
    }
}

impl std::fmt::Debug for LiveView {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LiveView").field("addr", &self.addr).finish()
    }
}

impl LiveView {
    /// Starts serving on `addr` (port 0: any free port); `name` is what viewers see.
    pub fn serve(addr: SocketAddr, name: &str) -> Result<Self, LiveError> {
        Self::serve_about(addr, name, Vec::new(), None)
    }

    /// [`Self::serve`], answering viewers' parameter requests (Foxglove's *Parameters* panel) with
    /// `about`: what the run is (tool version and commit, robot, policy, clip), read-only; with
    /// `twists`, viewers may publish (Foxglove's *Teleop* panel): each JSON geometry_msgs/Twist on
    /// `/cmd_vel` goes there.
    pub fn serve_about(
        addr: SocketAddr,
        name: &str,
        about: Vec<(String, String)>,
        twists: Option<std::sync::mpsc::SyncSender<[f64; 6]>>,
    ) -> Result<Self, LiveError> {
        let context = foxglove::Context::new();
        let publish = twists.is_some();
        let subscriptions = Arc::new(Subscriptions {
            count: AtomicU64::new(0),
            about,
            twists: twists.map(std::sync::Mutex::new),
            warned: AtomicBool::new(false),
        });
        let mut capabilities = vec![Capability::Parameters];
        if publish {
            capabilities.push(Capability::ClientPublish);
        }
        let runtime = runtime().map_err(|message| LiveError { addr, message })?;
        // The SDK's server on loopback, behind the front on the address asked for.
        let builder = context
            .websocket_server()
            .message_backlog_size(VIEWER_BACKLOG)
            .name(name)
            .capabilities(capabilities)
            .bind("127.0.0.1", 0)
            .listener(Arc::clone(&subscriptions) as Arc<dyn ServerListener>);
        let failed = |e: &dyn std::fmt::Display| LiveError {
            addr,
            message: e.to_string(),
        };
        // Started inside the runtime, the server and the front run on it.
        let server = runtime.block_on(builder.start()).map_err(|e| failed(&e))?;
        let inner = SocketAddr::new(std::net::Ipv4Addr::LOCALHOST.into(), server.port());
        let listener = runtime
            .block_on(tokio::net::TcpListener::bind(addr))
            .map_err(|e| failed(&e))?;
        let bound = listener.local_addr().map_err(|e| failed(&e))?;
        let front = runtime.spawn(front(listener, inner));
        Ok(Self {
            context,
            server: Some(server),
            front: Some(front),
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
        if let Some(front) = self.front.take() {
            front.abort();
        }
        if let Some(server) = self.server.take() {
            // Stops accepting and sending, and each viewer gets a close frame: waited for a
            // moment (the process may be about to exit), never for a viewer that stopped reading.
            let stopping = server.stop();
            match runtime() {
                Ok(rt) => rt.block_on(async {
                    let _ = tokio::time::timeout(CLOSE_WAIT, stopping.wait()).await;
                }),
                Err(_) => stopping.detach_all(),
            }
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

    /// A viewer offering `protocol`: the subprotocol the server answered with, and the socket.
    fn viewer(
        view: &LiveView,
        protocol: &str,
    ) -> (
        String,
        tungstenite::WebSocket<tungstenite::stream::MaybeTlsStream<std::net::TcpStream>>,
    ) {
        use tungstenite::client::IntoClientRequest;
        let mut request = view.url().into_client_request().unwrap();
        request
            .headers_mut()
            .insert("Sec-WebSocket-Protocol", protocol.parse().unwrap());
        let (socket, response) = tungstenite::connect(request).unwrap();
        let given = response
            .headers()
            .get("Sec-WebSocket-Protocol")
            .map(|v| v.to_str().unwrap().to_owned())
            .unwrap_or_default();
        (given, socket)
    }

    #[test]
    fn viewers_of_either_subprotocol_get_the_run_and_a_close_frame_when_it_ends() {
        use tungstenite::Message;
        let view = LiveView::serve("127.0.0.1:0".parse().unwrap(), "test").unwrap();
        let schema = foxglove::Schema::new("t", "jsonschema", br#"{"type":"object"}"#.to_vec());
        let channel = view.channel("/t", &schema, "json", &Default::default()).unwrap();
        let mut sockets = Vec::new();
        for protocol in [OLDER_SUBPROTOCOL, SUBPROTOCOL] {
            // Answered in the protocol's own name.
            let (given, mut ws) = viewer(&view, protocol);
            assert_eq!(given, protocol);
            let mut id = None;
            while id.is_none() {
                let Message::Text(text) = ws.read().unwrap() else {
                    continue;
                };
                let v: serde_json::Value = serde_json::from_str(&text).unwrap();
                if v["op"] == "advertise" {
                    id = v["channels"][0]["id"].as_u64();
                }
            }
            let subscribe = format!(
                r#"{{"op":"subscribe","subscriptions":[{{"id":3,"channelId":{}}}]}}"#,
                id.unwrap()
            );
            ws.send(Message::Text(subscribe.into())).unwrap();
            sockets.push(ws);
        }
        // Both get the run's messages (published until the subscriptions have taken effect).
        for ws in &mut sockets {
            if let tungstenite::stream::MaybeTlsStream::Plain(s) = ws.get_ref() {
                s.set_read_timeout(Some(Duration::from_millis(20))).unwrap();
            }
            let until = Instant::now() + Duration::from_secs(10);
            loop {
                assert!(Instant::now() < until, "no message data");
                publish(&channel, b"{}", 1);
                if let Ok(Message::Binary(b)) = ws.read() {
                    assert_eq!((b[0], &b[1..5]), (1, &3u32.to_le_bytes()[..]));
                    break;
                }
            }
            if let tungstenite::stream::MaybeTlsStream::Plain(s) = ws.get_ref() {
                s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
            }
        }
        // The run ends: each viewer is told so with a close frame before its connection ends.
        drop(channel);
        drop(view);
        for mut ws in sockets {
            let closed = loop {
                match ws.read() {
                    Ok(Message::Close(_)) => break true,
                    Ok(_) => {}
                    Err(_) => break false,
                }
            };
            assert!(closed, "the connection ended without a close frame");
        }
    }

    #[test]
    fn the_older_subprotocol_is_named_as_the_newer_and_back_only_when_offered_alone() {
        let head = "GET / HTTP/1.1\r\nHost: x\r\nsec-websocket-protocol: foxglove.websocket.v1\r\n\r\n";
        let (out, changed) =
            rewrite_subprotocol(head, |v| (v == OLDER_SUBPROTOCOL).then(|| SUBPROTOCOL.to_owned()));
        assert!(changed);
        assert_eq!(
            out,
            "GET / HTTP/1.1\r\nHost: x\r\nsec-websocket-protocol: foxglove.sdk.v1\r\n\r\n"
        );
        let (same, changed) = rewrite_subprotocol("GET / HTTP/1.1\r\nHost: x\r\n\r\n", |_| Some("y".into()));
        assert!(!changed);
        assert_eq!(same, "GET / HTTP/1.1\r\nHost: x\r\n\r\n");
        assert_eq!(head_end(b"a\r\n\r\nrest"), Some(5));
        assert_eq!(head_end(b"a\r\n"), None);
    }

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

#[cfg(test)]
mod twist_tests {
    use super::twist_of_json;

    #[test]
    fn a_json_twist_is_read_and_anything_else_is_none() {
        let full = br#"{"linear": {"x": 0.5, "y": -0.1, "z": 0}, "angular": {"x": 0, "y": 0, "z": 0.3}}"#;
        assert_eq!(twist_of_json(full), Some([0.5, -0.1, 0.0, 0.0, 0.0, 0.3]));
        // Missing components are 0, as ROS's defaults.
        let short = br#"{"linear": {"x": 0.2}, "angular": {}}"#;
        assert_eq!(twist_of_json(short), Some([0.2, 0.0, 0.0, 0.0, 0.0, 0.0]));
        for bad in [
            &b"not json"[..],
            br#"{"linear": {"x": "fast"}, "angular": {}}"#,
            br#"{"linear": {"x": 1e999}, "angular": {}}"#,
            br#"{"angular": {"z": 1}}"#,
            br#"[1, 2, 3]"#,
        ] {
            assert_eq!(twist_of_json(bad), None, "{}", String::from_utf8_lossy(bad));
        }
    }
}
