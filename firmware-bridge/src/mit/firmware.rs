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
//! - Robstride's factory protocol: the same loop behind its frames, plus get-ID, a parameter
//!   table (run mode, torque limit, position, velocity, current, bus voltage), stop-with-clear,
//!   and the impedance law only in run mode 0 (operation control); the run mode changes only
//!   while stopped, as on the motor.

use std::time::Duration;

use super::codec::{
    MitCommand, MitReply, MotorFault, MotorRequest, SpecialFrame, decode_request, reply_frame,
};
use super::models::{MotorFamily, MotorModel};
use super::robstride::{self, comm, param};
use crate::can::CanFrame;
use crate::plant::MotorPlant;
use crate::time::SimInstant;

/// An MIT motor's impedance law: `τ = kp (p − q) + kd (v − q̇) + t`, clamped to ±`limit`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PdLaw {
    /// Position target, rad.
    pub p: f64,
    /// Velocity target, rad/s.
    pub v: f64,
    /// Stiffness, N·m/rad.
    pub kp: f64,
    /// Damping, N·m·s/rad.
    pub kd: f64,
    /// Feed-forward torque, N·m.
    pub t: f64,
    /// Torque clamp, N·m.
    pub limit: f64,
}

impl PdLaw {
    /// The law's torque at position `q` and velocity `qd`, before the clamp.
    pub fn torque(&self, q: f64, qd: f64) -> f64 {
        self.kp * (self.p - q) + self.kd * (self.v - qd) + self.t
    }
}

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
    /// Robstride's run mode (0: operation control, the impedance law).
    run_mode: u8,
    /// The torque clamp in force, N·m (Robstride's limit_torque; the model's range elsewhere).
    torque_limit: f64,
    /// A simulator computes the law every physics step and says what torque acted
    /// ([`MitMotorFirmware::sense_torque`]): the motor reports that, not its own law's.
    law_outside: bool,
}

impl MitMotorFirmware {
    /// A disabled motor at ambient temperature.
    pub fn new(cfg: MitFirmwareConfig) -> Self {
        Self {
            temperature: cfg.ambient_c,
            enabled: false,
            zero: 0.0,
            command: MitCommand::default(),
            last_command: None,
            fault: MotorFault::None,
            torque: 0.0,
            injected: InjectedFaults::default(),
            frames_answered: 0,
            run_mode: 0,
            torque_limit: cfg.model.t_max,
            law_outside: false,
            cfg,
        }
    }

    /// The torque that acted on the shaft, N·m, from a simulator that computes the motor's law
    /// itself every physics step (a trainer's actuator model, with its own effort limit): from
    /// then on the motor reports it and heats by it, as its current sensor would.
    pub fn sense_torque(&mut self, torque: f64) {
        self.law_outside = true;
        self.torque = torque;
    }

    /// The shaft angle the motor is holding towards (rad, plant frame), while enabled with
    /// stiffness: what a simulator's position actuator should track instead of the PD torque.
    pub fn position_goal(&self) -> Option<f64> {
        (self.enabled && self.run_mode == 0 && self.command.kp > 0.0).then_some(self.command.p + self.zero)
    }

    /// The impedance law the motor runs, in the plant's frame (positions include the encoder
    /// zero), while torque is on: what a simulator that computes the law itself every physics
    /// step takes from the motor (the firmware still owns enabling, timeouts and faults).
    pub fn pd_law(&self) -> Option<PdLaw> {
        (self.enabled && self.run_mode == 0).then_some(PdLaw {
            p: self.command.p + self.zero,
            v: self.command.v,
            kp: self.command.kp,
            kd: self.command.kd,
            t: self.command.t,
            limit: self.torque_limit,
        })
    }

    /// The most torque the motor gives, N·m: its model's clamp, or a lower limit set in its
    /// parameters.
    pub fn torque_cap(&self) -> f64 {
        self.torque_limit
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
        if self.injected.silent {
            return None;
        }
        // A frame of the wrong length, or for another motor, is ignored: no reply.
        let request = decode_request(&self.cfg.model, self.cfg.motor_id, frame)?;
        let reply = match request {
            MotorRequest::Special { which, clear_faults } => {
                self.special(now, which, clear_faults, plant);
                self.reply(plant)
            }
            MotorRequest::Command(cmd) => {
                if self.enabled && self.run_mode == 0 {
                    self.command = cmd;
                }
                self.last_command = Some(now);
                self.reply(plant)
            }
            MotorRequest::Other { comm, data2: _ } => self.robstride_request(comm, frame, plant)?,
        };
        if self.injected.lost_replies > 0 {
            self.injected.lost_replies -= 1;
            return None;
        }
        self.frames_answered += 1;
        Some(reply)
    }

    /// Torque on, from a zero-gain command (no jump), unless a fault is latched and the winding
    /// has not cooled.
    fn enable(&mut self, now: SimInstant) {
        let cooled = self.temperature < self.cfg.temperature_limit_c - 10.0;
        if self.injected.fault.is_none() && (self.fault == MotorFault::None || cooled) {
            self.fault = MotorFault::None;
            self.enabled = true;
            self.command = MitCommand::default();
            self.last_command = Some(now);
        }
    }

