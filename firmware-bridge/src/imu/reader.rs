//! The host side of a streaming IMU: read what arrived, decode, keep the newest sample and its age.

use super::ImuProtocol;
use super::rvc::RvcDecoder;
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

/// The decoder of a protocol.
#[derive(Debug)]
enum Decoder {
    Wit(WitDecoder),
    Rvc(RvcDecoder),
    Bno055(super::bno055::Bno055Host),
}

/// Reads an IMU on a byte stream.
#[derive(Debug)]
pub struct ImuReader<S: ByteStream> {
    stream: S,
    decoder: Decoder,
    buf: Vec<u8>,
    latest: Option<ImuReading<S::Instant>>,
}

impl<S: ByteStream> ImuReader<S> {
    /// A reader of a WIT-protocol IMU on `stream`.
    pub fn new(stream: S) -> Self {
        Self::speaking(ImuProtocol::Wit, stream)
    }

    /// A reader of an IMU speaking `protocol` on `stream`, sampled at `rate_hz` where the host
    /// asks (BNO055).
    pub fn speaking_at(protocol: ImuProtocol, stream: S, rate_hz: f64) -> Self {
        let mut r = Self::speaking(protocol, stream);
        if protocol == ImuProtocol::Bno055 {
            r.decoder = Decoder::Bno055(super::bno055::Bno055Host::new(rate_hz));
        }
        r
    }

    /// A reader of an IMU speaking `protocol` on `stream`.
    pub fn speaking(protocol: ImuProtocol, stream: S) -> Self {
        Self {
            stream,
            decoder: match protocol {
                ImuProtocol::Wit => Decoder::Wit(WitDecoder::new()),
                ImuProtocol::Bno08xRvc => Decoder::Rvc(RvcDecoder::new()),
                ImuProtocol::Bno055 => {
                    Decoder::Bno055(super::bno055::Bno055Host::new(super::bno055::RATE_HZ))
                }
            },
            buf: vec![0; 4096],
            latest: None,
        }
    }

    /// Decodes everything that has arrived (not waiting) and returns the newest sample so far.
    pub fn poll(&mut self) -> std::io::Result<Option<ImuReading<S::Instant>>> {
        let now = self.stream.now();
        self.poll_by(now)
    }

    /// Polls until the part's first sample arrives or `within` passes on the stream's clock
    /// (a part the host must first configure, as a BNO055, takes a few round trips); whether one
    /// came.
    pub fn wait_first(&mut self, within: std::time::Duration) -> std::io::Result<bool> {
        let start = self.stream.seconds();
        while self.latest.is_none() && self.stream.seconds() - start < within.as_secs_f64() {
            let next = self.stream.now() + std::time::Duration::from_millis(1);
            self.poll_by(next)?;
        }
        Ok(self.latest.is_some())
    }

    /// Sends a due request, then decodes what arrives, waiting until `deadline` at most for the
    /// first bytes.
    fn poll_by(&mut self, deadline: S::Instant) -> std::io::Result<Option<ImuReading<S::Instant>>> {
        let mut wait_until = deadline;
        // A sensor the host asks: the next request, when one is due.
        if let Decoder::Bno055(host) = &mut self.decoder
            && let Some(request) = host.request(self.stream.seconds())
        {
            self.stream.write_all(request)?;
        }
        loop {
            let n = self.stream.read_until(&mut self.buf, wait_until)?;
            if n == 0 {
                break;
            }
            wait_until = self.stream.now();
            let mut newest = None;
            match &mut self.decoder {
                Decoder::Wit(d) => d.feed(&self.buf[..n], |s| newest = Some(*s)),
                Decoder::Rvc(d) => d.feed(&self.buf[..n], |s| newest = Some(*s)),
                Decoder::Bno055(h) => h.feed(&self.buf[..n], |s| newest = Some(*s)),
            }
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
        match &self.decoder {
            Decoder::Wit(d) => d.stats(),
            Decoder::Rvc(d) => d.stats(),
            Decoder::Bno055(h) => h.stats(),
        }
    }
}
