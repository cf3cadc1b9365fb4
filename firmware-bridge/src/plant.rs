//! The plant interface emulated firmware drives: one joint's state in, torque out.
//!
//! The mirrored simulator implements it on MuJoCo joints; [`InertiaPlant`] is a one-joint stand-in
//! for unit tests and benches.

/// What a servo or motor firmware sees of the mechanism it drives (output-shaft units).
pub trait MotorPlant {
    /// Output-shaft angle, rad (as an absolute encoder reads it, before any zero offset).
    fn position(&self) -> f64;
    /// Output-shaft velocity, rad/s.
    fn velocity(&self) -> f64;
    /// Sets the torque the motor applies until the next call, N·m.
    fn apply_torque(&mut self, torque: f64);
}

/// A rigid load on a shaft: inertia, viscous and Coulomb friction, integrated semi-implicitly.
#[derive(Debug, Clone, PartialEq)]
pub struct InertiaPlant {
    /// Reflected inertia at the output, kg·m².
    pub inertia: f64,
    /// Viscous friction, N·m·s/rad.
    pub damping: f64,
    /// Coulomb friction, N·m.
    pub friction: f64,
    /// Angle, rad.
    pub q: f64,
    /// Velocity, rad/s.
    pub qd: f64,
    /// Torque applied by the motor, N·m.
    pub torque: f64,
}

impl InertiaPlant {
    /// A plant at rest at `q`.
    pub fn new(inertia: f64, damping: f64, friction: f64, q: f64) -> Self {
        Self {
            inertia,
            damping,
            friction,
            q,
            qd: 0.0,
            torque: 0.0,
        }
    }

    /// Advances the plant by `dt` seconds under the applied torque.
    pub fn integrate(&mut self, dt: f64) {
        let drive = self.torque - self.damping * self.qd;
        // Coulomb friction opposes motion, and holds the shaft while the drive is below it.
        let accel = if self.qd.abs() > 1e-6 {
            (drive - self.friction * self.qd.signum()) / self.inertia
        } else if drive.abs() > self.friction {
            (drive - self.friction * drive.signum()) / self.inertia
        } else {
            -self.qd / dt
        };
        self.qd += accel * dt;
        self.q += self.qd * dt;
    }
}

impl MotorPlant for InertiaPlant {
    fn position(&self) -> f64 {
        self.q
    }
    fn velocity(&self) -> f64 {
        self.qd
    }
    fn apply_torque(&mut self, torque: f64) {
        self.torque = torque;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn constant_torque_accelerates_as_newton_says() {
        let mut p = InertiaPlant::new(0.01, 0.0, 0.0, 0.0);
        p.apply_torque(0.1);
        for _ in 0..1000 {
            p.integrate(0.001);
        }
        // a = τ/J = 10 rad/s², after 1 s: v = 10, q ≈ 5.
        assert!((p.qd - 10.0).abs() < 1e-9);
        assert!((p.q - 5.0).abs() < 0.02, "{}", p.q);
    }

    #[test]
    fn friction_holds_below_breakaway() {
        let mut p = InertiaPlant::new(0.01, 0.0, 0.2, 1.0);
        p.apply_torque(0.15);
        for _ in 0..100 {
            p.integrate(0.001);
        }
        assert_eq!((p.q, p.qd), (1.0, 0.0));
    }
}
