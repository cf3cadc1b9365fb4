//! CDR as DDS puts samples on the wire (XCDR version 1, the encoding Cyclone DDS, RustDDS and
//! ROS 2 use for plain structs): a 4-byte encapsulation header, then the fields in order, each
//! primitive aligned to its own size counted from the end of the header. Structs and arrays add no
//! alignment of their own; strings are a `uint32` length including the terminating NUL, then the
//! bytes and the NUL; sequences are a `uint32` count, then the elements.

/// The encapsulation header of little-endian CDR (representation id 0x0001, options 0).
pub const CDR_LE: [u8; 4] = [0x00, 0x01, 0x00, 0x00];
/// The representation id of big-endian CDR.
const CDR_BE_ID: [u8; 2] = [0x00, 0x00];
/// Bytes of the encapsulation header.
pub const HEADER_LEN: usize = 4;

/// A CDR sample being written into a reused buffer (little-endian).
#[derive(Debug)]
pub struct CdrWriter<'a> {
    buf: &'a mut Vec<u8>,
}

impl<'a> CdrWriter<'a> {
    /// Starts a sample in `buf` (cleared): the encapsulation header.
    pub fn new(buf: &'a mut Vec<u8>) -> Self {
        buf.clear();
        buf.extend_from_slice(&CDR_LE);
        Self { buf }
    }

    /// Pads to a multiple of `n` bytes from the end of the header.
    fn align(&mut self, n: usize) {
        while !(self.buf.len() - HEADER_LEN).is_multiple_of(n) {
            self.buf.push(0);
        }
    }

    /// An `octet`/`uint8`.
    pub fn u8(&mut self, v: u8) -> &mut Self {
        self.buf.push(v);
        self
    }

    /// Octets as they are (an `octet[N]` array: no count).
    pub fn octets(&mut self, v: &[u8]) -> &mut Self {
        self.buf.extend_from_slice(v);
        self
    }

    /// An `int16`.
    pub fn i16(&mut self, v: i16) -> &mut Self {
        self.align(2);
        self.buf.extend_from_slice(&v.to_le_bytes());
        self
    }

    /// A `uint32`.
    pub fn u32(&mut self, v: u32) -> &mut Self {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
        self
    }

    /// An `int32`.
    pub fn i32(&mut self, v: i32) -> &mut Self {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
        self
    }

    /// A `float32`.
    pub fn f32(&mut self, v: f32) -> &mut Self {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
        self
    }

    /// A `float64`.
    pub fn f64(&mut self, v: f64) -> &mut Self {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
        self
    }

    /// A `string` (no NUL inside: one is cut there, as a C reader would).
    pub fn string(&mut self, s: &str) -> &mut Self {
        let s = s.split('\0').next().unwrap_or("");
        self.u32(u32::try_from(s.len() + 1).unwrap_or(u32::MAX));
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
        self
    }

    /// A sequence's element count.
    pub fn count(&mut self, n: usize) -> &mut Self {
        self.u32(u32::try_from(n).unwrap_or(u32::MAX))
    }

    /// A `float64[]` (a sequence: count, then the elements).
    pub fn f64s(&mut self, values: impl ExactSizeIterator<Item = f64>) -> &mut Self {
        self.count(values.len());
        for v in values {
            self.f64(v);
        }
        self
    }

    /// A `builtin_interfaces/Time` of `ns` nanoseconds.
    pub fn time(&mut self, ns: u64) -> &mut Self {
        self.i32(i32::try_from(ns / 1_000_000_000).unwrap_or(i32::MAX));
        self.u32(u32::try_from(ns % 1_000_000_000).unwrap_or(0))
    }
}

/// Why a CDR sample could not be read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CdrError {
    /// Shorter than its fields.
    #[error("CDR sample ends at byte {len}, a field needs {needed} bytes from byte {at}")]
    Truncated {
        /// Where the field starts (from the end of the header).
        at: usize,
        /// Its size.
        needed: usize,
        /// Bytes after the header.
        len: usize,
    },
    /// A fixed-size type's sample of another size.
    #[error("CDR sample of {found} bytes where the type takes exactly {expected}")]
    Length {
        /// The type's size, header included.
        expected: usize,
        /// The sample's.
        found: usize,
    },
    /// An encapsulation this reader does not take (only plain CDR, little- or big-endian).
    #[error("CDR encapsulation {0:#06x} is not plain CDR (0x0000 big-endian, 0x0001 little-endian)")]
    Encapsulation(u16),
    /// A string without its NUL, or not UTF-8.
    #[error("CDR string at byte {0} is not a NUL-terminated UTF-8 string")]
    BadString(usize),
    /// A sequence longer than the reader allows.
    #[error("CDR sequence at byte {at} has {count} elements, more than the {max} allowed")]
    TooLong {
        /// Where its count is.
        at: usize,
        /// Its count.
        count: u32,
        /// The most the reader takes.
        max: usize,
    },
}

/// A CDR sample being read, in either byte order.
#[derive(Debug, Clone)]
pub struct CdrReader<'a> {
    body: &'a [u8],
    at: usize,
    big_endian: bool,
}

