//! Serial lines between a host and a simulated world: the world-side trait, a byte-stream view for
//! host code that only reads (IMUs), a stream line with wire time, and a pseudo-terminal server that
//! exposes any line of a world to programs that open a serial device.

use std::collections::VecDeque;
use std::io::{Read, Write};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use crate::time::SimWorld;
use crate::time::{BusInstant, SimInstant};

/// A simulated world with serial lines (Dynamixel buses, IMU streams) a host can talk on.
pub trait SerialSimWorld: SimWorld {
    /// The host puts `bytes` on line `line` now.
    fn host_transmit(&mut self, line: usize, bytes: &[u8]);
    /// Appends the bytes that reached the host on line `line` by now.
    fn host_receive(&mut self, line: usize, out: &mut Vec<u8>);
}

/// Bytes from a device to the host, each chunk arriving after its wire time (a streaming sensor).
#[derive(Debug)]
pub struct StreamLine {
    baud: u32,
    line_free_at: SimInstant,
    pending: VecDeque<(SimInstant, usize)>,
    bytes: VecDeque<u8>,
}

impl StreamLine {
    /// A line at `baud` (10 bits per byte).
    pub fn new(baud: u32) -> Self {
        Self {
            baud,
            line_free_at: SimInstant::ZERO,
            pending: VecDeque::with_capacity(64),
            bytes: VecDeque::with_capacity(4096),
        }
    }

    /// How long `bytes` bytes take on this line.
    pub fn wire_time(&self, bytes: usize) -> Duration {
        let bits = bytes as u64 * 10;
        Duration::from_nanos((bits * 1_000_000_000).div_ceil(u64::from(self.baud.max(1))))
    }

    /// The device starts sending `bytes` at `now` (after what it is still sending).
    pub fn device_transmit(&mut self, now: SimInstant, bytes: &[u8]) {
        let start = self.line_free_at.max(now);
        let end = start + self.wire_time(bytes.len());
        self.line_free_at = end;
        self.pending.push_back((end, bytes.len()));
        self.bytes.extend(bytes);
    }

    /// The next delivery after `now`.
    pub fn next_event(&self, now: SimInstant) -> Option<SimInstant> {
        self.pending.iter().map(|p| p.0).find(|&t| t > now)
    }

    /// Appends the bytes delivered by `now` to `out`.
    pub fn host_receive(&mut self, now: SimInstant, out: &mut Vec<u8>) {
        while let Some(&(at, n)) = self.pending.front() {
            if at > now {
                break;
            }
            self.pending.pop_front();
            out.extend(self.bytes.drain(..n));
        }
    }
}

/// A byte stream the host reads (a sensor's serial output), in its own clock.
pub trait ByteStream {
    /// Timestamps of this stream.
    type Instant: BusInstant;
    /// The stream's clock.
    fn now(&self) -> Self::Instant;
    /// Reads what has arrived into `buf`, waiting until `deadline` at most for the first byte.
    fn read_until(&mut self, buf: &mut [u8], deadline: Self::Instant) -> std::io::Result<usize>;
    /// Sends `bytes` to the device (a sensor the host asks, such as a BNO055).
    fn write_all(&mut self, bytes: &[u8]) -> std::io::Result<()>;
    /// Seconds of this stream's clock since some fixed origin (for request pacing).
    fn seconds(&self) -> f64;
}

/// A serial device (USB adapter or pseudo-terminal) as a byte stream.
#[derive(Debug)]
pub struct DeviceStream {
    port: serialport::TTYPort,
}

impl DeviceStream {
    /// Opens `path` at `baud`, 8N1.
    pub fn open(path: &str, baud: u32) -> std::io::Result<Self> {
        let port = serialport::new(path, baud)
            .timeout(Duration::from_millis(1))
            .open_native()
            .map_err(std::io::Error::other)?;
        Ok(Self { port })
    }
}

impl ByteStream for DeviceStream {
    type Instant = std::time::Instant;

    fn now(&self) -> std::time::Instant {
        std::time::Instant::now()
    }

    fn write_all(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        Write::write_all(&mut self.port, bytes)
    }

    fn seconds(&self) -> f64 {
        static ORIGIN: std::sync::OnceLock<std::time::Instant> = std::sync::OnceLock::new();
        ORIGIN
            .get_or_init(std::time::Instant::now)
            .elapsed()
            .as_secs_f64()
    }

