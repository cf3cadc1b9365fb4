//! Classic CAN: checked frame types, the transport trait the drivers use, wire-time modelling, and
//! the transports: in-process [`virtual_bus`], [`socketcand`] over TCP, and kernel [`socketcan`].

pub mod socketcan;
pub mod socketcand;
pub mod virtual_bus;
pub mod wire_time;

use crate::time::BusInstant;

/// A CAN identifier, checked at construction: 11-bit standard or 29-bit extended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum CanId {
    /// 11-bit identifier, `0..=0x7FF`.
    Standard(u16),
    /// 29-bit identifier, `0..=0x1FFF_FFFF`.
    Extended(u32),
}

impl CanId {
    /// A standard identifier, or `None` above `0x7FF`.
    pub const fn standard(raw: u16) -> Option<Self> {
        if raw <= 0x7FF {
            Some(Self::Standard(raw))
        } else {
            None
        }
    }

    /// An extended identifier, or `None` above `0x1FFF_FFFF`.
    pub const fn extended(raw: u32) -> Option<Self> {
        if raw <= 0x1FFF_FFFF {
            Some(Self::Extended(raw))
        } else {
            None
        }
    }

    /// The numeric identifier.
    pub const fn raw(self) -> u32 {
        match self {
            Self::Standard(id) => id as u32,
            Self::Extended(id) => id,
        }
    }

    /// True for 29-bit identifiers.
    pub const fn is_extended(self) -> bool {
        matches!(self, Self::Extended(_))
    }
}

/// A classic CAN data frame: identifier and 0–8 data bytes.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct CanFrame {
    id: CanId,
    len: u8,
    data: [u8; 8],
}

impl CanFrame {
    /// Most data bytes in a classic CAN frame.
    pub const MAX_DATA: usize = 8;

    /// A frame with `data`, or `None` when `data` is longer than 8 bytes.
    pub fn new(id: CanId, data: &[u8]) -> Option<Self> {
        if data.len() > Self::MAX_DATA {
            return None;
        }
        let mut buf = [0u8; 8];
        buf[..data.len()].copy_from_slice(data);
        Some(Self {
            id,
            len: data.len() as u8,
            data: buf,
        })
    }

    /// A frame carrying exactly eight bytes.
    pub const fn new8(id: CanId, data: [u8; 8]) -> Self {
        Self { id, len: 8, data }
    }

    /// The identifier.
    pub const fn id(&self) -> CanId {
        self.id
    }

    /// The data bytes (length = DLC).
    pub fn data(&self) -> &[u8] {
        &self.data[..usize::from(self.len)]
    }

    /// Data length code.
    pub const fn dlc(&self) -> usize {
        self.len as usize
    }
}

impl std::fmt::Debug for CanFrame {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.id {
            CanId::Standard(id) => write!(f, "{id:03X}#")?,
            CanId::Extended(id) => write!(f, "{id:08X}#")?,
        }
        for b in self.data() {
            write!(f, "{b:02X}")?;
        }
        Ok(())
    }
}

/// What can go wrong on a CAN transport.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum CanError {
    /// The controller is bus-off (too many transmit errors); nothing is sent or received until it
    /// recovers.
    #[error("CAN bus {bus} is bus-off")]
    BusOff {
        /// The bus name.
        bus: String,
    },
    /// The transmit queue is full.
    #[error("CAN bus {bus}: transmit queue full")]
    TxQueueFull {
        /// The bus name.
        bus: String,
    },
    /// The connection to the bus (socket, TCP peer) is gone.
    #[error("CAN bus {bus}: connection lost: {reason}")]
    Disconnected {
        /// The bus name.
        bus: String,
        /// The operating system's or peer's words.
        reason: String,
    },
    /// A peer sent something that is not a frame of this protocol (socketcand text, for instance).
    #[error("CAN bus {bus}: malformed input {input:?}: {reason}")]
    Malformed {
        /// The bus name.
        bus: String,
        /// The offending input (truncated to 80 characters).
        input: String,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// Any other operating-system error.
    #[error("CAN bus {bus}: {reason}")]
    Io {
        /// The bus name.
        bus: String,
        /// The operating system's words.
        reason: String,
    },
}

/// A CAN transport as the drivers use it: send a frame, receive with a deadline.
///
/// The transport names its own `Instant`, so a mock bus can run on simulated time while hardware
/// uses the monotonic clock. Receiving never blocks past the deadline.
pub trait CanBus {
    /// The clock this transport's deadlines are on.
    type Instant: BusInstant;

    /// The transport's current time.
    fn now(&self) -> Self::Instant;

    /// Queues `frame` for transmission.
    fn send(&mut self, frame: &CanFrame) -> Result<(), CanError>;

    /// The next received frame, or `Ok(None)` once `deadline` has passed with nothing received.
    fn recv_until(&mut self, deadline: Self::Instant) -> Result<Option<CanFrame>, CanError>;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_are_range_checked() {
        assert_eq!(CanId::standard(0x7FF), Some(CanId::Standard(0x7FF)));
        assert_eq!(CanId::standard(0x800), None);
        assert_eq!(CanId::extended(0x1FFF_FFFF).map(CanId::raw), Some(0x1FFF_FFFF));
        assert_eq!(CanId::extended(0x2000_0000), None);
    }

    #[test]
    fn frames_hold_at_most_eight_bytes() {
        let id = CanId::standard(0x12).unwrap();
        assert!(CanFrame::new(id, &[0; 9]).is_none());
        let f = CanFrame::new(id, &[1, 2, 3]).unwrap();
        assert_eq!((f.dlc(), f.data()), (3, &[1u8, 2, 3][..]));
        assert_eq!(format!("{f:?}"), "012#010203");
    }
}
