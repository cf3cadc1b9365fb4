//! What a viewer may send the live server: a WebSocket client on loopback offers a subprotocol the
//! fuzzer picks (`foxglove.sdk.v1`, the older `foxglove.websocket.v1`, none, any text) and sends
//! frames it chooses — text (the protocol's JSON operations: subscribe, unsubscribe, advertise,
//! getParameters, …, or anything), binary (client message data, service calls, anything), pings,
//! a close — then leaves. Whatever it sent, the server keeps serving: a well-behaved viewer that
//! connects next gets the server's info and the run's channel, and the run's messages once it
//! subscribes.

use std::net::TcpStream;
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

use tungstenite::client::IntoClientRequest;
use tungstenite::stream::MaybeTlsStream;
use tungstenite::{Message, WebSocket};
use viewers::live::{LiveView, publish};

/// The server of every input, with one channel a run would have.
fn server() -> &'static (LiveView, Arc<foxglove::RawChannel>) {
    static SERVER: OnceLock<(LiveView, Arc<foxglove::RawChannel>)> = OnceLock::new();
    SERVER.get_or_init(|| {
        let view = LiveView::serve("127.0.0.1:0".parse().expect("an address"), "fuzz")
            .expect("the live server starts on loopback");
        let schema = foxglove::Schema::new("fuzz", "jsonschema", br#"{"type":"object"}"#.to_vec());
        let channel = view
            .channel("/fuzz", &schema, "json", &Default::default())
            .expect("a channel");
        (view, channel)
    })
}

type Socket = WebSocket<MaybeTlsStream<TcpStream>>;

/// A client of the server offering `protocol` (none: no subprotocol header), each read waiting
/// `patience` at most.
fn connect(view: &LiveView, protocol: Option<&str>, patience: Duration) -> Result<Socket, String> {
    let mut request = view.url().into_client_request().map_err(|e| e.to_string())?;
    if let Some(p) = protocol {
        request.headers_mut().insert(
            "Sec-WebSocket-Protocol",
            p.parse().map_err(|_| "not a header value")?,
        );
    }
    let (socket, _) = tungstenite::connect(request).map_err(|e| e.to_string())?;
    if let MaybeTlsStream::Plain(s) = socket.get_ref() {
        s.set_read_timeout(Some(patience)).map_err(|e| e.to_string())?;
        s.set_write_timeout(Some(Duration::from_millis(200)))
            .map_err(|e| e.to_string())?;
    }
    Ok(socket)
}

/// The subprotocol the junk client offers, from the input's first byte.
fn protocol(b: u8, rest: &[u8]) -> Option<String> {
    match b % 4 {
        0 => Some("foxglove.sdk.v1".into()),
        1 => Some("foxglove.websocket.v1".into()),
        2 => None,
        _ => Some(
            String::from_utf8_lossy(&rest[..rest.len().min(16)])
                .chars()
                .filter(char::is_ascii_alphanumeric)
                .collect(),
        ),
    }
}

/// The frames of an input: a kind byte, a little-endian u16 length, the payload (cut at the end).
fn frames(mut data: &[u8]) -> Vec<Message> {
    let mut out = Vec::new();
    while data.len() >= 3 && out.len() < 64 {
        let len = usize::from(u16::from_le_bytes([data[1], data[2]])).min(data.len() - 3);
        let payload = &data[3..3 + len];
        out.push(match data[0] % 4 {
            0 => Message::Text(String::from_utf8_lossy(payload).into_owned().into()),
            1 => Message::Binary(payload.to_vec().into()),
            2 => Message::Ping(payload[..payload.len().min(125)].to_vec().into()),
            _ => Message::Close(None),
        });
        data = &data[3 + len..];
    }
    out
}

/// One input.
///
/// # Panics
/// When the server stops serving a well-behaved viewer after the input's client.
pub fn run(data: &[u8]) {
    let Some((&first, rest)) = data.split_first() else {
        return;
    };
    let (view, channel) = server();
    // The junk client: whatever the server makes of its handshake and frames, it then leaves.
    if let Ok(mut junk) = connect(view, protocol(first, rest).as_deref(), Duration::from_millis(10)) {
        for m in frames(rest) {
            if junk.send(m).is_err() {
                break;
            }
        }
        // Reads what the server answered until it has nothing more (or closed).
        let until = Instant::now() + Duration::from_millis(100);
        while Instant::now() < until && junk.read().is_ok() {}
    }
    // A viewer as Foxglove's app is: the server's info, the channel, then its messages.
    let mut viewer = connect(view, Some("foxglove.sdk.v1"), Duration::from_millis(10))
        .unwrap_or_else(|e| panic!("a viewer cannot connect after the junk: {e}"));
    let until = Instant::now() + Duration::from_secs(5);
    let mut channel_id = None;
    let mut info = false;
    while channel_id.is_none() {
        assert!(Instant::now() < until, "no server info and channel within 5 s");
        let Ok(Message::Text(text)) = viewer.read() else {
            continue;
        };
        let v: serde_json::Value = serde_json::from_str(&text).expect("the server sends JSON");
        info |= v["op"] == "serverInfo";
        if v["op"] == "advertise" {
            channel_id = v["channels"]
                .as_array()
                .and_then(|cs| cs.iter().find(|c| c["topic"] == "/fuzz"))
                .and_then(|c| c["id"].as_u64());
        }
    }
    assert!(info, "the server's info comes first");
    let subscribe = serde_json::json!({
        "op": "subscribe",
        "subscriptions": [{"id": 7, "channelId": channel_id}],
    });
    viewer
        .send(Message::Text(subscribe.to_string().into()))
        .expect("the viewer subscribes");
    loop {
        assert!(Instant::now() < until, "no message within 5 s of subscribing");
        // The subscription takes effect on the server's thread: publish until one arrives.
        publish(channel, b"{}", 1);
        if let Ok(Message::Binary(b)) = viewer.read()
            && b.first() == Some(&1)
            && b.get(1..5) == Some(&7u32.to_le_bytes()[..])
        {
            break;
        }
    }
    let _ = viewer.close(None);
}
