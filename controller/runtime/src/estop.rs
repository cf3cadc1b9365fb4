//! A network e-stop: any datagram saying `ESTOP` on the configured UDP address sets the flag the
//! loop checks every tick. Binds to loopback unless told otherwise. The operator's other one-word
//! signals (`LOWERED`: the harness has set the robot on its feet) arrive the same way, each on its
//! own socket and thread, so that nothing but the e-stop shares the e-stop's.

use std::net::{SocketAddr, UdpSocket};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use firmware_bridge::ratelimit::RateLimit;

/// Listens on `addr` for `ESTOP` until the returned flag is set (then keeps it set).
pub fn listen(addr: SocketAddr) -> std::io::Result<(Arc<AtomicBool>, SocketAddr)> {
    listen_for(addr, "ESTOP", "estop")
}

/// Listens on `addr` for a datagram saying `word` (any case, surrounding blanks ignored) until
/// the returned flag is set, on a thread named `name`.
pub fn listen_for(
    addr: SocketAddr,
    word: &'static str,
    name: &str,
) -> std::io::Result<(Arc<AtomicBool>, SocketAddr)> {
    let socket = UdpSocket::bind(addr)?;
    socket.set_read_timeout(Some(Duration::from_millis(100)))?;
    let local = socket.local_addr()?;
    let flag = Arc::new(AtomicBool::new(false));
    let set = Arc::clone(&flag);
    std::thread::Builder::new().name(name.into()).spawn(move || {
        let mut buf = [0u8; 64];
        let mut junk = RateLimit::per_second();
        while !set.load(Ordering::Relaxed) {
            if let Ok((n, from)) = socket.recv_from(&mut buf) {
                // A C sender's `sizeof` brings the string's NUL along: trailing NULs are padding.
                let text = buf[..n].trim_ascii_end();
                let end = text.iter().rposition(|&b| b != 0).map_or(0, |i| i + 1);
                if text[..end].trim_ascii().eq_ignore_ascii_case(word.as_bytes()) {
                    // The flag first: nothing, not even the log line, comes before it.
                    set.store(true, Ordering::Relaxed);
                    tracing::warn!(%from, "{word} received");
                } else if let Some(left_out) = junk.allow(Instant::now()) {
                    tracing::warn!(%from, bytes = n, left_out, "ignored a datagram that is not {word}");
                }
            }
        }
    })?;
    Ok((flag, local))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_estop_sent_with_its_c_string_nul_is_taken() {
        let (flag, local) = listen_for("127.0.0.1:0".parse().unwrap(), "ESTOP", "estop-test").unwrap();
        let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
        // `send(fd, "ESTOP", sizeof "ESTOP", …)` from C sends six bytes; a fixed buffer, more.
        socket.send_to(b"ESTOP\0\0\0", local).unwrap();
        let deadline = Instant::now() + Duration::from_secs(30);
        while !flag.load(Ordering::Relaxed) {
            assert!(Instant::now() < deadline, "ESTOP\\0 was not taken");
            std::thread::yield_now();
        }
    }
}
