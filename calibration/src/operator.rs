//! The person at the robot: confirms each step, clamps the jig, tilts the stand. On hardware a
//! console asks them; in the mirror [`MirrorHands`] does the physical part in the simulation.

use std::sync::{Arc, Mutex, PoisonError};

use sim2real::mirror::Mirror;

/// The operator said no, or asked to stop.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("aborted by the operator")]
pub struct Aborted;

/// What the procedure asks of the operator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Request<'a> {
    /// Go ahead with a step (`what` says what it will do).
    Confirm {
        /// The step and what it will do.
        what: &'a str,
    },
    /// Clamp every joint in the jig at `pose` (robot order, rad).
    ClampJig {
        /// Which jig setting, for the instructions.
        label: &'a str,
        /// Joint names, robot order.
        joints: &'a [String],
        /// Joint angles, rad.
        pose: &'a [f64],
    },
    /// Take the robot out of the jig (it hangs on its stand).
    ReleaseJig,
    /// Watch joint `index` (robot order): it is about to move under its own power.
    Watch {
        /// Robot index.
        index: usize,
        /// Joint name.
        joint: &'a str,
    },
    /// Hold the base still at roll/pitch/yaw (deg) on the stand.
    HoldBase {
        /// What the pose is for.
        label: &'a str,
        /// Roll, pitch, yaw, deg (approximate on hardware: the procedure measures the tilt).
        rpy_deg: [f64; 3],
    },
}

/// The person at the robot.
pub trait Operator {
    /// Carries out (or confirms) a request; `Err` stops the procedure into damping.
    fn request(&mut self, request: Request<'_>) -> Result<(), Aborted>;
    /// Since the last [`Request::Watch`] of this joint, did it turn in its positive direction (as
    /// the robot model's axis defines it: +1) or its negative one (−1)? Encoders cannot tell a
    /// flipped motor from a flipped joint; a person looking at the robot can.
    fn direction_seen(&mut self, index: usize, joint: &str) -> Result<f64, Aborted>;
    /// A line of output for the person.
    fn say(&mut self, line: &str);
    /// Progress of the current step, 0–1.
    fn progress(&mut self, _step: &str, _done: f64) {}
}

impl<O: Operator + ?Sized> Operator for &mut O {
    fn request(&mut self, request: Request<'_>) -> Result<(), Aborted> {
        (**self).request(request)
    }
    fn direction_seen(&mut self, index: usize, joint: &str) -> Result<f64, Aborted> {
        (**self).direction_seen(index, joint)
    }
    fn say(&mut self, line: &str) {
        (**self).say(line);
    }
    fn progress(&mut self, step: &str, done: f64) {
        (**self).progress(step, done);
    }
}

/// Says yes to everything and prints nothing (tests; `--yes` wraps a printing operator instead).
#[derive(Debug, Default)]
pub struct Silent {
    /// Every line said.
    pub lines: Vec<String>,
}

impl Operator for Silent {
    fn request(&mut self, _request: Request<'_>) -> Result<(), Aborted> {
        Ok(())
    }
    /// Nobody is looking: a step that needs eyes on the robot cannot go on.
    fn direction_seen(&mut self, _index: usize, _joint: &str) -> Result<f64, Aborted> {
        Err(Aborted)
    }
    fn say(&mut self, line: &str) {
        self.lines.push(line.to_owned());
    }
}

/// The operator's hands in the mirror: clamps the simulated jig and tilts the simulated stand, and
/// passes confirmations and output to `inner`.
#[derive(Debug)]
pub struct MirrorHands<O> {
    world: Arc<Mutex<Mirror>>,
    /// Joint angle (truth) when the watch began.
    watched: Option<(usize, f64)>,
    /// Who confirms and reads.
    pub inner: O,
}

impl<O> MirrorHands<O> {
    /// Hands on `world` (built with a gantry, so the stand can be tilted).
    pub fn new(world: Arc<Mutex<Mirror>>, inner: O) -> Self {
        Self {
            world,
            watched: None,
            inner,
        }
    }

    fn world(&self) -> std::sync::MutexGuard<'_, Mirror> {
        self.world.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

impl<O: Operator> Operator for MirrorHands<O> {
    fn request(&mut self, request: Request<'_>) -> Result<(), Aborted> {
        match request {
            Request::Confirm { .. } => return self.inner.request(request),
            Request::ClampJig { label, pose, .. } => {
                self.world().set_jig(Some(pose.to_vec()));
                self.inner
                    .say(&format!("  [mirror] robot clamped in jig setting {label}"));
            }
            Request::Watch { index, .. } => {
                let q = self.world().joint_positions().nth(index).unwrap_or(0.0);
                self.watched = Some((index, q));
            }
            Request::ReleaseJig => {
                self.world().set_jig(None);
                self.inner.say("  [mirror] jig released");
            }
            Request::HoldBase { label, rpy_deg } => {
                self.world().set_gantry_rpy(rpy_deg.map(f64::to_radians));
                self.inner.say(&format!(
                    "  [mirror] stand turned to roll {:.0}°, pitch {:.0}°, yaw {:.0}° ({label})",
                    rpy_deg[0], rpy_deg[1], rpy_deg[2]
                ));
            }
        }
        Ok(())
    }

    /// The person looks at the simulated robot: the sign of the joint's true motion.
    fn direction_seen(&mut self, index: usize, joint: &str) -> Result<f64, Aborted> {
        let q = self.world().joint_positions().nth(index).unwrap_or(0.0);
        match self.watched {
            Some((i, before)) if i == index && (q - before).abs() > 0.02 => {
                let sign = (q - before).signum();
                self.inner.say(&format!(
                    "  [mirror] {joint} turned {}",
                    if sign > 0.0 { "positive" } else { "negative" }
                ));
                Ok(sign)
            }
            _ => Err(Aborted),
        }
    }

    fn say(&mut self, line: &str) {
        self.inner.say(line);
    }

    fn progress(&mut self, step: &str, done: f64) {
        self.inner.progress(step, done);
    }
}
