//! The socketcand text protocol over TCP: a "CAN bus" another process can sit behind.
//!
//! Server greets `< hi >`; the client sends `< open BUS >` and `< rawmode >`, each answered
//! `< ok >`; then frames travel as `< send ID DLC B0 B1 … >` (client → server, bytes in hex) and
//! `< frame ID SECS.USECS HEXDATA >` (server → client). IDs of 3 hex digits are standard, 8 are
//! extended. Anything else is malformed: it is counted and logged with a typed error, and the
//! stream goes on (a peer's garbage never stops the bus).
//!
//! The server binds to 127.0.0.1 unless told otherwise and bridges one client at a time to a
//! [`VirtualCanNode`]; the client implements [`CanBus`] on the monotonic clock.

use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream, ToSocketAddrs};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use super::virtual_bus::VirtualCanNode;
use super::{CanBus, CanError, CanFrame, CanId};

/// Longest message accepted; longer input without `>` is discarded as malformed.
pub const MAX_MESSAGE: usize = 256;

/// One protocol message.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Message {
    /// `< hi >`
    Hi,
    /// `< ok >`
    Ok,
    /// `< open BUS >`
    Open(String),
    /// `< rawmode >`
    RawMode,
    /// `< echo >`
    Echo,
    /// `< send ID DLC B… >`
    Send(CanFrame),
    /// `< frame ID SECS.USECS HEX >`
    Frame(CanFrame, Duration),
    /// `< error … >`
    Error(String),
}

fn parse_id(s: &str) -> Result<CanId, &'static str> {
    let raw = u32::from_str_radix(s, 16).map_err(|_| "identifier is not hexadecimal")?;
    match s.len() {
        3 => u16::try_from(raw)
            .ok()
            .and_then(CanId::standard)
            .ok_or("standard identifier above 0x7FF"),
        8 => CanId::extended(raw).ok_or("extended identifier above 0x1FFFFFFF"),
        _ => Err("identifier must have 3 (standard) or 8 (extended) hex digits"),
    }
}

/// Parses one complete message `< … >`.
pub fn parse(msg: &str) -> Result<Message, &'static str> {
    let body = msg
        .strip_prefix('<')
        .and_then(|m| m.strip_suffix('>'))
        .ok_or("message must be enclosed in < >")?
        .trim();
    let mut words = body.split_ascii_whitespace();
    let cmd = words.next().ok_or("empty message")?;
    let mut data = [0u8; 8];
    match cmd {
        "hi" => Ok(Message::Hi),
        "ok" => Ok(Message::Ok),
        "rawmode" => Ok(Message::RawMode),
        "echo" => Ok(Message::Echo),
        "open" => Ok(Message::Open(
            words.next().ok_or("open needs a bus name")?.to_owned(),
        )),
        "error" => Ok(Message::Error(
            body.strip_prefix("error").unwrap_or("").trim().to_owned(),
        )),
        "send" => {
            let id = parse_id(words.next().ok_or("send needs an identifier")?)?;
            let dlc = usize::from_str_radix(words.next().ok_or("send needs a length")?, 16)
                .map_err(|_| "length is not hexadecimal")?;
            if dlc > 8 {
                return Err("length above 8");
            }
            for slot in data.iter_mut().take(dlc) {
                let w = words.next().ok_or("fewer data bytes than the length says")?;
                *slot = u8::from_str_radix(w, 16).map_err(|_| "data byte is not a hex byte")?;
            }
            if words.next().is_some() {
                return Err("more data bytes than the length says");
            }
            Ok(Message::Send(
                CanFrame::new(id, &data[..dlc]).ok_or("length above 8")?,
            ))
        }
        "frame" => {
            let id = parse_id(words.next().ok_or("frame needs an identifier")?)?;
            let stamp = words.next().ok_or("frame needs a timestamp")?;
            let (secs, usecs) = stamp.split_once('.').ok_or("timestamp must be SECS.USECS")?;
            let secs: u64 = secs.parse().map_err(|_| "timestamp seconds are not a number")?;
            let usecs: u64 = usecs
                .parse()
                .map_err(|_| "timestamp microseconds are not a number")?;
            let hex = words.next().unwrap_or("");
            // Digits only before slicing in pairs: a multi-byte character must not split.
            if hex.len() % 2 != 0 || hex.len() > 16 || !hex.bytes().all(|b| b.is_ascii_hexdigit()) {
                return Err("frame data must be 0–8 bytes of two hex digits each");
            }
            let n = hex.len() / 2;
            for (i, slot) in data.iter_mut().take(n).enumerate() {
                *slot = u8::from_str_radix(&hex[2 * i..2 * i + 2], 16)
                    .map_err(|_| "frame data is not hexadecimal")?;
            }
            let frame = CanFrame::new(id, &data[..n]).ok_or("frame data above 8 bytes")?;
            Ok(Message::Frame(
                frame,
                Duration::from_secs(secs) + Duration::from_micros(usecs),
            ))
        }
        _ => Err("unknown command"),
    }
}

