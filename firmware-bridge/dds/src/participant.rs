//! A DDS participant on one network interface and domain, and topics of raw CDR samples on it.
//!
//! Samples stay bytes here: each message type writes and reads its own CDR (its layout is a fact
//! of the peer's IDL, checked byte for byte by its own tests), and the middleware carries them
//! under the topic and type names the peers use.

use std::net::IpAddr;

use rustdds::no_key::{
    DataReader, DataWriter, Decode, DefaultDecoder, DeserializerAdapter, SerializerAdapter,
};
use rustdds::policy::{Durability, History, Reliability, ResourceLimits};
use rustdds::{
    DomainParticipant, DomainParticipantBuilder, QosPolicyBuilder, RepresentationIdentifier, TopicKind,
};

use crate::cdr::HEADER_LEN;

/// The largest DDS domain id: RTPS's default port mapping (7400 + 250 × domain + offsets) must stay
/// below 65536.
pub const MAX_DOMAIN: u32 = 232;

/// Where a participant joins: the domain and the network interface its traffic uses.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DdsConfig {
    /// DDS domain id, 0–[`MAX_DOMAIN`].
    pub domain: u32,
    /// Network interface by name (`eth0`, `lo`): discovery and data use only its addresses.
    pub interface: String,
}

/// Why DDS could not be set up or used.
#[derive(Debug, thiserror::Error)]
pub enum DdsError {
    /// The domain id is out of range.
    #[error("DDS domain {0} is out of range (0–{MAX_DOMAIN})")]
    Domain(u32),
    /// No such interface, or one without an address.
    #[error("network interface {name:?} {why} (this machine has: {available})")]
    Interface {
        /// The name asked for.
        name: String,
        /// What is wrong with it.
        why: &'static str,
        /// The interfaces there are.
        available: String,
    },
    /// The middleware refused.
    #[error("DDS: {0}")]
    Middleware(String),
}

/// How a topic's samples are delivered.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Delivery {
    /// Newest sample only, lost ones not resent: streams at a robot's rate (Unitree's low-level
    /// topics, joint states).
    Stream,
    /// Kept and resent to readers that join later (ROS 2's "transient local", reliable):
    /// `/robot_description`.
    Latched,
    /// Reliable, volatile, the newest ten kept: ROS 2's default profile, which every reader
    /// matches, reliable (tf2 listeners, RViz, diagnostic_aggregator) or best effort. A write
    /// never waits: with [`RELIABLE_WINDOW`] samples unacknowledged (a reader that stopped), the
    /// sample is dropped.
    Reliable,
}

/// Unacknowledged samples a [`Delivery::Reliable`] writer holds for its readers (5 s at 50 Hz).
pub const RELIABLE_WINDOW: i32 = 256;

/// One participant: a domain on one interface, with a publisher and a subscriber.
pub struct Participant {
    participant: DomainParticipant,
    publisher: rustdds::Publisher,
    subscriber: rustdds::Subscriber,
}

impl std::fmt::Debug for Participant {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Participant")
            .field("domain", &self.participant.domain_id())
            .finish_non_exhaustive()
    }
}

/// The DDS implementation robodeploy speaks through (pinned in the workspace's Cargo.toml).
pub const MIDDLEWARE: &str = "RustDDS 0.15.1";

/// This machine's network interfaces by name, each with its addresses (IPv4 first).
pub fn interfaces() -> Vec<(String, Vec<IpAddr>)> {
    let mut out: Vec<(String, Vec<IpAddr>)> = Vec::new();
    for (name, addr) in all_interfaces().unwrap_or_default() {
        let at = match out.iter().position(|(n, _)| *n == name) {
            Some(i) => i,
            None => {
                out.push((name, Vec::new()));
                out.len() - 1
            }
        };
        out[at].1.extend(addr);
    }
    for (_, addrs) in &mut out {
        addrs.sort_by_key(|a| a.is_ipv6());
    }
    out.sort_by(|a, b| a.0.cmp(&b.0));
    out
}

