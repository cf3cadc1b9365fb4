//! The operator's hands in the mirror: what a person does to the robot during calibration
//! (clamp it in the jig, tilt its stand, watch a joint turn), done to the simulated robot.

use std::sync::{Arc, Mutex, PoisonError};

use calibration::operator::{Aborted, Operator, Request};

use crate::mirror::Mirror;

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
