//! Linux SocketCAN transport (classic CAN) through the `socketcan` crate, for real adapters
//! (`can0` from a USB-CAN dongle, or a `vcan` interface where the kernel has it).

use std::time::{Duration, Instant};

use socketcan::{CanSocket, EmbeddedFrame, ExtendedId, Id, Socket, StandardId};

use super::{CanBus, CanError, CanFrame, CanId};

/// A SocketCAN interface opened for raw classic frames.
#[derive(Debug)]
pub struct SocketCanBus {
    name: String,
    socket: CanSocket,
}

impl SocketCanBus {
    /// Opens interface `name` (e.g. `can0`). The interface must be up with its bitrate set
    /// (`ip link set can0 up type can bitrate 1000000`).
    pub fn open(name: &str) -> Result<Self, CanError> {
        let socket = CanSocket::open(name).map_err(|e| CanError::Io {
            bus: name.to_owned(),
            reason: format!("cannot open SocketCAN interface: {e} (is it up? `ip link show {name}`)"),
        })?;
        Ok(Self {
            name: name.to_owned(),
            socket,
        })
    }

    fn io(&self, e: &std::io::Error) -> CanError {
        match e.raw_os_error() {
            Some(105) => CanError::TxQueueFull {
                bus: self.name.clone(),
            }, // ENOBUFS
            Some(100) => CanError::Disconnected {
                bus: self.name.clone(),
                reason: "network is down".into(),
            }, // ENETDOWN
            _ => CanError::Io {
                bus: self.name.clone(),
                reason: e.to_string(),
            },
        }
    }
}

fn to_socketcan(frame: &CanFrame) -> Option<socketcan::CanFrame> {
    let id: Id = match frame.id() {
        CanId::Standard(id) => StandardId::new(id)?.into(),
        CanId::Extended(id) => ExtendedId::new(id)?.into(),
    };
    socketcan::CanFrame::new(id, frame.data())
}

fn from_socketcan(frame: &socketcan::CanFrame) -> Option<CanFrame> {
    let id = match frame.id() {
        Id::Standard(id) => CanId::Standard(id.as_raw()),
        Id::Extended(id) => CanId::Extended(id.as_raw()),
    };
    CanFrame::new(id, frame.data())
}

impl CanBus for SocketCanBus {
    type Instant = Instant;

    fn now(&self) -> Instant {
        Instant::now()
    }

    fn send(&mut self, frame: &CanFrame) -> Result<(), CanError> {
        let f = to_socketcan(frame).ok_or_else(|| CanError::Malformed {
            bus: self.name.clone(),
            input: format!("{frame:?}"),
            reason: "frame not representable by SocketCAN",
        })?;
        self.socket.write_frame(&f).map_err(|e| self.io(&e))
    }

    fn recv_until(&mut self, deadline: Instant) -> Result<Option<CanFrame>, CanError> {
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(None);
            }
            match self.socket.read_frame_timeout(left.max(Duration::from_micros(1))) {
                Ok(f @ socketcan::CanFrame::Data(_)) => {
                    if let Some(frame) = from_socketcan(&f) {
                        return Ok(Some(frame));
                    }
                }
                // No device of ours sends remote frames; skip them.
                Ok(socketcan::CanFrame::Remote(_)) => {}
                Ok(socketcan::CanFrame::Error(e)) => {
                    return Err(CanError::Io {
                        bus: self.name.clone(),
                        reason: format!("error frame: {e:?}"),
                    });
                }
                // A signal interrupted the wait: wait again for what is left.
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) =>
                {
                    return Ok(None);
                }
                Err(e) => return Err(self.io(&e)),
            }
        }
    }
}
