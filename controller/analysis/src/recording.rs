//! Reading a recorded run (MCAP) defensively: the file is bounded in size, and every chunk's
//! claimed sizes are checked against the file before the MCAP reader trusts them (a corrupted
//! length must be an error, not a multi-gigabyte allocation).

use std::path::Path;

/// Largest recording read, bytes.
pub const MAX_RECORDING_BYTES: u64 = 4 << 30;

/// Largest ratio of a chunk's uncompressed to compressed size (lz4 and zstd stay well below it).
const MAX_COMPRESSION_RATIO: u64 = 256;

/// The bytes of the recording at `path`, checked (see the module docs).
pub fn read(path: &Path) -> Result<Vec<u8>, String> {
    let meta = std::fs::metadata(path).map_err(|e| format!("cannot read: {e}"))?;
    if !meta.is_file() {
        return Err("not a regular file".into());
    }
    if meta.len() > MAX_RECORDING_BYTES {
        return Err(format!("{} bytes: larger than {MAX_RECORDING_BYTES}", meta.len()));
    }
    let bytes = std::fs::read(path).map_err(|e| format!("cannot read: {e}"))?;
    check_chunks(&bytes)?;
    Ok(bytes)
}

const MAGIC: &[u8] = b"\x89MCAP0\r\n";
const OP_FOOTER: u8 = 0x02;
const OP_CHUNK: u8 = 0x06;

fn u64_at(b: &[u8], at: usize) -> Option<u64> {
    Some(u64::from_le_bytes(b.get(at..at + 8)?.try_into().ok()?))
}

fn u32_at(b: &[u8], at: usize) -> Option<u32> {
    Some(u32::from_le_bytes(b.get(at..at + 4)?.try_into().ok()?))
}

/// Walks the top-level records and refuses a chunk whose sizes cannot be true.
fn check_chunks(b: &[u8]) -> Result<(), String> {
    if !b.starts_with(MAGIC) {
        return Err("not an MCAP file (no magic)".into());
    }
    let mut at = MAGIC.len();
    while at < b.len() {
        let op = b[at];
        let Some(len) = u64_at(b, at + 1) else {
            break; // a truncated tail: the reader reports it
        };
        let body = at + 9;
        let end = usize::try_from(len).ok().and_then(|l| body.checked_add(l));
        let Some(end) = end.filter(|&e| e <= b.len()) else {
            break; // cut short (a crash): the reader gives what came before
        };
        if op == OP_CHUNK {
            // start time, end time, uncompressed size, crc, compression (len + text), records (len).
            let uncompressed = u64_at(b, body + 16).ok_or("truncated chunk header")?;
            let compression_len = u32_at(b, body + 28).ok_or("truncated chunk header")? as usize;
            let records_at = body + 32 + compression_len;
            let compressed = u64_at(b, records_at).ok_or("truncated chunk header")?;
            if compressed > (end - body) as u64 {
                return Err(format!(
                    "chunk at byte {at} claims {compressed} compressed bytes in a {len}-byte record"
                ));
            }
            let limit = compressed.saturating_mul(MAX_COMPRESSION_RATIO).max(1 << 20);
            if uncompressed > limit {
                return Err(format!(
                    "chunk at byte {at} claims {uncompressed} bytes uncompressed from {compressed}: corrupted"
                ));
            }
        }
        if op == OP_FOOTER {
            break;
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

/// Calls `each` with every message of `bytes` (a checked recording), in file order. Records are
/// bounded by the file's size and chunks' CRCs are checked (the `mcap` crate's own message stream
/// leaves its record lengths unbounded). A recording cut short (a crash, a full disk) gives every
/// message before the cut and a warning; damage inside the file is an error.
pub fn for_each_message(
    bytes: &[u8],
    mut each: impl FnMut(Message<'_>) -> Result<(), String>,
) -> Result<(), String> {
    let mut delivered = 0u64;
    use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_record_length_limit(bytes.len())
            .with_validate_chunk_crcs(true),
    );
    let mut channels: std::collections::HashMap<u16, mcap::records::Channel> = Default::default();
    let mut rest = bytes;
    while let Some(event) = reader.next_event() {
        let event = match event {
            Ok(e) => e,
            Err(e) if rest.is_empty() && delivered > 0 => {
                tracing::warn!("the recording ends early ({e}): read {delivered} messages before the cut");
                return Ok(());
            }
            Err(e) => return Err(e.to_string()),
        };
        match event {
            LinearReadEvent::ReadRequest(need) => {
                let n = need.min(rest.len());
                reader.insert(n).copy_from_slice(&rest[..n]);
                reader.notify_read(n);
                rest = &rest[n..];
            }
            LinearReadEvent::Record { data, opcode } => {
                match mcap::parse_record(opcode, data).map_err(|e| e.to_string())? {
                    mcap::records::Record::Channel(c) => {
                        channels.insert(c.id, c);
                    }
                    mcap::records::Record::Message { header, data } => {
                        let c = channels
                            .get(&header.channel_id)
                            .ok_or_else(|| format!("message on unknown channel {}", header.channel_id))?;
                        each(Message {
                            topic: &c.topic,
                            metadata: &c.metadata,
                            log_time: header.log_time,
                            data: &data,
                        })?;
                        delivered += 1;
                    }
                    _ => {}
                }
            }
        }
    }
    Ok(())
}
