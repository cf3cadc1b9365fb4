//! Dynamixel X-series models as data (`data/dxl_models.toml`) and the unit conversions of the
//! control table.

use std::collections::BTreeMap;
use std::f64::consts::TAU;
use std::sync::OnceLock;

/// Encoder ticks per output revolution.
pub const TICKS_PER_REV: f64 = 4096.0;
/// One unit of Present/Goal Velocity, rpm.
pub const VELOCITY_UNIT_RPM: f64 = 0.229;
/// One unit of Present/Goal Current, A.
pub const CURRENT_UNIT_A: f64 = 2.69e-3;
/// Goal PWM / PWM Limit value for 100 % duty.
pub const PWM_FULL_SCALE: f64 = 885.0;

/// Radians per encoder tick.
pub const fn rad_per_tick() -> f64 {
    TAU / TICKS_PER_REV
}

/// rad/s per velocity unit.
pub fn rad_s_per_velocity_unit() -> f64 {
    VELOCITY_UNIT_RPM * TAU / 60.0
}

/// One servo model: identity, factory defaults and the motor constants the emulator uses.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct DxlModel {
    /// Model name, e.g. `XM430-W350` (the table key).
    #[serde(skip)]
    pub name: String,
    /// Model Number (address 0), answered to ping.
    pub model_number: u16,
    /// Firmware Version (address 6).
    pub firmware_version: u8,
    /// Whether the servo measures current (XM) or only reports load (XL).
    pub current_sensing: bool,
    /// Supply voltage the constants refer to, V.
    pub nominal_voltage: f64,
    /// Output torque at stall, N·m.
    pub stall_torque: f64,
    /// Current at stall, A.
    pub stall_current: f64,
    /// Output speed without load, rpm.
    pub no_load_speed: f64,
    /// Factory PWM Limit (36).
    pub pwm_limit: u16,
    /// Factory Current Limit (38), 2.69 mA units; 0 where the model has none.
    pub current_limit: u16,
    /// Factory Velocity Limit (44), 0.229 rpm units.
    pub velocity_limit: u32,
    /// Factory Temperature Limit (31), °C.
    pub temperature_limit: u8,
    /// Factory position P, I, D gains (84, 82, 80).
    pub position_gains: [u16; 3],
    /// Factory velocity P, I gains (78, 76).
    pub velocity_gains: [u16; 2],
}

impl DxlModel {
    /// The servo's motor as the data sheet describes it.
    pub fn motor(&self) -> crate::plant::DcMotor {
        crate::plant::DcMotor {
            nominal_voltage: self.nominal_voltage,
            stall_torque: self.stall_torque,
            stall_current: self.stall_current,
            no_load_speed: self.no_load_speed * TAU / 60.0,
        }
    }

    /// Torque constant, N·m/A.
    pub fn torque_constant(&self) -> f64 {
        self.motor().torque_constant()
    }

    /// Winding resistance, Ω.
    pub fn resistance(&self) -> f64 {
        self.motor().resistance()
    }

    /// Back-EMF constant at the output, V·s/rad.
    pub fn back_emf(&self) -> f64 {
        self.motor().back_emf()
    }
}

/// Why a servo model table did not load.
#[derive(Debug, thiserror::Error)]
#[error("servo model table {source_name}: {reason}")]
pub struct DxlModelTableError {
    /// The file the table came from.
    pub source_name: String,
    /// What is wrong, naming the model and field.
    pub reason: String,
}

/// Parses a servo model table (the format of `data/dxl_models.toml`).
pub fn parse_table(source_name: &str, text: &str) -> Result<Vec<DxlModel>, DxlModelTableError> {
    let err = |reason: String| DxlModelTableError {
        source_name: source_name.to_owned(),
        reason,
    };
    let table: BTreeMap<String, DxlModel> = toml::from_str(text).map_err(|e| err(e.to_string()))?;
    let mut models = Vec::with_capacity(table.len());
    for (name, mut m) in table {
        crate::plant::check_motor_figures(
            &name,
            [
                ("nominal_voltage", m.nominal_voltage),
                ("stall_torque", m.stall_torque),
                ("stall_current", m.stall_current),
                ("no_load_speed", m.no_load_speed),
            ],
        )
        .map_err(|e| err(e.to_string()))?;
        if f64::from(m.pwm_limit) > PWM_FULL_SCALE {
            return Err(err(format!(
                "[{name}] pwm_limit = {}: at most {PWM_FULL_SCALE}",
                m.pwm_limit
            )));
        }
        if m.current_sensing == (m.current_limit == 0) {
            return Err(err(format!(
                "[{name}] current_limit = {}: must be > 0 exactly when current_sensing is true",
                m.current_limit
            )));
        }
        m.name = name;
        models.push(m);
    }
    Ok(models)
}

/// The built-in models (XM430-W350, XL430-W250).
pub fn builtin() -> &'static [DxlModel] {
    static MODELS: OnceLock<Vec<DxlModel>> = OnceLock::new();
    MODELS.get_or_init(|| {
        parse_table(
            "firmware-bridge/data/dxl_models.toml",
            include_str!("../../data/dxl_models.toml"),
        )
        .expect("the built-in servo table is valid (checked by a unit test)")
    })
}

/// A built-in model by name.
pub fn find(name: &str) -> Option<&'static DxlModel> {
    builtin().iter().find(|m| m.name == name)
}

/// A built-in model by the number it answers to ping.
pub fn find_by_number(model_number: u16) -> Option<&'static DxlModel> {
    builtin().iter().find(|m| m.model_number == model_number)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_models_carry_the_manual_numbers() {
        let xm = find("XM430-W350").unwrap();
        assert_eq!((xm.model_number, xm.position_gains[0]), (1020, 800));
        assert_eq!(find("XL430-W250").unwrap().model_number, 1060);
        assert_eq!(find_by_number(1060).unwrap().name, "XL430-W250");
        // 4.1 N·m / 2.3 A, 12 V / 2.3 A.
        assert!((xm.torque_constant() - 1.7826).abs() < 1e-3);
        assert!((xm.resistance() - 5.217).abs() < 1e-3);
        assert!((rad_per_tick() * 4096.0 - TAU).abs() < 1e-12);
    }

    #[test]
    fn bad_tables_name_model_and_field() {
        let text =
            include_str!("../../data/dxl_models.toml").replace("stall_current = 2.3", "stall_current = -1");
        let e = parse_table("t.toml", &text).unwrap_err().to_string();
        assert!(
            e.contains("t.toml") && e.contains("[XM430-W350] stall_current = -1"),
            "{e}"
        );
        let text =
            include_str!("../../data/dxl_models.toml").replace("current_limit = 1193", "current_limit = 0");
        let e = parse_table("t.toml", &text).unwrap_err().to_string();
        assert!(e.contains("current_limit = 0"), "{e}");
    }
}