impl<'a> CdrReader<'a> {
    /// Reads the encapsulation header of `sample`.
    pub fn new(sample: &'a [u8]) -> Result<Self, CdrError> {
        if sample.len() < HEADER_LEN {
            return Err(CdrError::Truncated {
                at: 0,
                needed: HEADER_LEN,
                len: sample.len(),
            });
        }
        let id = [sample[0], sample[1]];
        let big_endian = match id {
            _ if id == [CDR_LE[0], CDR_LE[1]] => false,
            CDR_BE_ID => true,
            _ => return Err(CdrError::Encapsulation(u16::from_be_bytes(id))),
        };
        Ok(Self {
            body: &sample[HEADER_LEN..],
            at: 0,
            big_endian,
        })
    }

    fn take<const N: usize>(&mut self) -> Result<[u8; N], CdrError> {
        self.at = self.at.next_multiple_of(N.min(8));
        let bytes = self.body.get(self.at..self.at + N).ok_or(CdrError::Truncated {
            at: self.at,
            needed: N,
            len: self.body.len(),
        })?;
        self.at += N;
        let mut out: [u8; N] = bytes.try_into().expect("N bytes");
        if self.big_endian {
            out.reverse();
        }
        Ok(out)
    }

    /// An `octet`/`uint8`.
    pub fn u8(&mut self) -> Result<u8, CdrError> {
        Ok(self.take::<1>()?[0])
    }

    /// `out.len()` octets (an `octet[N]` array).
    pub fn octets(&mut self, out: &mut [u8]) -> Result<(), CdrError> {
        let bytes = self
            .body
            .get(self.at..self.at + out.len())
            .ok_or(CdrError::Truncated {
                at: self.at,
                needed: out.len(),
                len: self.body.len(),
            })?;
        out.copy_from_slice(bytes);
        self.at += out.len();
        Ok(())
    }

    /// An `int16`.
    pub fn i16(&mut self) -> Result<i16, CdrError> {
        Ok(i16::from_le_bytes(self.take()?))
    }

    /// A `uint32`.
    pub fn u32(&mut self) -> Result<u32, CdrError> {
        Ok(u32::from_le_bytes(self.take()?))
    }

    /// An `int32`.
    pub fn i32(&mut self) -> Result<i32, CdrError> {
        Ok(i32::from_le_bytes(self.take()?))
    }

    /// A `float32`.
    pub fn f32(&mut self) -> Result<f32, CdrError> {
        Ok(f32::from_le_bytes(self.take()?))
    }

    /// A `float64`.
    pub fn f64(&mut self) -> Result<f64, CdrError> {
        Ok(f64::from_le_bytes(self.take()?))
    }

    /// A sequence's element count, at most `max`.
    pub fn count(&mut self, max: usize) -> Result<usize, CdrError> {
        let at = self.at;
        let count = self.u32()?;
        match usize::try_from(count) {
            Ok(n) if n <= max => Ok(n),
            _ => Err(CdrError::TooLong { at, count, max }),
        }
    }

    /// A `string` of at most `max` bytes, borrowed from the sample.
    pub fn string(&mut self, max: usize) -> Result<&'a str, CdrError> {
        let at = self.at;
        let len = self.count(max + 1)?;
        let bytes = self.body.get(self.at..self.at + len).ok_or(CdrError::Truncated {
            at: self.at,
            needed: len,
            len: self.body.len(),
        })?;
        self.at += len;
        match bytes.split_last() {
            Some((0, text)) => std::str::from_utf8(text).map_err(|_| CdrError::BadString(at)),
            _ => Err(CdrError::BadString(at)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_string_is_its_length_with_the_nul_then_its_bytes() {
        let mut buf = Vec::new();
        CdrWriter::new(&mut buf).string("hi");
        assert_eq!(buf, [0, 1, 0, 0, 3, 0, 0, 0, b'h', b'i', 0]);
        let mut r = CdrReader::new(&buf).unwrap();
        assert_eq!(r.string(16).unwrap(), "hi");
    }

    #[test]
    fn fields_align_from_the_end_of_the_header_and_read_back_in_either_byte_order() {
        let mut buf = Vec::new();
        CdrWriter::new(&mut buf).u8(7).f32(1.5).i16(-2).f64(0.25);
        // u8 at 0, f32 at 4, i16 at 8, f64 at 16.
        assert_eq!(buf.len(), HEADER_LEN + 24);
        let mut r = CdrReader::new(&buf).unwrap();
        assert_eq!(
            (r.u8(), r.f32(), r.i16(), r.f64()),
            (Ok(7), Ok(1.5), Ok(-2), Ok(0.25))
        );
        let be = [0, 0, 0, 0, 0x3f, 0xc0, 0, 0];
        assert_eq!(CdrReader::new(&be).unwrap().f32(), Ok(1.5));
    }

    #[test]
    fn short_samples_unknown_encapsulations_and_long_sequences_are_refused() {
        let mut buf = Vec::new();
        CdrWriter::new(&mut buf).u32(3);
        let mut r = CdrReader::new(&buf).unwrap();
        assert_eq!(r.u32(), Ok(3));
        assert_eq!(
            r.u32(),
            Err(CdrError::Truncated {
                at: 4,
                needed: 4,
                len: 4
            })
        );
        assert_eq!(
            CdrReader::new(&[0, 7, 0, 0]).unwrap_err(),
            CdrError::Encapsulation(7)
        );
        assert!(matches!(
            CdrReader::new(&buf).unwrap().count(2),
            Err(CdrError::TooLong { count: 3, .. })
        ));
    }
}