    /// Torque off; clears a fault that is no longer there when asked to.
    fn disable(&mut self, clear_faults: bool) {
        self.enabled = false;
        self.torque = 0.0;
        let cooled = self.temperature < self.cfg.temperature_limit_c - 10.0;
        if clear_faults && self.injected.fault.is_none() && cooled {
            self.fault = MotorFault::None;
        }
    }

    /// The motor run by a board rather than by frames (Unitree's: the robot's board turns each
    /// low-level command into its motors' commands): `Some` switches torque on if it is off
    /// (a latched fault permitting) and sets the law, `None` switches it off and clears a fault
    /// that has passed. Counts as a command for the timeout. A silent motor hears nothing.
    pub fn drive(&mut self, now: SimInstant, command: Option<MitCommand>) {
        if self.injected.silent {
            return;
        }
        match command {
            Some(cmd) => {
                if !self.enabled {
                    self.enable(now);
                }
                if self.enabled {
                    self.command = cmd;
                }
                self.last_command = Some(now);
            }
            None if self.enabled || self.fault != MotorFault::None => self.disable(true),
            None => {}
        }
    }

    /// Whether the motor was made silent ([`InjectedFaults::silent`]): it neither hears nor
    /// answers.
    pub fn silent(&self) -> bool {
        self.injected.silent
    }

    fn special(&mut self, now: SimInstant, which: SpecialFrame, clear_faults: bool, plant: &dyn MotorPlant) {
        match which {
            SpecialFrame::Enable => self.enable(now),
            SpecialFrame::Disable => self.disable(clear_faults),
            SpecialFrame::SetZero => {
                // Real firmware only rebases while disabled; enabled, it is refused silently.
                if !self.enabled {
                    self.zero = plant.position();
                }
            }
        }
    }

