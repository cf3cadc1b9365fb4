//! A robot's joints as the bus drivers of `firmware-bridge` want them.

use firmware_bridge::dxl::driver::{DxlJointConfig, DxlMode};
use firmware_bridge::dxl::models as dxl_models;
use firmware_bridge::feetech::{self, driver::FeetechJointConfig};
use firmware_bridge::mit::driver::MitJointConfig;

use crate::config::JointConfig;

/// The MIT driver's view of a joint of `robot` on an `mit_can` bus.
///
/// # Panics
/// When the joint's model is not an MIT motor (loading a [`crate::Robot`] checks this).
pub fn mit_joint(robot: &crate::Robot, j: &JointConfig) -> MitJointConfig {
    let model = robot
        .mit_model(&j.model)
        .expect("an MIT-mode motor (checked at load)");
    let mut c = MitJointConfig::new(&j.name, j.id, model);
    c.direction = j.direction;
    c.offset = j.zero_offset;
    c.gear_ratio = j.gear;
    // Below the motor's own range, the joint's limit is the motor's (where its protocol has one).
    let at_motor = j.torque_limit / j.gear;
    c.torque_limit = (at_motor < model.t_max).then_some(at_motor);
    c
}

/// The Feetech driver's view of a joint of `robot` on a `feetech` bus: zero at the middle of the
/// range shifted by the joint's zero offset, the policy's stiffness and damping as the servo's P
/// and D, its torque limit as the servo's Torque Limit. Direct drive only, as with Dynamixel.
///
/// # Panics
/// When the joint's model is not a Feetech servo (loading a [`crate::Robot`] checks this).
pub fn feetech_joint(robot: &crate::Robot, j: &JointConfig) -> FeetechJointConfig {
    let model = robot
        .feetech_model(&j.model)
        .expect("a Feetech servo (checked at load)");
    FeetechJointConfig {
        direction: j.direction,
        zero_ticks: 2048.0 + j.zero_offset / feetech::table::rad_per_tick(),
        homing_offset: j.homing_offset_ticks,
        gains: Some(feetech::driver::gains_for(j.kp, j.kd, model)),
        torque_limit: Some(feetech::driver::torque_limit_for(j.torque_limit, model)),
        ..FeetechJointConfig::new(&j.name, j.id, model)
    }
}

/// The Dynamixel driver's view of a joint of `robot` on a `dynamixel` bus. Direct drive only: the servo's
/// own position loop runs in servo ticks, so a gear between servo and joint is folded into the
/// joint's limits by the robot file, not here. Servos that sense current run current-based
/// position control, so the goal current caps their torque at the joint's limit
/// ([`goal_current_for`]); the others run plain position control under a PWM Limit that caps
/// their stall torque at the joint's limit ([`pwm_limit_for`]).
///
/// # Panics
/// When the joint's model is not a Dynamixel servo (loading a [`crate::Robot`] checks this).
pub fn dxl_joint(robot: &crate::Robot, j: &JointConfig) -> DxlJointConfig {
    let model = robot
        .dxl_model(&j.model)
        .expect("a Dynamixel servo (checked at load)");
    // The bus knows it by the shipped model it speaks as; its constants are the variant's.
    let mut c = DxlJointConfig::new(&j.name, j.id, robot.dxl_protocol_model(&j.model));
    if model.name != c.model {
        c.constants = Some(model.clone());
    }
    c.direction = j.direction;
    c.zero_ticks = 2048.0 + j.zero_offset / dxl_models::rad_per_tick();
    c.homing_offset = j.homing_offset_ticks;
    c.position_gains = Some(position_gains_for(j.kp, j.kd, model));
    if model.current_sensing {
        c.mode = DxlMode::CurrentBasedPosition;
    } else {
        c.pwm_limit = Some(pwm_limit_for(j.torque_limit, model));
    }
    c
}

/// The PWM Limit that caps the stall torque of a servo without current sensing at `torque`
/// (N·m): at stall the winding current, and so the torque, is proportional to the duty. Rounded
/// down so the cap stays at or under the limit; at least 1 (0 would disable the servo).
pub fn pwm_limit_for(torque: f64, model: &dxl_models::DxlModel) -> u16 {
    let duty = torque.abs() / model.stall_torque * dxl_models::PWM_FULL_SCALE;
    duty.floor().clamp(1.0, f64::from(model.pwm_limit)) as u16
}

/// The goal current (A) that caps a current-sensing servo's torque at `torque` (N·m), within the
/// model's current limit.
pub fn goal_current_for(torque: f64, model: &dxl_models::DxlModel) -> f64 {
    let max = f64::from(model.current_limit) * dxl_models::CURRENT_UNIT_A;
    (torque.abs() / model.torque_constant()).min(max)
}

/// Position P and D gains of a servo that give roughly stiffness `kp` (N·m/rad) and damping `kd`
/// (N·m·s/rad) at the joint, at nominal voltage: the firmware's PWM per tick of error is P/128
/// (D/16 per tick per control period of 1 ms), and PWM turns into stall torque linearly.
pub fn position_gains_for(kp: f64, kd: f64, model: &dxl_models::DxlModel) -> [u16; 3] {
    let stall_torque_per_pwm = model.stall_torque / dxl_models::PWM_FULL_SCALE;
    let per_tick = dxl_models::rad_per_tick();
    let p = kp * per_tick / stall_torque_per_pwm * 128.0;
    let d = kd * per_tick / 1e-3 / stall_torque_per_pwm * 16.0;
    [
        p.round().clamp(0.0, 16383.0) as u16,
        0,
        d.round().clamp(0.0, 16383.0) as u16,
    ]
}
