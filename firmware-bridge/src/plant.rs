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

/// Checks the figures a model table gives a servo's motor (nominal voltage, stall torque and
/// current, no-load speed): each a positive number; the message names the model and the field.
pub fn check_motor_figures(model: &str, figures: [(&'static str, f64); 4]) -> Result<(), BadMotorFigure> {
    for (field, value) in figures {
        if !(value.is_finite() && value > 0.0) {
            return Err(BadMotorFigure {
                model: model.to_owned(),
                field,
                value,
            });
        }
    }
    Ok(())
}

/// A model table's motor figure that is not a positive number.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("[{model}] {field} = {value}: must be a positive number")]
pub struct BadMotorFigure {
    /// The servo model.
    pub model: String,
    /// The figure's field.
    pub field: &'static str,
    /// Its value.
    pub value: f64,
}

/// A brushed DC motor with its gearbox, from the figures servo data sheets give: the constants
/// every emulated serial servo turns its duty cycle into current and torque with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DcMotor {
    /// Supply voltage the figures refer to, V.
    pub nominal_voltage: f64,
    /// Output torque at stall, N·m.
    pub stall_torque: f64,
    /// Current at stall, A.
    pub stall_current: f64,
    /// Output speed without load, rad/s.
    pub no_load_speed: f64,
}

impl DcMotor {
    /// Torque constant at the output, N·m/A.
    pub fn torque_constant(&self) -> f64 {
        self.stall_torque / self.stall_current
    }

    /// Winding resistance, Ω.
    pub fn resistance(&self) -> f64 {
        self.nominal_voltage / self.stall_current
    }

    /// Back-EMF constant at the output, V·s/rad.
    pub fn back_emf(&self) -> f64 {
        self.nominal_voltage / self.no_load_speed
    }

    /// The winding current when the bridge applies `duty` (−1…1) of `supply` volts while the
    /// output turns at `omega` rad/s (quasi-static winding).
    pub fn current(&self, duty: f64, supply: f64, omega: f64) -> f64 {
        (duty * supply - self.back_emf() * omega) / self.resistance()
    }

    /// The duty (unbounded) that makes `current` flow at `omega`: [`Self::current`]'s inverse.
    pub fn duty_for(&self, current: f64, supply: f64, omega: f64) -> f64 {
        (current * self.resistance() + self.back_emf() * omega) / supply
    }
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