fn write_id(out: &mut String, id: CanId) {
    use std::fmt::Write as _;
    let _ = match id {
        CanId::Standard(id) => write!(out, "{id:03X}"),
        CanId::Extended(id) => write!(out, "{id:08X}"),
    };
}

/// Appends `< send … >` for `frame` to `out`.
pub fn format_send(out: &mut String, frame: &CanFrame) {
    use std::fmt::Write as _;
    out.push_str("< send ");
    write_id(out, frame.id());
    let _ = write!(out, " {:X}", frame.dlc());
    for b in frame.data() {
        let _ = write!(out, " {b:02X}");
    }
    out.push_str(" >");
}

/// Appends `< frame … >` for `frame` received at `t` to `out`.
pub fn format_frame(out: &mut String, frame: &CanFrame, t: Duration) {
    use std::fmt::Write as _;
    out.push_str("< frame ");
    write_id(out, frame.id());
    let _ = write!(out, " {}.{:06} ", t.as_secs(), t.subsec_micros());
    for b in frame.data() {
        let _ = write!(out, "{b:02X}");
    }
    out.push_str(" >");
}

/// Splits a TCP byte stream into `< … >` messages; junk between messages is reported.
#[derive(Debug)]
pub struct Framer {
    buf: Vec<u8>,
}

/// One item out of a [`Framer`].
#[derive(Debug, PartialEq, Eq)]
pub enum Framed {
    /// A complete `< … >` message.
    Message(String),
    /// Bytes that are not part of any message (reported, then dropped).
    Junk(String),
}

impl Default for Framer {
    fn default() -> Self {
        Self {
            buf: Vec::with_capacity(4 * MAX_MESSAGE),
        }
    }
}

impl Framer {
    /// Appends received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// The next complete message or junk run, if any.
    pub fn next_item(&mut self) -> Option<Framed> {
        let (span, is_message) = self.next_span()?;
        let text = String::from_utf8_lossy(&self.buf[span.clone()]).into_owned();
        self.consume(span.end);
        Some(if is_message {
            Framed::Message(text)
        } else {
            Framed::Junk(text)
        })
    }

    /// Where the next complete message (`true`) or junk run (`false`) lies in the buffer, without
    /// copying it out; [`Self::consume`] drops it afterwards.
    pub fn next_span(&self) -> Option<(std::ops::Range<usize>, bool)> {
        let start = self.buf.iter().position(|&b| !b.is_ascii_whitespace())?;
        if self.buf[start] != b'<' {
            let end = self.buf[start..]
                .iter()
                .position(|&b| b == b'<')
                .map_or(self.buf.len(), |p| start + p);
            return Some((start..end, false));
        }
        match self.buf[start..].iter().position(|&b| b == b'>') {
            Some(p) => Some((start..start + p + 1, true)),
            None if self.buf.len() - start > MAX_MESSAGE => Some((start..self.buf.len(), false)),
            None => None,
        }
    }

    /// The bytes of a span from [`Self::next_span`].
    pub fn bytes(&self, span: std::ops::Range<usize>) -> &[u8] {
        &self.buf[span]
    }

    /// Drops everything before `end`.
    pub fn consume(&mut self, end: usize) {
        self.buf.drain(..end);
    }
}

fn truncated(s: &str) -> String {
    s.chars().take(80).collect()
}

/// Counters of malformed input, shared with whoever reports them; logged at most once a second
/// (a garbage flood must not become a flood of log lines).
#[derive(Debug)]
pub struct MalformedCounter {
    count: AtomicU64,
    log: crate::ratelimit::SharedRateLimit,
}

