//! Whether the robot's model is numerically stable at its physics step, found at load rather than
//! as a divergence mid-run: the mirror holds the default pose for a short settle (on the gantry,
//! and as the robot starts a run) through the real buses and firmware, and every joint that still
//! moves fast — or a simulation MuJoCo gave up on — is named with what to change.

use std::time::Duration;

use robots::Robot;

use crate::config::MirrorConfig;
use crate::host::{HostError, MirrorHost};

/// How long each settle lasts, s.
pub const SETTLE_S: f64 = 1.0;
/// A joint holding its pose is unstable when, in the settle's second half, it moves faster than
/// this share of its velocity limit.
pub const UNSTABLE_SHARE: f64 = 0.25;

/// Where a settle held the robot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Hold {
    /// Hanging from the gantry by its root, feet free.
    Gantry,
    /// As a run starts it: standing on the floor, or in the harness of a harness start.
    Start,
}

impl std::fmt::Display for Hold {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Gantry => "on the gantry",
            Self::Start => "as a run starts",
        })
    }
}

/// A joint that did not settle.
#[derive(Debug, Clone, PartialEq)]
pub struct Restless {
    /// The joint (robot.toml's name).
    pub joint: String,
    /// Its fastest speed in the settle's second half, rad/s.
    pub speed: f64,
    /// Its velocity limit, rad/s.
    pub limit: f64,
}

/// What one settle found.
#[derive(Debug, Clone, PartialEq)]
pub struct Settle {
    /// Where the robot was held.
    pub hold: Hold,
    /// The physics step, s.
    pub step: f64,
    /// MuJoCo gave up on the simulation: why.
    pub diverged: Option<String>,
    /// Joints that kept moving fast, fastest (relative to the limit) first.
    pub restless: Vec<Restless>,
}

impl Settle {
    /// Whether the model held still.
    pub fn stable(&self) -> bool {
        self.diverged.is_none() && self.restless.is_empty()
    }
}

impl std::fmt::Display for Settle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let step_ms = self.step * 1000.0;
        if self.stable() {
            return write!(
                f,
                "{}: still after {SETTLE_S} s at the {step_ms} ms step",
                self.hold
            );
        }
        write!(f, "{}: unstable at the {step_ms} ms step", self.hold)?;
        if let Some(why) = &self.diverged {
            write!(f, " ({why})")?;
        }
        if !self.restless.is_empty() {
            let names: Vec<String> = self
                .restless
                .iter()
                .map(|r| format!("{} {:.1} rad/s of {:.1}", r.joint, r.speed, r.limit))
                .collect();
            write!(f, "; still moving: {}", names.join(", "))?;
        }
        write!(
            f,
            " — give the joints their rotor armature (robot.toml [[joint_dynamics]] armature, the \
             motor's reflected rotor inertia) or a smaller step ([sim] timestep)"
        )
    }
}

/// Settles `robot` held as `hold` for [`SETTLE_S`], commanding its default pose every tick.
pub fn settle(robot: &Robot, hold: Hold) -> Result<Settle, HostError> {
    let config = match hold {
        Hold::Gantry => MirrorConfig {
            gantry: true,
            ..MirrorConfig::default()
        },
        Hold::Start => MirrorConfig::default().for_run(robot, robot.config.start.mode),
    };
    let mut host = MirrorHost::start(robot.clone(), config)?;
    let step = host.world.lock().map_or(0.0, |w| w.data().model().opt().timestep);
    // robot.toml holds the rate within [1, 1000] Hz.
    let period =
        Duration::try_from_secs_f64(1.0 / robot.config.control_rate_hz).unwrap_or(Duration::from_millis(20));
    let ticks = (SETTLE_S * robot.config.control_rate_hz).round() as u32;
    let q: Vec<f64> = robot.config.joints.iter().map(|j| j.default_position).collect();
    let mut fastest = vec![0.0f64; q.len()];
    let start = host.now();
    // Sampled at every physics step of the second half: an oscillation at the step's own
    // frequency shows at every sample.
    let substeps = (period.as_secs_f64() / step.max(1e-6)).round().max(1.0) as u32;
    let index = host
        .world
        .lock()
        .ok()
        .and_then(|w| crate::model_index::ModelIndex::of_robot(w.data().model(), robot).ok());
    let mut diverged = None;
    for k in 1..=ticks {
        host.command_positions(robot, &q)?;
        for s in 1..=substeps {
            host.wait_until(start + period * (k - 1) + period * s / substeps);
            if k <= ticks / 2 {
                continue;
            }
            let Ok(w) = host.world.lock() else { continue };
            if let Some(why) = w.diverged() {
                diverged = Some(why.to_owned());
            }
            if let Some(index) = &index {
                for (f, ids) in fastest.iter_mut().zip(&index.joints) {
                    let v = w.data().qvel()[ids.dof].abs();
                    *f = f.max(if v.is_finite() { v } else { f64::INFINITY });
                }
            }
        }
        if diverged.is_some() {
            break;
        }
    }
    let mut restless: Vec<Restless> = robot
        .config
        .joints
        .iter()
        .zip(&fastest)
        .filter(|(j, v)| **v > UNSTABLE_SHARE * j.velocity_limit)
        .map(|(j, v)| Restless {
            joint: j.name.clone(),
            speed: *v,
            limit: j.velocity_limit,
        })
        .collect();
    restless.sort_by(|a, b| (b.speed / b.limit).total_cmp(&(a.speed / a.limit)));
    Ok(Settle {
        hold,
        step,
        diverged,
        restless,
    })
}
