//! Emulated MIT-mode motor firmware: what a CubeMars AK or DaMiao DM-J does with the frames it
//! gets, and the torque it puts on its shaft.
//!
//! - State machine: disabled ⇄ enabled by the special frames; set-zero rebases the encoder.
//! - In-motor PD at the firmware rate: `τ = kp (p_des − p) + kd (v_des − v) + τ_ff`, clamped to ±t_max.
//! - Every frame addressed to the motor is answered with a state frame in its family's format
//!   (commands while disabled too; torque stays off).
//! - A command timeout drops torque (DaMiao reports "communication lost").
//! - A first-order thermal model heats with τ² and faults above the limit; faults latch until a
//!   disable → enable cycle after cooling, as the motors do.

use std::time::Duration;

use super::codec::{MitCommand, MitReply, MotorFault, SpecialFrame, pack_reply, unpack_command};
use super::models::{MotorFamily, MotorModel};
use crate::can::{CanFrame, CanId};
use crate::plant::MotorPlant;
use crate::time::SimInstant;

/// Configuration of one emulated motor.
#[derive(Debug, Clone, PartialEq)]
pub struct MitFirmwareConfig {
    /// The motor's CAN ID (commands arrive on it).
    pub motor_id: u8,
    /// The CAN ID replies are sent on (CubeMars: 0x000; DaMiao: the configured master ID).
    pub reply_id: u16,
    /// Ranges and reply format.
    pub model: MotorModel,
    /// Torque drops when no command arrives for this long (`None`: never).
    pub command_timeout: Option<Duration>,
    /// Ambient temperature, °C.
    pub ambient_c: f64,
    /// Winding temperature at which the motor faults, °C.
    pub temperature_limit_c: f64,
    /// Steady-state temperature rise at rated torque, K.
    pub rated_rise_k: f64,
    /// Thermal time constant, s.
    pub thermal_time_constant_s: f64,
}

impl MitFirmwareConfig {
    /// Defaults of the model's family: reply ID, a 100 ms timeout, 25 °C ambient, 100 °C limit.
    pub fn new(motor_id: u8, model: &MotorModel) -> Self {
        Self {
            motor_id,
            reply_id: model.family.default_reply_id(motor_id),
            model: model.clone(),
            command_timeout: Some(Duration::from_millis(100)),
            ambient_c: 25.0,
            temperature_limit_c: 100.0,
            rated_rise_k: 45.0,
            thermal_time_constant_s: 120.0,
        }
    }
}

/// Faults a test can force on an emulated motor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct InjectedFaults {
    /// The motor stops answering (and stops listening): a cut cable or a dead driver board.
    pub silent: bool,
    /// The next this many replies are lost on the wire (the motor heard and acted; its answer did
    /// not arrive): a loose connector, or frames the controller dropped for a bad CRC.
    pub lost_replies: u32,
    /// Report and act on this fault (torque off) from now on.
    pub fault: Option<MotorFault>,
}

/// One emulated motor.
#[derive(Debug, Clone)]
pub struct MitMotorFirmware {
    cfg: MitFirmwareConfig,
    enabled: bool,
    zero: f64,
    command: MitCommand,
    last_command: Option<SimInstant>,
    fault: MotorFault,
    temperature: f64,
    torque: f64,
    injected: InjectedFaults,
    frames_answered: u64,
}

impl MitMotorFirmware {
    /// A disabled motor at ambient temperature.
    pub fn new(cfg: MitFirmwareConfig) -> Self {
        Self {
            temperature: cfg.ambient_c,
            cfg,
            enabled: false,
            zero: 0.0,
            command: MitCommand::default(),
            last_command: None,
            fault: MotorFault::None,
            torque: 0.0,
            injected: InjectedFaults::default(),
            frames_answered: 0,
        }
    }

    /// The shaft angle the motor is holding towards (rad, plant frame), while enabled with
    /// stiffness: what a simulator's position actuator should track instead of the PD torque.
    pub fn position_goal(&self) -> Option<f64> {
        (self.enabled && self.command.kp > 0.0).then_some(self.command.p + self.zero)
    }

    /// The most torque the motor gives, N·m: its model's clamp.
    pub fn torque_cap(&self) -> f64 {
        self.cfg.model.t_max
    }

    /// The command being executed (motor units), as last received.
    pub fn command(&self) -> MitCommand {
        self.command
    }

    /// The configuration.
    pub fn config(&self) -> &MitFirmwareConfig {
        &self.cfg
    }

    /// True while torque is on.
    pub fn enabled(&self) -> bool {
        self.enabled
    }

    /// The latched fault.
    pub fn fault(&self) -> MotorFault {
        self.fault
    }

