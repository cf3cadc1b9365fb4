//! Feetech servo models as data: `data/feetech_models.toml`.

use std::collections::BTreeMap;
use std::sync::OnceLock;

/// One model.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FeetechModel {
    /// The table key, e.g. `STS3215`.
    #[serde(skip)]
    pub name: String,
    /// Model number (address 3).
    pub model_number: u16,
    /// Firmware major and minor versions (addresses 0, 1).
    pub firmware: [u8; 2],
    /// Supply voltage the figures refer to, V.
    pub nominal_voltage: f64,
    /// Output torque at stall, N·m.
    pub stall_torque: f64,
    /// Current at stall, A.
    pub stall_current: f64,
    /// Output speed without load, rad/s.
    pub no_load_speed: f64,
    /// Factory maximum input voltage (address 14), 0.1 V.
    pub max_voltage: u8,
    /// Factory minimum input voltage (address 15), 0.1 V.
    pub min_voltage: u8,
}

impl FeetechModel {
    /// The servo's motor.
    pub fn motor(&self) -> crate::plant::DcMotor {
        crate::plant::DcMotor {
            nominal_voltage: self.nominal_voltage,
            stall_torque: self.stall_torque,
            stall_current: self.stall_current,
            no_load_speed: self.no_load_speed,
        }
    }
}

/// Why a model table did not load.
#[derive(Debug, thiserror::Error)]
#[error("Feetech model table {source_name}: {reason}")]
pub struct FeetechModelTableError {
    /// The file.
    pub source_name: String,
    /// What is wrong, naming the model and field.
    pub reason: String,
}

/// Parses a model table, checking every figure.
pub fn parse_table(source_name: &str, text: &str) -> Result<Vec<FeetechModel>, FeetechModelTableError> {
    let err = |reason: String| FeetechModelTableError {
        source_name: source_name.to_owned(),
        reason,
    };
    let table: BTreeMap<String, FeetechModel> = toml::from_str(text).map_err(|e| err(e.to_string()))?;
    let mut out = Vec::with_capacity(table.len());
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
        if m.min_voltage >= m.max_voltage {
            return Err(err(format!("[{name}] min_voltage must be below max_voltage")));
        }
        m.name = name;
        out.push(m);
    }
    Ok(out)
}

/// The built-in models.
pub fn builtin() -> &'static [FeetechModel] {
    static MODELS: OnceLock<Vec<FeetechModel>> = OnceLock::new();
    MODELS.get_or_init(|| {
        parse_table(
            "firmware-bridge/data/feetech_models.toml",
            include_str!("../../data/feetech_models.toml"),
        )
        .expect("the built-in Feetech table is valid (checked by a unit test)")
    })
}

/// A built-in model by name.
pub fn find(name: &str) -> Option<&'static FeetechModel> {
    builtin().iter().find(|m| m.name == name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_table_loads_and_bad_figures_are_named() {
        let sts = find("STS3215").unwrap();
        assert_eq!(sts.model_number, 777);
        assert!((sts.motor().torque_constant() - 1.91 / 2.7).abs() < 1e-12);
        assert!(find("STS3215-12V").is_some());
        let e = parse_table(
            "m.toml",
            "[X]\nmodel_number=1\nfirmware=[1,0]\nnominal_voltage=7\nstall_torque=0\nstall_current=1\nno_load_speed=1\nmax_voltage=80\nmin_voltage=40\n",
        )
        .unwrap_err();
        assert!(e.to_string().contains("[X] stall_torque = 0"), "{e}");
    }
}