impl Default for MalformedCounter {
    fn default() -> Self {
        Self {
            count: AtomicU64::new(0),
            log: crate::ratelimit::SharedRateLimit::per_second(),
        }
    }
}

impl MalformedCounter {
    /// Counts one malformed input, and logs it unless one was logged less than a second ago.
    fn record(&self, err: &CanError) {
        self.count.fetch_add(1, Ordering::Relaxed);
        if let Some(left_out) = self.log.allow_now() {
            tracing::warn!(%err, left_out, "socketcand: rejected input");
        }
    }

    /// Malformed inputs so far.
    pub fn get(&self) -> u64 {
        self.count.load(Ordering::Relaxed)
    }
}

/// A socketcand client: the controller's side of a CAN bus served over TCP.
#[derive(Debug)]
pub struct SocketcandClient {
    bus: String,
    stream: TcpStream,
    framer: Framer,
    out: String,
    malformed: Arc<MalformedCounter>,
}

impl SocketcandClient {
    /// Connects to `addr`, opens `bus` and switches to raw mode.
    pub fn connect(addr: impl ToSocketAddrs, bus: &str, timeout: Duration) -> Result<Self, CanError> {
        let io = |e: std::io::Error| CanError::Disconnected {
            bus: bus.to_owned(),
            reason: e.to_string(),
        };
        let addr = addr
            .to_socket_addrs()
            .map_err(io)?
            .next()
            .ok_or_else(|| CanError::Io {
                bus: bus.to_owned(),
                reason: "address resolves to nothing".into(),
            })?;
        let stream = TcpStream::connect_timeout(&addr, timeout).map_err(io)?;
        stream.set_nodelay(true).map_err(io)?;
        let mut client = Self {
            bus: bus.to_owned(),
            stream,
            framer: Framer::default(),
            out: String::with_capacity(64),
            malformed: Arc::default(),
        };
        let deadline = Instant::now() + timeout;
        client.expect(Message::Hi, deadline)?;
        client.write_raw(&format!("< open {bus} >"))?;
        client.expect(Message::Ok, deadline)?;
        client.write_raw("< rawmode >")?;
        client.expect(Message::Ok, deadline)?;
        Ok(client)
    }

    /// Malformed input received so far.
    pub fn malformed(&self) -> u64 {
        self.malformed.get()
    }

    fn write_raw(&mut self, s: &str) -> Result<(), CanError> {
        self.stream
            .write_all(s.as_bytes())
            .map_err(|e| CanError::Disconnected {
                bus: self.bus.clone(),
                reason: e.to_string(),
            })
    }

    fn expect(&mut self, want: Message, deadline: Instant) -> Result<(), CanError> {
        match self.next_message(deadline)? {
            Some(m) if m == want => Ok(()),
            Some(Message::Error(e)) => Err(CanError::Io {
                bus: self.bus.clone(),
                reason: format!("server refused: {e}"),
            }),
            other => Err(CanError::Io {
                bus: self.bus.clone(),
                reason: format!("expected {want:?} from server, got {other:?}"),
            }),
        }
    }

    /// The next well-formed message before `deadline`; malformed input is counted and skipped.
    fn next_message(&mut self, deadline: Instant) -> Result<Option<Message>, CanError> {
        let mut chunk = [0u8; 512];
        loop {
            // Messages are parsed where they lie in the buffer: a steady stream of frames
            // allocates nothing.
            while let Some((span, is_message)) = self.framer.next_span() {
                let bytes = self.framer.bytes(span.clone());
                let parsed = match std::str::from_utf8(bytes) {
                    Ok(m) if is_message => parse(m),
                    Ok(_) => Err("text outside < >"),
                    Err(_) => Err("message is not ASCII text"),
                };
                let bad = match parsed {
                    Ok(msg) => {
                        self.framer.consume(span.end);
                        return Ok(Some(msg));
                    }
                    Err(reason) => CanError::Malformed {
                        bus: self.bus.clone(),
                        input: truncated(&String::from_utf8_lossy(bytes)),
                        reason,
                    },
                };
                self.framer.consume(span.end);
                self.malformed.record(&bad);
            }
            let left = deadline.saturating_duration_since(Instant::now());
            let read = if left.is_zero() {
                // Past the deadline, what the socket already holds still counts (a driver drops
                // late replies this way before its next commands): read it without waiting.
                let _ = self.stream.set_nonblocking(true);
                let r = self.stream.read(&mut chunk);
                let _ = self.stream.set_nonblocking(false);
                r
            } else {
                let _ = self
                    .stream
                    .set_read_timeout(Some(left.max(Duration::from_micros(50))));
                self.stream.read(&mut chunk)
            };
            match read {
                Ok(0) => {
                    return Err(CanError::Disconnected {
                        bus: self.bus.clone(),
                        reason: "server closed the connection".into(),
                    });
                }
                Ok(n) => self.framer.push(&chunk[..n]),
                // A signal (SIGSTOP/SIGCONT, a profiler) interrupted the wait: the bus is fine.
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => return Ok(None),
                Err(e) => {
                    return Err(CanError::Disconnected {
                        bus: self.bus.clone(),
                        reason: e.to_string(),
                    });
                }
            }
        }
    }
}