    /// Robstride's requests beyond the loop: get ID, parameters. `None`: not answered.
    fn robstride_request(&mut self, kind: u8, frame: &CanFrame, plant: &dyn MotorPlant) -> Option<CanFrame> {
        let motor = self.cfg.motor_id;
        let host = self.cfg.reply_id as u8;
        match kind {
            comm::GET_ID => {
                // The MCU's unique ID: fixed per motor here.
                let uid = 0x5253_0000_0000_0000u64 | u64::from(motor);
                Some(CanFrame::new8(
                    robstride::frame_id(comm::GET_ID, u16::from(motor), 0xFE),
                    uid.to_le_bytes(),
                ))
            }
            comm::READ_PARAM => {
                let (index, _) = robstride::param_of(frame.data())?;
                let f = |v: f64| (v as f32).to_le_bytes();
                let value = match index {
                    param::RUN_MODE => Some([self.run_mode, 0, 0, 0]),
                    param::LIMIT_TORQUE => Some(f(self.torque_limit)),
                    param::MECH_POS => Some(f(plant.position() - self.zero)),
                    param::MECH_VEL => Some(f(plant.velocity())),
                    // The q-axis current behind the torque (a torque constant of 1 N·m/A here).
                    param::IQF => Some(f(self.torque)),
                    param::VBUS => Some(f(48.0)),
                    _ => None,
                };
                let i = index.to_le_bytes();
                let v = value.unwrap_or([0; 4]);
                // Bit 16 of the answer marks an index the motor does not have.
                let data2 = u16::from(motor) | u16::from(value.is_none()) << 8;
                Some(CanFrame::new8(
                    robstride::frame_id(comm::READ_PARAM, data2, host),
                    [i[0], i[1], 0, 0, v[0], v[1], v[2], v[3]],
                ))
            }
            comm::WRITE_PARAM => {
                let (index, v) = robstride::param_of(frame.data())?;
                match index {
                    // The mode changes only while stopped, and to a mode the motor has.
                    param::RUN_MODE if !self.enabled && v[0] <= 3 => self.run_mode = v[0],
                    param::LIMIT_TORQUE => {
                        let limit = f64::from(f32::from_le_bytes(v));
                        if limit.is_finite() && limit >= 0.0 {
                            self.torque_limit = limit.min(self.cfg.model.t_max);
                        }
                    }
                    _ => {}
                }
                Some(self.reply(plant))
            }
            // Set CAN ID, fault report and the rest: not emulated, not answered.
            _ => None,
        }
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
        reply_frame(&self.cfg.model, self.cfg.reply_id, &r)
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
        if self.law_outside {
            // The simulator's own law acts; the plant keeps what it said acted.
            plant.apply_torque(self.torque);
            return;
        }
        self.torque = self.pd_law().map_or(0.0, |law| {
            law.torque(plant.position(), plant.velocity())
                .clamp(-law.limit, law.limit)
        });
        plant.apply_torque(self.torque);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::can::CanId;
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
    #[test]
    fn a_robstride_motor_runs_the_loop_behind_its_factory_frames() {
        let model = find("RS03").unwrap();
        let mut fw = MitMotorFirmware::new(MitFirmwareConfig::new(4, model));
        let mut plant = InertiaPlant::new(0.02, 0.1, 0.0, 0.0);
        let mut t = SimInstant::ZERO;
        let host = robstride::DEFAULT_HOST_ID;
        let feedback = |f: &CanFrame| robstride::unpack_feedback(model, f).unwrap();
        // Frames for another motor, or in MIT layout, go unanswered.
        assert!(
            fw.on_frame(t, &robstride::special(SpecialFrame::Enable, 5, host), &plant)
                .is_none()
        );
        assert!(
            fw.on_frame(t, &special(4, SpecialFrame::Enable), &plant)
                .is_none()
        );
        let r = fw
            .on_frame(t, &robstride::special(SpecialFrame::Enable, 4, host), &plant)
            .unwrap();
        assert_eq!(
            robstride::split_id(r.id()).map(|(c, _, h)| (c, h)),
            Some((comm::FEEDBACK, host))
        );
        assert_eq!(feedback(&r).enabled, Some(true));
        // The run mode changes only while stopped.
        let run_mode = |m: u8| robstride::write_param(4, host, param::RUN_MODE, [m, 0, 0, 0]);
        fw.on_frame(t, &run_mode(2), &plant).unwrap();
        let read = fw
            .on_frame(t, &robstride::read_param(4, host, param::RUN_MODE), &plant)
            .unwrap();
        assert_eq!(
            robstride::param_of(read.data()),
            Some((param::RUN_MODE, [0, 0, 0, 0]))
        );
        // A torque limit below the model's clamps the law.
        let limit = robstride::write_param(4, host, param::LIMIT_TORQUE, 5.0f32.to_le_bytes());
        fw.on_frame(t, &limit, &plant).unwrap();
        let step = MitCommand {
            p: 1.0,
            kp: 500.0,
            kd: 5.0,
            ..MitCommand::default()
        };
        fw.on_frame(t, &robstride::pack_control(model, 4, &step).unwrap(), &plant)
            .unwrap();
        fw.tick(t, DT, &mut plant);
        assert!((fw.torque() - 5.0).abs() < 1e-9, "{}", fw.torque());
        for _ in 0..2000 {
            let f = robstride::pack_control(model, 4, &MitCommand { kp: 50.0, ..step }).unwrap();
            fw.on_frame(t, &f, &plant);
            fw.tick(t, DT, &mut plant);
            plant.integrate(DT.as_secs_f64());
            t = t + DT;
        }
        let hold = robstride::pack_control(model, 4, &MitCommand { kp: 50.0, ..step }).unwrap();
        let r = feedback(&fw.on_frame(t, &hold, &plant).unwrap());
        assert!((r.p - 1.0).abs() < 0.01, "{r:?}");
        let vbus = fw
            .on_frame(t, &robstride::read_param(4, host, param::VBUS), &plant)
            .unwrap();
        assert_eq!(
            robstride::param_of(vbus.data()),
            Some((param::VBUS, 48.0f32.to_le_bytes()))
        );
        let pos = fw
            .on_frame(t, &robstride::read_param(4, host, param::MECH_POS), &plant)
            .unwrap();
        let pos = f32::from_le_bytes(robstride::param_of(pos.data()).unwrap().1);
        assert!((f64::from(pos) - r.p).abs() < 1e-3, "{pos}");
        // An unknown index is answered with bit 16 set.
        let unknown = fw
            .on_frame(t, &robstride::read_param(4, host, 0x7FFF), &plant)
            .unwrap();
        assert_eq!(
            robstride::split_id(unknown.id()).map(|(_, d2, _)| d2 >> 8),
            Some(1)
        );
        // Get ID: type 0 to 0xFE, the motor ID in data2.
        let id = fw
            .on_frame(
                t,
                &CanFrame::new8(robstride::frame_id(comm::GET_ID, u16::from(host), 4), [0; 8]),
                &plant,
            )
            .unwrap();
        assert_eq!(robstride::split_id(id.id()), Some((comm::GET_ID, 4, 0xFE)));
        // An overheated motor reports it in the ID; stop with data[0] = 1 clears it once cool.
        fw.inject(InjectedFaults {
            fault: Some(MotorFault::OverTemperature),
            ..InjectedFaults::default()
        });
        fw.tick(t, DT, &mut plant);
        let r = feedback(
            &fw.on_frame(t, &robstride::special(SpecialFrame::Enable, 4, host), &plant)
                .unwrap(),
        );
        assert_eq!((r.fault, r.enabled), (MotorFault::OverTemperature, Some(false)));
        fw.inject(InjectedFaults::default());
        let stop = CanFrame::new8(
            robstride::frame_id(comm::STOP, u16::from(host), 4),
            [1, 0, 0, 0, 0, 0, 0, 0],
        );
        let r = feedback(&fw.on_frame(t, &stop, &plant).unwrap());
        assert_eq!(r.fault, MotorFault::None);
    }
}