    /// Torque applied at the last firmware tick, N·m.
    pub fn torque(&self) -> f64 {
        self.torque
    }

    /// Winding temperature, °C.
    pub fn temperature(&self) -> f64 {
        self.temperature
    }

    /// Frames answered so far.
    pub fn frames_answered(&self) -> u64 {
        self.frames_answered
    }

    /// Forces faults (see [`InjectedFaults`]).
    pub fn inject(&mut self, faults: InjectedFaults) {
        self.injected = faults;
        if let Some(f) = faults.fault {
            self.fault = f;
        }
    }

    /// The encoder offset set by the last set-zero (output-shaft rad).
    pub fn zero_offset(&self) -> f64 {
        self.zero
    }

    /// Handles a frame from the bus; returns the reply to send, if any.
    pub fn on_frame(
        &mut self,
        now: SimInstant,
        frame: &CanFrame,
        plant: &dyn MotorPlant,
    ) -> Option<CanFrame> {
        if self.injected.silent || frame.id() != CanId::Standard(u16::from(self.cfg.motor_id)) {
            return None;
        }
        match SpecialFrame::parse(frame.data()) {
            Some(SpecialFrame::Enable) => {
                let cooled = self.temperature < self.cfg.temperature_limit_c - 10.0;
                if self.injected.fault.is_none() && (self.fault == MotorFault::None || cooled) {
                    self.fault = MotorFault::None;
                    self.enabled = true;
                    // Entering motor mode starts from a zero-gain command: no jump.
                    self.command = MitCommand::default();
                    self.last_command = Some(now);
                }
            }
            Some(SpecialFrame::Disable) => {
                self.enabled = false;
                self.torque = 0.0;
            }
            Some(SpecialFrame::SetZero) => {
                // Real firmware only rebases while disabled; enabled, it is refused silently.
                if !self.enabled {
                    self.zero = plant.position();
                }
            }
            None => {
                // A frame of the wrong length is ignored by the firmware: no reply.
                let cmd = unpack_command(&self.cfg.model, frame.data()).ok()?;
                if self.enabled {
                    self.command = cmd;
                }
                self.last_command = Some(now);
            }
        }
        if self.injected.lost_replies > 0 {
            self.injected.lost_replies -= 1;
            return None;
        }
        self.frames_answered += 1;
        Some(self.reply(plant))
    }

    fn reply(&self, plant: &dyn MotorPlant) -> CanFrame {
        let r = MitReply {
            motor_id: self.cfg.motor_id,
            p: plant.position() - self.zero,
            v: plant.velocity(),
            t: self.torque,
            temperature: Some(self.temperature),
            mos_temperature: Some(self.cfg.ambient_c + 0.5 * (self.temperature - self.cfg.ambient_c)),
            fault: self.fault,
            enabled: Some(self.enabled),
        };
        let (bytes, len) = pack_reply(&self.cfg.model, &r);
        let id = CanId::standard(self.cfg.reply_id & 0x7FF).unwrap_or(CanId::Standard(0));
        CanFrame::new(id, &bytes[..len]).unwrap_or_else(|| CanFrame::new8(id, bytes))
    }

