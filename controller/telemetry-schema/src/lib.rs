//! The typed messages of a robodeploy recording and live view, from
//! `proto/robodeploy/telemetry.proto` (read it for units, frames and quaternion conventions).
//!
//! The telemetry thread encodes them (the loop never does); `analysis` decodes them; MCAP files
//! and the Foxglove WebSocket carry [`DESCRIPTOR_SET`] as each channel's schema so that any
//! protobuf reader (Foxglove, Rerun, Python's `mcap-protobuf-support`) decodes them without this
//! crate.

#![allow(missing_docs, clippy::doc_markdown)] // Generated code: the .proto documents it.

include!(concat!(env!("OUT_DIR"), "/robodeploy.rs"));

pub mod ros2;

/// The encoded `FileDescriptorSet` of telemetry.proto and its imports: the schema data of every
/// channel whose schema is a message of this crate.
pub const DESCRIPTOR_SET: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/telemetry.fds"));

/// The protobuf timestamp of `ns` nanoseconds (since the Unix epoch, or a run's start).
pub fn timestamp(ns: u64) -> prost_types::Timestamp {
    prost_types::Timestamp {
        seconds: i64::try_from(ns / 1_000_000_000).unwrap_or(i64::MAX),
        nanos: i32::try_from(ns % 1_000_000_000).unwrap_or(0),
    }
}

/// Nanoseconds of a protobuf timestamp (0 before the epoch).
pub fn nanos(t: &prost_types::Timestamp) -> u64 {
    u64::try_from(t.seconds).unwrap_or(0) * 1_000_000_000 + u64::try_from(t.nanos).unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use prost::{Message, Name};

    #[test]
    fn descriptor_set_names_every_message_and_its_timestamp_import() {
        let fds = prost_types::FileDescriptorSet::decode(DESCRIPTOR_SET).unwrap();
        let files: Vec<&str> = fds.file.iter().map(|f| f.name()).collect();
        assert!(files.contains(&"google/protobuf/timestamp.proto"), "{files:?}");
        let ours = fds.file.iter().find(|f| f.package() == "robodeploy").unwrap();
        let messages: Vec<&str> = ours.message_type.iter().map(|m| m.name()).collect();
        for name in [
            JointStates::NAME,
            PolicyStep::NAME,
            StateEstimate::NAME,
            BusCycle::NAME,
        ] {
            assert!(messages.contains(&name), "{name} missing from {messages:?}");
        }
        assert_eq!(JointStates::full_name(), "robodeploy.JointStates");
    }

    #[test]
    fn messages_round_trip() {
        let m = JointStates {
            timestamp: Some(timestamp(1_500_000_001)),
            joints: vec![JointState {
                name: "left_knee".into(),
                position: -0.25,
                stale: true,
                ..Default::default()
            }],
        };
        let back = JointStates::decode(m.encode_to_vec().as_slice()).unwrap();
        assert_eq!(back, m);
        assert_eq!(nanos(&back.timestamp.unwrap()), 1_500_000_001);
    }
}