impl CanBus for SocketcandClient {
    type Instant = Instant;

    fn now(&self) -> Instant {
        Instant::now()
    }

    fn send(&mut self, frame: &CanFrame) -> Result<(), CanError> {
        let mut out = std::mem::take(&mut self.out);
        out.clear();
        format_send(&mut out, frame);
        let r = self.write_raw(&out);
        self.out = out;
        r
    }

    fn recv_until(&mut self, deadline: Instant) -> Result<Option<CanFrame>, CanError> {
        loop {
            match self.next_message(deadline)? {
                None => return Ok(None),
                Some(Message::Frame(f, _)) => return Ok(Some(f)),
                Some(Message::Error(e)) => {
                    return Err(CanError::Io {
                        bus: self.bus.clone(),
                        reason: format!("error frame: {e}"),
                    });
                }
                Some(other) => self.malformed.record(&CanError::Malformed {
                    bus: self.bus.clone(),
                    input: format!("{other:?}"),
                    reason: "unexpected message in raw mode",
                }),
            }
        }
    }
}

/// How long a socketcand client may take before the server drops it, so that no client holds the
/// bus for good. A client refused or dropped gets `< error … >` saying why.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ClientLimits {
    /// From connecting to raw mode (`< open bus >`, `< rawmode >`).
    pub handshake: Duration,
    /// In raw mode, the longest silence from the client (frames or `< echo >` keep it alive).
    pub idle: Duration,
    /// The longest a client may leave frames unread (its receive window full).
    pub stalled_reader: Duration,
}

impl Default for ClientLimits {
    fn default() -> Self {
        Self {
            handshake: Duration::from_secs(10),
            idle: Duration::from_secs(60),
            stalled_reader: Duration::from_secs(2),
        }
    }
}

/// A socketcand server bridging TCP clients to a virtual bus node. One client owns the bus at a
/// time (two controllers on one bus would fight over the motors); a second is refused with
/// `< error bus in use >` at once instead of waiting unanswered in the backlog.
#[derive(Debug)]
pub struct SocketcandServer {
    addr: SocketAddr,
    stop: Arc<AtomicBool>,
    malformed: Arc<MalformedCounter>,
    thread: Option<JoinHandle<()>>,
}

impl SocketcandServer {
    /// Serves bus `bus` on `listen` (use `127.0.0.1:0` for a free loopback port). `clock` gives the
    /// timestamp put on frames sent to the client.
    pub fn spawn(
        listen: SocketAddr,
        bus: &str,
        node: VirtualCanNode,
        clock: impl Fn() -> Duration + Send + 'static,
    ) -> std::io::Result<Self> {
        Self::spawn_with(listen, bus, node, clock, ClientLimits::default())
    }

