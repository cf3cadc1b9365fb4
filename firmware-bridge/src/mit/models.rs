//! MIT-mode motor models as data: field ranges and reply format per model, from
//! `data/mit_motors.toml` (built in) or a user's own file.

use std::collections::BTreeMap;
use std::sync::OnceLock;

/// How a motor family lays out its reply frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MotorFamily {
    /// CubeMars AK series: `[id, p16, v12|i12, temperature, error]`, sent with the host's ID 0.
    Cubemars,
    /// DaMiao DM-J series: `[error<<4|id, p16, v12|t12, T_mos, T_rotor]`, sent to the master ID.
    Damiao,
    /// Original Mini Cheetah firmware: 6 bytes `[id, p16, v12|i12]`.
    MiniCheetah,
    /// Robstride RS0x in the factory protocol: 29-bit IDs carrying the frame type, 16-bit fields
    /// (see [`super::robstride`]); state frames go to the host's ID.
    Robstride,
}

impl MotorFamily {
    /// The CAN ID a motor of this family replies on by default: CubeMars and Mini Cheetah answer
    /// the host on ID 0; DaMiao answers on its master ID, commonly set to motor ID + 0x10;
    /// Robstride addresses its state frames to the host ID the factory tools use, 0xFD.
    pub const fn default_reply_id(self, motor_id: u8) -> u16 {
        match self {
            Self::Damiao => motor_id as u16 + 0x10,
            Self::Cubemars | Self::MiniCheetah => 0,
            Self::Robstride => super::robstride::DEFAULT_HOST_ID as u16,
        }
    }
}

/// One motor model: the ranges its 16/12-bit command and reply fields map onto.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct MotorModel {
    /// The model's name, e.g. `AK80-9` (filled from the table key).
    #[serde(skip)]
    pub name: String,
    /// Reply format.
    pub family: MotorFamily,
    /// Position range ±p_max, rad.
    pub p_max: f64,
    /// Velocity range ±v_max, rad/s.
    pub v_max: f64,
    /// Torque range ±t_max, N·m (also the firmware's torque clamp).
    pub t_max: f64,
    /// Stiffness range 0..kp_max.
    pub kp_max: f64,
    /// Damping range 0..kd_max.
    pub kd_max: f64,
    /// Continuous torque the motor sustains without overheating, N·m.
    pub rated_torque: f64,
}

/// Why a motor table did not load.
#[derive(Debug, thiserror::Error)]
#[error("motor table {source_name}: {reason}")]
pub struct MotorTableError {
    /// The file the table came from.
    pub source_name: String,
    /// What is wrong, naming the model and field.
    pub reason: String,
}

/// Parses a motor table (the format of `data/mit_motors.toml`), validating every range.
pub fn parse_table(source_name: &str, text: &str) -> Result<Vec<MotorModel>, MotorTableError> {
    let err = |reason: String| MotorTableError {
        source_name: source_name.to_owned(),
        reason,
    };
    let table: BTreeMap<String, MotorModel> = toml::from_str(text).map_err(|e| err(e.to_string()))?;
    let mut models = Vec::with_capacity(table.len());
    for (name, mut m) in table {
        for (field, v) in [
            ("p_max", m.p_max),
            ("v_max", m.v_max),
            ("t_max", m.t_max),
            ("kp_max", m.kp_max),
            ("kd_max", m.kd_max),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(err(format!("[{name}] {field} = {v}: must be a positive number")));
            }
        }
        if !(m.rated_torque > 0.0 && m.rated_torque <= m.t_max) {
            return Err(err(format!(
                "[{name}] rated_torque = {}: must be in (0, t_max = {}]",
                m.rated_torque, m.t_max
            )));
        }
        m.name = name;
        models.push(m);
    }
    Ok(models)
}

/// The built-in models (AK80-9, AK10-9, DM-J4310, DM-J4340).
pub fn builtin() -> &'static [MotorModel] {
    static MODELS: OnceLock<Vec<MotorModel>> = OnceLock::new();
    MODELS.get_or_init(|| {
        parse_table(
            "firmware-bridge/data/mit_motors.toml",
            include_str!("../../data/mit_motors.toml"),
        )
        .expect("the built-in motor table is valid (checked by a unit test)")
    })
}

/// A built-in model by name.
pub fn find(name: &str) -> Option<&'static MotorModel> {
    builtin().iter().find(|m| m.name == name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_table_has_the_four_models_with_the_vendor_ranges() {
        let ak80 = find("AK80-9").unwrap();
        assert_eq!(
            (ak80.p_max, ak80.v_max, ak80.t_max, ak80.family),
            (12.5, 25.64, 18.0, MotorFamily::Cubemars)
        );
        assert_eq!(
            (find("AK10-9").unwrap().v_max, find("AK10-9").unwrap().t_max),
            (50.0, 65.0)
        );
        assert_eq!(
            (find("DM-J4310").unwrap().v_max, find("DM-J4310").unwrap().t_max),
            (30.0, 10.0)
        );
        assert_eq!(
            (find("DM-J4340").unwrap().v_max, find("DM-J4340").unwrap().t_max),
            (8.0, 28.0)
        );
        assert!(find("AK00-0").is_none());
    }

    #[test]
    fn bad_tables_name_model_and_field() {
        let e = parse_table(
            "m.toml",
            "[X]\nfamily='damiao'\np_max=0\nv_max=1\nt_max=1\nkp_max=1\nkd_max=1\nrated_torque=1\n",
        )
        .unwrap_err();
        assert!(e.to_string().contains("[X] p_max = 0"), "{e}");
        let e = parse_table("m.toml", "[X]\nfamily='nope'\n").unwrap_err();
        assert!(e.to_string().contains("m.toml"), "{e}");
    }
}
