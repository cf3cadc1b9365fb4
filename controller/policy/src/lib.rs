//! The policy stage: what a trained policy is and how it runs, knowing nothing of buses or
//! telemetry. The contract as data ([`contract`]: a manifest's observation terms, actions and
//! gains resolved against a robot and the ONNX shapes), the conventions of training frameworks'
//! exports ([`export`]: BeyondMimic and mjlab metadata; [`holosoma`]), the observation filled each
//! tick without allocating ([`observation`]), and ONNX inference ([`onnx`], the pinned runtime
//! found by [`native`]).

pub mod commands;
pub mod contract;
pub mod export;
pub mod holosoma;
pub mod native;
pub mod observation;
pub mod onnx;

pub use contract::*;
pub use observation::*;

/// Values of the `tracker_poses` observation term for three devices (headset, left and right
/// controller): position (3) and the first two columns of the rotation (6) each.
pub const TRACKER_VALUES: usize = 27;