    fn read_until(&mut self, buf: &mut [u8], deadline: std::time::Instant) -> std::io::Result<usize> {
        let wait = deadline.saturating_duration_since(std::time::Instant::now());
        // serialport builds an io::Error (on the heap) for every read that times out: with nothing
        // waiting and no time left, answer "nothing" without reading, so polling allocates nothing.
        if wait.is_zero()
            && serialport::SerialPort::bytes_to_read(&self.port).map_err(std::io::Error::other)? == 0
        {
            return Ok(0);
        }
        serialport::SerialPort::set_timeout(&mut self.port, wait.max(Duration::from_micros(1)))
            .map_err(std::io::Error::other)?;
        match self.port.read(buf) {
            Ok(n) => Ok(n),
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => Ok(0),
            Err(e) => Err(e),
        }
    }
}

/// The host's end of stream line `line` of a simulated world; reading runs the world forward.
#[derive(Debug)]
pub struct LockstepStream<W> {
    world: Arc<Mutex<W>>,
    line: usize,
    rx: Vec<u8>,
}

impl<W: SerialSimWorld> LockstepStream<W> {
    /// The host end of `line`.
    pub fn new(world: Arc<Mutex<W>>, line: usize) -> Self {
        Self {
            world,
            line,
            rx: Vec::with_capacity(4096),
        }
    }
}

impl<W: SerialSimWorld> ByteStream for LockstepStream<W> {
    type Instant = SimInstant;

    fn now(&self) -> SimInstant {
        self.world.lock().unwrap_or_else(PoisonError::into_inner).now()
    }

    fn write_all(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        let mut world = self.world.lock().unwrap_or_else(PoisonError::into_inner);
        world.host_transmit(self.line, bytes);
        Ok(())
    }

    fn seconds(&self) -> f64 {
        self.now().as_nanos() as f64 * 1e-9
    }

    fn read_until(&mut self, buf: &mut [u8], deadline: SimInstant) -> std::io::Result<usize> {
        let mut world = self.world.lock().unwrap_or_else(PoisonError::into_inner);
        loop {
            world.host_receive(self.line, &mut self.rx);
            if !self.rx.is_empty() || world.now() >= deadline {
                break;
            }
            let from = world.now();
            world.step_until(deadline.max(from));
        }
        let n = self.rx.len().min(buf.len());
        buf[..n].copy_from_slice(&self.rx[..n]);
        self.rx.drain(..n);
        Ok(n)
    }
}

/// Writes to the terminal never block (see [`deliver`]).
fn set_nonblocking(master: &serialport::TTYPort) -> std::io::Result<()> {
    use std::os::fd::{AsRawFd, BorrowedFd};
    #[allow(
        unsafe_code,
        reason = "serialport's TTYPort gives its descriptor only as a raw fd"
    )]
    // SAFETY: `master` owns the descriptor and outlives this borrow.
    let fd = unsafe { BorrowedFd::borrow_raw(master.as_raw_fd()) };
    let flags = rustix::fs::fcntl_getfl(fd)?;
    rustix::fs::fcntl_setfl(fd, flags | rustix::fs::OFlags::NONBLOCK)?;
    Ok(())
}

/// Like a UART whose reader stopped reading: writes what fits in the terminal's buffer now and
/// returns how many bytes were lost. On a blocking descriptor a reply larger than the room left
/// in a terminal nobody reads (a client gone, or not reading) would wait forever — and so would
/// whoever stops the server.
fn deliver(master: &mut serialport::TTYPort, bytes: &[u8]) -> std::io::Result<usize> {
    let mut rest = bytes;
    while !rest.is_empty() {
        match master.write(rest) {
            Ok(0) => break,
            Ok(k) => rest = &rest[k..],
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::TimedOut | std::io::ErrorKind::WouldBlock
                ) =>
            {
                break;
            }
            Err(e) => return Err(e),
        }
    }
    Ok(rest.len())
}

