//! A network e-stop: any datagram saying `ESTOP` on the configured UDP address sets the flag the
//! loop checks every tick. Binds to loopback unless told otherwise.

use std::net::{SocketAddr, UdpSocket};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use firmware_bridge::ratelimit::RateLimit;

/// Listens on `addr` until the returned flag is set (then keeps it set).
pub fn listen(addr: SocketAddr) -> std::io::Result<(Arc<AtomicBool>, SocketAddr)> {
    let socket = UdpSocket::bind(addr)?;
    socket.set_read_timeout(Some(Duration::from_millis(100)))?;
    let local = socket.local_addr()?;
    let flag = Arc::new(AtomicBool::new(false));
    let set = Arc::clone(&flag);
    std::thread::Builder::new().name("estop".into()).spawn(move || {
        let mut buf = [0u8; 64];
        let mut junk = RateLimit::per_second();
        while !set.load(Ordering::Relaxed) {
            if let Ok((n, from)) = socket.recv_from(&mut buf) {
                if buf[..n].trim_ascii().eq_ignore_ascii_case(b"ESTOP") {
                    // The flag first: nothing, not even the log line, comes before it.
                    set.store(true, Ordering::Relaxed);
                    tracing::warn!(%from, "e-stop received");
                } else if let Some(left_out) = junk.allow(Instant::now()) {
                    tracing::warn!(%from, bytes = n, left_out, "ignored a datagram that is not ESTOP");
                }
            }
        }
    })?;
    Ok((flag, local))
}
