//! Reading a recorded run (MCAP) defensively: the file is bounded in size, and every chunk's
//! claimed sizes are checked against the file before the MCAP reader trusts them (a corrupted
//! length must be an error, not a multi-gigabyte allocation).

use std::path::Path;

/// Largest recording read, bytes.
pub const MAX_RECORDING_BYTES: u64 = 4 << 30;

/// Largest ratio of a chunk's uncompressed to compressed size (lz4 and zstd stay well below it).
const MAX_COMPRESSION_RATIO: u64 = 256;

/// The bytes of the recording at `path`, checked (see the module docs).
pub fn read(path: &Path) -> Result<Vec<u8>, RecordingError> {
    let meta = std::fs::metadata(path).map_err(RecordingError::Unreadable)?;
    if !meta.is_file() {
        return Err(RecordingError::NotRegular);
    }
    if meta.len() > MAX_RECORDING_BYTES {
        return Err(RecordingError::TooLarge { bytes: meta.len() });
    }
    let bytes = std::fs::read(path).map_err(RecordingError::Unreadable)?;
    check_chunks(&bytes)?;
    Ok(bytes)
}

/// Why a recording cannot be read (the path is the caller's to name).
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    /// The system refused.
    #[error("cannot read: {0}")]
    Unreadable(std::io::Error),
    /// A folder, device or pipe.
    #[error("not a regular file")]
    NotRegular,
    /// Larger than [`MAX_RECORDING_BYTES`].
    #[error("{bytes} bytes: larger than {MAX_RECORDING_BYTES}")]
    TooLarge {
        /// The file's size.
        bytes: u64,
    },
    /// No MCAP magic at the start.
    #[error("not an MCAP file (no magic)")]
    NotMcap,
    /// The file ends inside its first record: nothing to read.
    #[error("the recording ends inside a record at byte {0}")]
    Cut(usize),
    /// A chunk whose sizes, compression or CRC cannot be true.
    #[error("chunk at byte {at}: {damage}")]
    Chunk {
        /// Where the chunk starts.
        at: usize,
        /// What is wrong with it.
        damage: ChunkDamage,
    },
    /// A channel record's string longer than the record.
    #[error("channel record: {0} longer than the record")]
    Channel(&'static str),
    /// A record the `mcap` crate cannot parse.
    #[error("{0}")]
    Record(String),
    /// A message on a channel never announced.
    #[error("message on unknown channel {0}")]
    UnknownChannel(u16),
    /// A message whose payload its reader cannot decode.
    #[error("{topic}: {reason}")]
    Decode {
        /// The message's topic.
        topic: String,
        /// The decoder's message.
        reason: String,
    },
}

impl RecordingError {
    /// A payload on `topic` that `reason` says cannot be decoded.
    pub fn decode(topic: &str, reason: impl std::fmt::Display) -> Self {
        Self::Decode {
            topic: topic.to_owned(),
            reason: reason.to_string(),
        }
    }
}

/// What is wrong with a chunk.
#[derive(Debug, thiserror::Error)]
pub enum ChunkDamage {
    /// Its header ends early.
    #[error("truncated chunk header")]
    TruncatedHeader,
    /// Its compression's name is not UTF-8.
    #[error("chunk compression is not text")]
    CompressionNotText,
    /// Its records run past the record holding them.
    #[error("claims {compressed} compressed bytes in a {record}-byte record")]
    PastRecord {
        /// Claimed compressed size.
        compressed: u64,
        /// The record's size.
        record: usize,
    },
    /// Its uncompressed size is beyond any real compression ratio.
    #[error("claims {uncompressed} bytes uncompressed from {compressed}: corrupted")]
    Ratio {
        /// Claimed uncompressed size.
        uncompressed: u64,
        /// Its compressed size.
        compressed: u64,
    },
    /// The decompressor failed.
    #[error("{codec}: {source}")]
    Decompress {
        /// `lz4` or `zstd`.
        codec: &'static str,
        /// Why.
        source: std::io::Error,
    },
    /// A compression other than lz4, zstd or none.
    #[error("compression {0:?} is not supported (lz4, zstd or none)")]
    Compression(String),
    /// Decompressed to another size than claimed.
    #[error("{got} bytes uncompressed where the chunk claims {claimed}")]
    Size {
        /// Bytes decompressed.
        got: usize,
        /// Bytes claimed.
        claimed: u64,
    },
    /// The CRC does not match.
    #[error("CRC mismatch: the chunk is damaged")]
    Crc,
    /// A record inside runs past the chunk's end.
    #[error("a record runs past the chunk's end")]
    RecordPastEnd,
}

