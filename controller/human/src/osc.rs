//! Open Sound Control 1.0 packets as VMC sends them over UDP: messages (address, type tags,
//! 4-byte aligned arguments, big endian) and bundles (`#bundle`, time tag, sized elements, nested).
//! Decoding borrows from the datagram and never allocates; anything malformed is an error, not a
//! guess.

/// One argument.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Arg<'a> {
    /// `i`: 32-bit integer.
    Int(i32),
    /// `f`: 32-bit float.
    Float(f32),
    /// `s`: string.
    Str(&'a str),
    /// `d`: 64-bit float.
    Double(f64),
    /// `h`: 64-bit integer.
    Long(i64),
    /// `b`: blob.
    Blob(&'a [u8]),
    /// `T` / `F`.
    Bool(bool),
    /// `N`.
    Nil,
}

/// Why a packet was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum OscError {
    /// Shorter than its contents say.
    #[error("truncated")]
    Truncated,
    /// A string without its terminator, or not UTF-8.
    #[error("bad string")]
    BadString,
    /// Not a message (`/…`) or a bundle (`#bundle`).
    #[error("not an OSC packet")]
    NotOsc,
    /// The type tag string is missing or names a type this decoder does not know.
    #[error("bad type tags")]
    BadTags,
    /// A bundle element of impossible size, or bundles nested too deep.
    #[error("bad bundle")]
    BadBundle,
    /// A message's arguments are not what its address needs.
    #[error("wrong arguments")]
    WrongArguments,
}

/// A message, borrowed from its packet.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Message<'a> {
    /// Address pattern, e.g. `/VMC/Ext/Hmd/Pos`.
    pub address: &'a str,
    tags: &'a [u8],
    args: &'a [u8],
}

/// Bundles inside bundles, at most.
const MAX_DEPTH: usize = 4;

fn padded(n: usize) -> usize {
    (n + 4) & !3
}

/// A NUL-terminated, 4-byte padded string at the start of `data`; returns it and the rest.
fn read_str(data: &[u8]) -> Result<(&str, &[u8]), OscError> {
    let end = data.iter().position(|&b| b == 0).ok_or(OscError::BadString)?;
    let size = padded(end);
    if size > data.len() {
        return Err(OscError::Truncated);
    }
    if data[end..size].iter().any(|&b| b != 0) {
        return Err(OscError::BadString);
    }
    let s = std::str::from_utf8(&data[..end]).map_err(|_| OscError::BadString)?;
    Ok((s, &data[size..]))
}

fn take(data: &[u8], n: usize) -> Result<(&[u8], &[u8]), OscError> {
    if data.len() < n {
        return Err(OscError::Truncated);
    }
    Ok(data.split_at(n))
}

impl<'a> Message<'a> {
    fn parse(data: &'a [u8]) -> Result<Self, OscError> {
        let (address, rest) = read_str(data)?;
        if !address.starts_with('/') {
            return Err(OscError::NotOsc);
        }
        let (tags, args) = read_str(rest)?;
        let tags = tags.as_bytes();
        if tags.first() != Some(&b',') {
            return Err(OscError::BadTags);
        }
        let m = Self {
            address,
            tags: &tags[1..],
            args,
        };
        // Walk once so a malformed message is refused here, not half-used later.
        let mut count = 0;
        for a in m.args() {
            a?;
            count += 1;
        }
        debug_assert_eq!(count, m.tags.len());
        Ok(m)
    }

    /// The arguments, in order.
    pub fn args(&self) -> Args<'a> {
        Args {
            tags: self.tags,
            data: self.args,
        }
    }
}

/// Iterator over a message's arguments.
#[derive(Debug, Clone)]
pub struct Args<'a> {
    tags: &'a [u8],
    data: &'a [u8],
}

impl<'a> Iterator for Args<'a> {
    type Item = Result<Arg<'a>, OscError>;