    /// [`Self::spawn`] with other time limits for clients.
    pub fn spawn_with(
        listen: SocketAddr,
        bus: &str,
        node: VirtualCanNode,
        clock: impl Fn() -> Duration + Send + 'static,
        limits: ClientLimits,
    ) -> std::io::Result<Self> {
        let listener = TcpListener::bind(listen)?;
        listener.set_nonblocking(true)?;
        let addr = listener.local_addr()?;
        let stop = Arc::new(AtomicBool::new(false));
        let malformed = Arc::new(MalformedCounter::default());
        let session = Session {
            bus: bus.to_owned(),
            node,
            stop: Arc::clone(&stop),
            malformed: Arc::clone(&malformed),
            clock: Box::new(clock),
            limits,
            send_failures: crate::ratelimit::SharedRateLimit::per_second(),
        };
        let thread = std::thread::Builder::new()
            .name(format!("socketcand-{bus}"))
            .spawn(move || {
                crate::time::serve_in_real_time();
                session.serve(&listener);
            })?;
        Ok(Self {
            addr,
            stop,
            malformed,
            thread: Some(thread),
        })
    }

    /// The address the server listens on.
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// Malformed client input so far.
    pub fn malformed(&self) -> u64 {
        self.malformed.get()
    }
}

impl Drop for SocketcandServer {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

struct Session {
    bus: String,
    node: VirtualCanNode,
    stop: Arc<AtomicBool>,
    malformed: Arc<MalformedCounter>,
    clock: Box<dyn Fn() -> Duration + Send>,
    limits: ClientLimits,
    send_failures: crate::ratelimit::SharedRateLimit,
}

/// How long a client's frame may wait for room in the bus's transmit queue before it is dropped.
const QUEUE_WAIT: Duration = Duration::from_secs(1);

#[derive(PartialEq)]
enum Mode {
    Greeted,
    Opened,
    Raw,
}

impl Session {
    fn serve(&self, listener: &TcpListener) {
        while !self.stop.load(Ordering::Relaxed) {
            match listener.accept() {
                Ok((stream, peer)) => {
                    tracing::info!(%peer, bus = %self.bus, "socketcand: client connected");
                    match self.client(stream, listener) {
                        Ok(()) => tracing::info!(%peer, bus = %self.bus, "socketcand: client left"),
                        Err(e) => tracing::info!(%peer, bus = %self.bus, "socketcand: client dropped: {e}"),
                    }
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => std::thread::sleep(Duration::from_millis(5)),
                Err(e) => {
                    tracing::warn!("socketcand: accept failed: {e}");
                    std::thread::sleep(Duration::from_millis(50));
                }
            }
        }
    }

    fn client(&self, mut stream: TcpStream, listener: &TcpListener) -> std::io::Result<()> {
        // Non-blocking with a short sleep, not a read timeout: socket timeouts are rounded up to
        // scheduler ticks (1–4 ms), which would hold every reply frame back that long.
        stream.set_nonblocking(true)?;
        stream.set_nodelay(true)?;
        let limits = self.limits;
        let connected = Instant::now();
        let mut heard = connected;
        write_fully(&mut stream, b"< hi >", connected + limits.stalled_reader)?;
        // Drop frames that were sent before this client connected.
        while self.node.try_recv().is_some() {}
        let mut mode = Mode::Greeted;
        let mut framer = Framer::default();
        let mut chunk = [0u8; 1024];
        let mut out = String::with_capacity(256);
        while !self.stop.load(Ordering::Relaxed) {
            refuse_waiting_clients(listener, &self.bus);
            let now = Instant::now();
            let overdue = match mode {
                Mode::Raw => (now.duration_since(heard) > limits.idle).then_some("idle timeout"),
                _ => (now.duration_since(connected) > limits.handshake).then_some("handshake timeout"),
            };
            if let Some(why) = overdue {
                let _ = write_fully(
                    &mut stream,
                    format!("< error {why} >").as_bytes(),
                    now + limits.stalled_reader,
                );
                return Err(std::io::Error::new(ErrorKind::TimedOut, why));
            }
            if mode == Mode::Raw {
                out.clear();
                while let Some(f) = self.node.try_recv() {
                    format_frame(&mut out, &f, (self.clock)());
                }
                if !out.is_empty() {
                    write_fully(&mut stream, out.as_bytes(), now + limits.stalled_reader)?;
                }
            }
            match stream.read(&mut chunk) {
                Ok(0) => return Ok(()),
                Ok(n) => {
                    heard = Instant::now();
                    framer.push(&chunk[..n]);
                }
                Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {
                    std::thread::sleep(Duration::from_micros(50));
                    continue;
                }
                Err(e) => return Err(e),
            }
            while let Some(item) = framer.next_item() {
                let msg = match item {
                    Framed::Message(m) => parse(&m).map_err(|reason| (m, reason)),
                    Framed::Junk(j) => Err((j, "text outside < >")),
                };
                let reply = match (msg, &mode) {
                    (Ok(Message::Open(name)), Mode::Greeted) if name == self.bus => {
                        mode = Mode::Opened;
                        "< ok >"
                    }
                    (Ok(Message::Open(_)), _) => "< error could not open bus >",
                    (Ok(Message::RawMode), Mode::Opened | Mode::Raw) => {
                        mode = Mode::Raw;
                        "< ok >"
                    }
                    (Ok(Message::Echo), _) => "< echo >",
                    (Ok(Message::Send(frame)), Mode::Raw) => {
                        if let Err(e) = self.send_waiting(&frame) {
                            self.send_failed(&e);
                        }
                        ""
                    }
                    (Ok(other), _) => {
                        self.malformed.record(&CanError::Malformed {
                            bus: self.bus.clone(),
                            input: format!("{other:?}"),
                            reason: "command not valid in this mode",
                        });
                        ""
                    }
                    (Err((input, reason)), _) => {
                        self.malformed.record(&CanError::Malformed {
                            bus: self.bus.clone(),
                            input: truncated(&input),
                            reason,
                        });
                        ""
                    }
                };
                if !reply.is_empty() {
                    write_fully(
                        &mut stream,
                        reply.as_bytes(),
                        Instant::now() + limits.stalled_reader,
                    )?;
                }
            }
        }
        Ok(())
    }

    /// Sends `frame`, waiting while the node's transmit queue is full, as socketcand's blocking
    /// write to its CAN socket does: the client's further frames wait in its TCP connection (a
    /// wire that lags the wall clock delays them, it does not lose them), and a client that leaves
    /// takes what it had queued with it. Gives up after [`QUEUE_WAIT`], or when stopping.
    fn send_waiting(&self, frame: &CanFrame) -> Result<(), CanError> {
        let give_up = Instant::now() + QUEUE_WAIT;
        loop {
            match self.node.send(frame) {
                Err(CanError::TxQueueFull { .. })
                    if Instant::now() < give_up && !self.stop.load(Ordering::Relaxed) =>
                {
                    std::thread::sleep(Duration::from_micros(200));
                }
                done => return done,
            }
        }
    }

    /// A failed send onto the bus (full queue), logged at most once a second.
    fn send_failed(&self, e: &CanError) {
        if let Some(left_out) = self.send_failures.allow_now() {
            tracing::warn!(%e, left_out, "socketcand: frame not sent onto the bus");
        }
    }
}

/// Answers every client waiting to connect with a refusal and closes it.
fn refuse_waiting_clients(listener: &TcpListener, bus: &str) {
    while let Ok((mut other, peer)) = listener.accept() {
        tracing::info!(%peer, bus, "socketcand: refused a second client");
        // Best effort, never blocking: the socket is fresh, its buffer empty.
        let _ = other.set_nonblocking(true);
        let _ = other.write(b"< error bus in use by another client >");
    }
}

/// `write_all` on a non-blocking socket: waits out a full send buffer until `deadline`, then
/// gives up with `TimedOut` (a client that stopped reading).
fn write_fully(stream: &mut TcpStream, mut bytes: &[u8], deadline: Instant) -> std::io::Result<()> {
    while !bytes.is_empty() {
        match stream.write(bytes) {
            Ok(0) => return Err(ErrorKind::WriteZero.into()),
            Ok(n) => bytes = &bytes[n..],
            Err(e) if e.kind() == ErrorKind::WouldBlock => {
                if Instant::now() > deadline {
                    return Err(std::io::Error::new(
                        ErrorKind::TimedOut,
                        "the client stopped reading",
                    ));
                }
                std::thread::sleep(Duration::from_micros(50));
            }
            Err(e) if e.kind() == ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_data_with_a_multibyte_character_is_refused_not_split() {
        // Found by the socketcand_text fuzz target: slicing "ff…" in pairs split a UTF-8 character.
        assert_eq!(
            parse("< frame 111 1.000000 f\u{9b}0 >"),
            Err("frame data must be 0–8 bytes of two hex digits each")
        );
    }

    #[test]
    fn parses_the_documented_messages() {
        assert_eq!(parse("< hi >"), Ok(Message::Hi));
        assert_eq!(parse("< open can0 >"), Ok(Message::Open("can0".into())));
        let send = parse("< send 123 8 11 22 33 44 55 66 77 88 >").unwrap();
        let Message::Send(f) = send else {
            panic!("{send:?}")
        };
        assert_eq!(
            (f.id(), f.data()),
            (
                CanId::Standard(0x123),
                &[0x11, 0x22, 0x33, 0x44, 0x55, 0x66, 0x77, 0x88][..]
            )
        );
        // python-can writes bytes without zero padding and IDs in upper case.
        let Ok(Message::Send(f)) = parse("< send 001 3 ff 0 a >") else {
            panic!()
        };
        assert_eq!(f.data(), &[0xFF, 0x00, 0x0A]);
        let Ok(Message::Frame(f, t)) = parse("< frame 12345678 23.000450 0102 >") else {
            panic!()
        };
        assert_eq!(
            (f.id(), f.data(), t),
            (
                CanId::Extended(0x1234_5678),
                &[1u8, 2][..],
                Duration::from_micros(23_000_450)
            )
        );
    }

    #[test]
    fn malformed_messages_are_rejected_with_a_reason() {
        for (bad, why) in [
            ("< send 800 1 00 >", "standard identifier above 0x7FF"),
            (
                "< send 12 1 00 >",
                "identifier must have 3 (standard) or 8 (extended) hex digits",
            ),
            ("< send 123 9 00 >", "length above 8"),
            ("< send 123 2 00 >", "fewer data bytes than the length says"),
            ("< send 123 1 00 11 >", "more data bytes than the length says"),
            ("< send 123 1 zz >", "data byte is not a hex byte"),
            (
                "< frame 123 1.5 ABC >",
                "frame data must be 0–8 bytes of two hex digits each",
            ),
            ("< fly away >", "unknown command"),
            ("hi", "message must be enclosed in < >"),
        ] {
            assert_eq!(parse(bad), Err(why), "{bad}");
        }
    }

    #[test]
    fn format_and_parse_round_trip() {
        let f = CanFrame::new(CanId::standard(0x7A).unwrap(), &[0xDE, 0xAD]).unwrap();
        let mut s = String::new();
        format_frame(&mut s, &f, Duration::from_micros(1_500_002));
        assert_eq!(s, "< frame 07A 1.500002 DEAD >");
        assert_eq!(parse(&s), Ok(Message::Frame(f, Duration::from_micros(1_500_002))));
        s.clear();
        format_send(&mut s, &f);
        assert_eq!(s, "< send 07A 2 DE AD >");
        assert_eq!(parse(&s), Ok(Message::Send(f)));
    }

    #[test]
    fn framer_splits_streams_and_reports_junk() {
        let mut fr = Framer::default();
        fr.push(b"< ok >garbage< fra");
        assert_eq!(fr.next_item(), Some(Framed::Message("< ok >".into())));
        assert_eq!(fr.next_item(), Some(Framed::Junk("garbage".into())));
        assert_eq!(fr.next_item(), None);
        fr.push(b"me 123 0.000001 01 >");
        assert_eq!(
            fr.next_item(),
            Some(Framed::Message("< frame 123 0.000001 01 >".into()))
        );
        fr.push(&[b'<'; MAX_MESSAGE + 2]);
        assert!(matches!(fr.next_item(), Some(Framed::Junk(_))));
    }

    #[test]
    fn random_input_never_panics() {
        let mut rng = crate::time::SimRng::new(77);
        let alphabet = b"<> sendframeopenhirawmodeok0123456789ABCDEFabcdef.\n\x00\xff";
        let mut fr = Framer::default();
        let mut messages = 0;
        for _ in 0..20_000 {
            let n = (rng.next_u64() % 40) as usize;
            let bytes: Vec<u8> = (0..n)
                .map(|_| alphabet[(rng.next_u64() % alphabet.len() as u64) as usize])
                .collect();
            fr.push(&bytes);
            while let Some(item) = fr.next_item() {
                if let Framed::Message(m) = item {
                    let _ = parse(&m);
                    messages += 1;
                }
            }
        }
        assert!(
            messages > 1000,
            "the generator should produce many candidate messages ({messages})"
        );
    }
}