/// Serves line `line` of a world on a pseudo-terminal, in wall-clock time: programs open
/// [`PtyServer::path`] like a USB serial adapter.
#[derive(Debug)]
pub struct PtyServer {
    path: String,
    stop: Arc<AtomicBool>,
    dropped: Arc<std::sync::atomic::AtomicU64>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl PtyServer {
    /// Opens a pseudo-terminal pair and starts serving; the world's clock follows the wall clock,
    /// checked every `resolution`.
    pub fn spawn<W: SerialSimWorld + Send + 'static>(
        world: Arc<Mutex<W>>,
        line: usize,
        resolution: Duration,
    ) -> std::io::Result<Self> {
        let (mut master, slave) = serialport::TTYPort::pair().map_err(std::io::Error::other)?;
        let path = serialport::SerialPort::name(&slave)
            .ok_or_else(|| std::io::Error::other("the pseudo-terminal has no device path"))?;
        serialport::SerialPort::set_timeout(&mut master, resolution).map_err(std::io::Error::other)?;
        set_nonblocking(&master)?;
        let stop = Arc::new(AtomicBool::new(false));
        let flag = Arc::clone(&stop);
        let lost_bytes = Arc::new(std::sync::atomic::AtomicU64::new(0));
        let dropped = Arc::clone(&lost_bytes);
        let thread = std::thread::Builder::new()
            .name("serial-pty".into())
            .spawn(move || {
                crate::time::serve_in_real_time();
                // Keeping the slave open means the master never reads EIO between clients.
                let _slave = slave;
                let start = std::time::Instant::now();
                let origin = world.lock().unwrap_or_else(PoisonError::into_inner).now();
                let mut inbound = [0u8; 4096];
                let mut outbound = Vec::with_capacity(8192);
                let mut overflow_log = crate::ratelimit::RateLimit::per_second();
                while !flag.load(Ordering::Relaxed) {
                    let n = match master.read(&mut inbound) {
                        Ok(n) => n,
                        Err(e) if e.kind() == std::io::ErrorKind::TimedOut => 0,
                        Err(e) if e.kind() == std::io::ErrorKind::Interrupted => 0,
                        Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => 0,
                        Err(e) => {
                            tracing::warn!("pseudo-terminal read failed: {e}; stopping the serial server");
                            break;
                        }
                    };
                    let target = origin + start.elapsed();
                    outbound.clear();
                    {
                        let mut w = world.lock().unwrap_or_else(PoisonError::into_inner);
                        while w.now() < target {
                            w.step_until(target);
                        }
                        if n > 0 {
                            w.host_transmit(line, &inbound[..n]);
                        }
                        w.host_receive(line, &mut outbound);
                    }
                    let lost = match deliver(&mut master, &outbound) {
                        Ok(lost) => lost,
                        Err(e) => {
                            tracing::warn!("pseudo-terminal write failed: {e}; stopping the serial server");
                            return;
                        }
                    };
                    if lost > 0 {
                        let lost = dropped.fetch_add(lost as u64, Ordering::Relaxed) + lost as u64;
                        if let Some(left_out) = overflow_log.allow(std::time::Instant::now()) {
                            tracing::warn!(
                                lost,
                                left_out,
                                "pseudo-terminal: the client is not reading; bytes dropped"
                            );
                        }
                    }
                }
            })?;
        Ok(Self {
            path,
            stop,
            dropped: lost_bytes,
            thread: Some(thread),
        })
    }

    /// Bytes lost because the client did not read them in time.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// The device path to open (e.g. `/dev/pts/7`).
    pub fn path(&self) -> &str {
        &self.path
    }
}

impl Drop for PtyServer {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_reply_nobody_reads_is_dropped_not_waited_on() {
        // A megabyte into a terminal whose other end is open and never read: a blocking write
        // would wait forever (and with it whoever stops the server).
        let (mut master, _slave) = serialport::TTYPort::pair().unwrap();
        serialport::SerialPort::set_timeout(&mut master, Duration::from_micros(200)).unwrap();
        set_nonblocking(&master).unwrap();
        let (done, wait) = std::sync::mpsc::sync_channel(1);
        let writer = std::thread::Builder::new()
            .name("pty-writer".into())
            .spawn(move || {
                let lost = deliver(&mut master, &vec![0x55; 1 << 20]);
                let _ = done.send(lost.map_err(|e| e.to_string()));
            })
            .unwrap();
        // A deadline only so that a regression fails instead of hanging; the write returns at once.
        let lost = wait
            .recv_timeout(Duration::from_secs(30))
            .expect("the write blocked")
            .unwrap();
        assert!(lost > 0 && lost < 1 << 20, "{lost} bytes lost");
        writer.join().unwrap();
    }
}
