//! The person at the robot: confirms each step, clamps the jig, tilts the stand. On hardware a
//! console asks them; in the mirror `sim2real::hands::MirrorHands` does the physical part in the
//! simulation.

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