    fn next(&mut self) -> Option<Self::Item> {
        let (&tag, rest) = self.tags.split_first()?;
        self.tags = rest;
        let data = self.data;
        let r = (|| {
            let (arg, rest) = match tag {
                b'i' => {
                    let (b, r) = take(data, 4)?;
                    (Arg::Int(i32::from_be_bytes([b[0], b[1], b[2], b[3]])), r)
                }
                b'f' => {
                    let (b, r) = take(data, 4)?;
                    (Arg::Float(f32::from_be_bytes([b[0], b[1], b[2], b[3]])), r)
                }
                b'd' => {
                    let (b, r) = take(data, 8)?;
                    (
                        Arg::Double(f64::from_be_bytes(b.try_into().map_err(|_| OscError::Truncated)?)),
                        r,
                    )
                }
                b'h' => {
                    let (b, r) = take(data, 8)?;
                    (
                        Arg::Long(i64::from_be_bytes(b.try_into().map_err(|_| OscError::Truncated)?)),
                        r,
                    )
                }
                b's' | b'S' => {
                    let (s, r) = read_str(data)?;
                    (Arg::Str(s), r)
                }
                b'b' => {
                    let (b, r) = take(data, 4)?;
                    let n = u32::from_be_bytes([b[0], b[1], b[2], b[3]]) as usize;
                    let (blob, r) = take(r, n)?;
                    let (_, r) = take(r, (4 - n % 4) % 4)?;
                    (Arg::Blob(blob), r)
                }
                b'T' => (Arg::Bool(true), data),
                b'F' => (Arg::Bool(false), data),
                b'N' => (Arg::Nil, data),
                _ => return Err(OscError::BadTags),
            };
            self.data = rest;
            Ok(arg)
        })();
        if r.is_err() {
            // Stop after the first error.
            self.tags = &[];
        }
        Some(r)
    }
}

/// Calls `visit` with every message of `packet` (a message or a bundle, nested up to four deep).
/// Nothing is visited unless the whole packet is well formed.
pub fn parse<'a>(packet: &'a [u8], visit: &mut dyn FnMut(Message<'a>)) -> Result<(), OscError> {
    walk(packet, 0, &mut |_| {})?;
    walk(packet, 0, visit)
}

fn walk<'a>(packet: &'a [u8], depth: usize, visit: &mut dyn FnMut(Message<'a>)) -> Result<(), OscError> {
    match packet.first() {
        Some(b'/') => {
            visit(Message::parse(packet)?);
            Ok(())
        }
        Some(b'#') => {
            let (tag, rest) = read_str(packet)?;
            if tag != "#bundle" || depth >= MAX_DEPTH {
                return Err(if tag == "#bundle" {
                    OscError::BadBundle
                } else {
                    OscError::NotOsc
                });
            }
            let (_time, mut rest) = take(rest, 8)?;
            while !rest.is_empty() {
                let (size, r) = take(rest, 4)?;
                let size = u32::from_be_bytes([size[0], size[1], size[2], size[3]]) as usize;
                if size == 0 || !size.is_multiple_of(4) {
                    return Err(OscError::BadBundle);
                }
                let (element, r) = take(r, size)?;
                walk(element, depth + 1, visit)?;
                rest = r;
            }
            Ok(())
        }
        _ => Err(OscError::NotOsc),
    }
}

fn push_str(out: &mut Vec<u8>, s: &str) {
    out.extend_from_slice(s.as_bytes());
    out.resize(out.len() + (4 - s.len() % 4), 0);
}