/// The IP addresses of the interface `name`, or an error that lists the machine's interfaces.
pub fn interface_addresses(name: &str) -> Result<Vec<IpAddr>, DdsError> {
    let all =
        all_interfaces().map_err(|e| DdsError::Middleware(format!("listing network interfaces: {e}")))?;
    let mut names: Vec<&str> = all.iter().map(|(n, _)| n.as_str()).collect();
    names.sort_unstable();
    names.dedup();
    let error = |why| DdsError::Interface {
        name: name.to_owned(),
        why,
        available: names.join(", "),
    };
    if !names.contains(&name) {
        return Err(error("does not exist"));
    }
    let addrs: Vec<IpAddr> = all
        .iter()
        .filter(|(n, _)| n == name)
        .filter_map(|(_, a)| *a)
        .collect();
    if addrs.is_empty() {
        return Err(error("has no IP address"));
    }
    Ok(addrs)
}

/// Every interface with each of its addresses (`None`: an interface without one).
fn all_interfaces() -> std::io::Result<Vec<(String, Option<IpAddr>)>> {
    let mut out = Vec::new();
    for i in netdev::get_interfaces() {
        let v4 = i.ipv4.iter().map(|n| IpAddr::V4(n.addr()));
        let v6 = i.ipv6.iter().map(|n| IpAddr::V6(n.addr()));
        let addrs: Vec<IpAddr> = v4.chain(v6).collect();
        if addrs.is_empty() {
            out.push((i.name.clone(), None));
        }
        out.extend(addrs.into_iter().map(|a| (i.name.clone(), Some(a))));
    }
    Ok(out)
}

impl DdsConfig {
    /// Checks the domain and that the interface exists with an address.
    pub fn check(&self) -> Result<Vec<IpAddr>, DdsError> {
        if self.domain > MAX_DOMAIN {
            return Err(DdsError::Domain(self.domain));
        }
        interface_addresses(&self.interface)
    }
}

fn middleware(context: &str) -> impl FnOnce(rustdds::dds::CreateError) -> DdsError + '_ {
    move |e| DdsError::Middleware(format!("{context}: {e:?}"))
}

impl Participant {
    /// Joins the domain on the interface: discovery and data use only its addresses.
    pub fn join(config: &DdsConfig) -> Result<Self, DdsError> {
        let addrs = config.check()?;
        let domain = u16::try_from(config.domain).map_err(|_| DdsError::Domain(config.domain))?;
        let participant = DomainParticipantBuilder::new(domain)
            .with_only_networks(addrs)
            .build()
            .map_err(middleware("joining the domain"))?;
        let qos = QosPolicyBuilder::new().build();
        let publisher = participant
            .create_publisher(&qos)
            .map_err(middleware("publisher"))?;
        let subscriber = participant
            .create_subscriber(&qos)
            .map_err(middleware("subscriber"))?;
        Ok(Self {
            participant,
            publisher,
            subscriber,
        })
    }

    fn topic(
        &self,
        name: &str,
        type_name: &str,
        delivery: Delivery,
    ) -> Result<(rustdds::Topic, rustdds::QosPolicies), DdsError> {
        let qos = match delivery {
            Delivery::Stream => QosPolicyBuilder::new()
                .reliability(Reliability::BestEffort)
                .durability(Durability::Volatile)
                .history(History::KeepLast { depth: 1 })
                .build(),
            Delivery::Latched => QosPolicyBuilder::new()
                .reliability(Reliability::Reliable {
                    max_blocking_time: rustdds::Duration::from_millis(100),
                })
                .durability(Durability::TransientLocal)
                .history(History::KeepLast { depth: 1 })
                .build(),
            Delivery::Reliable => QosPolicyBuilder::new()
                .reliability(Reliability::Reliable {
                    max_blocking_time: rustdds::Duration::ZERO,
                })
                .durability(Durability::Volatile)
                .history(History::KeepLast { depth: 10 })
                .resource_limits(ResourceLimits {
                    max_samples: RELIABLE_WINDOW,
                    max_instances: 1,
                    max_samples_per_instance: RELIABLE_WINDOW,
                })
                .build(),
        };
        let topic = self
            .participant
            .create_topic(name.to_owned(), type_name.to_owned(), &qos, TopicKind::NoKey)
            .map_err(middleware(name))?;
        Ok((topic, qos))
    }

    /// A topic to publish CDR samples of `type_name` on.
    pub fn publication(
        &self,
        topic: &str,
        type_name: &str,
        delivery: Delivery,
    ) -> Result<Publication, DdsError> {
        let (t, qos) = self.topic(topic, type_name, delivery)?;
        let writer = self
            .publisher
            .create_datawriter_no_key::<Sample, RawCdr>(&t, Some(qos))
            .map_err(middleware(topic))?;
        Ok(Publication { writer })
    }

