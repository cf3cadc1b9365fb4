//! DDS on the wire: a participant on one network interface and domain (RustDDS), topics of raw
//! CDR samples under the names the peers use, the CDR encoding itself, ROS 2's names and the ROS 2
//! messages a run publishes and takes. Unitree's low-level link and ROS 2's topics both ride on it.

pub mod cdr;
pub mod names;
mod participant;
pub mod ros2;

/// The event loop library topics register with ([`Subscription::register`]).
pub use rustdds::mio1 as mio;

pub use participant::{
    DdsConfig, DdsError, Delivery, MAX_DOMAIN, MIDDLEWARE, Participant, Publication, Subscription,
    interface_addresses, interfaces,
};