    /// One firmware period of `dt`: timeout and thermal checks, then the PD law onto the plant.
    pub fn tick(&mut self, now: SimInstant, dt: Duration, plant: &mut dyn MotorPlant) {
        let dt_s = dt.as_secs_f64();
        if let (Some(timeout), Some(last), true) = (self.cfg.command_timeout, self.last_command, self.enabled)
            && now.saturating_since(last) > timeout
        {
            self.enabled = false;
            if self.cfg.model.family == MotorFamily::Damiao {
                self.fault = MotorFault::CommunicationLost;
            }
        }
        let load = self.torque / self.cfg.model.rated_torque;
        let target = self.cfg.ambient_c + self.cfg.rated_rise_k * load * load;
        self.temperature += (target - self.temperature) * (dt_s / self.cfg.thermal_time_constant_s).min(1.0);
        if self.temperature > self.cfg.temperature_limit_c && self.fault == MotorFault::None {
            self.fault = MotorFault::OverTemperature;
        }
        let faulted = !matches!(self.fault, MotorFault::None | MotorFault::CommunicationLost);
        if faulted {
            self.enabled = false;
        }
        self.torque = if self.enabled {
            let c = &self.command;
            let p = plant.position() - self.zero;
            let v = plant.velocity();
            (c.kp * (c.p - p) + c.kd * (c.v - v) + c.t).clamp(-self.cfg.model.t_max, self.cfg.model.t_max)
        } else {
            0.0
        };
        plant.apply_torque(self.torque);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mit::codec::{pack_command, unpack_reply};
    use crate::mit::models::find;
    use crate::plant::InertiaPlant;

    const DT: Duration = Duration::from_micros(500);

    fn cmd_frame(id: u8, model: &MotorModel, cmd: &MitCommand) -> CanFrame {
        CanFrame::new8(CanId::Standard(u16::from(id)), pack_command(model, cmd).unwrap())
    }

    fn special(id: u8, s: SpecialFrame) -> CanFrame {
        CanFrame::new8(CanId::Standard(u16::from(id)), s.bytes())
    }

    /// Runs firmware + plant for `secs`, re-sending `cmd` every 20 ms as a 50 Hz controller would.
    fn run(
        fw: &mut MitMotorFirmware,
        plant: &mut InertiaPlant,
        t: &mut SimInstant,
        secs: f64,
        cmd: Option<&MitCommand>,
    ) {
        let steps = (secs / DT.as_secs_f64()).round() as u64;
        for i in 0..steps {
            if let Some(c) = cmd
                && i % 40 == 0
            {
                let f = cmd_frame(fw.config().motor_id, &fw.config().model, c);
                fw.on_frame(*t, &f, plant);
            }
            fw.tick(*t, DT, plant);
            plant.integrate(DT.as_secs_f64());
            *t = *t + DT;
        }
    }

    #[test]
    fn pd_law_tracks_a_setpoint_and_torque_is_clamped() {
        let model = find("AK80-9").unwrap();
        let mut fw = MitMotorFirmware::new(MitFirmwareConfig::new(1, model));
        let mut plant = InertiaPlant::new(0.02, 0.05, 0.0, 0.0);
        let mut t = SimInstant::ZERO;
        let reply = fw.on_frame(t, &special(1, SpecialFrame::Enable), &plant).unwrap();
        assert_eq!(reply.id(), CanId::Standard(0));
        assert!(fw.enabled());
        let cmd = MitCommand {
            p: 1.0,
            v: 0.0,
            kp: 40.0,
            kd: 1.0,
            t: 0.0,
        };
        run(&mut fw, &mut plant, &mut t, 2.0, Some(&cmd));
        assert!((plant.q - 1.0).abs() < 0.01, "settled at {}", plant.q);
        // A huge error saturates at the model's torque limit.
        let far = MitCommand {
            p: 12.0,
            kp: 500.0,
            ..cmd
        };
        fw.on_frame(t, &cmd_frame(1, model, &far), &plant);
        fw.tick(t, DT, &mut plant);
        assert_eq!(fw.torque(), model.t_max);
    }

    #[test]
    fn disabled_motor_answers_but_applies_no_torque() {
        let model = find("DM-J4310").unwrap();
        let mut fw = MitMotorFirmware::new(MitFirmwareConfig::new(3, model));
        let mut plant = InertiaPlant::new(0.01, 0.0, 0.0, 0.3);
        let cmd = MitCommand {
            p: 0.0,
            kp: 50.0,
            ..MitCommand::default()
        };
        let reply = fw
            .on_frame(SimInstant::ZERO, &cmd_frame(3, model, &cmd), &plant)
            .unwrap();
        assert_eq!(
            reply.id(),
            CanId::Standard(0x13),
            "DaMiao replies to its master ID"
        );
        let r = unpack_reply(model, reply.data()).unwrap();
        assert_eq!((r.motor_id, r.enabled), (3, Some(false)));
        assert!((r.p - 0.3).abs() < 1e-3);
        fw.tick(SimInstant::ZERO, DT, &mut plant);
        assert_eq!(plant.torque, 0.0);
        // Frames for other IDs and short frames are ignored.
        assert!(
            fw.on_frame(SimInstant::ZERO, &cmd_frame(4, model, &cmd), &plant)
                .is_none()
        );
        let short = CanFrame::new(CanId::Standard(3), &[1, 2, 3]).unwrap();
        assert!(fw.on_frame(SimInstant::ZERO, &short, &plant).is_none());
    }

    #[test]
    fn set_zero_rebases_the_reported_position() {
        let model = find("AK10-9").unwrap();
        let mut fw = MitMotorFirmware::new(MitFirmwareConfig::new(2, model));
        let plant = InertiaPlant::new(0.01, 0.0, 0.0, 0.7);
        let r = fw
            .on_frame(SimInstant::ZERO, &special(2, SpecialFrame::SetZero), &plant)
            .unwrap();
        assert!(unpack_reply(model, r.data()).unwrap().p.abs() < 1e-3);
        assert_eq!(fw.zero_offset(), 0.7);
    }

    #[test]
    fn command_timeout_drops_torque() {
        let model = find("DM-J4340").unwrap();
        let mut fw = MitMotorFirmware::new(MitFirmwareConfig::new(1, model));
        let mut plant = InertiaPlant::new(0.02, 0.1, 0.0, 0.0);
        let mut t = SimInstant::ZERO;
        fw.on_frame(t, &special(1, SpecialFrame::Enable), &plant);
        let cmd = MitCommand {
            p: 0.5,
            kp: 30.0,
            kd: 1.0,
            ..MitCommand::default()
        };
        fw.on_frame(t, &cmd_frame(1, model, &cmd), &plant);
        run(&mut fw, &mut plant, &mut t, 0.09, None);
        assert!(fw.enabled() && fw.torque() != 0.0);
        run(&mut fw, &mut plant, &mut t, 0.02, None);
        assert!(!fw.enabled());
        assert_eq!(fw.torque(), 0.0);
        assert_eq!(fw.fault(), MotorFault::CommunicationLost);
    }

    #[test]
    fn sustained_overload_overheats_and_latches_a_fault() {
        let model = find("AK80-9").unwrap();
        let mut cfg = MitFirmwareConfig::new(1, model);
        cfg.thermal_time_constant_s = 2.0;
        cfg.command_timeout = None;
        let mut fw = MitMotorFirmware::new(cfg);
        // A locked shaft (huge inertia) held against a full-torque command.
        let mut plant = InertiaPlant::new(1e9, 0.0, 0.0, 0.0);
        let mut t = SimInstant::ZERO;
        fw.on_frame(t, &special(1, SpecialFrame::Enable), &plant);
        let cmd = MitCommand {
            t: model.t_max,
            ..MitCommand::default()
        };
        let mut waited = 0.0;
        while fw.fault() == MotorFault::None && waited < 20.0 {
            run(&mut fw, &mut plant, &mut t, 0.1, Some(&cmd));
            waited += 0.1;
        }
        assert_eq!(
            fw.fault(),
            MotorFault::OverTemperature,
            "after {waited} s at {} °C",
            fw.temperature()
        );
        assert!(!fw.enabled());
        let r = fw.on_frame(t, &cmd_frame(1, model, &cmd), &plant).unwrap();
        assert_eq!(
            unpack_reply(model, r.data()).unwrap().fault,
            MotorFault::OverTemperature
        );
        // Re-enabling while hot is refused; after cooling it is accepted and the fault clears.
        fw.on_frame(t, &special(1, SpecialFrame::Enable), &plant);
        assert!(!fw.enabled());
        run(&mut fw, &mut plant, &mut t, 10.0, None);
        fw.on_frame(t, &special(1, SpecialFrame::Enable), &plant);
        assert!(fw.enabled());
        assert_eq!(fw.fault(), MotorFault::None);
    }

    #[test]
    fn lost_replies_come_back_after_their_count_while_the_motor_keeps_listening() {
        let model = find("AK80-9").unwrap();
        let mut fw = MitMotorFirmware::new(MitFirmwareConfig::new(1, model));
        let plant = InertiaPlant::new(0.01, 0.0, 0.0, 0.0);
        fw.inject(InjectedFaults {
            lost_replies: 2,
            ..InjectedFaults::default()
        });
        let enable = special(1, SpecialFrame::Enable);
        assert!(fw.on_frame(SimInstant::ZERO, &enable, &plant).is_none());
        assert!(fw.enabled(), "a lost reply is not a deaf motor");
        assert!(fw.on_frame(SimInstant::ZERO, &enable, &plant).is_none());
        assert!(fw.on_frame(SimInstant::ZERO, &enable, &plant).is_some());
    }

    #[test]
    fn injected_faults_silence_or_trip_the_motor() {
        let model = find("AK80-9").unwrap();
        let mut fw = MitMotorFirmware::new(MitFirmwareConfig::new(1, model));
        let plant = InertiaPlant::new(0.01, 0.0, 0.0, 0.0);
        fw.inject(InjectedFaults {
            silent: true,
            ..InjectedFaults::default()
        });
        assert!(
            fw.on_frame(SimInstant::ZERO, &special(1, SpecialFrame::Enable), &plant)
                .is_none()
        );
        fw.inject(InjectedFaults {
            fault: Some(MotorFault::OverCurrent),
            ..InjectedFaults::default()
        });
        let r = fw
            .on_frame(SimInstant::ZERO, &special(1, SpecialFrame::Enable), &plant)
            .unwrap();
        assert!(!fw.enabled());
        assert_eq!(
            unpack_reply(model, r.data()).unwrap().fault,
            MotorFault::OverCurrent
        );
    }
}
