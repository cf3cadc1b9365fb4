//! The host side of a streaming IMU: read what arrived, decode, keep the newest sample and its age.

use super::wit::{DecoderStats, ImuSample, WitDecoder};
use crate::serial::ByteStream;

/// The newest IMU sample and when it arrived.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuReading<I> {
    /// The sample.
    pub sample: ImuSample,
    /// When the read that completed it returned.
    pub received_at: I,
}

/// Reads a WIT-protocol IMU on a byte stream.
#[derive(Debug)]
pub struct ImuReader<S: ByteStream> {
    stream: S,
    decoder: WitDecoder,
    buf: Vec<u8>,
    latest: Option<ImuReading<S::Instant>>,
}

impl<S: ByteStream> ImuReader<S> {
    /// A reader on `stream`.
    pub fn new(stream: S) -> Self {
        Self {
            stream,
            decoder: WitDecoder::new(),
            buf: vec![0; 4096],
            latest: None,
        }
    }

    /// Decodes everything that has arrived (not waiting) and returns the newest sample so far.
    pub fn poll(&mut self) -> std::io::Result<Option<ImuReading<S::Instant>>> {
        let now = self.stream.now();
        loop {
            let n = self.stream.read_until(&mut self.buf, now)?;
            if n == 0 {
                break;
            }
            let mut newest = None;
            self.decoder.feed(&self.buf[..n], |s| newest = Some(*s));
            if let Some(sample) = newest {
                self.latest = Some(ImuReading {
                    sample,
                    received_at: self.stream.now(),
                });
            }
        }
        Ok(self.latest)
    }

    /// Decoder counters (checksum errors, junk).
    pub fn stats(&self) -> DecoderStats {
        self.decoder.stats()
    }
}
