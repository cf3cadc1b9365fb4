//! The robot zoo: test robots the project makes from rd-mini's geometry, with the physical
//! properties of robots users bring (issue 50), none of them tuned on. Each is written into a
//! directory of its own (the MJCF, its scene and meshes beside a robot.toml) and walks on rd-mini's
//! walking fixture (`robots/mini/policies/walk.toml`). None has foot switches: contacts come from
//! the estimator.
//!
//! - `mini`: rd-mini on its Dynamixel servos (2.5 kg), its foot switches taken off.
//! - `feetech-biped`: the same on Feetech STS3215 servos, whose load reads in coarse steps.
//! - `mit-biped`: 11.2 kg (every body 4.4 × heavier, the same size) on low-torque MIT-mode CAN
//!   motors of ±10 N·m whose trainer clipped the PD torque at 5 N·m every physics step
//!   (`explicit_pd`, the model's actuators plain motors), the gains 4.4 × rd-mini's.

use std::path::{Path, PathBuf};

use crate::fixtures::workspace_root;

/// A zoo robot's name and what it stands for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ZooRobot {
    Mini,
    FeetechBiped,
    MitBiped,
}

impl ZooRobot {
    pub const ALL: [ZooRobot; 3] = [ZooRobot::Mini, ZooRobot::FeetechBiped, ZooRobot::MitBiped];

    pub fn name(self) -> &'static str {
        match self {
            ZooRobot::Mini => "mini",
            ZooRobot::FeetechBiped => "feetech-biped",
            ZooRobot::MitBiped => "mit-biped",
        }
    }

    /// Writes the robot into `dir/<name>/` and returns its robot.toml.
    pub fn write(self, dir: &Path) -> PathBuf {
        let mini = workspace_root().join("robots/mini");
        let out = dir.join(self.name());
        std::fs::create_dir_all(out.join("meshes")).unwrap();
        for file in ["scene.xml", "mini.xml"] {
            std::fs::copy(mini.join(file), out.join(file)).unwrap();
        }
        for mesh in std::fs::read_dir(mini.join("meshes")).unwrap() {
            let mesh = mesh.unwrap().path();
            std::fs::copy(&mesh, out.join("meshes").join(mesh.file_name().unwrap())).unwrap();
        }
        let toml = without_switches(&std::fs::read_to_string(mini.join("robot.toml")).unwrap());
        let toml = match self {
            ZooRobot::Mini => toml,
            ZooRobot::FeetechBiped => on_feetech(&toml),
            ZooRobot::MitBiped => {
                let mjcf = std::fs::read_to_string(mini.join("mini.xml")).unwrap();
                std::fs::write(out.join("mini.xml"), heavy_on_motors(&mjcf, 4.4)).unwrap();
                on_low_torque_mit(&toml, 4.4)
            }
        };
        let path = out.join("robot.toml");
        std::fs::write(&path, toml).unwrap();
        path
    }

    /// The policy the zoo robots walk on.
    pub fn walking_policy() -> PathBuf {
        workspace_root().join("robots/mini/policies/walk.toml")
    }
}

/// robot.toml text without its `[[contacts]]` tables.
fn without_switches(text: &str) -> String {
    let mut out = String::new();
    let mut skipping = false;
    for line in text.lines() {
        if line.starts_with('[') {
            skipping = line == "[[contacts]]";
        }
        if !skipping {
            out.push_str(line);
            out.push('\n');
        }
    }
    out
}

/// rd-mini's file with every servo swapped for a Feetech STS3215 (12 V) on a 1 Mbit/s line, its
/// speed and torque limits brought within the servo's.
pub fn on_feetech(text: &str) -> String {
    let mut s = text
        .replace("kind = \"dynamixel\"", "kind = \"feetech\"")
        .replace("rate = 4000000", "rate = 1000000")
        .replace("fast_reads = true\n", "")
        .replace("velocity_limit = 6.0", "velocity_limit = 4.5")
        .replace("torque_limit = 3.5", "torque_limit = 2.9");
    for m in ["XL430-W250", "XM430-W350"] {
        s = s.replace(&format!("model = \"{m}\""), "model = \"STS3215-12V\"");
    }
    s
}

/// rd-mini's MJCF with every mass `scale` × and its position servos replaced by plain motors.
fn heavy_on_motors(mjcf: &str, scale: f64) -> String {
    let mut out = String::new();
    let mut rest = mjcf;
    while let Some(at) = rest.find("mass=\"") {
        let (head, tail) = rest.split_at(at + 6);
        let end = tail.find('"').unwrap();
        let mass: f64 = tail[..end].parse().unwrap();
        out.push_str(head);
        out.push_str(&format!("{}", mass * scale));
        rest = &tail[end..];
    }
    out.push_str(rest);
    out.lines()
        .map(|line| {
            // An actuator (not a default class's settings) names its joint.
            let joint = line
                .trim_start()
                .strip_prefix("<position ")
                .and_then(|attrs| attrs.split("joint=\"").nth(1))
                .and_then(|rest| rest.split('"').next());
            match joint {
                Some(joint) => {
                    format!("    <motor name=\"{joint}\" joint=\"{joint}\" ctrlrange=\"-10 10\"/>")
                }
                None => line.to_owned(),
            }
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// rd-mini's file on one MIT-mode CAN bus of ±10 N·m motors, every joint's torque clipped at
/// 5 N·m by the trainer's per-step PD law, the gains `scale` × (as heavy as the bodies).
fn on_low_torque_mit(text: &str, scale: f64) -> String {
    let mut out = String::new();
    for line in text.lines() {
        let line = if let Some(v) = line.strip_prefix("kp = ") {
            format!("kp = {}", v.parse::<f64>().unwrap() * scale)
        } else if let Some(v) = line.strip_prefix("kd = ") {
            format!("kd = {}", v.parse::<f64>().unwrap() * scale)
        } else if line.starts_with("torque_limit = ") {
            "torque_limit = 5.0".to_owned()
        } else if line.starts_with("model = \"X") {
            "model = \"ZOO-10NM\"".to_owned()
        } else if line == "kind = \"dynamixel\"" {
            "kind = \"mit_can\"".to_owned()
        } else if line == "device = \"/dev/ttyUSB0\"" {
            "device = \"can0\"".to_owned()
        } else if line == "rate = 4000000" {
            "rate = 1000000".to_owned()
        } else if line == "fast_reads = true" || line.starts_with("# One status packet") {
            continue;
        } else {
            line.to_owned()
        };
        out.push_str(&line);
        out.push('\n');
    }
    out.replacen(
        "[[buses]]",
        "[[actuators]]\njoints = [\"*\"]\nmodel = \"explicit_pd\"\n\n\
         [[mit_models]]\nname = \"ZOO-10NM\"\nreply = \"damiao\"\nposition = [-12.5, 12.5]\n\
         velocity = [-30.0, 30.0]\ntorque = [-10.0, 10.0]\nkp = [0.0, 500.0]\nkd = [0.0, 5.0]\n\
         rated_torque = 5.0\n\n[[buses]]",
        1,
    )
}
