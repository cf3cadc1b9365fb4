//! The lifecycle of a run: the state machine's place (mode, ticks in it, transitions, the cause of
//! a stop under way), the safety monitor, the stop and e-stop flags, and what a harness start and
//! a soft stop need (the operator's word, the crane, where the robot goes).

use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use crate::options::HarnessPhase;
use crate::safety::{Cause, Mode, SafetyMonitor, Transition};

/// The state machine's place.
#[derive(Debug)]
pub(crate) struct Machine {
    pub(crate) mode: Mode,
    /// Ticks in the current mode.
    pub(crate) ticks: u64,
    pub(crate) transitions: Vec<Transition>,
    /// The cause that started the current stop, if any.
    pub(crate) pending: Option<Cause>,
}

/// The lifecycle of a run: modes and their transitions, the safety monitor, the stop and e-stop
/// flags, how a run starts (the harness) and where a stop takes the robot.
#[derive(Debug)]
pub(crate) struct Lifecycle {
    pub(crate) stop: Arc<AtomicBool>,
    pub(crate) estop: Option<Arc<AtomicBool>>,
    /// The stop flag as this tick's checks saw it (recorded, so a replay sees the same).
    pub(crate) stop_seen: bool,
    pub(crate) machine: Machine,
    pub(crate) monitor: SafetyMonitor,
    pub(crate) start_pose: Vec<f64>,
    /// Where a soft stop goes (robot order): the default pose, or the sit keyframe.
    pub(crate) stop_pose: Vec<f64>,
    /// The tick the robot started standing after a soft stop (`OnStop::Stay`).
    pub(crate) standing_since: Option<u64>,
    /// The soft stop under way began with the policy in control (it keeps it).
    pub(crate) stop_under_policy: bool,
    /// The mirror's crane, when the robot hangs in its harness: raised, it takes the weight.
    pub(crate) harness_hoist: Option<Arc<AtomicBool>>,
    /// The operator's word that the harness has set the robot on its feet (hardware, or a
    /// rehearsal on the mirror): until it comes, the motion waits on its first frame.
    pub(crate) lowered: Option<Arc<AtomicBool>>,
    /// The harness start's phase at the last tick.
    pub(crate) harness_phase: HarnessPhase,
}