/// Appends the message `address` with `args` to `out`.
pub fn encode_message(out: &mut Vec<u8>, address: &str, args: &[Arg<'_>]) {
    push_str(out, address);
    let start = out.len();
    out.push(b',');
    for a in args {
        out.push(match a {
            Arg::Int(_) => b'i',
            Arg::Float(_) => b'f',
            Arg::Str(_) => b's',
            Arg::Double(_) => b'd',
            Arg::Long(_) => b'h',
            Arg::Blob(_) => b'b',
            Arg::Bool(true) => b'T',
            Arg::Bool(false) => b'F',
            Arg::Nil => b'N',
        });
    }
    let n = out.len() - start;
    out.resize(out.len() + (4 - n % 4), 0);
    for a in args {
        match *a {
            Arg::Int(v) => out.extend_from_slice(&v.to_be_bytes()),
            Arg::Float(v) => out.extend_from_slice(&v.to_be_bytes()),
            Arg::Str(s) => push_str(out, s),
            Arg::Double(v) => out.extend_from_slice(&v.to_be_bytes()),
            Arg::Long(v) => out.extend_from_slice(&v.to_be_bytes()),
            Arg::Blob(b) => {
                out.extend_from_slice(&(b.len() as u32).to_be_bytes());
                out.extend_from_slice(b);
                out.resize(out.len() + (4 - b.len() % 4) % 4, 0);
            }
            Arg::Bool(_) | Arg::Nil => {}
        }
    }
}

/// Appends a bundle (time tag 1 = "immediately") of already encoded `elements` to `out`.
pub fn encode_bundle(out: &mut Vec<u8>, elements: &[&[u8]]) {
    push_str(out, "#bundle");
    out.extend_from_slice(&1u64.to_be_bytes());
    for e in elements {
        out.extend_from_slice(&(e.len() as u32).to_be_bytes());
        out.extend_from_slice(e);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn messages(p: &[u8]) -> Result<Vec<(String, Vec<String>)>, OscError> {
        let mut out = Vec::new();
        parse(p, &mut |m| {
            out.push((
                m.address.to_owned(),
                m.args().map(|a| format!("{:?}", a.unwrap())).collect(),
            ));
        })?;
        Ok(out)
    }

    #[test]
    fn the_specifications_examples_encode_and_decode_bit_exactly() {
        // OSC 1.0 spec: "/oscillator/4/frequency" ,f 440.0
        let want: Vec<u8> = [
            &b"/oscillator/4/frequency\0"[..],
            &[0x2c, 0x66, 0, 0],
            &[0x43, 0xdc, 0x00, 0x00],
        ]
        .concat();
        let mut got = Vec::new();
        encode_message(&mut got, "/oscillator/4/frequency", &[Arg::Float(440.0)]);
        assert_eq!(got, want);
        assert_eq!(
            messages(&want).unwrap(),
            [("/oscillator/4/frequency".into(), vec!["Float(440.0)".into()])]
        );
        // "/foo" ,iisff 1000 -1 "hello" 1.234 5.678
        let want: Vec<u8> = [
            &b"/foo\0\0\0\0"[..],
            b",iisff\0\0",
            &[0, 0, 0x03, 0xe8, 0xff, 0xff, 0xff, 0xff],
            b"hello\0\0\0",
            &[0x3f, 0x9d, 0xf3, 0xb6, 0x40, 0xb5, 0xb2, 0x2d],
        ]
        .concat();
        let mut got = Vec::new();
        let args = [
            Arg::Int(1000),
            Arg::Int(-1),
            Arg::Str("hello"),
            Arg::Float(1.234),
            Arg::Float(5.678),
        ];
        encode_message(&mut got, "/foo", &args);
        assert_eq!(got, want);
        let m = messages(&want).unwrap();
        assert_eq!(m[0].1[2], "Str(\"hello\")");
    }

    #[test]
    fn bundles_nest_and_malformed_packets_are_refused_whole() {
        let (mut a, mut b) = (Vec::new(), Vec::new());
        encode_message(&mut a, "/a", &[Arg::Int(1)]);
        encode_message(
            &mut b,
            "/b",
            &[Arg::Str("x"), Arg::Bool(true), Arg::Blob(&[1, 2, 3])],
        );
        let mut inner = Vec::new();
        encode_bundle(&mut inner, &[&b]);
        let mut outer = Vec::new();
        encode_bundle(&mut outer, &[&a, &inner]);
        let m = messages(&outer).unwrap();
        assert_eq!(m.iter().map(|x| x.0.as_str()).collect::<Vec<_>>(), ["/a", "/b"]);

        // Every truncation of a good bundle between its elements' edges is refused, and nothing
        // of it is visited (an empty bundle, or one cut after an element, is a good bundle).
        let edges = [16, 16 + 4 + a.len(), outer.len()];
        for n in (0..outer.len()).filter(|n| !edges.contains(n)) {
            let mut seen = 0;
            assert!(parse(&outer[..n], &mut |_| seen += 1).is_err(), "cut at {n}");
            assert_eq!(seen, 0);
        }
        assert_eq!(messages(b"hello").unwrap_err(), OscError::NotOsc);
        assert_eq!(messages(b"/a\0\0,q\0\0").unwrap_err(), OscError::BadTags);
        assert_eq!(messages(b"/a\0\0i\0\0\0").unwrap_err(), OscError::BadTags);
        assert_eq!(messages(b"/a\0\0,s\0\0abcd").unwrap_err(), OscError::BadString);
        // Too deep.
        let mut deep = a.clone();
        for _ in 0..6 {
            let mut next = Vec::new();
            encode_bundle(&mut next, &[&deep]);
            deep = next;
        }
        assert_eq!(messages(&deep).unwrap_err(), OscError::BadBundle);
    }
}