    /// A topic to take CDR samples of `type_name` from.
    pub fn subscription(
        &self,
        topic: &str,
        type_name: &str,
        delivery: Delivery,
    ) -> Result<Subscription, DdsError> {
        let (t, qos) = self.topic(topic, type_name, delivery)?;
        let reader = self
            .subscriber
            .create_datareader_no_key::<Sample, RawCdr>(&t, Some(qos))
            .map_err(middleware(topic))?;
        Ok(Subscription { reader })
    }
}

/// A CDR sample with its encapsulation header, as the middleware hands it over.
#[derive(Debug, Clone)]
pub struct Sample(Vec<u8>);

/// The adapter that passes samples through as bytes.
struct RawCdr;

impl SerializerAdapter<Sample> for RawCdr {
    type Error = std::convert::Infallible;
    fn output_encoding() -> RepresentationIdentifier {
        RepresentationIdentifier::CDR_LE
    }
    fn to_bytes(value: &Sample) -> Result<rustdds::bytes::Bytes, Self::Error> {
        Ok(rustdds::bytes::Bytes::copy_from_slice(
            value.0.get(HEADER_LEN..).unwrap_or_default(),
        ))
    }
}

impl DeserializerAdapter<Sample> for RawCdr {
    type Error = std::convert::Infallible;
    type Decoded = Sample;
    fn supported_encodings() -> &'static [RepresentationIdentifier] {
        &[RepresentationIdentifier::CDR_LE, RepresentationIdentifier::CDR_BE]
    }
    fn transform_decoded(decoded: Sample) -> Sample {
        decoded
    }
}

/// Puts the encapsulation header back in front of the body.
#[derive(Debug, Clone, Copy)]
struct RawDecoder;

impl Decode<'_, Sample> for RawDecoder {
    type Error = std::convert::Infallible;
    fn decode_bytes(self, input: &[u8], encoding: RepresentationIdentifier) -> Result<Sample, Self::Error> {
        let mut bytes = Vec::with_capacity(HEADER_LEN + input.len());
        bytes.extend_from_slice(&encoding.to_bytes());
        bytes.extend_from_slice(&[0, 0]);
        bytes.extend_from_slice(input);
        Ok(Sample(bytes))
    }
}

impl DefaultDecoder<Sample> for RawCdr {
    type Decoder = RawDecoder;
    const DECODER: RawDecoder = RawDecoder;
}

/// A topic this participant writes.
pub struct Publication {
    writer: DataWriter<Sample, RawCdr>,
}

impl std::fmt::Debug for Publication {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Publication").finish_non_exhaustive()
    }
}

impl Publication {
    /// Sends one CDR sample (header included, as [`crate::cdr::CdrWriter`] writes it).
    pub fn publish(&self, cdr: &[u8]) -> Result<(), DdsError> {
        self.writer
            .write(Sample(cdr.to_vec()), None)
            .map_err(|e| DdsError::Middleware(format!("write: {e:?}")))
    }
}

/// A topic this participant reads.
pub struct Subscription {
    reader: DataReader<Sample, RawCdr>,
}

impl std::fmt::Debug for Subscription {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Subscription").finish_non_exhaustive()
    }
}

impl Subscription {
    /// Takes every sample that arrived, calling `each` with each one's CDR bytes (header
    /// included), oldest first; returns how many.
    pub fn take_all(&mut self, each: &mut dyn FnMut(&[u8])) -> Result<usize, DdsError> {
        let mut n = 0;
        while let Some(sample) = self
            .reader
            .take_next_sample()
            .map_err(|e| DdsError::Middleware(format!("take: {e:?}")))?
        {
            each(&sample.value().0);
            n += 1;
        }
        Ok(n)
    }

    /// Registers the topic with a poll (rustdds's mio 1): `token` turns up when samples arrive.
    /// Each wake-up must take every sample ([`Self::take_all`]).
    pub fn register(
        &mut self,
        registry: &rustdds::mio1::Registry,
        token: rustdds::mio1::Token,
    ) -> std::io::Result<()> {
        registry.register(&mut self.reader, token, rustdds::mio1::Interest::READABLE)
    }
}