const MAGIC: &[u8] = b"\x89MCAP0\r\n";
const OP_FOOTER: u8 = 0x02;
const OP_CHUNK: u8 = 0x06;
const OP_CHANNEL: u8 = 0x04;
const OP_MESSAGE: u8 = 0x05;

fn u64_at(b: &[u8], at: usize) -> Option<u64> {
    Some(u64::from_le_bytes(b.get(at..at + 8)?.try_into().ok()?))
}

fn u32_at(b: &[u8], at: usize) -> Option<u32> {
    Some(u32::from_le_bytes(b.get(at..at + 4)?.try_into().ok()?))
}

/// One top-level or chunk-level record: its opcode and body, and where the next one starts.
enum Next<'a> {
    Record {
        op: u8,
        body: &'a [u8],
        end: usize,
    },
    /// No bytes left.
    End,
    /// The bytes stop inside a record (a crash or a full disk cut the file).
    Cut,
}

fn next_record(b: &[u8], at: usize) -> Next<'_> {
    if at >= b.len() {
        return Next::End;
    }
    let Some(len) = u64_at(b, at + 1) else {
        return Next::Cut;
    };
    let body = at + 9;
    match usize::try_from(len)
        .ok()
        .and_then(|l| body.checked_add(l))
        .filter(|&e| e <= b.len())
    {
        Some(end) => Next::Record {
            op: b[at],
            body: &b[body..end],
            end,
        },
        None => Next::Cut,
    }
}

/// A chunk's header, its sizes checked against each other and the record.
struct Chunk<'a> {
    uncompressed: u64,
    crc: u32,
    compression: &'a str,
    records: &'a [u8],
}

fn chunk(body: &[u8]) -> Result<Chunk<'_>, ChunkDamage> {
    use ChunkDamage::TruncatedHeader;
    // start time, end time, uncompressed size, crc, compression (len + text), records (len + bytes).
    let uncompressed = u64_at(body, 16).ok_or(TruncatedHeader)?;
    let crc = u32_at(body, 24).ok_or(TruncatedHeader)?;
    let compression_len = u32_at(body, 28).ok_or(TruncatedHeader)? as usize;
    let records_at = 32usize.checked_add(compression_len).ok_or(TruncatedHeader)?;
    let compression = body
        .get(32..records_at)
        .and_then(|c| std::str::from_utf8(c).ok())
        .ok_or(ChunkDamage::CompressionNotText)?;
    let compressed = u64_at(body, records_at).ok_or(TruncatedHeader)?;
    let records = usize::try_from(compressed)
        .ok()
        .and_then(|c| (records_at + 8).checked_add(c))
        .and_then(|e| body.get(records_at + 8..e))
        .ok_or(ChunkDamage::PastRecord {
            compressed,
            record: body.len(),
        })?;
    let limit = compressed.saturating_mul(MAX_COMPRESSION_RATIO).max(1 << 20);
    if uncompressed > limit {
        return Err(ChunkDamage::Ratio {
            uncompressed,
            compressed,
        });
    }
    Ok(Chunk {
        uncompressed,
        crc,
        compression,
        records,
    })
}

impl Chunk<'_> {
    /// The records, decompressed into `out` (bounded by the claimed size) and checked against the
    /// claimed size and CRC.
    fn decompress_into(&self, out: &mut Vec<u8>) -> Result<(), ChunkDamage> {
        use std::io::Read;
        out.clear();
        let claimed = self.uncompressed;
        let mut bounded = |r: &mut dyn Read| r.take(claimed + 1).read_to_end(out);
        match self.compression {
            "" => out.extend_from_slice(self.records),
            "lz4" => {
                lz4::Decoder::new(self.records)
                    .and_then(|mut d| bounded(&mut d))
                    .map_err(|source| ChunkDamage::Decompress { codec: "lz4", source })?;
            }
            "zstd" => {
                zstd::stream::read::Decoder::new(self.records)
                    .and_then(|mut d| bounded(&mut d))
                    .map_err(|source| ChunkDamage::Decompress {
                        codec: "zstd",
                        source,
                    })?;
            }
            other => return Err(ChunkDamage::Compression(other.to_owned())),
        }
        if out.len() as u64 != claimed {
            return Err(ChunkDamage::Size {
                got: out.len(),
                claimed,
            });
        }
        if self.crc != 0 && crc32fast::hash(out) != self.crc {
            return Err(ChunkDamage::Crc);
        }
        Ok(())
    }
}

