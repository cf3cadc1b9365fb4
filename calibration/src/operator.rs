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
    /// A line of output for the person.
    fn say(&mut self, line: &str);
    /// Progress of the current step, 0–1.
    fn progress(&mut self, _step: &str, _done: f64) {}
}

impl<O: Operator + ?Sized> Operator for &mut O {
    fn request(&mut self, request: Request<'_>) -> Result<(), Aborted> {
        (**self).request(request)
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
    fn say(&mut self, line: &str) {
        self.lines.push(line.to_owned());
    }
}

/// The operator's hands in the mirror: clamps the simulated jig and tilts the simulated stand, and
/// passes confirmations and output to `inner`.
#[derive(Debug)]
pub struct MirrorHands<O> {
    world: Arc<Mutex<Mirror>>,
    /// Who confirms and reads.
    pub inner: O,
}

impl<O> MirrorHands<O> {
    /// Hands on `world` (built with a gantry, so the stand can be tilted).
    pub fn new(world: Arc<Mutex<Mirror>>, inner: O) -> Self {
        Self { world, inner }
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

    fn say(&mut self, line: &str) {
        self.inner.say(line);
    }

    fn progress(&mut self, step: &str, done: f64) {
        self.inner.progress(step, done);
    }
}