/// Walks the top-level records and refuses a chunk whose sizes cannot be true (before anything
/// is allocated for it).
pub fn check_chunks(b: &[u8]) -> Result<(), RecordingError> {
    if !b.starts_with(MAGIC) {
        return Err(RecordingError::NotMcap);
    }
    let mut at = MAGIC.len();
    // A cut tail is not checked here: the reader gives what came before it.
    while let Next::Record { op, body, end } = next_record(b, at) {
        match op {
            OP_CHUNK => {
                chunk(body).map_err(|damage| RecordingError::Chunk { at, damage })?;
            }
            OP_FOOTER => break,
            _ => {}
        }
        at = end;
    }
    Ok(())
}

/// One message of a recording.
#[derive(Debug, Clone, PartialEq)]
pub struct Message<'a> {
    /// Its channel's topic.
    pub topic: &'a str,
    /// Its channel's metadata.
    pub metadata: &'a std::collections::BTreeMap<String, String>,
    /// Log time, ns.
    pub log_time: u64,
    /// The payload.
    pub data: &'a [u8],
}

/// Checks every length prefix of a channel record against the record: the `mcap` crate reserves
/// a string's claimed length before reading it (found by fuzzing: a flipped bit asked for 3.5 GB).
fn check_channel(record: &[u8]) -> Result<(), RecordingError> {
    let bad = RecordingError::Channel;
    // id, schema id; then topic and message encoding.
    let mut at = 4;
    for what in ["topic", "message encoding"] {
        let len = u32_at(record, at).ok_or_else(|| bad(what))? as usize;
        at = (at + 4)
            .checked_add(len)
            .filter(|&e| e <= record.len())
            .ok_or_else(|| bad(what))?;
    }
    // Metadata: a byte length, then key and value strings.
    let map_len = u32_at(record, at).ok_or_else(|| bad("metadata"))? as usize;
    let map_end = (at + 4)
        .checked_add(map_len)
        .filter(|&e| e <= record.len())
        .ok_or_else(|| bad("metadata"))?;
    at += 4;
    // Key and value are read as a pair while the map has bytes left: both must fit.
    while at < map_end {
        for what in ["metadata key", "metadata value"] {
            let len = u32_at(record, at).ok_or_else(|| bad(what))? as usize;
            at = (at + 4)
                .checked_add(len)
                .filter(|&e| e <= map_end)
                .ok_or_else(|| bad(what))?;
        }
    }
    Ok(())
}

/// Channels seen so far, and how many messages went out.
#[derive(Default)]
struct Walk {
    channels: std::collections::HashMap<u16, mcap::records::Channel>,
    delivered: u64,
}

impl Walk {
    /// One record: channels are kept, messages handed to `each`, everything else skipped unparsed.
    fn visit(
        &mut self,
        op: u8,
        body: &[u8],
        each: &mut impl FnMut(Message<'_>) -> Result<(), RecordingError>,
    ) -> Result<(), RecordingError> {
        if op != OP_CHANNEL && op != OP_MESSAGE {
            return Ok(());
        }
        if op == OP_CHANNEL {
            check_channel(body)?;
        }
        match mcap::parse_record(op, body).map_err(|e| RecordingError::Record(e.to_string()))? {
            mcap::records::Record::Channel(c) => {
                self.channels.insert(c.id, c);
            }
            mcap::records::Record::Message { header, data } => {
                let c = self
                    .channels
                    .get(&header.channel_id)
                    .ok_or(RecordingError::UnknownChannel(header.channel_id))?;
                each(Message {
                    topic: &c.topic,
                    metadata: &c.metadata,
                    log_time: header.log_time,
                    data: &data,
                })?;
                self.delivered += 1;
            }
            _ => {}
        }
        Ok(())
    }
}

/// How a recording ends.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ending {
    /// With its footer: the logger finished the file.
    Finished,
    /// Without one, at byte `at` (at a record's end or inside one): the process was killed or
    /// its disk filled; what happened after is not in the file.
    Cut {
        /// Where the bytes stop.
        at: usize,
    },
}

/// Calls `each` with every message of `bytes`, in file order, and says how the file ends. The records are walked here, not
/// by the `mcap` crate's reader: every length is bounded by the bytes it claims to cover, chunks
/// are decompressed no further than their claimed size and checked against it and their CRC (the
/// crate's reader loops forever on a chunk shorter than it claims; found by fuzzing). A recording
/// cut short (a crash, a full disk) gives every message before the cut and a warning; damage
/// inside the file is an error. `each` says why it cannot take a message with
/// [`RecordingError::decode`].
pub fn for_each_message(
    bytes: &[u8],
    mut each: impl FnMut(Message<'_>) -> Result<(), RecordingError>,
) -> Result<Ending, RecordingError> {
    if !bytes.starts_with(MAGIC) {
        return Err(RecordingError::NotMcap);
    }
    let mut walk = Walk::default();
    let mut records = Vec::new();
    let mut at = MAGIC.len();
    loop {
        match next_record(bytes, at) {
            Next::End => return Ok(Ending::Cut { at }),
            Next::Cut if walk.delivered > 0 => {
                tracing::warn!(
                    "the recording ends early (inside a record at byte {at}): read {} messages before the cut",
                    walk.delivered
                );
                return Ok(Ending::Cut { at });
            }
            Next::Cut => return Err(RecordingError::Cut(at)),
            Next::Record { op: OP_FOOTER, .. } => return Ok(Ending::Finished),
            Next::Record {
                op: OP_CHUNK,
                body,
                end,
            } => {
                let damaged = |damage| RecordingError::Chunk { at, damage };
                chunk(body)
                    .and_then(|c| c.decompress_into(&mut records))
                    .map_err(damaged)?;
                let mut inner = 0;
                loop {
                    match next_record(&records, inner) {
                        Next::End => break,
                        Next::Cut => return Err(damaged(ChunkDamage::RecordPastEnd)),
                        Next::Record { op, body, end } => {
                            walk.visit(op, body, &mut each)?;
                            inner = end;
                        }
                    }
                }
                at = end;
            }
            Next::Record { op, body, end } => {
                walk.visit(op, body, &mut each)?;
                at = end;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const CORPUS: &str = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/fuzz/corpus/mcap_recording/"
    );

    fn topics(file: &str) -> Result<Vec<String>, RecordingError> {
        let bytes = std::fs::read(format!("{CORPUS}{file}")).unwrap();
        check_chunks(&bytes)?;
        let mut topics = Vec::new();
        for_each_message(&bytes, |m| {
            topics.push(m.topic.to_owned());
            Ok(())
        })?;
        Ok(topics)
    }

    #[test]
    fn lz4_and_zstd_chunks_read_alike() {
        // Written by scripts/gen_fuzz_seeds.py with the Python `mcap` writer.
        let expected = ["/joints", "/joints", "/joints", "/safety"];
        assert_eq!(topics("tiny_lz4.mcap").unwrap(), expected);
        assert_eq!(topics("tiny_zstd.mcap").unwrap(), expected);
    }

    #[test]
    fn a_channel_string_longer_than_its_record_is_refused_not_allocated() {
        // Found by the mcap_recording fuzz target: the mcap crate reserved 3.5 GB for the topic.
        for file in [
            "regression-channel-string-length",
            "regression-metadata-value-past-map",
        ] {
            let err = topics(file).unwrap_err().to_string();
            assert!(err.contains("longer than the record"), "{file}: {err}");
        }
    }

    #[test]
    fn a_chunk_whose_data_ends_before_its_claimed_size_is_refused_not_looped_on() {
        // Found by the mcap_recording fuzz target: the mcap crate's reader spun forever on it.
        let err = topics("regression-chunk-shorter-than-claimed")
            .unwrap_err()
            .to_string();
        assert!(err.contains("chunk at byte"), "{err}");
    }
}
